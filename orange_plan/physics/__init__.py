"""The ORangE energy model: physics terms, the model (terms + coefficients + covariance),
the battery and the range estimators."""

from orange_plan.physics.battery import Battery, Losses
from orange_plan.physics.model import EnergyModel, SegmentEnergy
from orange_plan.physics.state import MotionState
from orange_plan.physics.terms import G_MPS2, TERMS

__all__ = [
    "G_MPS2",
    "TERMS",
    "Battery",
    "EnergyModel",
    "Losses",
    "MotionState",
    "SegmentEnergy",
]
