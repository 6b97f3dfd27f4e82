"""Online ORangE: coefficients and remaining operational range updated from streamed samples.

The paper's generalised range (Eq. 11) needs the path integral of the position-, time- and
speed-dependent forces. Offline, it is approximated a priori from the map; online, it is
replaced by live data (the paper's online ORangE). Here:

1. Coefficients: exponentially-weighted, regularised recursive least squares on theta
   (equivalently a Kalman filter whose data information decays). After a batch of samples
   with Jacobian ``H`` (``EnergyModel.power_jacobian``, the no-recovery clip as a mask at the
   current theta) and power ``y``::

       D <- f D + H'H,     b <- f b + H' y_lin,     f = exp(-dt / memory_s)
       theta = (P0^-1 + D / R)^-1 (P0^-1 theta0 + b / R),   P = (P0^-1 + D / R)^-1

   with ``y_lin = y - P(theta) + H theta`` (Gauss-Newton linearisation; equal to ``y`` without
   regen). The prior (scenario theta0, covariance P0) never decays, so coefficients the
   recent data cannot see fall back to it instead of winding up. ``R`` is the noise
   variance: the exponentially-weighted mean squared residual of the current fit (same
   memory). It weighs the prior against the data only; old and new samples weigh by age
   alone, so a change (a payload picked up) is followed within about one memory.
   ``memory_s`` is the forgetting time constant: the forgetting factor per sample is
   ``lambda = exp(-dt / memory_s)``; short memories track gusts and payload changes,
   long ones average noise.
2. Energy: ``E_used`` is the measured battery energy so far (sum of P dt);
   ``E_remaining = max(0, E_avail - E_used)``.
3. Energy per metre: ``e = (G . theta + C) / d_w`` with ``G = sum H dt`` and ``d_w = sum v dt``
   over the last ``window_s`` of motion (stops included: the duty cycle is in the data).
   ``C = sum (P(theta_b) - H theta_b) dt`` at each batch's theta: zero for terms linear in
   theta; with regen (bilinear: ``H theta`` counts the recovered power twice) it restores
   the modelled power.
   Its uncertainty adds, in quadrature, the coefficient part ``sqrt(G' P G) / d_w`` and the
   variability of the conditions: the std of ``e`` over ``WINDOW_PARTS`` sub-windows divided
   by sqrt(WINDOW_PARTS) (gusts, terrain and stops make the energy per metre wander; the
   coefficient part alone is far too narrow: it holds the conditions fixed).
4. Remaining range ``E_remaining / e`` with ``sd = E_remaining sd(e) / e^2``; never
   negative; infinite when ``e <= 0`` (nothing consumed per metre, e.g. downhill).
"""

from __future__ import annotations

import itertools
import math
from collections import deque
from dataclasses import asdict, dataclass

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics.battery import energy_used_after
from orange_plan.physics.model import EnergyModel
from orange_plan.physics.state import MotionState

WINDOW_PARTS = 5
"""Sub-windows used to measure how much the energy per metre varies (gusts, terrain) [-]."""


@dataclass(frozen=True)
class OnlineEstimate:
    """The online estimator's state after an update.

    Attributes
    ----------
    t_s : mission time [s]
    theta, stderr : coefficients and their standard errors, by name
    energy_used_J, energy_remaining_J : measured energy so far, usable energy left [J]
    distance_m : distance travelled so far [m]
    energy_per_m_J, energy_per_m_sd_J : live energy per metre and its std [J/m]
    range_remaining_m, range_remaining_sd_m : remaining operational range and std [m]
    range_total_m : distance so far + remaining range [m]
    """

    t_s: float
    theta: dict
    stderr: dict
    energy_used_J: float
    energy_remaining_J: float
    distance_m: float
    energy_per_m_J: float
    energy_per_m_sd_J: float
    range_remaining_m: float
    range_remaining_sd_m: float
    range_total_m: float

    def to_dict(self) -> dict:
        return asdict(self)


class OnlineEstimator:
    """Recursive estimator of theta and the remaining range (module docstring).

    Parameters
    ----------
    model : the scenario model: its theta and covariance are the prior
    energy_available_J : usable battery energy at the start, E_avail [J]
    memory_s : forgetting time constant of the coefficient estimate [s]
    window_s : span of recent motion over which energy per metre is taken [s]

    Attributes (scikit-learn style, like ``Calibrator``)
    ----------------------------------------------------
    theta_ : current coefficients, in ``model.names`` order
    cov_ : their covariance
    """

    def __init__(self, model: EnergyModel, energy_available_J: float, memory_s: float = 300.0,
                 window_s: float = 300.0):
        for name, value in (("energy_available_J", energy_available_J), ("memory_s", memory_s),
                            ("window_s", window_s)):
            if not (value > 0 and math.isfinite(value)):
                raise InputError(f"{name} = {value!r} must be a positive number")
        self.model = model
        self.energy_available_J = float(energy_available_J)
        self.memory_s, self.window_s = float(memory_s), float(window_s)
        sd = np.sqrt(np.clip(np.diag(model.cov), 0.0, None))
        self._info0 = np.diag(np.where(sd > 0, 1.0 / np.where(sd > 0, sd, 1.0) ** 2, 0.0))
        self._theta0 = model.theta.copy()
        k = model.theta.size
        self._data_info, self._data_b = np.zeros((k, k)), np.zeros(k)
        self.theta_ = model.theta.copy()
        self.cov_ = model.cov.copy()
        self._noise_var: float | None = None
        self._data_yy = self._data_n = 0.0
        self._recent: deque = deque()  # (duration_s, distance_m, G, C) per batch
        self.t_s = self.energy_used_J = self.distance_m = 0.0

    def update(self, state: MotionState, power_W, dt_s) -> OnlineEstimate:
        """Feed a batch of samples (arrays of one value per sample; dt_s per sample or scalar).

        Raises
        ------
        InputError
            Mismatched lengths, non-finite power, negative dt.
        """
        y = np.atleast_1d(np.asarray(power_W, float))
        dt = np.broadcast_to(np.asarray(dt_s, float), y.shape)
        speed = np.broadcast_to(np.asarray(state.speed_mps, float), y.shape)
        if not np.all(np.isfinite(y)) or np.any(dt < 0) or not np.all(np.isfinite(dt)):
            raise InputError("online update needs finite power and dt_s >= 0")
        current = self.model.with_theta(dict(zip(self.model.names, self.theta_)))
        jac = np.asarray(current.power_jacobian(state), float).reshape(y.size, -1)
        pred = np.asarray(current.power_W(state), float) * np.ones(y.size)
        correction_J = float(np.sum((pred - jac @ self.theta_) * dt))
        self._learn(jac, y, pred, float(dt.sum()))
        self.t_s += float(dt.sum())
        self.energy_used_J = float(energy_used_after(self.energy_used_J, y, dt)[-1])
        self.distance_m += float(np.sum(speed * dt))
        # energy = G.theta + C: C is what G.theta misses where power is not linear-homogeneous
        # in theta (regen is bilinear: H.theta counts the recovered power twice)
        self._remember(float(dt.sum()), float(np.sum(speed * dt)), jac.T @ dt, correction_J)
        return self.estimate()

    def _learn(self, jac, y, pred, duration_s) -> None:
        f = math.exp(-duration_s / self.memory_s)
        y_lin = y - pred + jac @ self.theta_
        # data sums without the noise variance: old and new samples weigh by age alone
        self._data_info = f * self._data_info + jac.T @ jac
        self._data_b = f * self._data_b + jac.T @ y_lin
        self._data_yy = f * self._data_yy + float(y_lin @ y_lin)
        self._data_n = f * self._data_n + y.size
        if self._noise_var is None:
            self._noise_var = max(float(np.mean((y - pred) ** 2)), 1e-12)
        for _ in range(2):  # theta given R, then R from the weighted residuals of that theta
            info = self._info0 + self._data_info / self._noise_var
            self.cov_ = np.linalg.pinv(info)
            self.theta_ = self.cov_ @ (self._info0 @ self._theta0 + self._data_b / self._noise_var)
            sse = (self._data_yy - 2 * self.theta_ @ self._data_b
                   + self.theta_ @ self._data_info @ self.theta_)
            dof = max(self._data_n - np.count_nonzero(np.diag(self._data_info) > 0), 1.0)
            self._noise_var = max(sse / dof, 1e-12)
        # directions neither prior nor data inform keep the prior value
        unseen = np.diag(info) <= 0
        self.theta_[unseen] = self._theta0[unseen]

    def _remember(self, duration_s, distance_m, g, correction_J) -> None:
        self._recent.append((duration_s, distance_m, g, correction_J))
        span = sum(b[0] for b in self._recent)
        while len(self._recent) > 1 and span - self._recent[0][0] >= self.window_s:
            span -= self._recent.popleft()[0]

    def _spread_J_per_m(self) -> float:
        """Variability of the energy per metre within the window: std of the
        ``WINDOW_PARTS`` sub-window values / sqrt(WINDOW_PARTS) [J/m] (0 if too short)."""
        batches = list(self._recent)
        if len(batches) < 2 * WINDOW_PARTS:
            return 0.0
        values = []
        for part in np.array_split(np.arange(len(batches)), WINDOW_PARTS):
            dist = sum(batches[i][1] for i in part)
            g = sum((batches[i][2] for i in part), np.zeros(self.theta_.size))
            if dist <= 0:
                return 0.0
            values.append((float(g @ self.theta_) + sum(batches[i][3] for i in part)) / dist)
        return float(np.std(values, ddof=1)) / math.sqrt(WINDOW_PARTS)

    def estimate(self, route_jacobian=None, route_length_m: float | None = None) -> OnlineEstimate:
        """The current coefficients, remaining energy and remaining range.

        Parameters
        ----------
        route_jacobian : optional d(energy)/d theta of the planned route ahead, shape (k,)
            (e.g. ``pathcost.segments_energy_jacobian`` summed): energy per metre is then
            taken on that route with the current theta instead of on the recent motion
            (``route_jacobian . theta`` is the route's energy only for a model linear in
            theta, i.e. without ``regen``)
        route_length_m : that route's length [m]
        """
        if route_jacobian is not None:
            if not (route_length_m and route_length_m > 0):
                raise InputError("route_length_m must be > 0 with a route_jacobian")
            dist, g = float(route_length_m), np.asarray(route_jacobian, float)
            correction_J = 0.0
        else:
            dist = sum(b[1] for b in self._recent)
            g = sum((b[2] for b in self._recent), np.zeros(self.theta_.size))
            correction_J = sum(b[3] for b in self._recent)
        remaining = max(0.0, self.energy_available_J - self.energy_used_J)
        if dist > 0:
            e = (float(g @ self.theta_) + correction_J) / dist
            e_sd = math.hypot(math.sqrt(max(float(g @ self.cov_ @ g), 0.0)) / dist,
                              0.0 if route_jacobian is not None else self._spread_J_per_m())
        else:
            e, e_sd = float("nan"), float("nan")
        if not (e > 0):
            rng_m, rng_sd = (float("inf"), float("nan")) if dist > 0 else (float("nan"),) * 2
            if remaining == 0.0:
                rng_m, rng_sd = 0.0, 0.0
        else:
            rng_m = remaining / e
            rng_sd = rng_m * (e_sd / e)  # = remaining sd(e) / e^2 without overflowing
        names = self.model.names
        sd = np.sqrt(np.clip(np.diag(self.cov_), 0.0, None))
        return OnlineEstimate(
            t_s=self.t_s, theta=dict(zip(names, self.theta_.tolist())),
            stderr=dict(zip(names, sd.tolist())), energy_used_J=self.energy_used_J,
            energy_remaining_J=remaining, distance_m=self.distance_m, energy_per_m_J=e,
            energy_per_m_sd_J=e_sd, range_remaining_m=rng_m, range_remaining_sd_m=rng_sd,
            range_total_m=self.distance_m + rng_m if rng_m == rng_m else float("nan"))


def stream(estimator: OnlineEstimator, state: MotionState, power_W, t_s, batch_s: float = 1.0,
           until_s: float | None = None) -> list[OnlineEstimate]:
    """Feed a whole recording in batches of ``batch_s`` (as a robot would), up to ``until_s``.

    ``dt`` of a sample is its forward interval (the last sample gets the median interval).
    Returns the estimate after each batch.
    """
    t = np.asarray(t_s, float)
    y = np.asarray(power_W, float)
    if t.size < 2:
        raise InputError("streaming needs at least two samples")
    dt = np.r_[np.diff(t), np.median(np.diff(t))]
    stop = t.size if until_s is None else int(np.searchsorted(t, t[0] + until_s, "right"))
    edges = np.r_[np.arange(0, stop, max(1, round(batch_s / float(np.median(dt))))), stop]
    out = []
    for a, b in itertools.pairwise(edges):
        if b <= a:
            continue
        idx = slice(int(a), int(b))
        out.append(estimator.update(state.take(idx, t.size), y[idx], dt[idx]))
    return out
