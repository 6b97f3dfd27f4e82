"""Battery capacity decay (the paper's Eq. 3), the four loss groups eta_1..eta_4, and the
energy used from measured power."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from orange_plan.errors import InputError

J_PER_WH = 3600.0


@dataclass(frozen=True)
class Losses:
    """Fractions of energy lost, the paper's eta_1..eta_4 (each in [0, 1)).

    Parameters
    ----------
    battery : eta_1, charge storage (self-discharge) loss [-]
    motor : eta_2, drive motor loss [-]
    mechanical : eta_3, power-train loss [-]
    ancillary : eta_4, heat lost by sensors, drivers, controllers [-]
    """

    battery: float
    motor: float
    mechanical: float
    ancillary: float

    def __post_init__(self):
        for name in ("battery", "motor", "mechanical", "ancillary"):
            value = getattr(self, name)
            if not (0.0 <= value < 1.0):
                raise InputError(
                    f"losses.{name} = {value!r} must be a fraction in [0, 1) "
                    "(efficiency 1 - loss must lie in (0, 1])"
                )

    @property
    def omega(self) -> float:
        """Manoeuvring efficiency ``Omega = (1 - eta_2)(1 - eta_3)`` [-] (Eq. 4)."""
        return (1.0 - self.motor) * (1.0 - self.mechanical)


@dataclass(frozen=True)
class Battery:
    """A battery with capacity decay by cycles and age (Eq. 3).

    Parameters
    ----------
    rated_energy_Wh : E_O, rated energy [Wh]
    cycles : C, charge cycles so far [-]
    age_days : t, calendar age [day]
    k1_per_cycle : decay per cycle [1/cycle]
    k2_per_day : decay per day [1/day]
    storage_loss : eta_1, self-discharge fraction [-]
    """

    rated_energy_Wh: float
    cycles: float = 0.0
    age_days: float = 0.0
    k1_per_cycle: float = 0.0
    k2_per_day: float = 0.0
    storage_loss: float = 0.0

    def __post_init__(self):
        if not (self.rated_energy_Wh > 0 and math.isfinite(self.rated_energy_Wh)):
            raise InputError(
                f"battery.rated_energy_Wh = {self.rated_energy_Wh!r} must be a positive number"
            )
        for name in ("cycles", "age_days", "k1_per_cycle", "k2_per_day"):
            value = getattr(self, name)
            if not (value >= 0 and math.isfinite(value)):
                raise InputError(f"battery.{name} = {value!r} must be >= 0")
        if not (0.0 <= self.storage_loss < 1.0):
            raise InputError(f"losses.battery = {self.storage_loss!r} must be in [0, 1)")

    @property
    def rated_energy_J(self) -> float:
        """E_O in joules [J]."""
        return J_PER_WH * self.rated_energy_Wh

    @property
    def capacity_J(self) -> float:
        """Decayed capacity ``E = E_O exp(-(k1 C + k2 t))`` [J] (Eq. 3)."""
        decay = self.k1_per_cycle * self.cycles + self.k2_per_day * self.age_days
        return self.rated_energy_J * math.exp(-decay)

    @property
    def storage_loss_J(self) -> float:
        """Energy eta_1 takes (self-discharge) [J]."""
        return self.capacity_J * self.storage_loss

    @property
    def usable_J(self) -> float:
        """Usable energy ``E_avail = E (1 - eta_1)`` [J]."""
        return self.capacity_J * (1.0 - self.storage_loss)


def energy_used_after(start_J: float, power_W, dt_s) -> np.ndarray:
    """Battery energy used after each sample [J]: ``start + cumsum(P dt)``, held at 0 from
    below. A negative power (regeneration: braking, going downhill) gives energy back, but a
    full battery takes no more: the energy used never goes below 0, and the energy left
    never exceeds the battery's.

    This is the running clamp ``E_k = max(0, E_{k-1} + P_k dt_k)``, in closed form:
    ``S_k - min(0, min_{j<=k} S_j)`` with ``S`` the unclamped sum.

    Parameters
    ----------
    start_J : energy used before the first sample [J] (>= 0)
    power_W : battery power per sample [W] (negative: regeneration)
    dt_s : time each sample's power lasts [s]
    """
    total = float(start_J) + np.cumsum(np.asarray(power_W, float) * np.asarray(dt_s, float))
    return total - np.minimum(0.0, np.minimum.accumulate(total))
