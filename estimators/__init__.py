"""Online identification of pilot parameters: the estimator protocol, the family, metrics.

The family (``manualcontrol estimators`` lists it; :data:`ESTIMATORS` holds it): the
DEKF, the joint and dual UKF, the recursive maximum-likelihood filter bank (:class:`RML`,
remnant modelled) and the papers' other members, all on the shared Kalman core
:mod:`manualcontrol.estimators.filters`; :func:`smooth` turns a filtered result of any
of them into a smoothed one (registered as ``"<name>-smoothed"`` for the bench), and
:func:`~manualcontrol.estimators.offline.cross_validation.choose_noise_scale` smooths a pilot
filter's run at the process-noise scale chosen by cross-validation (``"<name>-cv"``);
:func:`fit_pilot_sigmoid` fits a pilot that changes once, along a sigmoid
(``"sigmoid-fit"``, offline).

Importing the package imports none of them: each public name is imported from its
module when first used (:mod:`manualcontrol.envs._lazy`), so a member that is never
used costs nothing, nor does scipy.signal, which only the offline fits need. A new
public name goes into the ``TYPE_CHECKING`` imports, ``__all__`` and the table at the
end (``tests/test_package_imports.py`` checks that the three agree).
"""

from typing import TYPE_CHECKING

# importing envs first, as every subpackage does: it registers the Gymnasium ids and
# refreshes the compiled kernels' caches before any kernel here is loaded
from manualcontrol.envs._lazy import lazy_exports

if TYPE_CHECKING:  # what tools read; at run time each name is imported on first use
    from manualcontrol.estimators.analysis.metrics import (
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
    from manualcontrol.estimators.members.dekf import DEKF, DEKFSettings, ResolvedSettings
    from manualcontrol.estimators.members.internal_model import InternalModel, build_internal_model
    from manualcontrol.estimators.members.rdi import RDI, RDISettings
    from manualcontrol.estimators.members.rml import RML, RMLSettings
    from manualcontrol.estimators.members.schiess_roland import SchiessRoland, SchiessRolandSettings
    from manualcontrol.estimators.members.ukf import DualUKF, DualUKFSettings, JointUKF, UKFSettings
    from manualcontrol.estimators.members.zhao_ukf import (
        MultiUKF,
        MultiUKFSettings,
        ZhaoUKF,
        ZhaoUKFSettings,
    )
    from manualcontrol.estimators.offline.schedule_fit import (
        SigmoidFit,
        SigmoidFitEstimator,
        fit_pilot_sigmoid,
    )
    from manualcontrol.estimators.offline.smoothing import smooth
    from manualcontrol.estimators.protocol import (
        Estimate,
        EstimateHealth,
        EstimationResult,
        Estimator,
        HealthSummary,
        load_result,
    )
    from manualcontrol.estimators.registry import ESTIMATORS, EstimatorEntry, make_estimator

__all__ = [
    "DEKF",
    "ESTIMATORS",
    "RDI",
    "RML",
    "DEKFSettings",
    "DualUKF",
    "DualUKFSettings",
    "Estimate",
    "EstimateHealth",
    "EstimationMetrics",
    "EstimationResult",
    "Estimator",
    "EstimatorEntry",
    "HealthSummary",
    "InternalModel",
    "JointUKF",
    "MultiUKF",
    "MultiUKFSettings",
    "RDISettings",
    "RMLSettings",
    "ResolvedSettings",
    "SchiessRoland",
    "SchiessRolandSettings",
    "SigmoidFit",
    "SigmoidFitEstimator",
    "UKFSettings",
    "ZhaoUKF",
    "ZhaoUKFSettings",
    "build_internal_model",
    "evaluate",
    "fit_pilot_sigmoid",
    "innovation_fractions",
    "load_result",
    "make_estimator",
    "moving_vaf",
    "nrmse",
    "observability_gramian",
    "relative_bias",
    "resimulate",
    "smooth",
    "vaf",
]

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        "manualcontrol.estimators.analysis.metrics": (
            "EstimationMetrics",
            "evaluate",
            "innovation_fractions",
            "moving_vaf",
            "nrmse",
            "observability_gramian",
            "relative_bias",
            "resimulate",
            "vaf",
        ),
        "manualcontrol.estimators.members.dekf": ("DEKF", "DEKFSettings", "ResolvedSettings"),
        "manualcontrol.estimators.members.internal_model": (
            "InternalModel",
            "build_internal_model",
        ),
        "manualcontrol.estimators.members.rdi": ("RDI", "RDISettings"),
        "manualcontrol.estimators.members.rml": ("RML", "RMLSettings"),
        "manualcontrol.estimators.members.schiess_roland": (
            "SchiessRoland",
            "SchiessRolandSettings",
        ),
        "manualcontrol.estimators.members.ukf": (
            "DualUKF",
            "DualUKFSettings",
            "JointUKF",
            "UKFSettings",
        ),
        "manualcontrol.estimators.members.zhao_ukf": (
            "MultiUKF",
            "MultiUKFSettings",
            "ZhaoUKF",
            "ZhaoUKFSettings",
        ),
        "manualcontrol.estimators.offline.schedule_fit": (
            "SigmoidFit",
            "SigmoidFitEstimator",
            "fit_pilot_sigmoid",
        ),
        "manualcontrol.estimators.offline.smoothing": ("smooth",),
        "manualcontrol.estimators.protocol": (
            "Estimate",
            "EstimateHealth",
            "EstimationResult",
            "Estimator",
            "HealthSummary",
            "load_result",
        ),
        "manualcontrol.estimators.registry": ("ESTIMATORS", "EstimatorEntry", "make_estimator"),
    },
)
