"""Replay a recording's motion through an EnergyModel: predicted vs recorded power and energy.

The prediction uses nothing but ``EnergyModel.power_W`` on the recording's per-sample
MotionState (``telemetry.state.recording_state``), so it is the same physics the planner uses. Energies are
trapezoid integrals over time with the recording's gaps skipped on both sides. The predicted
energy's standard deviation is the model's predictive one (``EnergyModel.
predictive_variance_J2``: coefficient covariance along the run's energy gradient, plus the
run-to-run discrepancy), the same quantity a ``confidence`` reserve is sized from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState
from orange_plan.telemetry.recording import Recording, cumulative_J, integrate_J
from orange_plan.telemetry.state import recording_state
from orange_plan.world.positions import check_on_map


@dataclass(frozen=True)
class Replay:
    """Recorded and predicted battery power of one recording.

    Attributes
    ----------
    source : the recording's source
    t_s : sample times [s]
    recorded_W, predicted_W : battery power per sample [W]
    energy_recorded_J, energy_predicted_J : integrals over the run, gaps skipped [J]
    energy_predicted_sd_J : predictive standard deviation of the predicted energy [J]
    energy_error_pct : ``100 (predicted - recorded) / |recorded|`` (signed: > 0 over-predicts) [%]
    rmse_W : root-mean-square of ``predicted - recorded`` over the samples [W]
    duration_s : first to last sample [s]
    """

    source: str
    t_s: np.ndarray
    recorded_W: np.ndarray
    predicted_W: np.ndarray
    energy_recorded_J: float
    energy_predicted_J: float
    energy_error_pct: float
    rmse_W: float
    duration_s: float
    energy_predicted_sd_J: float

    def to_dict(self) -> dict:
        """keys (docs/json.md) of ``predict --json`` plus the sample count and mean powers."""
        return {
            "energy_recorded_J": self.energy_recorded_J,
            "energy_predicted_J": self.energy_predicted_J,
            "energy_predicted_sd_J": self.energy_predicted_sd_J,
            "energy_error_pct": self.energy_error_pct,
            "rmse_W": self.rmse_W,
            "duration_s": self.duration_s,
            "recording": self.source,
            "samples": int(self.t_s.size),
            "mean_recorded_W": float(np.mean(self.recorded_W)),
            "mean_predicted_W": float(np.mean(self.predicted_W)),
        }


@dataclass(frozen=True)
class RunEnergy:
    """A model's prediction of one recording's whole-run energy.

    Attributes
    ----------
    power_W : predicted battery power per sample [W] (n,)
    energy_J : its integral over the run, gaps skipped [J]
    sd_J : predictive standard deviation of ``energy_J`` [J]
    param_sd_J : its coefficient-covariance part alone, ``sqrt(g' Cov g)`` [J]
    """

    power_W: np.ndarray
    energy_J: float
    sd_J: float
    param_sd_J: float


def run_energy(recording: Recording, model: EnergyModel, state: MotionState) -> RunEnergy:
    """Predicted whole-run energy of a recording's motion and its standard deviation.

    Parameters
    ----------
    recording : gives the times and gaps
    model : the energy model
    state : per-sample motion state of the recording (``telemetry.state.recording_state``)

    Returns
    -------
    RunEnergy
        ``E = integral P dt``; ``sd = sqrt(g' Cov g + (discrepancy_rel_sd E)^2)`` with
        ``g = integral dP/dtheta dt`` (``EnergyModel.predictive_variance_J2``).
    """
    n = len(recording.frame)
    power = np.broadcast_to(np.asarray(model.power_W(state), dtype=float), (n,)).astype(float)
    jac = np.broadcast_to(model.power_jacobian(state), (n, len(model.names)))
    energy = integrate_J(recording, power)
    gradient = np.array([integrate_J(recording, column) for column in jac.T])
    sd = float(np.sqrt(model.predictive_variance_J2(gradient, energy)))
    return RunEnergy(power, energy, sd, float(np.sqrt(model.energy_variance_J2(gradient))))


def replay(recording: Recording, model: EnergyModel, world=None,
           sensor_rate_Hz: float = 0.0, conditions=None) -> Replay:
    """Compare a recording's power with the model's prediction along the same motion.

    Parameters
    ----------
    recording : cleaned recording (``load_recording``)
    model : the energy model (e.g. ``load_context(scenario).model``)
    world : the scenario's World (surfaces, default rolling coefficient, wind)
    sensor_rate_Hz : sensor rate where the recording has no ``sensor_rate_Hz`` column [Hz]
    conditions : the scenario's operating conditions (sensor rate and the channel values
        where the recording lacks their column; ``telemetry.state.recording_state``)

    Returns
    -------
    Replay
    """
    recorded = recording.frame["power_W"].to_numpy(float)
    state = recording_state(recording, world, sensor_rate_Hz, conditions=conditions)
    predicted = run_energy(recording, model, state)
    e_rec = float(cumulative_J(recording, recorded)[-1])
    e_pred = predicted.energy_J
    error_pct = 100.0 * (e_pred - e_rec) / abs(e_rec) if e_rec != 0 else float("nan")
    rmse = float(np.sqrt(np.mean((predicted.power_W - recorded) ** 2)))
    return Replay(recording.source, recording.t_s, recorded, predicted.power_W, e_rec, e_pred,
                  error_pct, rmse, recording.duration_s, predicted.sd_J)


def check_positions_on_map(recording: Recording, world) -> None:
    """Refuse a recording whose positions lie far outside the map (another frame or origin):
    ``world.positions.check_on_map``, the rule every entry point applies.

    Raises
    ------
    InputError
        Naming how many positions lie off the map, the first such sample and how far off.
    """
    frame = recording.frame
    if "x_m" in frame and "y_m" in frame:
        check_on_map(world, frame["x_m"].to_numpy(float), frame["y_m"].to_numpy(float),
                     recording.source)


def replay_context(recording: Recording, ctx) -> Replay:
    """``replay`` with a scenario Context's model, world and sensor rate."""
    return replay(recording, ctx.model, ctx.world, conditions=ctx.conditions)
