"""The task table: what each tracking display shows, looked up by the task's name."""

import dataclasses
import pickle
import re

import pytest

from manualcontrol.envs import tasks
from manualcontrol.envs.postview import PostviewTracking
from manualcontrol.envs.tasks import TASKS, TASKS_BY_NAME, Task, available_preview_for, task_named
from manualcontrol.envs.tracking import CompensatoryTracking, PreviewTracking, PursuitTracking
from manualcontrol.pilots.models import MODEL_NAMES, make_model

# name: (shows_error_only, shows_target, shows_preview, shows_postview, pilot_model)
TABLE = {
    "compensatory": (True, False, False, False, "precision"),
    "pursuit": (False, True, False, False, "preview"),
    "preview": (False, True, True, False, "preview"),
    "postview": (False, False, False, True, "postview"),
}


@pytest.mark.parametrize("name", list(TABLE))
def test_each_task_says_what_its_display_shows(name):
    task = task_named(name)
    assert isinstance(task, Task) and task.name == name
    flags = (
        task.shows_error_only,
        task.shows_target,
        task.shows_preview,
        task.shows_postview,
        task.pilot_model,
    )
    assert flags == TABLE[name]
    assert task is TASKS_BY_NAME[name]


def test_the_table_covers_the_task_names_in_their_order():
    assert tuple(TASKS_BY_NAME) == TASKS == tuple(TABLE)
    for name in TASKS:
        task = TASKS_BY_NAME[name]
        # every display shows exactly one of: the error, the present target, the past track
        assert task.shows_error_only + task.shows_target + task.shows_postview == 1
        # preview is shown ahead of a target shown now
        assert not task.shows_preview or task.shows_target
        assert task.pilot_model in MODEL_NAMES
        assert make_model(task.pilot_model).task in TASKS


def test_tasks_are_frozen_and_the_table_read_only():
    task = task_named("pursuit")
    with pytest.raises(dataclasses.FrozenInstanceError):
        task.shows_preview = True
    with pytest.raises(TypeError):
        TASKS_BY_NAME["lane-keeping"] = task
    assert pickle.loads(pickle.dumps(task)) == task


@pytest.mark.parametrize("name", ["gap", "Compensatory", "lane-keeping", "open-loop", None, 1])
def test_an_unknown_name_is_refused_naming_the_argument_and_the_choices(name):
    message = f"task must be one of 'compensatory', 'pursuit', 'preview', 'postview', got {name!r}"
    with pytest.raises(ValueError) as caught:
        task_named(name)
    assert str(caught.value) == message


def test_the_new_names_are_exported():
    for name in ("Task", "TASKS_BY_NAME", "task_named"):
        assert name in tasks.__all__


@pytest.mark.parametrize(
    ("display", "model", "fits"),
    [
        ("compensatory", "compensatory", True),
        ("pursuit", "preview", True),  # a preview model with nothing ahead
        ("preview", "preview", True),
        ("postview", "postview", True),
        ("compensatory", "preview", False),
        ("pursuit", "compensatory", False),
        ("preview", "compensatory", False),
        ("preview", "postview", False),
        ("postview", "preview", False),
        ("postview", "compensatory", False),
    ],
)
def test_which_models_fly_which_display(display, model, fits):
    assert task_named(display).fits_models_for(task_named(model)) is fits


def test_only_the_preview_display_shows_preview():
    assert available_preview_for("preview", None) == tasks.DEFAULT_AVAILABLE_PREVIEW
    assert available_preview_for("preview", 2.5) == 2.5
    for name in ("compensatory", "pursuit", "postview"):
        assert available_preview_for(name, None) == 0.0
        with pytest.raises(ValueError, match=re.escape(f"in a {name} task, got 0.5")):
            available_preview_for(name, 0.5)
    with pytest.raises(ValueError, match=r"task must be one of .*, got 'gap'"):
        available_preview_for("gap", None)


@pytest.mark.parametrize(
    ("env", "task"),
    [
        (CompensatoryTracking, "compensatory"),
        (PursuitTracking, "pursuit"),
        (PreviewTracking, "preview"),
        (PostviewTracking, "postview"),
    ],
)
def test_environments_keep_the_name_and_read_the_table(env, task):
    made = env(measurement_time=2.0)
    assert made._display is task_named(task)
    made.reset(seed=0)
    made.step(made.action_space.sample() * 0.0)
    made.step(made.action_space.sample() * 0.0)
    recorded = made.recording().metadata["task"]
    assert made.task == recorded == task and type(recorded) is str
