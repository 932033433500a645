"""The task world: signals, dynamics, controlled elements, recordings and Gymnasium envs.

Importing this package registers ``ManualControl/CompensatoryTracking-v0``,
``ManualControl/PursuitTracking-v0``, ``ManualControl/PreviewTracking-v0`` and
``ManualControl/PostviewTracking-v0`` (Boer & Kenyon's gap-postview display) and
``ManualControl/LaneKeeping-v0``. Gymnasium
1.x has no plugin entry points any more, so either import ``manualcontrol.envs`` first
or name the module in the id:
``gymnasium.make("manualcontrol.envs:ManualControl/PreviewTracking-v0")``.
"""

from gymnasium.envs.registration import register, registry

from manualcontrol.envs._kernel_cache import refresh_kernel_cache

# before any kernel module is imported (every subpackage imports envs first)
refresh_kernel_cache()

_TASKS = ("Compensatory", "Pursuit", "Preview")

for _task in _TASKS:
    _id = f"ManualControl/{_task}Tracking-v0"
    if _id not in registry:
        register(
            id=_id,
            entry_point=f"manualcontrol.envs.tracking:{_task}Tracking",
            vector_entry_point=f"manualcontrol.envs.tracking_vector:{_task}TrackingVector",
        )

if "ManualControl/PostviewTracking-v0" not in registry:
    register(
        id="ManualControl/PostviewTracking-v0",
        entry_point="manualcontrol.envs.postview:PostviewTracking",
    )

if "ManualControl/LaneKeeping-v0" not in registry:
    register(
        id="ManualControl/LaneKeeping-v0",
        entry_point="manualcontrol.envs.driving:LaneKeeping",
        vector_entry_point="manualcontrol.envs.driving_vector:LaneKeepingVector",
    )
