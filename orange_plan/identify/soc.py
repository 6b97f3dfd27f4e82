"""The battery's usable energy as its state of charge shows it, mid-mission.

A scenario states the usable energy ``E_avail`` of the battery it expects (Eq. 3: rated
capacity after decay with cycles and age). A battery that has aged more than the scenario
says holds less, and energy measured as ``sum P dt`` cannot show it: only the battery's own
state of charge (the recording's optional ``soc``, 0..1 of the usable energy; see
docs/formats.md) does.

Model: ``soc_k = a - E_k / C`` with ``E_k`` the energy drawn by sample ``k`` (measured,
``sum P dt``, counted from the same origin as the scenario's ``E_avail``) and ``C`` the usable
energy [J]. A least-squares line through ``(E_k, soc_k)`` gives the slope ``b = -1/C`` and the
intercept ``a``; the battery is empty where the line reaches ``soc = 0``, at ``E = -a / b``:
that is the usable energy the state of charge shows.

Why it is safe to use: it is only said once the state of charge has fallen by
``MIN_SPAN`` over at least ``MIN_SAMPLES`` samples (a gauge's 1 % steps then move the answer
by a few percent at most), and the session counts on ``min(scenario, shown)``: a gauge that
reads high never lets the robot spend more than the scenario allows.
"""

from __future__ import annotations

import numpy as np

MIN_SPAN = 0.05
"""Fall of the state of charge [-] before the fit is used."""
MIN_SAMPLES = 10
"""Samples with a state of charge before the fit is used."""
GAUGE_STEP = 0.01
"""Resolution of a battery gauge's state of charge (1 %) [-]: the error of a reading."""


class SocCapacity:
    """Running least-squares line of state of charge against energy drawn.

    ``add`` takes samples as they arrive; ``usable_J`` answers at any time (None while the
    state of charge has not fallen enough to say). The sums are kept, not the samples, so a
    mission of any length costs the same.
    """

    def __init__(self):
        self.n = 0
        self._sums = np.zeros(5)  # sum E, sum s, sum E^2, sum E s, sum s^2
        self._soc_max = -np.inf
        self._soc_min = np.inf
        self._soc_last = np.nan
        self._scale = None  # energies are centred on the first one (round-off of E^2)

    def add(self, energy_J, soc) -> None:
        """Samples: energy drawn by each [J] and its state of charge [-] (non-finite or
        outside [0, 1]: skipped, as a gauge that has no reading)."""
        e = np.asarray(energy_J, float).ravel()
        s = np.asarray(soc, float).ravel()
        if e.shape != s.shape:
            raise ValueError(f"energy_J has {e.size} values but soc {s.size}")
        keep = np.isfinite(e) & np.isfinite(s) & (s >= 0.0) & (s <= 1.0)
        e, s = e[keep], s[keep]
        if not e.size:
            return
        if self._scale is None:
            self._scale = float(e[0])
        x = e - self._scale
        self._sums += (x.sum(), s.sum(), x @ x, x @ s, s @ s)
        self.n += int(e.size)
        self._soc_max = max(self._soc_max, float(s.max()))
        self._soc_min = min(self._soc_min, float(s.min()))
        self._soc_last = float(s[-1])

    @property
    def span(self) -> float:
        """Fall of the state of charge seen so far [-] (0 before two readings)."""
        return max(0.0, self._soc_max - self._soc_min) if self.n else 0.0

    def usable_J(self) -> float | None:
        """Usable energy the state of charge shows [J], or None while it cannot say (too few
        samples, too small a fall, or a state of charge that does not fall with the energy
        drawn)."""
        line = self._line()
        if line is None:
            return None
        slope, intercept = line
        return float(self._scale - intercept / slope)

    def _line(self) -> tuple[float, float] | None:
        """(slope [1/J], intercept [-]) of the fitted line, None while it cannot say."""
        if self.n < MIN_SAMPLES or self.span < MIN_SPAN:
            return None
        sx, ss, sxx, sxs, _ = self._sums
        n = self.n
        var_x = sxx - sx * sx / n
        if var_x <= 0:
            return None
        slope = (sxs - sx * ss / n) / var_x
        if not slope < 0:
            return None
        return float(slope), float((ss - slope * sx) / n)

    def usable_low_J(self, step: float = GAUGE_STEP) -> float | None:
        """A low estimate of ``usable_J`` [J], for spending the battery to its last joules.

        The line's slope is known to about ``step / span`` (a reading's error over the fall
        seen), so the energy still in the battery, ``soc_last C``, to ``soc_last C step /
        span``: that much is taken off. Early (a 5 % fall) it is a fifth of what is left; it
        shrinks as the charge falls. None while ``usable_J`` is.
        """
        shown = self.usable_J()
        if shown is None:
            return None
        capacity = -1.0 / self._line()[0]
        left = max(self._soc_last, 0.0) * capacity
        return float(shown - left * step / self.span)

