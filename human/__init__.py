"""A person at the controls: input devices, the real-time loop, experiment sessions.

:mod:`~manualcontrol.human.devices` reads a mouse, keyboard, joystick or a scripted
stick and turns it into an environment's action (:class:`DeviceAction`);
:mod:`~manualcontrol.human.realtime` flies an episode in real time (:func:`fly`) and
says whether its timing is good enough for identification; :mod:`~manualcontrol.human.cli`
is the ``manualcontrol play`` command. Each public name is imported from its module
when first used (:mod:`manualcontrol.envs._lazy`): importing the package loads neither
pygame nor the loop.
"""

from typing import TYPE_CHECKING

# importing envs first, as every subpackage does: it registers the Gymnasium ids and
# refreshes the compiled kernels' caches before any kernel here is loaded
from manualcontrol.envs._lazy import lazy_exports

if TYPE_CHECKING:  # what tools read; at run time each name is imported on first use
    from manualcontrol.human.devices import (
        DeviceAction,
        DeviceLost,
        InputDevice,
        InputDeviceError,
        JoystickInput,
        KeyboardInput,
        MouseInput,
        NoInputDevice,
        ScriptedInput,
        default_action_scale,
        make_device,
    )
    from manualcontrol.human.protocol import (
        PlannedRun,
        Protocol,
        ProtocolError,
        load_protocol,
        parse_protocol,
    )
    from manualcontrol.human.realtime import (
        Clock,
        Flight,
        ManualClock,
        RealClock,
        RunAborted,
        StepReport,
        Timing,
        fly,
    )
    from manualcontrol.human.report import SessionReport, write_session_report
    from manualcontrol.human.session import (
        PygameScreen,
        Screen,
        ScriptedKeys,
        SessionAborted,
        SessionError,
        SessionEvent,
        SessionResult,
        run_session,
    )

__all__ = [
    "Clock",
    "DeviceAction",
    "DeviceLost",
    "Flight",
    "InputDevice",
    "InputDeviceError",
    "JoystickInput",
    "KeyboardInput",
    "ManualClock",
    "MouseInput",
    "NoInputDevice",
    "PlannedRun",
    "Protocol",
    "ProtocolError",
    "PygameScreen",
    "RealClock",
    "RunAborted",
    "Screen",
    "ScriptedInput",
    "ScriptedKeys",
    "SessionAborted",
    "SessionError",
    "SessionEvent",
    "SessionReport",
    "SessionResult",
    "StepReport",
    "Timing",
    "default_action_scale",
    "fly",
    "load_protocol",
    "make_device",
    "parse_protocol",
    "run_session",
    "write_session_report",
]

__getattr__, __dir__ = lazy_exports(
    globals(),
    {
        "manualcontrol.human.devices": (
            "DeviceAction",
            "DeviceLost",
            "InputDevice",
            "InputDeviceError",
            "JoystickInput",
            "KeyboardInput",
            "MouseInput",
            "NoInputDevice",
            "ScriptedInput",
            "default_action_scale",
            "make_device",
        ),
        "manualcontrol.human.realtime": (
            "Clock",
            "Flight",
            "ManualClock",
            "RealClock",
            "RunAborted",
            "StepReport",
            "Timing",
            "fly",
        ),
        "manualcontrol.human.protocol": (
            "PlannedRun",
            "Protocol",
            "ProtocolError",
            "load_protocol",
            "parse_protocol",
        ),
        "manualcontrol.human.session": (
            "PygameScreen",
            "Screen",
            "ScriptedKeys",
            "SessionAborted",
            "SessionError",
            "SessionEvent",
            "SessionResult",
            "run_session",
        ),
        "manualcontrol.human.report": ("SessionReport", "write_session_report"),
    },
)
