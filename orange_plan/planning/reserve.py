"""Reserve rules: the energy kept back for getting home (``mission.reserve``: docs/formats.md), one object per rule.

A scenario's ``mission.reserve`` names one of three rules; ``reserve_from`` turns it into one
of the objects below, and planning asks that object rather than the rule's name:

* ``ConfidenceReserve(p)`` (``confidence = p``): the energy still to be drawn is taken as
  normal around its prediction with the model's predictive variance, and ``z_p`` standard
  deviations are kept back, so that the robot gets home with probability ``p``;
* ``FractionReserve(f)`` (``fraction = f``): ``f E_avail`` is kept back;
* ``EnergyReserve(E)`` (``energy_J = E``): ``E`` joules are kept back.

Every rule answers the same questions (``ReserveRule``): its size for a predicted energy and
variance (``size_J``), whether that needs the variance at all (``needs_variance``), the
probability of getting home for a slack and a spread (``return_probability``: the same normal
law for every rule), a budget guess before any path exists (``budget_guess_J``) and one line
for users (``describe``).

Return reserve: in the closed loop the energy already spent is measured, not predicted, so
only the way home is still uncertain; ``return_only_J`` is the reserve for that return alone
(a confidence reserve of the return's spread; the fixed rules keep their fixed amount), and
``RETURN_SPREAD_FLOOR`` the least relative spread a closed loop takes for that return.

The normal distribution is scipy's ``ndtr`` / ``ndtri`` (the functions behind
``scipy.stats.norm``, without the seconds ``scipy.stats`` takes to import), the package's one
implementation of it.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from scipy.special import ndtr, ndtri

from orange_plan.errors import InputError

RETURN_SPREAD_FLOOR = 0.2
"""A closed loop's way home is never taken as better known than this share of the model's
a-priori run-to-run discrepancy (``EnergyModel.discrepancy_rel_sd``) [-]: the estimator learns
the run on the way out, the way back crosses other ground in other headings. At confidence
0.99 on the study's robot (discrepancy 0.25) it keeps 2.33 x 0.2 x 0.25 = 11.7 % of the
return's energy. Sized on 200 training returns of ``bench mission`` (seeds 1000-1199, apart
from the benchmark's 0-499): the route flown home against the session's own prediction of it
(``MissionSession.homeward_energy_J``) was 1.3 % cheaper on average, sd 3.2 %, at worst 3.8 %
dearer: the floor is that spread rounded up by half and more, about three times the worst
excess. It covers the return alone: the batch before the turn is the look-ahead's, which
charges at least the last batch's draw (without that floor of the look-ahead, one of the
benchmark's 500 missions stranded by 14 J with this reserve: its last batch drew 172 J where
the stretch ahead was costed at about 100)."""


def normal_quantiles(p) -> np.ndarray:
    """Quantiles of the standard normal law at probabilities ``p`` (array-like, 0..1)."""
    return ndtri(np.asarray(p, float))


def normal_upper_tail(x) -> np.ndarray:
    """``1 - Phi(x)``: the standard normal law's probability above ``x`` (array-like),
    accurate far out in the tail, where ``1 - ndtr(x)`` rounds to 0."""
    return ndtr(-np.asarray(x, float))


def closed_loop_return_spread(model) -> float:
    """The least relative spread [-] a closed loop takes for its way home:
    ``RETURN_SPREAD_FLOOR`` of ``model``'s a-priori run-to-run discrepancy. The session's
    live check keeps it, and sweeps are chosen under it, so both use this one rule."""
    return RETURN_SPREAD_FLOOR * float(model.discrepancy_rel_sd)


def _broadcast(values, *operands) -> np.ndarray:
    """``values`` as a new float array of the shape the operands broadcast to."""
    shape = np.broadcast_shapes(np.shape(values), *(np.shape(o) for o in operands))
    return np.array(np.broadcast_to(values, shape), dtype=float)


@dataclass(frozen=True)
class ReserveRule(ABC):
    """A reserve rule: the energy kept back for getting home.

    Attributes
    ----------
    value : the rule's number as the scenario gives it (p [-], f [-] or E [J])
    kind : the scenario's key for the rule (``confidence``, ``fraction``, ``energy_J``)
    needs_variance : whether sizing the reserve needs the predictive variance (the exact
        checks compute energy gradients only then)
    """

    value: float
    kind: ClassVar[str]
    needs_variance: ClassVar[bool] = False

    def __post_init__(self):
        # numpy scalars and ints from callers become one plain float (equality, text)
        try:
            value = float(self.value)
        except (TypeError, ValueError):
            raise InputError(f"reserve {self.kind} must be a number, got {self.value!r}") from None
        object.__setattr__(self, "value", value)

    @abstractmethod
    def size_J(self, energy_J, variance_J2, energy_available_J) -> np.ndarray:
        """Energy kept back [J], broadcast over the three arguments.

        Parameters
        ----------
        energy_J : predicted energy still to be drawn (the trip so far plus the return) [J]
        variance_J2 : its predictive variance,
            ``EnergyModel.predictive_variance_J2(g, E)`` = ``g' Cov g + (discrepancy_rel_sd
            E)^2`` (coefficient uncertainty plus run-to-run discrepancy) [J^2]
        energy_available_J : usable battery energy E_avail [J]
        """

    def return_only_J(self, return_energy_J, return_variance_J2,
                      energy_available_J) -> np.ndarray:
        """Reserve for the uncertainty of the way home alone [J] (closed loop).

        Once the robot is under way the energy it has spent is measured, so only the return
        is still a prediction: a confidence reserve is ``z_p`` times the return's predictive
        sd (``return_variance_J2``), not that of the whole trip; a fraction or a fixed energy
        is the same amount as ``size_J`` (it does not depend on any prediction).

        Parameters
        ----------
        return_energy_J : predicted energy of the way home [J]
        return_variance_J2 : its predictive variance [J^2]
        energy_available_J : usable battery energy E_avail [J]
        """
        return self.size_J(return_energy_J, return_variance_J2, energy_available_J)

    @abstractmethod
    def budget_guess_J(self, left_J: float, available_J: float,
                       discrepancy_rel_sd: float) -> float:
        """Energy left for driving once the reserve is set aside, guessed before any path
        exists [J].

        Parameters
        ----------
        left_J : battery energy not yet spent [J]
        available_J : usable battery energy E_avail [J]
        discrepancy_rel_sd : the model's run-to-run spread relative to the energy [-]; a
            confidence reserve is guessed as ``z_p`` times that spread of the driving energy
            (the coefficient part depends on the path and is left to the exact check)
        """

    @abstractmethod
    def describe(self) -> str:
        """The rule in one line for users, e.g. ``95 % confidence of getting home``."""

    def rule_text(self) -> str:
        """The rule as the scenario writes it, e.g. ``confidence = 0.95`` (the plan summary's
        ``reserve_rule``)."""
        return f"{self.kind} = {self.value:g}"

    def falls_short(self, probability: float) -> bool:
        """Whether a probability of getting home is below what the rule promises (only a
        confidence rule promises one)."""
        return False

    def rescaled_J(self, reserve_J, energy_ratio: float):
        """A reserve sized for some energies, once every energy is ``energy_ratio`` times its
        planned value [J]: fixed rules keep their amount."""
        return reserve_J

    @staticmethod
    def return_probability(slack_J, sd_J) -> np.ndarray:
        """Probability of getting home [-], broadcast over the arguments.

        The energy still needed is taken as normal around its prediction with standard
        deviation ``sd_J``; ``slack_J`` is the energy left beyond that prediction
        (``E_avail - E_used - E_home``). A zero spread makes it certain: 1 when the slack is
        >= 0, else 0. The same law for every rule (a plan reports it whatever the reserve).
        """
        slack = np.asarray(slack_J, float)
        sd = np.asarray(sd_J, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.where(sd > 0, slack / sd, np.where(slack >= 0, np.inf, -np.inf))
        return ndtr(z)


@dataclass(frozen=True)
class ConfidenceReserve(ReserveRule):
    """``confidence = p``: ``z_p`` predictive standard deviations kept back, so that the
    robot gets home with probability ``p`` (the reserve is sized by the model, not
    a magic margin). ``bench calibration`` measures how often real runs exceed it.

    A ``p`` below 0.5 gives a negative ``z_p``: the plan may then count on drawing less than
    predicted.
    """

    kind: ClassVar[str] = "confidence"
    needs_variance: ClassVar[bool] = True

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 < self.value < 1.0:
            raise InputError(f"reserve confidence = {self.value:g} must be in (0, 1)")

    @property
    def z(self) -> float:
        """The standard normal quantile ``z_p`` [-]."""
        return float(ndtri(self.value))

    def size_J(self, energy_J, variance_J2, energy_available_J) -> np.ndarray:
        sd = np.sqrt(np.clip(np.asarray(variance_J2, float), 0.0, None))
        return _broadcast(self.z * sd, energy_J, energy_available_J)

    def budget_guess_J(self, left_J: float, available_J: float,
                       discrepancy_rel_sd: float) -> float:
        # driving energy E with reserve z_p d E must fit: E + z_p d E <= left
        return left_J / (1.0 + self.z * discrepancy_rel_sd)

    def describe(self) -> str:
        return f"{100 * self.value:g} % confidence of getting home"

    def falls_short(self, probability: float) -> bool:
        return probability < self.value

    def rescaled_J(self, reserve_J, energy_ratio: float):
        # the predictive sd grows with the energy (the discrepancy term exactly, the
        # coefficient term through the gradient): the reserve scales with it
        return reserve_J * energy_ratio


@dataclass(frozen=True)
class FractionReserve(ReserveRule):
    """``fraction = f``: ``f E_avail`` kept back."""

    kind: ClassVar[str] = "fraction"

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= self.value < 1.0:
            raise InputError(f"reserve fraction = {self.value:g} must be in [0, 1)")

    def size_J(self, energy_J, variance_J2, energy_available_J) -> np.ndarray:
        return _broadcast(self.value * np.asarray(energy_available_J, float), energy_J,
                          variance_J2)

    def budget_guess_J(self, left_J: float, available_J: float,
                       discrepancy_rel_sd: float) -> float:
        return left_J - self.value * available_J

    def describe(self) -> str:
        return f"{100 * self.value:g} % of the available energy"


@dataclass(frozen=True)
class EnergyReserve(ReserveRule):
    """``energy_J = E``: ``E`` joules kept back."""

    kind: ClassVar[str] = "energy_J"

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 <= self.value < np.inf:
            raise InputError(f"reserve energy_J = {self.value:g} must be >= 0 and finite")

    def size_J(self, energy_J, variance_J2, energy_available_J) -> np.ndarray:
        return _broadcast(self.value, energy_J, variance_J2, energy_available_J)

    def budget_guess_J(self, left_J: float, available_J: float,
                       discrepancy_rel_sd: float) -> float:
        return left_J - self.value

    def describe(self) -> str:
        return f"{self.value:g} J"


RULES: dict[str, type[ReserveRule]] = {
    rule.kind: rule for rule in (ConfidenceReserve, FractionReserve, EnergyReserve)}
"""The rule for each ``mission.reserve`` key."""


def from_scenario(reserve) -> ReserveRule:
    """The rule object of a scenario's ``mission.reserve`` (``scenario.Reserve``: ``kind`` and
    ``value``); a ``ReserveRule`` is returned as it is."""
    if isinstance(reserve, ReserveRule):
        return reserve
    if reserve.kind not in RULES:
        raise InputError(f"unknown reserve rule {reserve.kind!r}: one of {', '.join(RULES)}")
    return RULES[reserve.kind](reserve.value)


def reserve_from(scenario) -> ReserveRule:
    """The rule object of a scenario's ``mission.reserve``."""
    return from_scenario(scenario.mission.reserve)
