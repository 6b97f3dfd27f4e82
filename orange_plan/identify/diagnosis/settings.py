"""The thresholds of diagnosis, in one frozen object handed to every stage.

``DiagnosisSettings()`` holds the values diagnosis uses by default; a study of the method
passes another instance (``dataclasses.replace(DiagnosisSettings(), min_t=3.0)``) to
``diagnose`` or ``build_design`` and every stage reads it from there (``Design.settings``).
How each threshold is used: docs/guide/diagnosis.md.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class DiagnosisSettings:
    """Every threshold of diagnosis, with its default value.

    Attributes
    ----------
    min_gain : smallest relative fall of the held-out RMSE for a candidate to be kept [-]
    min_folds : held-out folds (of ``n_folds``) that a kept candidate must not make worse (by
        more than 0.5 %) [-]: a real effect helps where it acts and harms nowhere; a fluke
        fitted to one stretch of the run makes the others worse
    min_t : smallest |coefficient| / standard error (autocorrelation-inflated) of a kept
        term [-]
    min_effect_share : smallest RMS of a term's fitted power, as a share of the mean |power|,
        for it to be worth keeping [-]: a perfect model's residual is small, and 2 % of
        little is nothing
    grade_windows_m : elevation smoothing windows tried for the grade [m] (``build_design``)
    max_lag_s : largest delay of the recorded power behind the motion that is corrected [s]:
        power meters and logging stacks lag the odometry by tenths of a second, which smears
        every transient (acceleration, turns) across the residual
    inflation_block_s : batch length of the autocorrelation inflation of runs too short for
        its autoregression (``calibrate.autoregressive_inflation``) [s]: batch means
        estimate the integrated autocorrelation time only when a batch is several times
        longer than it, and disturbances (gusts, a controller, traffic) last tens of seconds
    min_drag_share : a wind is looked for only where drag draws at least this share of the
        mean power [-]: a sidewalk robot's drag at 1 m/s is a fraction of a watt, and a wind
        fitted to it would be a heading-dependent fluke (a slope met in one direction)
        scaled up to gale force
    max_wind_mps : largest wind (or water current) a finding may claim [m/s]
    scanned : candidates whose change time (a payload's), delay (a surface label's), shape
        (a drift's) or set-points (an HVAC's) is the best of a scan: the largest of the scan's t statistics is itself
        large, so their t must exceed ``min_t`` by the scan's typical maximum. Neighbouring
        change times give nearly the same statistic (a standardised CUSUM), so that maximum
        grows like sqrt(2 ln ln n_eff) (Darling-Erdos), not like the sqrt(2 ln n_eff) of
        independent tests: on the null cases the scan's largest t was 1.7-3.2
    rivals : single candidates (the best by held-out gain) checked as alternatives to a
        found term [-]
    max_label_lag_s : largest delay of a recording's ``surface`` labels behind the terrain
        under the wheels that is looked for [s]: a terrain classifier labels what it has
        seen over a window of a second or a few, and a logging stack adds tenths
    label_windows_s : majority windows tried on a recording's ``surface`` labels [s] (0: the
        labels as given): a classifier's slips (a shadow, a wet patch) are short bursts, and
        a wrong label pulls each label's rolling coefficient towards the others' (2-8 % of
        the samples wrong moved them by up to 14 % of their difference); the majority over a
        window removes bursts shorter than half of it, and the window is chosen by the fit
        like the delay
    min_label_share : a surface label gets its own rolling coefficient when it covers at
        least this share of the moving samples [-] (a label seen for a few seconds is a
        classifier's slip)
    n_blocks : equal-time blocks of the recording; fold k holds out blocks k, k + n_folds,
        ... [-]
    n_folds : held-out folds [-]
    landed_min_s : a leading or trailing stationary period at least this long counts as
        landed [s]
    prior_scale : the scenario's a priori standard errors are widened by this factor for the
        baseline refit; the prior weighs against residuals in units of the noise, as
        calibration's does (``Design.ridge``) [-]
    prior_dof : degrees of freedom of the baseline's Student-t prior, as sharp at the
        scenario's value as a normal one of the widened sd: it steers what the recording
        cannot separate and yields where the recording contradicts it by many sd (a normal
        prior split such a difference: a Husky run on snow whose ancillary draw is 11 sd
        above the scenario's was fitted with a quarter of its energy missing) [-]
    prior_rounds : reweighting rounds at most to the t prior's most probable value [-]
    regen_rounds : Gauss-Newton rounds of a fit with ``regen`` inside the model [-]: the
        efficiency and the force coefficients are a product on braking samples, and the clip
        moves with both
    drift_taus_s : time constants a drift's ``decay`` is tried at [s]
    drift_step_times : change times a drift's ``step`` is tried at, evenly over 5-95 % of
        the run [-]
    hvac_setpoint_step_K : spacing of the set-points an ``hvac_ambient``'s heating and
        cooling are tried at, over physics.terms.HVAC_SETPOINT_RANGE_C [K]
    payload_step_spread : largest spread (peak to peak, a share of its mean) of the power per
        kg of mass at which a drift's step is a payload's [-]
    min_bic_evidence : smallest fall of the information criterion that counts as evidence of
        one explanation over another that draws nearly the same power [-] (2: "positive" on
        Kass and Raftery's scale): a rolling coefficient's step is named in a payload's place
        only with it, and a round chooses by the criterion only with it
    detection_power_z : the stated detection limits are the effects found with this
        standard normal quantile's probability [-] (1.645: 95 %): a coefficient's estimate
        scatters by one standard error about its true value, so an effect whose expected t
        is exactly the bar is seen only half the time; the limit adds this many standard
        errors to the bar (the detection limit of IUPAC and Currie, 1968: the true value
        missed with a probability of 5 %)
    """

    min_gain: float = 0.02
    min_folds: int = 3
    min_t: float = 4.0
    min_effect_share: float = 0.01
    grade_windows_m: tuple[float, ...] = (0.5, 2.0, 5.0, 10.0, 20.0)
    max_lag_s: float = 1.0
    inflation_block_s: float = 120.0
    min_drag_share: float = 0.02
    max_wind_mps: float = 30.0
    scanned: frozenset[str] = frozenset({"payload", "surface_label", "drift", "drift_rolling",
                                     "hvac_ambient"})
    rivals: int = 4
    max_label_lag_s: float = 5.0
    label_windows_s: tuple[float, ...] = (0.0, 2.0, 4.0, 8.0)
    min_label_share: float = 0.05
    n_blocks: int = 20
    n_folds: int = 5
    landed_min_s: float = 10.0
    prior_scale: float = 10.0
    prior_dof: float = 1.0
    prior_rounds: int = 30
    regen_rounds: int = 4
    drift_taus_s: tuple[float, ...] = (300.0, 600.0, 1200.0, 2400.0, 4800.0)
    drift_step_times: int = 37
    payload_step_spread: float = 0.01
    hvac_setpoint_step_K: float = 0.25
    min_bic_evidence: float = 2.0
    detection_power_z: float = 1.645


DEFAULT_SETTINGS = DiagnosisSettings()
"""The thresholds diagnosis uses unless told otherwise."""
