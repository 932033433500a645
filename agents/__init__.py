"""RL surrogate human operators: human-limitation wrappers, training, evaluation.

The wrappers are imported when first used (:mod:`manualcontrol.envs._lazy`).
"""

from typing import TYPE_CHECKING

# importing envs first, as every subpackage does: it registers the Gymnasium ids and
# refreshes the compiled kernels' caches before any kernel here is loaded
from manualcontrol.envs._lazy import lazy_exports

if TYPE_CHECKING:  # what tools read; at run time each name is imported on first use
    from manualcontrol.agents.wrappers import (
        WRAPPERS,
        ActionDelay,
        EffortCost,
        MotorNoise,
        NeuromuscularFilter,
        ObservationHistory,
        ObservationNoise,
        ObservationScale,
        apply_wrappers,
    )

__all__ = [
    "WRAPPERS",
    "ActionDelay",
    "EffortCost",
    "MotorNoise",
    "NeuromuscularFilter",
    "ObservationHistory",
    "ObservationNoise",
    "ObservationScale",
    "apply_wrappers",
]

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        "manualcontrol.agents.wrappers": (
            "WRAPPERS",
            "ActionDelay",
            "EffortCost",
            "MotorNoise",
            "NeuromuscularFilter",
            "ObservationHistory",
            "ObservationNoise",
            "ObservationScale",
            "apply_wrappers",
        ),
    },
)
