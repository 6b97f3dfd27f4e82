"""System identification: calibration (offline) and the online ORangE estimator."""
