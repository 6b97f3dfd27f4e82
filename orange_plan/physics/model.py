"""EnergyModel: an ordered set of physics terms with coefficients and their covariance."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from orange_plan.errors import InputError
from orange_plan.physics import ops
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import ROLLING_DEFAULT_GROUND, Term


@dataclass(frozen=True)
class SegmentEnergy:
    """Battery-side energy of straight steps (arrays broadcast like the inputs).

    Attributes
    ----------
    ancillary_J : power terms x mission time (stops included through the duty cycle) [J]
    traversal_J : ``max(0, F) L`` minus any regenerated energy [J] (Eq. 2, 7)
    turning_J : turning losses at the step's start vertex [J]
    moving_time_s : ``L / v`` [s]
    mission_time_s : ``L / (v D)`` [s]
    """

    ancillary_J: object
    traversal_J: object
    turning_J: object
    moving_time_s: object
    mission_time_s: object

    @property
    def total_J(self):
        """Ancillary + traversal + turning [J]."""
        return self.ancillary_J + self.traversal_J + self.turning_J


class EnergyModel:
    """Battery power as an ordered sum of physics terms (each term linear in one lumped coefficient).

    Parameters
    ----------
    terms : the terms, in order; a switched-off term is simply absent
    theta : coefficient values by name (every coefficient of every term)
    cov : covariance of the coefficients in ``names`` order; default zeros
    omega : manoeuvring efficiency Omega (kept for reports; the lumped coefficients carry it,
        and ``regen`` does not use it) [-]
    discrepancy_rel_sd : run-to-run (model discrepancy) standard deviation of a whole run's
        energy, relative to the predicted energy [-]: what the same motion draws differently
        from run to run beyond what any coefficient values explain; default 0

    Notes
    -----
    Time domain: ``P = sum_power theta phi + max(0, F) v - eff max(0, -F) v
    + sum_rate theta |yaw rate|`` with ``F = sum_force theta phi`` the lumped traction force
    (positive when the motors drive) and ``eff`` the ``regen`` efficiency (0 without it):
    with ``P_mech = F v`` the traction power, braking returns ``P_regen = -eff max(0,
    -P_mech)``, the same form in the time domain, on a path and in the speed optimiser.
    Path domain: a step of length L at speed v costs ``P_power L / (v D)
    + max(0, F) L + theta_turn |heading change|``.
    Predictive variance of a run's energy E with gradient g = dE/dtheta:
    ``g' Cov g + (discrepancy_rel_sd E)^2`` (``predictive_variance_J2``).
    """

    def __init__(
        self,
        terms: Sequence[Term],
        theta: Mapping[str, float],
        cov: np.ndarray | None = None,
        omega: float = 1.0,
        discrepancy_rel_sd: float = 0.0,
    ):
        ids = [t.id for t in terms]
        if len(set(ids)) != len(ids):
            raise InputError(f"EnergyModel terms repeat an id: {ids}")
        if "surface_rolling" in ids:
            # Surface points belong to surface_rolling; plain rolling keeps default ground only.
            terms = [ROLLING_DEFAULT_GROUND if t.id == "rolling" else t for t in terms]
        self.terms: tuple[Term, ...] = tuple(terms)
        self.names: tuple[str, ...] = tuple(c for t in terms for c in t.coefficients)
        missing = [n for n in self.names if n not in theta]
        if missing:
            raise InputError(f"EnergyModel: no value for coefficient(s) {missing}")
        extra = sorted(set(theta) - set(self.names))
        if extra:
            raise InputError(f"EnergyModel: coefficient(s) {extra} belong to no term")
        self.theta = np.array([float(theta[n]) for n in self.names])
        if not np.all(np.isfinite(self.theta)):
            raise InputError("EnergyModel: coefficients must be finite")
        k = len(self.names)
        self.cov = np.zeros((k, k)) if cov is None else np.asarray(cov, dtype=float)
        if self.cov.shape != (k, k):
            raise InputError(f"EnergyModel: cov has shape {self.cov.shape}, expected {(k, k)}")
        if not (0.0 < omega <= 1.0):
            raise InputError(f"EnergyModel: omega = {omega!r} must be in (0, 1]")
        self.omega = float(omega)
        if not (np.isfinite(discrepancy_rel_sd) and discrepancy_rel_sd >= 0.0):
            raise InputError(f"EnergyModel: discrepancy_rel_sd = {discrepancy_rel_sd!r} must be "
                             ">= 0")
        self.discrepancy_rel_sd = float(discrepancy_rel_sd)

    # --- bookkeeping ------------------------------------------------------------------
    @property
    def term_ids(self) -> tuple[str, ...]:
        return tuple(t.id for t in self.terms)

    def has(self, term_id: str) -> bool:
        return term_id in self.term_ids

    def coefficient(self, name: str) -> float:
        """Value of one coefficient by name."""
        try:
            return float(self.theta[self.names.index(name)])
        except ValueError:
            raise InputError(f"no coefficient named {name!r}; have {list(self.names)}") from None

    def stderr(self) -> dict[str, float]:
        """Standard error of each coefficient, by name."""
        return dict(zip(self.names, np.sqrt(np.clip(np.diag(self.cov), 0.0, None))))

    def as_dict(self) -> dict[str, float]:
        return dict(zip(self.names, self.theta.tolist()))

    def with_theta(self, theta: Mapping[str, float], cov: np.ndarray | None = None) -> EnergyModel:
        """The same terms with new coefficients (and covariance, if given)."""
        merged = {**self.as_dict(), **theta}
        return EnergyModel(self.terms, merged, self.cov if cov is None else cov, self.omega,
                           self.discrepancy_rel_sd)

    def with_discrepancy(self, discrepancy_rel_sd: float) -> EnergyModel:
        """The same model with another run-to-run relative standard deviation [-]."""
        return EnergyModel(self.terms, self.as_dict(), self.cov, self.omega, discrepancy_rel_sd)

    def with_terms(self, terms: Sequence[Term], theta: Mapping[str, float]) -> EnergyModel:
        """A model with other terms; known coefficients keep their values and variances."""
        merged = {**{n: v for n, v in self.as_dict().items()}, **theta}
        names = [c for t in terms for c in t.coefficients]
        model = EnergyModel(terms, {n: merged[n] for n in names}, None, self.omega,
                            self.discrepancy_rel_sd)
        old = {n: i for i, n in enumerate(self.names)}
        for i, a in enumerate(model.names):
            for j, b in enumerate(model.names):
                if a in old and b in old:
                    model.cov[i, j] = self.cov[old[a], old[b]]
        return model

    # --- evaluation ---------------------------------------------------------------------
    def _group_sum(self, state: MotionState, group: str, theta=None):
        theta = self.theta if theta is None else theta
        total, i = 0.0, 0
        for term in self.terms:
            n = len(term.coefficients)
            if term.group == group:
                for k, phi in enumerate(term.features(state)):
                    total = total + theta[i + k] * phi
            i += n
        return total

    def regen_fraction(self, theta=None) -> float:
        """Share r of the negative traction power ``F v`` that returns to the battery [-]: the
        ``regen_efficiency`` itself (0 without a ``regen`` term).

        Why not a further ``Omega^2`` (the drivetrain passed twice): the lumped force already
        carries an Omega that only the fit knows (``inertia_kg = m / Omega``), so an assumed
        one makes the efficiency a product with a guess; on the BMW i3 trips it then had to
        exceed 1 (1.02-1.08), held at its bound. As the share of the model's own negative
        traction power it is what a recording identifies (0.6-0.8 on those trips)."""
        if not self.has("regen"):
            return 0.0
        theta = self.theta if theta is None else theta
        return theta[self.names.index("regen_efficiency")]

    def ancillary_power_W(self, state: MotionState, theta=None):
        """Sum of the ``power`` terms at ``state`` [W] (P_anc, Eq. 10)."""
        return self._group_sum(state, "power", theta)

    def traction_force_N(self, state: MotionState, theta=None):
        """Lumped net traction force ``F / Omega`` [N] (before the no-recovery clip)."""
        return self._group_sum(state, "force", theta)

    def charged_force_N(self, force, positive_part=None, theta=None):
        """The no-recovery clip: the traction force charged to the battery [N].

        ``max(0, F) - r max(0, -F)``, written ``r F + (1 - r) max(0, F)`` (equal for every
        F). ``positive_part`` stands for ``max(0, F)``: an optimiser passes its epigraph
        variable ``s >= F, s >= 0`` there (``planning.speed``), exact at its optimum.
        """
        positive = ops.fmax(force, 0.0) if positive_part is None else positive_part
        if not self.has("regen"):  # not `if regen`: theta may be a CasADi symbol
            return positive
        regen = self.regen_fraction(theta)
        return regen * force + (1 - regen) * positive

    def traversal_power_W(self, state: MotionState, theta=None):
        """Battery power for traction: ``max(0,F) v`` minus regeneration [W]."""
        force = self.traction_force_N(state, theta)
        return self.charged_force_N(force, theta=theta) * state.speed_mps

    def load_power_W(self, state: MotionState, theta=None):
        """Power the loads draw, before any in-battery loss: ancillary + traction + turning [W]."""
        return (
            self.ancillary_power_W(state, theta)
            + self.traversal_power_W(state, theta)
            + self._group_sum(state, "rate", theta)
        )

    def battery_loss_factor(self, state: MotionState, theta=None):
        """``B`` of the in-battery I^2 R loss ``B P^2`` [1/W] (0 without ``battery`` terms)."""
        return self._group_sum(state, "battery", theta)

    def power_W(self, state: MotionState, theta=None):
        """Battery power at ``state`` in the time domain [W]: the load power ``P`` plus the
        in-battery loss, ``P (1 + B P)`` (``physics.terms``)."""
        load = self.load_power_W(state, theta)
        if not self._has_group("battery"):
            return load
        return load * (1.0 + self.battery_loss_factor(state, theta) * load)

    def _has_group(self, group: str) -> bool:
        return any(t.group == group for t in self.terms)

    def segment_energy(
        self,
        state: MotionState,
        length_m,
        duty_cycle,
        heading_change_rad=0.0,
        theta=None,
    ) -> SegmentEnergy:
        """Energy of straight steps of 3-D length ``length_m`` at ``state``.

        Parameters
        ----------
        state : motion state per step (speed, grade, direction, wind, crr...)
        length_m : 3-D step length L [m]
        duty_cycle : D, fraction of mission time spent moving (0, 1] [-]
        heading_change_rad : heading change at the step's start vertex [rad]

        Returns
        -------
        SegmentEnergy
        """
        moving_time_s = length_m / state.speed_mps
        mission_time_s = moving_time_s / duty_cycle
        ancillary_J = self.ancillary_power_W(state, theta) * mission_time_s
        traversal_J = self.traversal_power_W(state, theta) * moving_time_s
        turning_J = self.turning_energy_J(heading_change_rad, theta)
        if self._has_group("battery"):
            # I^2 R at the step's mean load power, shared by the loads in proportion to their
            # draw: (A + T)(1 + B P_mean) = A + T + B P_mean^2 t_mission.
            scale = 1.0 + self.battery_loss_factor(state, theta) * self._mean_load_W(
                ancillary_J, traversal_J, mission_time_s)
            ancillary_J, traversal_J = ancillary_J * scale, traversal_J * scale
        return SegmentEnergy(ancillary_J, traversal_J, turning_J, moving_time_s, mission_time_s)

    @staticmethod
    def _mean_load_W(ancillary_J, traversal_J, mission_time_s):
        """Mean load power of a step (its ancillary and traction energy over its time) [W]."""
        return (ancillary_J + traversal_J) / mission_time_s

    def turning_energy_J(self, heading_change_rad, theta=None):
        """Energy of the ``rate`` terms for heading changes [J] (0 without such terms)."""
        state = MotionState(speed_mps=0.0 * heading_change_rad, yaw_rate_radps=heading_change_rad)
        return self._group_sum(state, "rate", theta) + 0.0 * heading_change_rad

    # --- linearisation (calibration, reserve sizing) -------------------------------------
    def power_jacobian(self, state: MotionState) -> np.ndarray:
        """d power / d theta at numeric ``state``, shape ``(n_samples, n_coefficients)``.

        The no-recovery clip is applied as a mask at the current coefficients; ``regen``'s
        column is the (negative) recovered power per unit efficiency.
        """
        force = np.asarray(self.traction_force_N(state), dtype=float)
        speed = np.asarray(state.speed_mps, dtype=float)
        shape = np.broadcast(force, speed).shape
        moving_on = np.broadcast_to(force >= 0, shape)  # at F = 0: the side a push moves to
        columns = []
        for term in self.terms:
            phis = [np.broadcast_to(np.asarray(p, dtype=float), shape) for p in term.features(state)]
            if term.group == "power" or term.group == "rate":
                columns += phis
            elif term.group == "force":
                regen = self.regen_fraction()
                columns += [np.where(moving_on, p * speed, regen * p * speed) for p in phis]
            elif term.group == "regen":  # d/d(eff) of -eff max(0, -F) v
                columns.append(-np.maximum(-force, 0.0) * speed)
            else:  # battery: filled in below, once the load power is known
                columns += [None] * len(phis)
        return self._with_battery_loss(state, columns, shape,
                                       lambda: np.asarray(self.load_power_W(state), float))

    def _with_battery_loss(self, state, columns, shape, load, duration=1.0) -> np.ndarray:
        """Jacobian columns of the loads turned into those of ``E (1 + B E / duration)`` (the
        in-battery loss, ``E`` the load energy or power): a load column scales by
        ``1 + 2 B E / duration``, a battery coefficient's column is ``phi E^2 / duration``."""
        if not self._has_group("battery"):
            return np.stack([np.broadcast_to(c, shape) for c in columns], axis=-1)
        load = np.broadcast_to(load(), shape)
        factor = np.broadcast_to(np.asarray(self.battery_loss_factor(state), float), shape)
        phis = iter(np.broadcast_to(np.asarray(p, float), shape) for t in self.terms
                    if t.group == "battery" for p in t.features(state))
        out = [next(phis) * load**2 / duration if c is None
               else np.broadcast_to(c, shape) * (1.0 + 2.0 * factor * load / duration)
               for c in columns]
        return np.stack(out, axis=-1)

    def segment_energy_jacobian(
        self, state: MotionState, length_m, duty_cycle, heading_change_rad=0.0
    ) -> np.ndarray:
        """d(segment energy)/d theta at numeric ``state``, shape ``(n_steps, n_coefficients)``.

        Energy is linear in theta apart from the no-recovery clip, applied here as a mask at
        the current coefficients; with it, ``jacobian @ theta`` equals the segment energy (without
        ``regen``: its efficiency multiplies the force coefficients, a bilinear product).
        """
        length = np.asarray(length_m, dtype=float)
        speed = np.asarray(state.speed_mps, dtype=float)
        moving_s = length / speed
        force = np.asarray(self.traction_force_N(state), dtype=float)
        shape = np.broadcast(force, speed, length).shape
        regen = self.regen_fraction()
        turn_state = MotionState(speed_mps=speed, yaw_rate_radps=heading_change_rad)
        columns = []
        for term in self.terms:
            source = turn_state if term.group == "rate" else state
            for phi in term.features(source):
                phi = np.asarray(phi, dtype=float)
                if term.group == "power":
                    columns.append(phi * moving_s / duty_cycle)
                elif term.group == "rate":
                    columns.append(phi)
                elif term.group == "force":
                    columns.append(np.where(force > 0, phi * length, regen * phi * length))
                elif term.group == "regen":  # recovered energy is -eff max(0, -F) L
                    columns.append(-np.maximum(-force, 0.0) * length)
                else:  # battery: filled in below
                    columns.append(None)
        if not self._has_group("battery"):
            return np.stack([np.broadcast_to(c, shape) for c in columns], axis=-1)
        # the turning columns (rate terms) are charged at a vertex, outside the mean load
        plain = EnergyModel(tuple(t for t in self.terms if t.group != "battery"),
                            {n: v for n, v in self.as_dict().items() if n in self._plain_names()},
                            None, self.omega)
        e = plain.segment_energy(state, length_m, duty_cycle, heading_change_rad)
        mission = np.asarray(e.mission_time_s, float)
        rate = {i for i, t in enumerate(self._coefficient_groups()) if t == "rate"}
        turn = [c if i in rate else None for i, c in enumerate(columns)]
        load = [None if c is None else (0.0 * c if i in rate else c) for i, c in enumerate(columns)]
        jac = self._with_battery_loss(state, load, shape,
                                      lambda: np.asarray(e.ancillary_J + e.traversal_J, float),
                                      np.broadcast_to(mission, shape))
        for i, c in enumerate(turn):
            if c is not None:
                jac[..., i] += np.broadcast_to(c, shape)
        return jac

    def _plain_names(self) -> set[str]:
        return {c for t in self.terms if t.group != "battery" for c in t.coefficients}

    def _coefficient_groups(self) -> list[str]:
        return [t.group for t in self.terms for _ in t.coefficients]

    def energy_variance_J2(self, gradient: np.ndarray) -> np.ndarray:
        """Parameter part ``g' Cov g`` of energies with gradients ``gradient`` (..., k) [J^2]."""
        g = np.asarray(gradient, dtype=float)
        return np.einsum("...i,ij,...j->...", g, self.cov, g)

    def predictive_variance_J2(self, gradient: np.ndarray, energy_J) -> np.ndarray:
        """Predictive variance of runs' energies: what a confidence reserve is sized from [J^2].

        Parameters
        ----------
        gradient : dE/dtheta of each run (..., k) [J per coefficient unit]
        energy_J : predicted energy E of each run (broadcasts with ``gradient[..., 0]``) [J]

        Returns
        -------
        ndarray
            ``g' Cov g + (discrepancy_rel_sd E)^2``, shape of the broadcast [J^2].

        Notes
        -----
        Two independent sources: the coefficients' uncertainty (their covariance) and the
        run-to-run discrepancy, the spread of real runs around the best model (estimated from
        held-out recordings at calibration time, ``Calibrator.discrepancy_rel_sd_``). A
        ``confidence = p`` reserve is ``z_p`` times its square root (``mission.reserve``: docs/formats.md).
        """
        disc = self.discrepancy_rel_sd * np.asarray(energy_J, dtype=float)
        return self.energy_variance_J2(gradient) + disc**2
