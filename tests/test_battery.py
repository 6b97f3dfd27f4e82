"""Battery capacity decay (Eq. 3), usable energy and the four losses eta_1..eta_4."""

from __future__ import annotations

import math

import pytest

from orange_plan.errors import InputError
from orange_plan.physics.battery import Battery, Losses


def test_capacity_decay_eq3_hand_value():
    b = Battery(rated_energy_Wh=10.0, cycles=100, age_days=50, k1_per_cycle=0.001,
                k2_per_day=0.002, storage_loss=0.1)
    # E_O = 10 Wh * 3600 = 36000 J; exponent k1 C + k2 t = 0.1 + 0.1 = 0.2
    # E = 36000 * exp(-0.2) = 36000 * 0.81873075 = 29474.307 J
    assert b.rated_energy_J == 36000.0
    assert b.capacity_J == pytest.approx(29474.307, rel=1e-7)
    # eta_1 = 0.1 takes 2947.43 J, leaving 26526.88 J usable
    assert b.storage_loss_J == pytest.approx(2947.4307, rel=1e-7)
    assert b.usable_J == pytest.approx(26526.876, rel=1e-7)
    assert b.usable_J + b.storage_loss_J == pytest.approx(b.capacity_J)


def test_new_battery_has_rated_energy():
    b = Battery(rated_energy_Wh=24.4)
    assert b.capacity_J == b.usable_J == pytest.approx(87840.0)


def test_decay_monotone_in_cycles_and_age():
    base = dict(rated_energy_Wh=5.0, k1_per_cycle=0.0005, k2_per_day=0.0002)
    e = [Battery(cycles=c, age_days=t, **base).capacity_J for c, t in ((0, 0), (40, 0), (40, 120))]
    assert e[0] > e[1] > e[2]
    assert e[2] == pytest.approx(18000 * math.exp(-(0.02 + 0.024)))


def test_losses_omega_hand_value():
    losses = Losses(battery=0.03, motor=0.2, mechanical=0.1, ancillary=0.05)
    # Omega = (1 - 0.2) (1 - 0.1) = 0.72
    assert losses.omega == pytest.approx(0.72)
    assert Losses(0.0, 0.0, 0.0, 0.0).omega == 1.0


@pytest.mark.parametrize("name", ["battery", "motor", "mechanical", "ancillary"])
@pytest.mark.parametrize("value", [1.0, -0.1, 1.5])
def test_losses_bad_fraction(name, value):
    kw = dict(battery=0.0, motor=0.0, mechanical=0.0, ancillary=0.0)
    kw[name] = value
    with pytest.raises(InputError, match=rf"losses\.{name} = {value!r} must be a fraction in \[0, 1\)"):
        Losses(**kw)


@pytest.mark.parametrize(
    ("kw", "match"),
    [
        ({"rated_energy_Wh": 0.0}, r"battery.rated_energy_Wh = 0.0 must be a positive number"),
        ({"rated_energy_Wh": float("inf")}, "rated_energy_Wh = inf"),
        ({"cycles": -1}, r"battery.cycles = -1 must be >= 0"),
        ({"age_days": float("nan")}, r"battery.age_days = nan must be >= 0"),
        ({"k1_per_cycle": -0.1}, r"battery.k1_per_cycle"),
        ({"storage_loss": 1.0}, r"losses.battery = 1.0 must be in \[0, 1\)"),
    ],
)
def test_battery_bad_values(kw, match):
    with pytest.raises(InputError, match=match):
        Battery(**{"rated_energy_Wh": 10.0, **kw})
