"""Online identification of pilot parameters: the estimator protocol, the family, metrics."""

from manualcontrol.estimators.dekf import DEKF, DEKFSettings, ResolvedSettings
from manualcontrol.estimators.internal_model import InternalModel, build_internal_model
from manualcontrol.estimators.metrics import (
    EstimationMetrics,
    evaluate,
    innovation_fractions,
    moving_vaf,
    nrmse,
    observability_gramian,
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
from manualcontrol.estimators.zhao_ukf import MultiUKF, MultiUKFSettings, ZhaoUKF, ZhaoUKFSettings

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
    "MultiUKF",
    "MultiUKFSettings",
    "ResolvedSettings",
    "ZhaoUKF",
    "ZhaoUKFSettings",
    "build_internal_model",
    "evaluate",
    "innovation_fractions",
    "load_result",
    "moving_vaf",
    "nrmse",
    "observability_gramian",
    "relative_bias",
    "resimulate",
    "vaf",
]
