"""RL surrogate human operators: human-limitation wrappers, training, evaluation."""

from manualcontrol.agents.wrappers import (
    WRAPPERS,
    ActionDelay,
    MotorNoise,
    NeuromuscularFilter,
    ObservationNoise,
    apply_wrappers,
)

__all__ = [
    "WRAPPERS",
    "ActionDelay",
    "MotorNoise",
    "NeuromuscularFilter",
    "ObservationNoise",
    "apply_wrappers",
]
