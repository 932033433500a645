"""Cybernetic pilot models: structures, synthetic pilots, remnant and closed-loop simulation."""

from manualcontrol.pilots.models import (
    MODEL_NAMES,
    GainDelayModel,
    ParameterSpec,
    PilotModel,
    PrecisionModel,
    PreviewModel,
    SchiessRolandModel,
    make_model,
)
from manualcontrol.pilots.ocm import OCMSolution, OptimalControlPilot, simulate_ocm, solve_ocm
from manualcontrol.pilots.pilot import HumanLimitWarning, Pilot
from manualcontrol.pilots.remnant import (
    INJECTION_POINTS,
    LevisonRemnant,
    Remnant,
    SchiessRolandRemnant,
    ZaalRemnant,
    make_remnant,
)
from manualcontrol.pilots.simulation import (
    SimulationSetup,
    closed_loop,
    remnant_power_ratio,
    simulate,
)
from manualcontrol.pilots.stability import (
    UnstableLoopError,
    UnstableLoopWarning,
    typical_parameters,
)

__all__ = [
    "INJECTION_POINTS",
    "MODEL_NAMES",
    "GainDelayModel",
    "HumanLimitWarning",
    "LevisonRemnant",
    "OCMSolution",
    "OptimalControlPilot",
    "ParameterSpec",
    "Pilot",
    "PilotModel",
    "PrecisionModel",
    "PreviewModel",
    "Remnant",
    "SchiessRolandModel",
    "SchiessRolandRemnant",
    "SimulationSetup",
    "UnstableLoopError",
    "UnstableLoopWarning",
    "ZaalRemnant",
    "closed_loop",
    "make_model",
    "make_remnant",
    "remnant_power_ratio",
    "simulate",
    "simulate_ocm",
    "solve_ocm",
    "typical_parameters",
]
