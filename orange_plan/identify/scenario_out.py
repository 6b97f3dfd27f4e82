"""Write a fitted model back into a scenario TOML (``calibrate -o``), and read it physically.

Rule (documented in docs/guide/recordings.md): the fitted lumped coefficients are written into the
``[model]`` table (``name = value`` plus ``stderr = {name = value}``), which the scenario
loader applies verbatim, so the written scenario rebuilds exactly the fitted coefficients and
their standard errors (correlations are not stored). Where a lumped coefficient maps to one
physical key, that key is updated too, so the file reads right and switches on terms that the
reference model enables by their physical value:

* ``ancillary_W``    -> ``[ancillary] s0_W, compute_W, comm_W`` scaled by one factor so that
  ``(s0 + compute + comm) / (1 - eta_4)`` equals it (all into ``s0_W`` if they were all 0)
* ``sensor_W_per_Hz`` -> ``s1_W_per_Hz = theta (1 - eta_4)``
* ``hover_W``        -> ``[robot] hover_W``
* ``drag_kg_per_m``  -> ``[robot] drag_coeff_kg_per_m = theta Omega``
* ``turn_J_per_rad`` -> ``[robot] turn_coeff_W_s_per_rad``

Mass and crr stay as they were: ``rolling_kg``, ``grade_kg``, ``inertia_kg`` and the
per-surface ``rolling_kg_<s>`` live in ``[model]`` (``model_builder.physical_values``, the
lumped <-> physical table read backwards, reports the implied crr factor and masses). Physical keys are clipped at 0 where a fit went negative; the term
stays on because ``[model]`` sets its coefficient (``model_builder.reference_term_ids``).

Everything the fit did not touch stays as the scenario had it: a term left out by
``calibrate --terms`` keeps its value, and the ``[model]`` table keeps its other entries
(e.g. a coefficient set to 0 to switch a term's effect off); extra terms the fit added join
``[model] terms``. Keeping rather than dropping errs on the safe side for planning (a grade
term not fitted on flat recordings still charges hills). ``[model] discrepancy_rel_sd`` is the
fitted model's run-to-run relative standard deviation (estimated from held-out recordings by
``Calibrator``). ``write_calibrated_scenario`` checks that the file rebuilds every fitted
coefficient before it replaces its target.
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path

import tomli_w

from orange_plan.atomic import atomic_path
from orange_plan.errors import InputError, OrangeError
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.model_builder import LUMPED, build_model, physical_values
from orange_plan.physics.terms import TERMS
from orange_plan.scenario import DRIFT_TERMS, HVAC_SETPOINT_KEYS, MODEL_EXTRA_TERMS, load_scenario

WRITTEN_BACK = tuple(row.physical for row in LUMPED.values()
                    if row.physical is not None and row.physical.startswith(("robot.", "ancillary.")))
"""Physical scenario keys (rows of ``model_builder.LUMPED``) a calibrated scenario updates,
clipped at 0."""


def calibrated_scenario_dict(scenario, model: EnergyModel, out_dir: Path,
                             changes: dict | None = None) -> dict:
    """The scenario's TOML mapping with the fitted values (module docstring rule), and
    ``changes``: other scenario values by dotted key (``environment.wind_speed_mps``: a wind
    that diagnosis found)."""
    data = tomllib.loads(Path(scenario.path).read_text(encoding="utf-8"))
    for dotted, value in (changes or {}).items():
        section, key = dotted.split(".")
        data.setdefault(section, {})[key] = value
    data["map"] = Path(os.path.relpath(scenario.map_path, out_dir.resolve())).as_posix()
    theta, sd = model.as_dict(), model.stderr()
    physical = physical_values(scenario, model)
    if "ancillary_load_W" in physical:
        anc = data.setdefault("ancillary", {})
        parts = ("s0_W", "compute_W", "comm_W")
        total = sum(float(anc.get(k, 0.0)) for k in parts)
        target = max(0.0, physical["ancillary_load_W"])
        for k in parts:
            anc[k] = float(anc.get(k, 0.0)) * target / total if total > 0 else 0.0
        if total <= 0:
            anc["s0_W"] = target
    for dotted in WRITTEN_BACK:
        if dotted in physical:
            section, key = dotted.split(".")
            data.setdefault(section, {})[key] = max(0.0, physical[dotted])
    table = dict(data.get("model", {}))
    fitted_extras = [t for t in model.term_ids if t in MODEL_EXTRA_TERMS]
    table["terms"] = list(dict.fromkeys([*table.get("terms", []), *fitted_extras]))
    table["discrepancy_rel_sd"] = model.discrepancy_rel_sd
    for drift in (t for t in model.terms if t.id in DRIFT_TERMS):
        if drift.shape != TERMS[drift.id].shape:  # the shape diagnosis chose
            for key, value in zip(("shape", "tau_s", "from_s"), drift.shape):
                table[f"{drift.id}_{key}"] = value
    hvac = next((t for t in model.terms if t.id == "hvac_ambient"), None)
    if hvac is not None and hvac.shape != TERMS["hvac_ambient"].shape:  # fitted set-points
        table.update(zip(HVAC_SETPOINT_KEYS, hvac.shape))
    table.update({k: float(v) for k, v in theta.items()})
    table["stderr"] = {**table.get("stderr", {}), **{k: float(v) for k, v in sd.items()}}
    data["model"] = table
    return data


def _check_rebuild(path: Path, model: EnergyModel) -> None:
    """The scenario at ``path`` must rebuild every coefficient of ``model`` and its discrepancy."""
    surface = next((t for t in model.terms if t.id == "surface_rolling"), None)
    names = [] if surface is None else [c.removeprefix("rolling_kg_") for c in surface.coefficients]
    rebuilt = build_model(load_scenario(path), names)
    have = rebuilt.as_dict()
    wrong = [n for n, v in model.as_dict().items() if have.get(n) != v]
    if wrong or rebuilt.discrepancy_rel_sd != model.discrepancy_rel_sd:
        raise OrangeError(f"the calibrated scenario does not rebuild the fitted model "
                          f"(coefficients {wrong})")


def write_calibrated_scenario(scenario, model: EnergyModel, path: str | Path,
                              changes: dict | None = None) -> Path:
    """Write the calibrated scenario atomically; it is loaded back and must rebuild ``model``'s
    coefficients and discrepancy (correlations are not stored) before it replaces ``path``.
    ``changes``: further scenario values by dotted key (``calibrated_scenario_dict``).

    A missing output folder is created, as by every other writer (``atomic_path``).

    Raises
    ------
    InputError
        The file cannot be written there.
    OrangeError
        The written file would not load or not rebuild the model (an internal failure).
    """
    path = Path(path)
    text = tomli_w.dumps(calibrated_scenario_dict(scenario, model, path.parent, changes))
    with atomic_path(path, suffix=".toml") as tmp:
        tmp.write_text(text, encoding="utf-8")
        try:
            _check_rebuild(tmp, model)
        except InputError as exc:
            raise OrangeError(f"the calibrated scenario does not load: {exc}") from None
    return path
