"""Online identification of pilot parameters: the estimator protocol, the family, metrics."""

from manualcontrol.estimators.dekf import DEKF, DEKFSettings, ResolvedSettings
from manualcontrol.estimators.internal_model import InternalModel, build_internal_model
from manualcontrol.estimators.metrics import (
    EstimationMetrics,
    evaluate,
    innovation_fractions,
    moving_vaf,
    nrmse,
    relative_bias,
    resimulate,
    vaf,
)
from manualcontrol.estimators.protocol import (
    Estimate,
    EstimateHealth,
    EstimationResult,
    Estimator,
    HealthSummary,
    load_result,
)
from manualcontrol.estimators.schiess_roland import SchiessRoland, SchiessRolandSettings

__all__ = [
    "DEKF",
    "DEKFSettings",
    "Estimate",
    "EstimateHealth",
    "EstimationMetrics",
    "EstimationResult",
    "Estimator",
    "HealthSummary",
    "InternalModel",
    "ResolvedSettings",
    "SchiessRoland",
    "SchiessRolandSettings",
    "build_internal_model",
    "evaluate",
    "innovation_fractions",
    "load_result",
    "moving_vaf",
    "nrmse",
    "relative_bias",
    "resimulate",
    "vaf",
]
