"""Replay a recording's motion through an EnergyModel: predicted vs recorded power and energy.

The prediction uses nothing but ``EnergyModel.power_W`` on the recording's per-sample
MotionState (``motion_state``), so it is the same physics the planner uses. Energies are
trapezoid integrals over time with the recording's gaps skipped on both sides.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from orange_plan.physics.model import EnergyModel
from orange_plan.telemetry.recording import Recording, cumulative_J, motion_state


@dataclass(frozen=True)
class Replay:
    """Recorded and predicted battery power of one recording.

    Attributes
    ----------
    source : the recording's source
    t_s : sample times [s]
    recorded_W, predicted_W : battery power per sample [W]
    energy_recorded_J, energy_predicted_J : integrals over the run, gaps skipped [J]
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

    def to_dict(self) -> dict:
        """SPEC §5 keys of ``predict --json`` plus the sample count and mean powers."""
        return {
            "energy_recorded_J": self.energy_recorded_J,
            "energy_predicted_J": self.energy_predicted_J,
            "energy_error_pct": self.energy_error_pct,
            "rmse_W": self.rmse_W,
            "duration_s": self.duration_s,
            "recording": self.source,
            "samples": int(self.t_s.size),
            "mean_recorded_W": float(np.mean(self.recorded_W)),
            "mean_predicted_W": float(np.mean(self.predicted_W)),
        }


def predicted_power_W(recording: Recording, model: EnergyModel, world=None,
                      sensor_rate_Hz: float = 0.0) -> np.ndarray:
    """Battery power the model predicts at every sample of a recording [W] (n,)."""
    state = motion_state(recording, world, sensor_rate_Hz=sensor_rate_Hz)
    power = np.asarray(model.power_W(state), dtype=float)
    return np.broadcast_to(power, (len(recording.frame),)).astype(float)


def replay(recording: Recording, model: EnergyModel, world=None,
           sensor_rate_Hz: float = 0.0) -> Replay:
    """Compare a recording's power with the model's prediction along the same motion.

    Parameters
    ----------
    recording : cleaned recording (``load_recording``)
    model : the energy model (e.g. ``load_context(scenario).model``)
    world : the scenario's World (surfaces, default rolling coefficient, wind)
    sensor_rate_Hz : sensor rate where the recording has no ``sensor_rate_Hz`` column [Hz]

    Returns
    -------
    Replay
    """
    recorded = recording.frame["power_W"].to_numpy(float)
    predicted = predicted_power_W(recording, model, world, sensor_rate_Hz)
    e_rec = float(cumulative_J(recording, recorded)[-1])
    e_pred = float(cumulative_J(recording, predicted)[-1])
    error_pct = 100.0 * (e_pred - e_rec) / abs(e_rec) if e_rec != 0 else float("nan")
    rmse = float(np.sqrt(np.mean((predicted - recorded) ** 2)))
    return Replay(recording.source, recording.t_s, recorded, predicted, e_rec, e_pred,
                  error_pct, rmse, recording.duration_s)


def replay_context(recording: Recording, ctx) -> Replay:
    """``replay`` with a scenario Context's model, world and sensor rate."""
    return replay(recording, ctx.model, ctx.world, ctx.sensor_rate_Hz)
