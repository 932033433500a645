"""Set-up shared by every tracking run: the environments and the closed-loop simulation.

A tracking run is fixed by its task, controlled element, forcing realisation, sample
time, run-in and measurement time. The Gymnasium environments
(:mod:`~manualcontrol.envs.tracking`) and :func:`manualcontrol.pilots.simulate` resolve
these the same way through the helpers here, so a pilot acting in an environment and
the simulation of the same run stay one problem:

* :class:`Task` -- what each task's display shows (:func:`task_named`,
  :data:`TASKS_BY_NAME`): the one place that says it, where every module would
  otherwise re-decide it from the task's name;
* :func:`resolve_forcing` -- a preset name (and realisation) or a ``ForcingPair``;
* :func:`measurement_time_for` -- default: the forcing's period ``T_m`` (120 s when the
  forcing has none);
* :func:`available_preview_for` -- the preview a task shows (1 s by default in the
  preview task, none otherwise) and :func:`check_preview_time` for a point read in it;
* :func:`sample_counts` -- run-in and total samples;
* :data:`DISTURBANCE_POINTS` -- where the disturbance ``fd`` enters the loop;
* :func:`task_metadata` -- what a recording of the run says about how it was made.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_choice, check_positive
from manualcontrol.envs.elements import ControlledElement
from manualcontrol.envs.signals import ForcingPair, forcing_preset

__all__ = [
    "DEFAULT_AVAILABLE_PREVIEW",
    "DEFAULT_MEASUREMENT_TIME",
    "DISTURBANCE_POINTS",
    "TASKS",
    "TASKS_BY_NAME",
    "Task",
    "available_preview_for",
    "check_preview_time",
    "measurement_time_for",
    "resolve_forcing",
    "sample_counts",
    "task_metadata",
    "task_named",
]

#: The display types, see :mod:`~manualcontrol.envs.tracking`.
TASKS: tuple[str, ...] = ("compensatory", "pursuit", "preview", "postview")
#: Preview shown by default in preview tasks (s): covers nominal far-view preview times.
DEFAULT_AVAILABLE_PREVIEW = 1.0
#: Measurement time (s) of a forcing that has no period of its own.
DEFAULT_MEASUREMENT_TIME = 120.0
#: Where the disturbance forcing function ``fd`` enters the loop: added to the
#: controlled element's output (``y = H_c u + fd``, the default) or to its input
#: (``y = H_c (u + fd)``: a force on the stick, a gust on the vehicle), where the
#: element's own dynamics shape it.
DISTURBANCE_POINTS: tuple[str, ...] = ("output", "input")


@dataclass(frozen=True)
class Task:
    """A tracking task, described by what its display shows the pilot.

    The task travels by its name (the environments' ``task``, ``task=`` of
    :func:`~manualcontrol.pilots.simulate`, recording metadata, suite files); where code
    has to act on what the display shows (the observation, the drawing, which preview is
    allowed, which pilot model fits) it reads these attributes of :func:`task_named`'s
    Task instead of comparing the name, so what each display shows is said here once:

    ============  ==========  ======  =======  ========  ===========
    name          error only  target  preview  postview  pilot model
    ============  ==========  ======  =======  ========  ===========
    compensatory  yes         no      no       no        precision
    pursuit       no          yes     no       no        preview
    preview       no          yes     yes      no        preview
    postview      no          no      no       yes       postview
    ============  ==========  ======  =======  ========  ===========

    Attributes
    ----------
    name
        The task's name, one of :data:`TASKS`.
    shows_error_only
        The display shows the tracking error ``e = ft - y`` alone (compensatory): a
        pilot there responds to the error.
    shows_target
        The display shows the present target ``ft(t)`` and the output ``y`` apart
        (pursuit, preview): two channels, the pilot responds to both.
    shows_preview
        The target is shown ahead of the present as well (preview; how far is the
        run's ``available_preview``).
    shows_postview
        Only the target's past is shown, down to a gap before the present, with the
        output (Boer & Kenyon's gap-postview display,
        :mod:`~manualcontrol.envs.postview`).
    pilot_model
        The pilot model written for this display, fitted or flown where none is
        named: ``"precision"`` (the error), ``"preview"`` (the target and the output;
        on pursuit with nothing ahead) or ``"postview"``.
    """

    name: str
    shows_error_only: bool
    shows_target: bool
    shows_preview: bool
    shows_postview: bool
    pilot_model: str

    def fits_models_for(self, other: Task) -> bool:
        """Whether a pilot model written for the ``other`` display can fly this one.

        The model has to read what this display shows: the error alone, the present
        target and the output (a preview model flies pursuit, with nothing ahead), or
        the target's past.
        """
        return (self.shows_error_only, self.shows_target, self.shows_postview) == (
            other.shows_error_only,
            other.shows_target,
            other.shows_postview,
        )


#: Every :class:`Task` by its name, in the order of :data:`TASKS` (read-only).
TASKS_BY_NAME: Mapping[str, Task] = MappingProxyType(
    {
        task.name: task
        for task in (
            Task(
                "compensatory",
                shows_error_only=True,
                shows_target=False,
                shows_preview=False,
                shows_postview=False,
                pilot_model="precision",
            ),
            Task(
                "pursuit",
                shows_error_only=False,
                shows_target=True,
                shows_preview=False,
                shows_postview=False,
                pilot_model="preview",
            ),
            Task(
                "preview",
                shows_error_only=False,
                shows_target=True,
                shows_preview=True,
                shows_postview=False,
                pilot_model="preview",
            ),
            Task(
                "postview",
                shows_error_only=False,
                shows_target=False,
                shows_preview=False,
                shows_postview=True,
                pilot_model="postview",
            ),
        )
    }
)


def task_named(name: Any) -> Task:
    """The :class:`Task` called ``name``; an unknown name raises ``ValueError`` listing them."""
    return TASKS_BY_NAME[check_choice("task", name, TASKS)]


def resolve_forcing(forcing: str | ForcingPair, realisation: int = 0) -> ForcingPair:
    """The forcing pair of a preset name and realisation, or ``forcing`` itself."""
    if isinstance(forcing, str):
        return forcing_preset(forcing, realisation)
    if not isinstance(forcing, ForcingPair):
        raise TypeError(f"forcing must be a preset name or a ForcingPair, got {forcing!r}")
    return forcing


def measurement_time_for(forcing: ForcingPair, measurement_time: float | None) -> float:
    """``measurement_time`` checked, or by default the forcing's period ``T_m``."""
    if measurement_time is None:
        signal = forcing.target or forcing.disturbance
        measurement_time = getattr(signal, "measurement_time", None) or DEFAULT_MEASUREMENT_TIME
    return check_positive("measurement_time", measurement_time)


def available_preview_for(task: str, available_preview: float | None) -> float:
    """The preview (s) the task's display shows: only the preview task shows any."""
    if task_named(task).shows_preview:
        preview = DEFAULT_AVAILABLE_PREVIEW if available_preview is None else available_preview
        return check_positive("available_preview", preview, allow_zero=True)
    if available_preview not in (None, 0, 0.0):
        raise ValueError(
            f"available_preview must be 0 (or omitted) in a {task} task, got {available_preview!r}"
        )
    return 0.0


def check_preview_time(name: str, values: NDArray[np.float64], available: float, task: str) -> None:
    """Raise unless every preview time in ``values`` lies within the shown preview."""
    if np.any(values < 0.0):
        raise ValueError(f"{name} must be >= 0 s (a preview time), got {float(values.min())!r}")
    if np.any(values > available + 1e-12):
        # a pursuit display shows nothing ahead: its pilot is the preview model's pursuit form
        hint = (
            f" (a pursuit pilot is the preview model with {name} = 0, e.g. "
            f"Pilot.typical('preview', element, {{'{name}': 0.0}}))"
            if available == 0.0 and task_named(task).shows_target
            else ""
        )
        raise ValueError(
            f"{name} must not exceed the available preview of {available:g} s in a {task} task, "
            f"got {float(values.max())!r}{hint}"
        )


def sample_counts(dt: float, run_in: float, measurement_time: float) -> tuple[int, int]:
    """Samples of run-in and of the whole run (run-in included)."""
    n_run_in = round(run_in / dt)
    return n_run_in, n_run_in + round(measurement_time / dt)


def task_metadata(
    task: str,
    element: ControlledElement,
    forcing: ForcingPair,
    available_preview: float,
    run_in: float,
    measurement_time: float,
    disturbance_at: str = "output",
) -> dict[str, Any]:
    """The description every recording of a tracking run carries.

    ``disturbance_at`` (one of :data:`DISTURBANCE_POINTS`) is always written, so a
    reader of the recording (the describing function, an estimator) knows which loop
    the recorded ``fd`` entered without guessing the default.
    """
    return {
        "task": task,
        "controlled_element": element.to_dict(),
        "forcing": forcing.to_dict(),
        "forcing_name": forcing.name,
        "realisation": forcing.realisation,
        "disturbance_at": check_choice("disturbance_at", disturbance_at, DISTURBANCE_POINTS),
        "available_preview": available_preview,
        "run_in": run_in,
        "measurement_time": measurement_time,
    }
