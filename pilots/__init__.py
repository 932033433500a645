"""Cybernetic pilot models: structures, synthetic pilots and drivers, remnant, simulation.

Each public name is imported from its module when first used
(:mod:`manualcontrol.envs._lazy`): ``Pilot`` does not load the optimal control model
and its scipy.optimize.
"""

from typing import TYPE_CHECKING

# importing envs first, as every subpackage does: it registers the Gymnasium ids and
# refreshes the compiled kernels' caches before any kernel here is loaded
from manualcontrol.envs._lazy import lazy_exports

if TYPE_CHECKING:  # what tools read; at run time each name is imported on first use
    from manualcontrol.pilots.driver import Driver
    from manualcontrol.pilots.driving import simulate_driving
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
        simulate_many,
    )
    from manualcontrol.pilots.stability import (
        UnstableLoopError,
        UnstableLoopWarning,
        typical_parameters,
    )

__all__ = [
    "INJECTION_POINTS",
    "MODEL_NAMES",
    "Driver",
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
    "simulate_driving",
    "simulate_many",
    "simulate_ocm",
    "solve_ocm",
    "typical_parameters",
]

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        "manualcontrol.pilots.driver": ("Driver",),
        "manualcontrol.pilots.driving": ("simulate_driving",),
        "manualcontrol.pilots.models": (
            "MODEL_NAMES",
            "GainDelayModel",
            "ParameterSpec",
            "PilotModel",
            "PrecisionModel",
            "PreviewModel",
            "SchiessRolandModel",
            "make_model",
        ),
        "manualcontrol.pilots.ocm": (
            "OCMSolution",
            "OptimalControlPilot",
            "simulate_ocm",
            "solve_ocm",
        ),
        "manualcontrol.pilots.pilot": ("HumanLimitWarning", "Pilot"),
        "manualcontrol.pilots.remnant": (
            "INJECTION_POINTS",
            "LevisonRemnant",
            "Remnant",
            "SchiessRolandRemnant",
            "ZaalRemnant",
            "make_remnant",
        ),
        "manualcontrol.pilots.simulation": (
            "SimulationSetup",
            "closed_loop",
            "remnant_power_ratio",
            "simulate",
            "simulate_many",
        ),
        "manualcontrol.pilots.stability": (
            "UnstableLoopError",
            "UnstableLoopWarning",
            "typical_parameters",
        ),
    },
)
