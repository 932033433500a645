"""The tasks a person flies, and what they are told about them.

:data:`TASKS` maps each task's name (``manualcontrol play --task``, a protocol's
``task``) to the Gymnasium environment it flies; :data:`TASK_GOALS` and
:data:`HOW_TO_MOVE` are the words the start screen (``manualcontrol play``) and a
session's instructions (:mod:`~manualcontrol.human.session`) use to say what to do
and how to move the stick. Plain tables: importing this module loads nothing else.
"""

from __future__ import annotations

__all__ = ["HOW_TO_MOVE", "TASKS", "TASK_GOALS"]

#: Task name -> the Gymnasium id of the environment it flies.
TASKS: dict[str, str] = {
    "compensatory": "ManualControl/CompensatoryTracking-v0",
    "pursuit": "ManualControl/PursuitTracking-v0",
    "preview": "ManualControl/PreviewTracking-v0",
    "postview": "ManualControl/PostviewTracking-v0",
    "lane-keeping": "ManualControl/LaneKeeping-v0",
}
#: What the person is asked to do, per task (the start screen and the sessions' instructions).
TASK_GOALS: dict[str, str] = {
    "compensatory": "keep the cross between the brackets",
    "pursuit": "keep the cursor under the circle",
    "preview": "keep the cursor on the track where it meets the cursor's line",
    "postview": "keep the cursor where the track will cross its line",
    "lane-keeping": "keep the car in its lane",
}
#: How to move the stick, per input device.
HOW_TO_MOVE: dict[str, str] = {
    "mouse": "move the mouse left and right",
    "keyboard": "hold the left and right arrow keys",
    "joystick": "move the stick left and right",
}
