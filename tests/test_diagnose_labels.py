"""Diagnosis reads a recording's ``surface`` labels where the map has no surfaces: per-surface
rolling from a terrain classifier's labels, delayed and sometimes wrong
(``identify.diagnose.label_lag``, ``sim.concealed`` case ``surface_label``)."""

from __future__ import annotations

import numpy as np
import pytest

from orange_plan.context import load_context
from orange_plan.identify.diagnose import diagnose
from orange_plan.sim.concealed import concealed_case


@pytest.fixture(scope="module", params=[0, 1])
def labelled(request):
    case = concealed_case(["surface_label"], request.param)
    return case, diagnose(case.recording, case.ctx)


def test_a_rolling_that_differs_by_surface_is_found_from_the_labels(labelled):
    """The map handed over has no surfaces; the recording's labels lag the ground by
    0.5-3 s and are wrong on 2-8 % of the samples. The per-label rolling is found (before
    the labels were read nothing was named on either seed: the best candidates were pairs,
    battery_resistance + regen at 0.9 % held out, payload + hvac_ambient at t = 2.8)."""
    case, result = labelled
    assert [(f.term, f.variant) for f in result.findings] == [("surface_rolling",
                                                               "surface_label")]
    found = result.findings[0]
    truth = case.truth["surface_label"]
    assert found.params["label_lag_s"] == pytest.approx(
        truth["label_lag_s"], abs=max(3 * found.stderr["label_lag_s"], 0.3))
    for name, value in found.params.items():
        if name == "label_lag_s":
            continue
        # what the labels' majority leaves of their slips pulls each label's coefficient
        # towards the others' (errors in the regressor), which the standard error omits
        assert value == pytest.approx(truth[name], rel=0.15), (name, value, truth[name])
    assert result.improved.cv_rmse_W < 0.8 * result.baseline.cv_rmse_W
    assert result.model.term_ids == result.design.base.term_ids  # no surfaces to write to


def test_labels_that_carry_nothing_add_no_term():
    """Every surface rolls as the default ground: the labels, lagged and noisy as above,
    must not be taken for a surface effect."""
    case = concealed_case((), 0, kind="ground", labels=True)
    assert case.name == "null-ground-labels/seed0"
    result = diagnose(case.recording, case.ctx)
    assert result.findings == []
    assert any(t.id == "surface_label" for t in result.trials)  # it was tried


def test_a_labelled_case_hands_over_a_map_without_surfaces(tmp_path):
    case = concealed_case(["surface_label"], 3, duration_s=120.0)
    assert case.ctx.world.true_map.surfaces == ()
    labels = case.frame["surface"].to_numpy(str)
    assert set(labels) <= {"asphalt", "paving", "lawn"} and len(set(labels)) >= 2
    assert 0.5 <= case.truth["surface_label"]["label_lag_s"] <= 3.0
    scenario, recording = case.write(tmp_path)
    ctx = load_context(scenario)  # the written map loads, with its raster and no surfaces
    assert ctx.world.map.surfaces == ()
    assert np.ptp(ctx.world.elevation_at(np.array([100.0, 400.0]), np.array([400.0, 400.0]))) \
        >= 0.0
    assert "surface" in recording.read_text().splitlines()[0]
