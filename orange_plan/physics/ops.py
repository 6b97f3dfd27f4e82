"""Elementary maths that works on numpy arrays, Python floats and CasADi symbols alike.

The physics terms are written once with these helpers so the planner (numpy, vectorised)
and the speed optimiser (CasADi MX/SX) evaluate the very same expressions.
"""

from __future__ import annotations

import numpy as np


def is_symbolic(*values) -> bool:
    """True if any value is a CasADi SX/MX/DM object.

    Tested by the type's module, so that numpy-only work (range, reach, predict) never pays
    for importing CasADi; a CasADi object can only exist once CasADi has been imported.
    """
    return any(type(v).__module__.startswith("casadi") for v in values)


def _ca():
    import casadi

    return casadi


def sqrt(x):
    """Square root for numpy or CasADi."""
    return _ca().sqrt(x) if is_symbolic(x) else np.sqrt(x)


def fabs(x):
    """Absolute value for numpy or CasADi."""
    return _ca().fabs(x) if is_symbolic(x) else np.abs(x)


def fmax(x, y):
    """Element-wise maximum for numpy or CasADi (``max(0, F)``: no energy recovery)."""
    return _ca().fmax(x, y) if is_symbolic(x, y) else np.maximum(x, y)


def fmin(x, y):
    """Element-wise minimum for numpy or CasADi."""
    return _ca().fmin(x, y) if is_symbolic(x, y) else np.minimum(x, y)


def exp(x):
    """Exponential for numpy or CasADi."""
    return _ca().exp(x) if is_symbolic(x) else np.exp(x)


def wrap_pi(angle_rad):
    """Angles wrapped into [-pi, pi) [rad]: the shorter way round (numpy or float)."""
    return (angle_rad + np.pi) % (2 * np.pi) - np.pi
