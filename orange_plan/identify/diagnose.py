"""Diagnosis: find the physics a model left out of a recording, model it, show the fit improve.

The entry point kept where other code imports it: the method lives in the package
``identify.diagnosis``, one module per stage (design, candidates, fitting, selection,
report); its thresholds are a ``DiagnosisSettings``. The user's guide:
docs/guide/diagnosis.md.
"""

from __future__ import annotations

from orange_plan.identify.diagnosis import *  # noqa: F403 (the package's public names)
from orange_plan.identify.diagnosis import __all__ as __all__
