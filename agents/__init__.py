"""RL surrogate human operators: human-limitation wrappers, training, evaluation."""

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
