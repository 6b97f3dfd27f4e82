"""Elementary maths that works on numpy arrays, Python floats and CasADi symbols alike.

The physics terms are written once with these helpers so the planner (numpy, vectorised)
and the speed optimiser (CasADi MX/SX) evaluate the very same expressions.
"""

from __future__ import annotations

import numpy as np

try:  # CasADi is a hard dependency, but keep the import local to this module.
    import casadi as ca

    _CASADI_TYPES: tuple[type, ...] = (ca.SX, ca.MX, ca.DM)
except ImportError:  # pragma: no cover - casadi is in the dependencies
    ca = None
    _CASADI_TYPES = ()


def is_symbolic(*values) -> bool:
    """True if any value is a CasADi SX/MX/DM object."""
    return any(isinstance(v, _CASADI_TYPES) for v in values)


def sqrt(x):
    """Square root for numpy or CasADi."""
    return ca.sqrt(x) if is_symbolic(x) else np.sqrt(x)


def fabs(x):
    """Absolute value for numpy or CasADi."""
    return ca.fabs(x) if is_symbolic(x) else np.abs(x)


def fmax(x, y):
    """Element-wise maximum for numpy or CasADi (``max(0, F)``: no energy recovery)."""
    return ca.fmax(x, y) if is_symbolic(x, y) else np.maximum(x, y)


def fmin(x, y):
    """Element-wise minimum for numpy or CasADi."""
    return ca.fmin(x, y) if is_symbolic(x, y) else np.minimum(x, y)


def exp(x):
    """Exponential for numpy or CasADi."""
    return ca.exp(x) if is_symbolic(x) else np.exp(x)
