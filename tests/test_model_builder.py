"""model_builder: one table of lumped <-> physical maps read both ways, one term builder.

The reference is the energy model (docs/guide/range.md) written out by hand from the scenario mapping (no package code):
``Omega = (1 - eta_2)(1 - eta_3)``, ``ancillary_W = (s0 + compute + comm) / (1 - eta_4)``...
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from conftest import scenario_dict, write_map
from hypothesis import given, settings
from hypothesis import strategies as st

from orange_plan.errors import InputError
from orange_plan.physics.model_builder import (
    LUMPED,
    build_model,
    is_mass_coefficient,
    make_term,
    model_with_terms,
    physical_values,
)
from orange_plan.physics.terms import TERMS
from orange_plan.scenario import scenario_from_dict

positive = st.floats(0.01, 100.0)


@pytest.fixture(scope="module")
def where(tmp_path_factory):
    """A scenario path next to the yard map (scenarios are validated, not read, here)."""
    folder = tmp_path_factory.mktemp("builder")
    write_map(folder)
    return folder / "prop.toml"
fraction = st.floats(0.0, 0.6)


@st.composite
def physical(draw):
    return {
        "robot.mass_kg": draw(positive), "robot.drag_coeff_kg_per_m": draw(st.floats(0.0, 2.0)),
        "robot.turn_coeff_W_s_per_rad": draw(st.floats(0.0, 20.0)),
        "robot.hover_W": draw(st.floats(0.0, 200.0)), "losses.motor": draw(fraction),
        "losses.mechanical": draw(fraction), "losses.ancillary": draw(fraction),
        "ancillary.s0_W": draw(st.floats(0.0, 50.0)), "ancillary.s1_W_per_Hz": draw(
            st.floats(0.0, 1.0)), "ancillary.compute_W": draw(st.floats(0.0, 50.0)),
        "ancillary.comm_W": draw(st.floats(0.0, 5.0)),
    }


def by_hand(v: dict) -> tuple[dict, dict]:
    """Lumped coefficients and their physical readings, the energy model by hand."""
    omega = (1 - v["losses.motor"]) * (1 - v["losses.mechanical"])
    keep = 1 - v["losses.ancillary"]
    load = v["ancillary.s0_W"] + v["ancillary.compute_W"] + v["ancillary.comm_W"]
    m = v["robot.mass_kg"]
    lumped = {"ancillary_W": load / keep, "sensor_W_per_Hz": v["ancillary.s1_W_per_Hz"] / keep,
              "hover_W": v["robot.hover_W"], "rolling_kg": m / omega,
              "drag_kg_per_m": v["robot.drag_coeff_kg_per_m"] / omega, "grade_kg": m / omega,
              "turn_J_per_rad": v["robot.turn_coeff_W_s_per_rad"]}
    readings = {"ancillary_load_W": load, "ancillary.s1_W_per_Hz": v["ancillary.s1_W_per_Hz"],
                "robot.hover_W": v["robot.hover_W"], "crr_factor": 1.0,
                "robot.drag_coeff_kg_per_m": v["robot.drag_coeff_kg_per_m"],
                "mass_from_grade_kg": m,
                "robot.turn_coeff_W_s_per_rad": v["robot.turn_coeff_W_s_per_rad"]}
    return lumped, readings


@settings(max_examples=60, deadline=None)
@given(values=physical(), scale=st.floats(0.2, 5.0))
def test_lumped_and_physical_maps_agree_with_spec_both_ways(where, values, scale):
    sc = scenario_from_dict(scenario_dict(values), where)
    model = build_model(sc)
    lumped, readings = by_hand(values)
    have = model.as_dict()
    for name, value in lumped.items():
        if name in have:
            assert have[name] == pytest.approx(value, rel=1e-12, abs=1e-12), name
    read = physical_values(sc, model)
    for key, value in readings.items():
        if key in read:
            assert read[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key
    # backwards on fitted values: every reading scales with its coefficient
    fitted = physical_values(sc, model.with_theta({n: v * scale for n, v in have.items()}))
    for key, value in read.items():
        assert fitted[key] == pytest.approx(value * scale, rel=1e-12, abs=1e-12), key


@settings(max_examples=30, deadline=None)
@given(values=physical(), extra=st.sets(st.sampled_from(
    ["inertia", "regen", "rolling_torque", "turning_torque", "drift", "surface_rolling"])))
def test_model_with_terms_equals_the_scenario_built_with_those_terms(where, values, extra):
    """Calibration's term list and the scenario loader build the same coefficients and prior."""
    sc = scenario_from_dict(scenario_dict(values), where)
    surfaces = ("grass", "gravel")
    loaded = build_model(sc, surfaces, extra_terms=sorted(extra))
    ctx = SimpleNamespace(model=build_model(sc, surfaces), scenario=sc,
                          world=SimpleNamespace(map=SimpleNamespace(surface_names=surfaces)))
    built = model_with_terms(ctx, loaded.term_ids)
    assert built.names == loaded.names
    np.testing.assert_array_equal(built.theta, loaded.theta)
    np.testing.assert_array_equal(np.diag(built.cov), np.diag(loaded.cov))


def test_every_vocabulary_coefficient_has_one_row():
    names = {c for t in TERMS.values() for c in t.coefficients}
    assert names == set(LUMPED)
    assert is_mass_coefficient("rolling_kg_grass") and is_mass_coefficient("grade_kg")
    assert not is_mass_coefficient("drag_kg_per_m") and not is_mass_coefficient("nonsense")


def test_make_term_names_the_problem():
    with pytest.raises(InputError, match=r"unknown term 'hvca'.*did you mean 'hvac'"):
        make_term("hvca", ())
    with pytest.raises(InputError, match="surface_rolling' needs surfaces"):
        make_term("surface_rolling", ())
