"""The candidates' columns (``Effect``): a physics term's Jacobian columns beside the
baseline, per-surface rolling, and the effects with non-linear parameters estimated on the
training rows (a payload's change time, a drift's shape, a wind vector).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from orange_plan.identify.calibrate import autoregressive_inflation
from orange_plan.identify.diagnosis.design import (
    Alternatives,
    Design,
    Effect,
    _bounds,
    _surfaces_seen,
)
from orange_plan.identify.diagnosis.fitting import _covariance
from orange_plan.physics.model_builder import make_term, mass_exponents
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import (
    DRIFT_TAU_S,
    STEP_RISE_S,
    aero_drag_feature,
    drift_rolling_term,
    drift_shape_feature,
    drift_term,
    step_ramp,
)
from orange_plan.physics.wind import wind_speed_and_from


def _term_effect(term_id: str):
    """Effect of a physics term: its ``power_jacobian`` columns at coefficient 0 next to the
    baseline (so a force term is masked by the baseline's clip, a battery loss scales the
    baseline's load power)."""

    def effect(d: Design, _resid, _rows) -> Effect:
        # linear in its coefficients: the same columns whatever the rows, built once
        if term_id not in d.cache:
            d.cache[term_id] = _term_columns(d, term_id)
        return d.cache[term_id]

    return effect


def _term_columns(d: Design, term_id: str, term=None) -> Effect:
    """The columns of ``term`` (default: vocabulary id ``term_id``'s) beside the baseline."""
    term = term or make_term(term_id, d.world.map.surface_names)
    # a whisker of the term (not 0) sets the clip mask where the baseline has no traction
    # force at all (a drone's drag: without it every sample would read "no force, no power")
    model = d.base.with_terms([*d.base.terms, term], dict.fromkeys(term.coefficients, 1e-9))
    jac = d.aligned(model.power_jacobian(d.state))[:, len(d.base.names):]
    if term_id == "hover":  # aloft only: a landed drone idles
        jac = jac * d.airborne[:, None]
    lo, hi = _bounds(term.coefficients)
    return Effect(jac, term.coefficients, lo, hi)


def _surface_effect(d: Design, _resid, _rows) -> Effect:
    """Per-surface change of the rolling coefficient: ``rolling_kg_<s> - rolling_kg`` on the
    samples on surface s (the baseline's one coefficient covers every surface)."""
    rolling = d.rolling_column
    code = np.broadcast_to(np.asarray(d.state.surface_code), (d.n,))
    names = _surfaces_seen(d)
    cols = np.stack([rolling * (code == d.world.map.surface_names.index(s)) for s in names], 1)
    base = d.base.coefficient("rolling_kg")
    return Effect(cols, tuple(f"delta_rolling_kg_{s}" for s in names),
                  np.full(len(names), -base), np.full(len(names), np.inf))



def _mass_per_kg_W(d: Design) -> np.ndarray:
    """Battery power per kg of extra moving mass at the baseline coefficients [W/kg]: the
    derivative of ``model_builder.mass_scales`` (the simulator's payload) at no extra mass,
    ``sum_i column_i theta_i exponent_i / m``; a hover power only aloft (landed, it idles)."""
    if "mass_per_kg" not in d.cache:  # the scan and every step column share it
        columns = d.columns
        if "hover_W" in d.base.names:
            columns = columns.copy()
            columns[:, d.base.names.index("hover_W")] *= d.airborne
        weights = d.base.theta * mass_exponents(d.base.names) / d.scenario.robot.mass_kg
        d.cache["mass_per_kg"] = columns @ weights
    return d.cache["mass_per_kg"]


@dataclass(frozen=True)
class _PayloadScan:
    """A payload's change time scanned over every sample: the fall of the training rows'
    residual sum of squares for a change at each sample ``gain`` [W^2] (-inf where not
    ``valid``), and the residual on the training rows (0 elsewhere) ``resid`` [W]."""

    gain: np.ndarray
    valid: np.ndarray
    resid: np.ndarray


def _payload_scan(d: Design, resid, rows) -> _PayloadScan:
    """The least-squares fit of a mass change at every sample at once, by cumulative sums.

    The residual comes from a fit whose coefficients already took what they could of the
    change (the mass terms the run's average mass, the ancillary draw a share of it), so a
    step column ``c`` is judged by its part orthogonal to the baseline's columns ``X``: the
    fall of the residual sum of squares ``(r.c)^2 / (c.c - c'X (X'X)^-1 X'c)``. Judged
    against the mass column alone, a change near an end of the run (little left to
    orthogonalise) looked as good as the true one."""
    g = _mass_per_kg_W(d)
    r = np.where(rows, resid, 0.0)
    gr = np.where(rows, g, 0.0)
    x = np.where(rows[:, None], d.columns, 0.0)
    x = x / np.maximum(np.linalg.norm(x, axis=0), 1e-300)
    # sums over t >= t0 of r g, g^2 and g X, for every t0 at once
    rg, gg, gx = (_sums_to_end(v)[:-1] for v in (r * gr, gr * gr, gr[:, None] * x))
    explained = np.einsum("ij,ij->i", gx @ np.linalg.pinv(x.T @ x, rcond=1e-10), gx)
    spread = gg - explained
    # a change whose step the baseline's columns already span (one that starts where the
    # mass power starts) has no part of its own: its spread is rounding error
    valid = ((d.t_s >= d.t_s[-1] * 0.05) & (d.t_s <= d.t_s[-1] * 0.95)
             & (spread > 1e-6 * gg[0]))
    gain = np.where(valid, rg**2 / np.where(spread > 0, spread, 1.0), -np.inf)
    return _PayloadScan(gain, valid, r)


def _sums_to_end(x: np.ndarray) -> np.ndarray:
    """The sums of ``x`` (along its first axis) from each sample to the end, one row per
    sample and a last row of 0 (from one past the end): a step's inner products at every
    change time at once (``_payload_scan``, ``_step_falls``)."""
    return np.concatenate([np.cumsum(x[::-1], axis=0)[::-1], np.zeros((1, *x.shape[1:]))])


def _payload_effect(d: Design, resid, rows) -> Effect:
    """A mass change at an unknown time: ``payload_kg * per_kg(t) * [t >= t0]``; t0 is the
    training rows' least-squares change time (``_payload_scan``)."""
    scan = _payload_scan(d, resid, rows)
    gain, valid, r = scan.gain, scan.valid, scan.resid
    # every change time inside a stretch of held-out rows (and the first training row after
    # it) fits the training rows alike; the first of them, argmax's pick, put the step at the
    # start of the gap, and the held-out fold paid for the whole gap's worth of a wrong mass
    # (payload seed 301: -0.4 % held out for +31 % told the true time). The middle of the tie
    # is as far as the data allow from both ends (no valid time at all: argmax's 0, as before)
    ties = np.flatnonzero(valid & (gain == gain.max()))
    k = int(ties[ties.size // 2]) if ties.size else int(np.argmax(gain))
    t0 = float(d.t_s[k])
    # the change time's uncertainty: half the span of times whose fit is within one unit of
    # chi-square (noise variance x autocorrelation time) of the best, from the profile of the
    # residual sum of squares
    tau = autoregressive_inflation(resid, d.samples, d.settings.inflation_block_s)
    near = valid & (gain >= gain[k] - float(np.mean(r[rows] ** 2)) * tau)
    dt = float(np.median(np.diff(d.t_s)))
    sd = max(0.5 * float(np.ptp(d.t_s[near])), dt) if near.any() else dt
    return replace(payload_step(d, t0, sd), alternatives=_payload_alternatives(d, rows))


def _payload_alternatives(d: Design, rows) -> Alternatives | None:
    """A payload's change at each of ``settings.drift_step_times`` times over the 5-95 % of
    the run its scan searches (``_payload_scan``), as the effect's alternatives, on the
    effect fitted on all samples only (``_drift_alternatives``)."""
    if not np.all(rows):
        return None
    times = d.t_s[-1] * np.linspace(0.05, 0.95, d.settings.drift_step_times)
    # the columns' inputs, not the design: the design's cache holds this effect, and a
    # closure over the design would make a cycle that keeps every fit of the recording (a
    # few GB over a benchmark's cases) until the cyclic collector happens to run
    per_kg, t_s = _mass_per_kg_W(d), d.t_s
    return Alternatives(tuple({"payload_from_s": float(t)} for t in times),
                        lambda: per_kg[:, None] * (t_s[:, None] >= times))


@dataclass(frozen=True)
class DriftShape:
    """One member of the drift family: ``shape`` (``"linear"``, ``"decay"``, ``"step"``), its
    time scale ``tau_s`` [s] (a line's span, a decay's time constant) and a step's time
    ``from_s`` [s] (``physics.terms.drift_shape_feature``)."""

    shape: str
    tau_s: float
    from_s: float


@dataclass(frozen=True)
class DriftFamily:
    """The drift family on one recording: its shapes and their columns (n, shapes) [-]."""

    shapes: list[DriftShape]
    columns: np.ndarray


@dataclass(frozen=True)
class _DriftProjection:
    """Each drift shape's part orthogonal to the baseline's columns on some rows (``own``),
    its squared norm ``cc`` (inf where the baseline spans it) and the effective sample count
    ``n_eff`` of the information criterion."""

    own: np.ndarray
    cc: np.ndarray
    n_eff: float
    q: np.ndarray  # an orthonormal basis of the baseline's columns on the rows


_DRIFT_FAMILIES: list = []
"""The last few recordings' drift families, ``(t_s array, settings, family)``: a design's
cache is emptied with every Gauss-Newton step of the model, its time axis is not."""


def _drift_shapes(d: Design) -> DriftFamily:
    """The drift family on this recording: a linear change over the run, a decay at each of
    ``settings.drift_taus_s`` and a step at each of ``settings.drift_step_times`` times."""
    for t_s, settings, family in _DRIFT_FAMILIES:
        if t_s is d.t_s and settings == d.settings:
            return family
    span = max(float(d.t_s[-1] - d.t_s[0]), 1.0)
    step_times = span * np.linspace(0.05, 0.95, d.settings.drift_step_times)
    shapes = [DriftShape("linear", span, 0.0),
              *(DriftShape("decay", tau, 0.0) for tau in d.settings.drift_taus_s),
              *(DriftShape("step", span, float(t0)) for t0 in step_times)]
    family = DriftFamily(shapes, _shape_columns(d, shapes))
    _DRIFT_FAMILIES[:] = [*_DRIFT_FAMILIES[-3:], (d.t_s, d.settings, family)]
    return family


def _shape_columns(d: Design, shapes: list[DriftShape]) -> np.ndarray:
    """Each drift shape's feature over the recording's elapsed time, one column per shape
    (n, shapes) [-] (``physics.terms.drift_shape_feature``)."""
    elapsed = d.t_s - d.t_s[0]
    state = MotionState(speed_mps=np.ones(d.n), channels={"elapsed_s": elapsed})
    return np.column_stack([np.broadcast_to(np.asarray(
        drift_shape_feature(s.shape, s.tau_s, s.from_s)(state)[0], float), (d.n,))
        for s in shapes])


def _drift_as_effect(d: Design, term_id: str, column: np.ndarray, shape: DriftShape,
                     alternatives=None) -> Effect:
    """A power drift's (``drift_W``, either sign) or the rolling coefficient's
    (``drift_rolling_kg``, never below minus the baseline's coefficient) column of one
    shape as the candidate's effect, the shape its parameters."""
    if term_id == "drift_rolling":
        names, lower = ("drift_rolling_kg",), -max(d.base.coefficient("rolling_kg"), 0.0)
    else:
        names, lower = ("drift_W",), -np.inf
    return Effect(column[:, None], names, np.array([lower]), np.array([np.inf]),
                  _shape_params(shape), scanned=_shape_scanned(shape), alternatives=alternatives)


def _drift_effect(d: Design, resid, rows) -> Effect:
    """A power that changes slowly over the run, of the shape of the drift family
    (``_drift_shapes``) that the information criterion prefers on the training rows: each
    shape's column is judged by its part orthogonal to the baseline's columns (what the
    refitted coefficients could not already take), its fall of the residual sum of squares
    set against ``ln n_eff`` per non-linear parameter (a decay's time constant, a step's
    time; BIC with the effective sample count). Either sign: a load that grows through a
    run (a vessel's ancillary draw, +25 % over it) is a negative decay or a rising line.
    Without a residual (the power's delay estimate): the cold-start decay."""
    family = _drift_shapes(d)
    best = (family.shapes.index(DriftShape("decay", DRIFT_TAU_S, 0.0)) if resid is None
            else _best_drift_shape(d, resid, rows, family))
    chosen, col = _refined(d, resid, rows, family, best, np.ones(d.n), "drift")
    return _drift_as_effect(d, "drift", col, chosen,
                            _drift_alternatives(family, np.ones(d.n), rows))


def _drift_rolling_effect(d: Design, resid, rows) -> Effect:
    """The rolling coefficient changing slowly over the run: each shape of the drift family
    times the baseline's rolling column (the rolling force per kg, charged where the baseline
    drives), the shape chosen by the information criterion as a power drift's
    (``_drift_effect``). A coefficient that changes only where the robot rolls is told from a
    power drift by that column: at rest and on a descent it adds nothing. A step of the
    rolling coefficient and a payload's step of the mass differ only by the grade's and the
    inertia's share of the mass, so a rolling step is offered only where it fits the
    training rows better than the best payload's step by ``settings.min_bic_evidence``
    (``_rolling_step_earned``); otherwise the step is the payload's and the rolling family
    offers lines and decays. Without that rule the two traded places both ways
    (``turning+payload`` seed 0 named a rolling step for its payload at a BIC 0.3 apart,
    ``drift_rolling`` seed 3 a payload for its rolling step at a BIC 140 apart)."""
    family = _drift_shapes(d)
    rolling = d.rolling_column
    columns = family.columns * rolling[:, None]  # one per shape, for the choice
    if resid is None:
        best = family.shapes.index(DriftShape("decay", DRIFT_TAU_S, 0.0))
    else:
        best = _best_drift_shape(d, resid, rows, family, columns, "drift_rolling", False)
    chosen, col = _refined(d, resid, rows, family, best, rolling, "drift_rolling")
    if chosen.shape == "step" and not _rolling_step_earned(d, resid, rows, col):
        best = _best_drift_shape(d, resid, rows, family, columns, "drift_rolling", True)
        chosen, col = _refined(d, resid, rows, family, best, rolling, "drift_rolling")
    return _drift_as_effect(d, "drift_rolling", col, chosen,
                            _drift_alternatives(family, rolling, rows))


def _drift_alternatives(family: DriftFamily, scale: np.ndarray, rows) -> Alternatives | None:
    """Every shape of the drift family as the effect's alternatives (times ``scale`` per
    sample, as ``_refined``'s column), on the effect fitted on all samples (``rows`` all
    true) only: that is the fit whose detection limits are stated."""
    if rows is None or not np.all(rows):
        return None
    params = tuple({k: v for k, (v, _sd) in _shape_params(s).items()} for s in family.shapes)
    return Alternatives(params, lambda: family.columns * scale[:, None])


def _refined(d: Design, resid, rows, family: DriftFamily, best: int, scale: np.ndarray,
             tag: str) -> tuple[DriftShape, np.ndarray]:
    """The chosen shape and its column (the shape times ``scale`` per sample); a step's time
    refined to the second within a grid spacing of the grid's pick, as a payload's change
    time is scanned over every sample. On the grid alone a step fell up to half a spacing
    (22 s of a 30-minute run) from its time, and a payload's step, scanned finely, fitted a
    rolling coefficient's step better than the drift's own (seed 3 of ``drift_rolling``)."""
    chosen = family.shapes[best]
    if chosen.shape != "step" or resid is None:
        return chosen, family.columns[:, best] * scale
    elapsed = d.t_s - d.t_s[0]
    spacing = family.shapes[best].tau_s * 0.9 / max(d.settings.drift_step_times - 1, 1)
    times = np.arange(max(chosen.from_s - spacing, 0.0), chosen.from_s + spacing + 0.5, 1.0)
    proj = d.cache[(f"{tag}_projection", hash(np.packbits(rows).tobytes()))]
    fall = _step_falls(elapsed, rows, scale, resid, proj.q, times)
    # every time inside a stretch of held-out rows fits the training rows alike: the middle
    # of the tie, as a payload's change time (``_payload_effect``), not its start
    ties = np.flatnonzero(fall >= fall.max() - 1e-9 * abs(fall.max()))
    from_s = float(times[ties[ties.size // 2]])
    return DriftShape("step", chosen.tau_s, from_s), step_ramp(elapsed, from_s) * scale


def _step_falls(elapsed, rows, scale, resid, q, times) -> np.ndarray:
    """The fall of the training rows' residual sum of squares for a step of ``scale`` at
    each of ``times`` [s], each step judged by its part orthogonal to the baseline's columns
    (``q``, an orthonormal basis on the rows), -inf where the baseline spans the step.

    The step is the term list's ramp (``physics.terms.step_ramp``): 1 from half of
    STEP_RISE_S after ``t`` on, a fraction on the samples within half of it of ``t``. Its
    inner products with the residual, itself and the basis are sums over the rows from some
    sample to the end (``_sums_to_end``, as a payload's scan) plus the few samples of the
    ramp, so a scan over ~100 times costs two passes over the recording rather than a
    projection of an n x 100 matrix."""
    w = np.where(rows, scale, 0.0)
    r = np.where(rows, resid, 0.0)
    qf = np.zeros((elapsed.size, q.shape[1]))
    qf[rows] = q

    rs, ss, qs = _sums_to_end(r * w), _sums_to_end(w * w), _sums_to_end(qf * w[:, None])
    half = 0.5 * STEP_RISE_S
    lo = np.searchsorted(elapsed, times - half, side="right")  # first sample on the ramp
    hi = np.searchsorted(elapsed, times + half, side="left")  # first sample at 1
    band = lo[:, None] + np.arange(max(int(np.max(hi - lo, initial=0)), 1))[None, :]
    inside = band < hi[:, None]
    band = np.minimum(band, elapsed.size - 1)
    ramp = np.where(inside, step_ramp(elapsed[band], times[:, None]), 0.0)
    part = ramp * w[band]  # the steps' values on their ramps' samples
    rc = rs[hi] + np.einsum("jk,jk->j", part, r[band])
    cc = ss[hi] + np.einsum("jk,jk->j", part, part)
    qc = qs[hi] + np.einsum("jk,jkp->jp", part, qf[band])
    own_rc = rc - qc @ (q.T @ resid[rows])
    own_cc = cc - np.einsum("jp,jp->j", qc, qc)
    spanned = own_cc <= 1e-9 * np.maximum(cc, 1e-300)
    return np.where(spanned, -np.inf, own_rc**2 / np.where(spanned, 1.0, own_cc))


def _shape_params(chosen: DriftShape) -> dict:
    """A drift shape as a finding's parameters (``_drift_term_of`` reads them back)."""
    if chosen.shape == "step":
        return {"drift_from_s": (chosen.from_s, 0.0)}
    return {"drift_span_s" if chosen.shape == "linear" else "drift_tau_s": (chosen.tau_s, 0.0)}


def _shape_scanned(chosen: DriftShape) -> int:
    """A drift shape's non-linear parameters: a decay's time constant or a step's time (a
    line over the run has none), as ``_best_drift_shape``'s criterion counts them."""
    return 0 if chosen.shape == "linear" else 1


def _best_drift_shape(d: Design, resid, rows, family: DriftFamily, columns=None,
                      tag: str = "drift", no_steps: bool | None = None) -> int:
    """The index of the shape with the smallest BIC on ``rows`` (``_drift_effect``); the
    shapes' ``columns`` (default: the family's own, a power drift's), cached under ``tag``,
    steps left out when ``no_steps`` (default: a power step that is a payload's)."""
    columns = family.columns if columns is None else columns
    key = (f"{tag}_projection", hash(np.packbits(rows).tobytes()))
    if key not in d.cache:  # the same for every residual on these rows: built once
        q = _column_basis(d.columns[rows])
        c = columns[rows]
        own = c - q @ (q.T @ c)  # each shape's part the baseline's columns do not span
        cc = np.einsum("ij,ij->j", own, own)
        spanned = cc <= 1e-9 * np.maximum(np.einsum("ij,ij->j", c, c), 1e-300)  # a constant
        # the autocorrelation time of the first residual seen (the baseline's): BIC's
        # effective sample count, the same for every shape compared
        tau = autoregressive_inflation(resid, d.samples, d.settings.inflation_block_s)
        d.cache[key] = _DriftProjection(own, np.where(spanned, np.inf, cc),
                                        max(rows.sum() / tau, 2.0), q)
    proj = d.cache[key]
    r = resid[rows]
    fall = (r @ proj.own) ** 2 / proj.cc
    rss = np.maximum(float(r @ r) - fall, 1e-300)
    nonlinear = np.array([_shape_scanned(s) for s in family.shapes], float)
    bic = proj.n_eff * np.log(rss) + nonlinear * np.log(proj.n_eff)
    if _steps_are_payloads(d) if no_steps is None else no_steps:
        bic[[i for i, s in enumerate(family.shapes) if s.shape == "step"]] = np.inf
    return int(np.argmin(bic))


def _column_basis(x) -> np.ndarray:
    """An orthonormal basis of the span of ``x``'s columns: the left singular vectors of
    the column-scaled matrix above a relative 1e-10 (a QR of a matrix with a column that is
    zero on these rows, a surface never driven on, adds a direction the columns do not
    span)."""
    u, sv, _ = np.linalg.svd(x / np.maximum(np.linalg.norm(x, axis=0), 1e-300),
                             full_matrices=False)
    return u[:, sv > 1e-10 * max(float(sv.max(initial=0.0)), 1e-300)]


def _needs_mass(d: Design):
    return None if np.any(_mass_per_kg_W(d) > 0) else "no mass-dependent power in the model"


def _steps_are_payloads(d: Design) -> bool:
    """Whether a drift's step is the same evidence as a payload's: a mass change shows in the
    mass-dependent (force and hover) terms, a drift in a power of its own, and where the power
    per kg does not vary (a drone hovering the whole run) the two steps are one column, the
    recording cannot tell them apart. The step is then the payload's, whose change time is
    scanned over every sample, not a grid: beside a drone's wind, a drift step on the grid
    took the payload's place (48 % held-out gain against 42 %) only because its grid time
    fell nearer the truth in the one fold that held the change out."""
    per_kg = _mass_per_kg_W(d)
    mean = float(np.mean(per_kg))
    spread = d.settings.payload_step_spread
    return _needs_mass(d) is None and float(np.ptp(per_kg)) <= spread * abs(mean)


def _rolling_step_earned(d: Design, resid, rows, column) -> bool:
    """Whether a rolling coefficient's step ``column`` leaves the training rows' residual
    smaller than the best payload's step by ``settings.min_bic_evidence`` of BIC (at the
    drift's effective sample count; both have one coefficient and one time). Where the mass
    shows only in the rolling force, the two are one column and the payload keeps it."""
    if _needs_mass(d) is not None:
        return True
    proj = d.cache[("drift_rolling_projection", hash(np.packbits(rows).tobytes()))]
    r = resid[rows]
    own = column[rows] - proj.q @ (proj.q.T @ column[rows])
    rolling_fall = float((r @ own) ** 2 / max(float(own @ own), 1e-300))
    payload_fall = max(float(np.max(_payload_scan(d, resid, rows).gain)), 0.0)
    rr = float(r @ r)
    evidence = proj.n_eff * np.log(max(rr - payload_fall, 1e-300)
                                   / max(rr - rolling_fall, 1e-300))
    return evidence >= d.settings.min_bic_evidence


def _shape_of(params: dict) -> DriftShape:
    """The drift shape a finding's parameters name (``_shape_params`` writes them):
    ``drift_from_s`` a step, ``drift_span_s`` a line, else a decay (at ``drift_tau_s``,
    default the term list's cold-start DRIFT_TAU_S)."""
    if "drift_from_s" in params:
        return DriftShape("step", DRIFT_TAU_S, float(params["drift_from_s"]))
    if "drift_span_s" in params:
        return DriftShape("linear", float(params["drift_span_s"]), 0.0)
    return DriftShape("decay", float(params.get("drift_tau_s", DRIFT_TAU_S)), 0.0)


def _drift_term_of(params: dict, term_id: str = "drift"):
    """The ``drift`` (or ``drift_rolling``) term of a finding's shape (``_shape_of``)."""
    make = drift_rolling_term if term_id == "drift_rolling" else drift_term
    shape = _shape_of(params)
    return make(shape.shape, shape.tau_s, shape.from_s)


def drift_of_shape(d: Design, term_id: str, params: dict) -> Effect:
    """The ``drift`` (or ``drift_rolling``) candidate's effect at the shape ``params`` name
    (``_shape_of``), with nothing scanned: a drift told its shape, as ``payload_step`` is a
    payload told its time."""
    shape = _shape_of(params)
    column = _shape_columns(d, [shape])[:, 0]
    if term_id == "drift_rolling":
        column = column * d.rolling_column
    return replace(_drift_as_effect(d, term_id, column, shape), scanned=0)


def payload_step(d: Design, t0: float, sd: float = 0.0) -> Effect:
    """The payload's column for a change at ``t0`` [s] (standard error ``sd``): the power per
    kg of extra mass from then on [W/kg]."""
    col = (_mass_per_kg_W(d) * (d.t_s >= t0))[:, None]
    # physical range: the robot cannot drop more than most of itself, nor carry more than
    # twice its mass (a fold whose scan lands on a fluke must not extrapolate wildly)
    mass = d.scenario.robot.mass_kg
    return Effect(col, ("payload_kg",), np.array([-0.8 * mass]), np.array([2.0 * mass]),
                  {"payload_from_s": (t0, sd)}, scanned=1)


def _wind_effect(d: Design, resid, rows) -> Effect:
    """An unreported wind: the drag term under a wind vector w in place of the baseline's
    drag (under the scenario's wind), by variable projection: for each w, the drag
    coefficient k and the baseline's other coefficients are solved linearly on the training
    rows, and w minimises what is left (Gauss-Newton from the scenario's wind). A drag
    ``k |v - w|^2`` identifies ``k w`` through the heading but ``k |w|^2`` only against the
    constant loads, so w and k are estimated with those loads free: fitted against the
    baseline's fixed columns, a drone's wind beside a payload came out at 2.3-2.6 x its true
    speed, 3-6 standard errors off. What is judged is the wind's change from the scenario's."""
    from scipy.optimize import least_squares

    drag_i = d.base.names.index("drag_kg_per_m")
    base_drag = d.columns[:, drag_i] * d.base.theta[drag_i]
    speed = np.asarray(d.state.speed_mps)
    moving = (speed > 0.1) & rows
    others = np.delete(d.columns, drag_i, axis=1)[moving]
    # the residual with the baseline's fit put back: what the wind's drag and the other
    # columns share
    target = (resid + base_drag)[moving] + others @ np.delete(d.base.theta, drag_i)

    def drag_per_k(w):
        windy = d.state.with_(wind_x_mps=w[0] + 0.0 * speed, wind_y_mps=w[1] + 0.0 * speed)
        (phi,) = aero_drag_feature(windy)
        return d.aligned(phi * speed)

    def solve(drag_moving):
        x = np.column_stack([drag_moving, others])
        return np.linalg.lstsq(x, target, rcond=None)[0], x

    def fun(w):
        theta, x = solve(drag_per_k(w)[moving])
        return x @ theta - target

    assumed = np.array([np.mean(d.state.wind_x_mps), np.mean(d.state.wind_y_mps)], float)
    # unit steps in m/s on both axes (MINPACK's fixed scaling; its default rescales by the
    # Jacobian's columns as it goes)
    sol = least_squares(fun, assumed, method="lm", x_scale=np.array([1.0, 1.0]))
    per_k = drag_per_k(sol.x)
    theta, x = solve(per_k[moving])
    k = float(theta[0])
    # the joint Jacobian (w, k, the other coefficients) at the solution gives w's covariance
    # with everything it trades against
    step = 1e-4
    dw = [(drag_per_k(sol.x + step * e)[moving] - x[:, 0]) * k / step for e in np.eye(2)]
    jac = np.column_stack([*dw, x])
    s2 = float(np.mean(sol.fun**2)) * autoregressive_inflation(
        sol.fun, d.samples.subset(moving), d.settings.inflation_block_s)
    full_cov = _covariance(jac) * s2
    cov = full_cov[:2, :2]
    wx, wy = sol.x
    speed_mps, from_deg = wind_speed_and_from(wx, wy)
    # delta method for speed and direction
    r2 = max(wx * wx + wy * wy, 1e-12)
    g_speed = np.array([wx, wy]) / np.sqrt(r2)
    g_dir = np.degrees(np.array([-wy, wx]) / r2)
    change = sol.x - assumed
    g_change = change / max(float(np.hypot(*change)), 1e-12)
    extra = {"wind_change_mps": (float(np.hypot(*change)),
                                 float(np.sqrt(g_change @ cov @ g_change))),
             "wind_x_mps": (float(wx), float(np.sqrt(cov[0, 0]))),
             "wind_y_mps": (float(wy), float(np.sqrt(cov[1, 1]))),
             "wind_speed_mps": (float(speed_mps), float(np.sqrt(g_speed @ cov @ g_speed))),
             "wind_from_deg": (float(from_deg), float(np.sqrt(g_dir @ cov @ g_dir))),
             "drag_kg_per_m": (k, float(np.sqrt(full_cov[2, 2])))}
    col = (k * per_k - base_drag)[:, None]
    # the column enters at its own size (a share held at 1; a free share would let a fluke
    # scale a small wind into a large effect)
    return Effect(col, ("wind_share",), np.array([1.0 - 1e-9]), np.array([1.0 + 1e-9]), extra,
                  scanned=2)
