"""An experiment with people, as a file: the conditions, the runs and their order.

A protocol is a TOML file a lab writes once and runs for every participant
(:func:`~manualcontrol.human.session.run_session`, ``manualcontrol experiment``). It is
validated where it is read, like a benchmark suite: every mistake is a
:class:`ProtocolError` that names the file, the table (``condition 2 (DI)``), the key,
the value found and what is allowed; unknown keys are refused by name, and each
condition's environment is built once, so a bad task, element, forcing, realisation or
display setting stops the file before anyone sits down.

Schema::

    name = "si-di"                   # optional, default the file's name
    description = "..."              # optional
    participant = "P01"              # optional; --participant overrides it
    order = "counterbalanced"        # "as-listed" (default), "counterbalanced", "random"
    seed = 7                         # order = "random" only, and required there
    practice = 2                     # practice runs per condition (default 0), or
    # practice = {until_rms_below = 0.5, max_runs = 5, min_runs = 1}
    measurement_runs = 4             # measured runs per condition (>= 1)
    show_score = true                # show the RMS error after each run (default true)

    [breaks]                         # or breaks = 30, or breaks = "key": both alike
    between_runs = 10                # seconds (>= 0) or "key" (wait for space)
    between_conditions = "key"

    [instructions]                   # or instructions = "text" (before_condition)
    before_condition = "..."         # shown before a condition's first run
    before_run = "..."               # shown on the task's first frame before every run

    [input]                          # or input = "joystick"
    device = "mouse"                 # mouse (default), keyboard, joystick
    range = 240                      # raw reading for full deflection (mouse px,
                                     # joystick axis value); not for the keyboard
    dead_zone = 0.0                  # share of full deflection read as zero, [0, 1)
    joystick_axis = 0

    [[condition]]
    name = "SI"                      # letters, digits, '-', '_' (file names use it)
    task = "compensatory"            # compensatory, pursuit, preview, postview,
                                     # lane-keeping
    element = "SI"                   # tracking tasks: preset, transfer function or table
    forcing = "vanderel-bw4"         # tracking tasks: preset, or a table (below)
    realisations = [0, 1, 2, 3]      # or realisation = 0 (default [0])
    practice_realisations = [5]      # default: realisations
    measurement_time = 120.0         # s, > 0 (default: the forcing's period)
    # optional, as the environments take them: dt, run_in, available_preview
    # (preview), gap and postview (postview), disturbance_at, loss_of_control;
    # lane keeping: road, vehicle, speed, steering
    scale = 8.0                      # action at full stick deflection (default: sized
                                     # to the forcing and the element, see docs/play.md)
    practice = 1                     # a condition may override practice,
    measurement_runs = 3             # measurement_runs and instructions (a string)

A custom forcing is a table with ``target`` and/or ``disturbance`` multisines (and an
optional ``name``)::

    [condition.forcing]
    name = "fast"
    target = {frequencies = [1.2566, 2.5133], amplitudes = [0.8, 0.4],
              phases = [0.0, 1.0], measurement_time = 5.0}

Practice
--------
``practice = N`` flies ``N`` practice runs of each condition before its measurement
runs. ``practice = {until_rms_below = x, max_runs = M, min_runs = m}`` flies practice
runs until one run's RMS error is below ``x`` (the RMS over the whole run of the
error ``e`` shown to the participant; lane keeping: of the lateral offset ``y_L``, m)
and at least ``m`` runs (default 1) have been flown, and never more than ``M``: the
practice of a condition ends after the first run ``i >= m`` whose RMS is below ``x``,
or after run ``M``. The plan holds ``M`` practice slots; those left when the criterion
is met are skipped.

Order
-----
Conditions are flown one after the other, each its practice runs then its measurement
runs. ``"as-listed"``: in the file's order. ``"counterbalanced"``: the rows of a
balanced Latin square (Williams design: for ``n`` conditions ``n`` rows when ``n`` is
even, ``2n`` when odd: each row and its mirror), so each condition comes first equally
often and each follows every other equally often; participant number ``p`` flies row
``(p - 1) mod rows`` (participant 1 the first row, as listed). The number is the last
group of digits of the participant id (``P07`` is 7, ``s12b`` is 12), or given
(``--participant-number``). ``"random"``: a permutation drawn by
``numpy.random.default_rng([seed, crc32(participant id)])``, so each participant has
their own order, the same every time.

Realisations and seeds
----------------------
Measurement run ``i`` (from 1) of a condition flies ``realisations[(i - 1) mod n]``,
practice run ``i`` ``practice_realisations[(i - 1) mod n]``. Each run's reset seed is
``crc32("<participant>:<condition>:<kind>:<i>")`` (it draws a random road in lane
keeping; a tracking run's forcing is fixed by its realisation).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import numbers
import re
import string
import sys
import zlib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401 - registers the environments
from manualcontrol.envs.elements import make_element
from manualcontrol.envs.signals import FORCING_PRESETS, ForcingPair
from manualcontrol.envs.tasks import resolve_forcing, task_named
from manualcontrol.human.devices import DeviceAction, make_device
from manualcontrol.human.tasks import TASKS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = [
    "KINDS",
    "ORDERS",
    "Breaks",
    "Condition",
    "InputSettings",
    "Instructions",
    "PlannedRun",
    "Practice",
    "Protocol",
    "ProtocolError",
    "balanced_latin_square",
    "check_participant",
    "load_protocol",
    "parse_protocol",
    "participant_number",
    "protocol_differences",
]

#: Orders of the conditions a protocol may ask for.
ORDERS: tuple[str, ...] = ("as-listed", "counterbalanced", "random")
#: The two kinds of run.
KINDS: tuple[str, ...] = ("practice", "measurement")
_DEVICES = ("mouse", "keyboard", "joystick")
_TOP_KEYS = (
    "name",
    "description",
    "participant",
    "order",
    "seed",
    "practice",
    "measurement_runs",
    "show_score",
    "breaks",
    "instructions",
    "input",
    "condition",
)
_COMMON_KEYS = (
    "name",
    "task",
    "measurement_time",
    "dt",
    "run_in",
    "scale",
    "practice",
    "measurement_runs",
    "instructions",
)
_TRACKING_KEYS = (
    "element",
    "forcing",
    "realisation",
    "realisations",
    "practice_realisations",
    "available_preview",
    "disturbance_at",
    "loss_of_control",
    "gap",
    "postview",
)
_LANE_KEYS = ("road", "vehicle", "speed", "steering")
# condition key -> the environment's keyword
_ENV_KEYWORDS = {
    "element": "controlled_element",
    "measurement_time": "measurement_time",
    "dt": "dt",
    "run_in": "run_in",
    "available_preview": "available_preview",
    "disturbance_at": "disturbance_at",
    "loss_of_control": "loss_of_control",
    "gap": "gap",
    "postview": "postview",
    "road": "road",
    "vehicle": "vehicle",
    "speed": "speed",
    "steering": "steering",
}
_PRACTICE_KEYS = ("until_rms_below", "max_runs", "min_runs")
_BREAK_KEYS = ("between_runs", "between_conditions")
_INSTRUCTION_KEYS = ("before_condition", "before_run")
_INPUT_KEYS = ("device", "range", "dead_zone", "joystick_axis")
_FORCING_KEYS = ("name", "target", "disturbance")
_MULTISINE_KEYS = ("frequencies", "amplitudes", "phases", "measurement_time")
_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9_-]*\Z")

#: Placeholders the instruction texts may use, filled in when they are shown.
CONDITION_FIELDS = ("condition", "task", "goal", "how", "practice", "measurement_runs")
RUN_FIELDS = ("condition", "kind", "index", "count", "number", "total", "goal", "how")
DEFAULT_BEFORE_CONDITION = (
    "Next: {condition} ({task}). Your task: {goal}. {how}. Practice: {practice}; then "
    "{measurement_runs} measured runs."
)
DEFAULT_BEFORE_RUN = "{condition}: {kind} run {index} of {count}. {how}."


class ProtocolError(ValueError):
    """A protocol file or table that does not describe a valid experiment."""


def _error(where: str, message: str) -> ProtocolError:
    return ProtocolError(f"{where}: {message}")


def _show(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


# ------------------------------------------------------------------ participants


def check_participant(participant: Any, label: str = "participant") -> str:
    """``participant`` if it is a usable id (it names a folder), else ``ValueError``."""
    if not isinstance(participant, str) or not _NAME.match(participant):
        raise ValueError(
            f"{label} must be letters, digits, '-' or '_', starting with a letter or digit "
            f"(it names the participant's folder), got {_show(participant)}"
        )
    return participant


def participant_number(participant: str) -> int | None:
    """The last group of digits of ``participant`` (``P07`` is 7), or None without one."""
    groups = re.findall(r"\d+", participant)
    return int(groups[-1]) if groups else None


def balanced_latin_square(n: int) -> list[list[int]]:
    """The rows of a balanced Latin square of ``n`` conditions (Williams design).

    Row ``r`` of the first square is ``(r + c_j) mod n`` with ``c = 0, 1, n-1, 2,
    n-2, ...``: every condition is first once and follows every other once. For odd
    ``n`` the mirrored rows are added (``2n`` rows), which balances the carry-over.
    """
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n!r}")
    offsets, low, high = [0], 1, n - 1
    while len(offsets) < n:
        offsets.append(low)
        low += 1
        if len(offsets) < n:
            offsets.append(high)
            high -= 1
    rows = [[(r + c) % n for c in offsets] for r in range(n)]
    if n % 2 and n > 1:
        rows += [row[::-1] for row in rows]
    return rows


# ------------------------------------------------------------------ the parts


@dataclass(frozen=True)
class Practice:
    """Practice runs of a condition: a count, or until a criterion (module docstring).

    ``until_rms_below`` None: ``runs`` runs. Otherwise ``runs`` is the cap (``max_runs``)
    and practice ends after the first run ``i >= min_runs`` whose RMS error is below
    ``until_rms_below``.
    """

    runs: int = 0
    until_rms_below: float | None = None
    min_runs: int = 0

    @property
    def has_criterion(self) -> bool:
        """Whether practice ends on a criterion rather than after a count."""
        return self.until_rms_below is not None

    def met(self, index: int, rms: float) -> bool:
        """Whether practice ends after run ``index`` (from 1) with RMS error ``rms``."""
        if index >= self.runs:
            return True
        return (
            self.until_rms_below is not None
            and index >= self.min_runs
            and rms < self.until_rms_below
        )

    def to_dict(self) -> Any:
        """The protocol's form: a count, or the criterion's table."""
        if self.until_rms_below is None:
            return self.runs
        return {
            "until_rms_below": self.until_rms_below,
            "max_runs": self.runs,
            "min_runs": self.min_runs,
        }

    def describe(self) -> str:
        """In words, for people."""
        if self.until_rms_below is None:
            return "none" if self.runs == 0 else f"{self.runs} run{'s' if self.runs != 1 else ''}"
        return (
            f"until a run's RMS error is below {self.until_rms_below:g} ({self.min_runs} to "
            f"{self.runs} runs)"
        )


@dataclass(frozen=True)
class Breaks:
    """Breaks before a run: seconds (>= 0, 0 for none) or ``"key"`` (wait for space)."""

    between_runs: float | str = 0.0
    between_conditions: float | str = 0.0

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        return {"between_runs": self.between_runs, "between_conditions": self.between_conditions}


@dataclass(frozen=True)
class Instructions:
    """Texts shown before each condition and each run (placeholders: module constants)."""

    before_condition: str = DEFAULT_BEFORE_CONDITION
    before_run: str = DEFAULT_BEFORE_RUN

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        return {"before_condition": self.before_condition, "before_run": self.before_run}


@dataclass(frozen=True)
class InputSettings:
    """The stick: device and calibration (None takes the device's default)."""

    device: str = "mouse"
    range: float | None = None
    dead_zone: float | None = None
    joystick_axis: int = 0

    def make(self) -> Any:
        """The :class:`~manualcontrol.human.devices.InputDevice` these settings describe."""
        return make_device(
            self.device,
            dead_zone=self.dead_zone,
            range=self.range,
            joystick_axis=self.joystick_axis,
        )

    def to_dict(self) -> dict[str, Any]:
        """The protocol's ``[input]`` table (defaults left out)."""
        data: dict[str, Any] = {"device": self.device, "joystick_axis": self.joystick_axis}
        if self.range is not None:
            data["range"] = self.range
        if self.dead_zone is not None:
            data["dead_zone"] = self.dead_zone
        return data


@dataclass(frozen=True)
class Condition:
    """One condition: a task and its settings, and how many runs of it.

    ``options`` are the environment's keywords (JSON-able; a custom forcing is its
    table), ``env_id`` the environment flown.
    """

    name: str
    task: str
    options: Mapping[str, Any]
    realisations: tuple[int, ...]
    practice_realisations: tuple[int, ...]
    practice: Practice
    measurement_runs: int
    scale: float | None = None
    instructions: str | None = None

    @property
    def env_id(self) -> str:
        """The Gymnasium id of the task."""
        return TASKS[self.task]

    @property
    def tracking(self) -> bool:
        """A tracking task (with an element and a forcing), not lane keeping."""
        return self.task != "lane-keeping"

    def env_keywords(self) -> dict[str, Any]:
        """The environment's keywords, the custom forcing built."""
        keywords = {_ENV_KEYWORDS.get(key, key): value for key, value in self.options.items()}
        forcing = keywords.get("forcing")
        if isinstance(forcing, Mapping):
            keywords["forcing"] = _forcing_pair(forcing)
        if self.tracking:
            keywords["realisation"] = self.realisations[0]
        return keywords

    def make_env(self, render_mode: str | None = None) -> Any:
        """The condition's environment (runs pick their realisation at reset)."""
        return gym.make(
            self.env_id, render_mode=render_mode, disable_env_checker=True, **self.env_keywords()
        )

    def forcing_pair(self, realisation: int) -> Any:
        """The forcing pair of ``realisation`` (tracking tasks)."""
        forcing = self.options["forcing"]
        if isinstance(forcing, Mapping):
            return _forcing_pair(forcing)
        return resolve_forcing(forcing, realisation)

    def to_dict(self) -> dict[str, Any]:
        """The protocol's ``[[condition]]`` table, every default written out."""
        data: dict[str, Any] = {"name": self.name, "task": self.task, **self.options}
        if self.tracking:
            data["realisations"] = list(self.realisations)
            data["practice_realisations"] = list(self.practice_realisations)
        data["practice"] = self.practice.to_dict()
        data["measurement_runs"] = self.measurement_runs
        if self.scale is not None:
            data["scale"] = self.scale
        if self.instructions is not None:
            data["instructions"] = self.instructions
        return json.loads(json.dumps(data))


@dataclass(frozen=True)
class PlannedRun:
    """One run of the plan (:meth:`Protocol.runs`).

    ``number`` is its place in the session (from 1), ``index`` its place among the
    condition's runs of its ``kind`` (from 1) and ``count`` how many of them there are
    (for practice to a criterion: the cap). ``realisation`` is None in lane keeping.
    """

    number: int
    condition: str
    kind: str
    index: int
    count: int
    realisation: int | None
    seed: int

    @property
    def file_name(self) -> str:
        """``NN-<condition>-<kind>-<index>.npz``."""
        return f"{self.number:02d}-{self.condition}-{self.kind}-{self.index}.npz"

    def label(self, total: int | None = None) -> str:
        """``run 3 of 12 (SI practice 1 of 2)``."""
        of = f" of {total}" if total is not None else ""
        return f"run {self.number}{of} ({self.condition} {self.kind} {self.index} of {self.count})"

    def to_dict(self) -> dict[str, Any]:  # noqa: D102
        return {**dataclasses.asdict(self), "file": self.file_name}


@dataclass(frozen=True)
class Protocol:
    """A validated experiment protocol (see the module docstring for the file).

    ``source`` names the file it was read from and ``text`` holds it; neither counts
    in :attr:`digest`, which is the hash of :meth:`to_dict` (every setting, the
    defaults written out): two protocols with the same digest run the same experiment.
    """

    name: str
    conditions: tuple[Condition, ...]
    order: str = "as-listed"
    seed: int | None = None
    breaks: Breaks = field(default_factory=Breaks)
    instructions: Instructions = field(default_factory=Instructions)
    input: InputSettings = field(default_factory=InputSettings)
    show_score: bool = True
    participant: str | None = None
    description: str = ""
    source: str = field(default="<table>", compare=False)
    text: str | None = field(default=None, compare=False, repr=False)

    def condition(self, name: str) -> Condition:
        """The condition called ``name``."""
        for condition in self.conditions:
            if condition.name == name:
                return condition
        raise KeyError(f"protocol {self.name!r} has no condition {name!r}")

    def participant_number(self, participant: str, number: int | None = None) -> int | None:
        """``number`` if given, else the last group of digits of the id."""
        if number is not None:
            if isinstance(number, bool) or not isinstance(number, numbers.Integral):
                raise ValueError(f"participant number must be a whole number, got {number!r}")
            return int(number)
        return participant_number(participant)

    def condition_order(
        self, participant: str, number: int | None = None
    ) -> tuple[tuple[str, ...], str]:
        """The conditions in the order ``participant`` flies them, and why that order."""
        names = tuple(condition.name for condition in self.conditions)
        if self.order == "as-listed":
            return names, "as listed"
        if self.order == "random":
            assert self.seed is not None  # load_protocol requires it
            rng = np.random.default_rng([self.seed, zlib.crc32(participant.encode())])
            order = tuple(names[i] for i in rng.permutation(len(names)))
            return order, f"random (seed {self.seed}, participant {participant})"
        p = self.participant_number(participant, number)
        if p is None:
            raise ValueError(
                f"order = 'counterbalanced' needs a participant number: the id "
                f"{participant!r} has no digits; use an id such as P01, or give the number "
                "(--participant-number)"
            )
        rows = balanced_latin_square(len(names))
        row = (p - 1) % len(rows)
        order = tuple(names[i] for i in rows[row])
        return order, (
            f"counterbalanced: participant number {p}, row {row + 1} of the {len(rows)} of "
            "a balanced Latin square"
        )

    def runs(self, participant: str, number: int | None = None) -> list[PlannedRun]:
        """Every run ``participant`` is to fly, in order (see the module docstring).

        Practice to a criterion has its cap's worth of slots; the session skips those
        left when the criterion is met.
        """
        participant = check_participant(participant)
        order, _ = self.condition_order(participant, number)
        plan: list[PlannedRun] = []
        for name in order:
            condition = self.condition(name)
            for kind, count, realisations in (
                ("practice", condition.practice.runs, condition.practice_realisations),
                ("measurement", condition.measurement_runs, condition.realisations),
            ):
                for index in range(1, count + 1):
                    realisation = (
                        realisations[(index - 1) % len(realisations)]
                        if condition.tracking
                        else None
                    )
                    key = f"{participant}:{name}:{kind}:{index}"
                    plan.append(
                        PlannedRun(
                            number=len(plan) + 1,
                            condition=name,
                            kind=kind,
                            index=index,
                            count=count,
                            realisation=realisation,
                            seed=zlib.crc32(key.encode()),
                        )
                    )
        return plan

    def with_input(
        self,
        *,
        device: str | None = None,
        range: float | None = None,
        dead_zone: float | None = None,
        joystick_axis: int | None = None,
    ) -> Protocol:
        """The protocol with its input settings changed (the command line's flags).

        A new device takes its own defaults for what is not given; the settings are
        checked as the file's are.
        """
        current = self.input
        if device is not None and device != current.device:
            current = InputSettings(device)
        settings = {
            "device": current.device,
            "range": current.range if range is None else range,
            "dead_zone": current.dead_zone if dead_zone is None else dead_zone,
            "joystick_axis": current.joystick_axis if joystick_axis is None else joystick_axis,
        }
        where = f"{self.source}: input"
        checked = _input({k: v for k, v in settings.items() if v is not None}, where)
        return dataclasses.replace(self, input=checked)

    def to_dict(self) -> dict[str, Any]:
        """Every setting in the file's layout, defaults written out (JSON-able).

        :func:`parse_protocol` reads it back into an equal protocol.
        """
        data: dict[str, Any] = {"name": self.name}
        if self.description:
            data["description"] = self.description
        if self.participant is not None:
            data["participant"] = self.participant
        data["order"] = self.order
        if self.seed is not None:
            data["seed"] = self.seed
        data["show_score"] = self.show_score
        data["breaks"] = self.breaks.to_dict()
        data["instructions"] = self.instructions.to_dict()
        data["input"] = self.input.to_dict()
        data["condition"] = [condition.to_dict() for condition in self.conditions]
        return data

    @property
    def digest(self) -> str:
        """Hash of :meth:`to_dict` (the first 16 hex digits of its SHA-256)."""
        text = json.dumps(self.to_dict(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def differences(self, other: Protocol) -> list[str]:
        """The settings in which ``other`` differs from this protocol, as ``key: a -> b``."""
        return protocol_differences(self.to_dict(), other.to_dict())


def protocol_differences(before: Mapping[str, Any], after: Mapping[str, Any]) -> list[str]:
    """The settings in which two protocols' :meth:`Protocol.to_dict` differ (``key: a -> b``)."""
    mine, theirs = _flatten(before), _flatten(after)
    return [
        f"{key}: {_show(mine.get(key, '(absent)'))} -> {_show(theirs.get(key, '(absent)'))}"
        for key in sorted(set(mine) | set(theirs))
        if mine.get(key, _ABSENT) != theirs.get(key, _ABSENT)
    ]


_ABSENT = object()


def _flatten(data: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(data, Mapping):
        out: dict[str, Any] = {}
        for key, value in data.items():
            out.update(_flatten(value, f"{prefix}.{key}" if prefix else str(key)))
        return out
    if isinstance(data, list) and data and all(isinstance(item, Mapping) for item in data):
        out = {}
        for i, item in enumerate(data):
            label = item.get("name", i + 1) if isinstance(item, Mapping) else i + 1
            out.update(_flatten(item, f"{prefix}[{label}]"))
        return out
    return {prefix: data}


# ------------------------------------------------------------------ reading


def _whole(where: str, key: str, value: Any, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise _error(where, f"{key} must be a whole number >= {minimum}, got {_show(value)}")
    if value < minimum:
        raise _error(where, f"{key} must be a whole number >= {minimum}, got {value!r}")
    return int(value)


def _number(where: str, key: str, value: Any, *, above: float | None = None) -> float:
    allowed = "a number" if above is None else f"a number > {above:g}"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _error(where, f"{key} must be {allowed}, got {_show(value)}")
    value = float(value)
    if not math.isfinite(value) or (above is not None and not value > above):
        raise _error(where, f"{key} must be {allowed}, got {value!r}")
    return value


def _text(where: str, key: str, value: Any) -> str:
    if not isinstance(value, str):
        raise _error(where, f"{key} must be a string, got {_show(value)}")
    return value


def _table(where: str, key: str, value: Any, keys: Sequence[str]) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise _error(where, f"{key} must be a table ({{...}} or [{key}]), got {_show(value)}")
    unknown = sorted(set(value) - set(keys))
    if unknown:
        raise _error(where, f"{key} has unknown key(s) {unknown}; allowed: {sorted(keys)}")
    return dict(value)


def _practice(where: str, value: Any) -> Practice:
    if isinstance(value, Mapping):
        table = _table(where, "practice", value, _PRACTICE_KEYS)
        if "until_rms_below" not in table or "max_runs" not in table:
            raise _error(
                where,
                "practice as a table needs until_rms_below (the RMS error that ends "
                f"practice) and max_runs (the cap), got {_show(table)}",
            )
        threshold = _number(where, "practice.until_rms_below", table["until_rms_below"], above=0)
        cap = _whole(where, "practice.max_runs", table["max_runs"], 1)
        least = _whole(where, "practice.min_runs", table.get("min_runs", 1), 1)
        if least > cap:
            raise _error(where, f"practice.min_runs must be at most max_runs ({cap}), got {least}")
        return Practice(cap, threshold, least)
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise _error(
            where,
            "practice must be a whole number of runs >= 0 or a table {until_rms_below = ..., "
            f"max_runs = ...}}, got {_show(value)}",
        )
    return Practice(_whole(where, "practice", value, 0))


def _break(where: str, key: str, value: Any) -> float | str:
    if value == "key" and isinstance(value, str):
        return "key"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise _error(where, f'{key} must be a number of seconds >= 0 or "key", got {_show(value)}')
    value = float(value)
    if not (math.isfinite(value) and value >= 0.0):
        raise _error(where, f'{key} must be a number of seconds >= 0 or "key", got {value!r}')
    return value


def _breaks(where: str, value: Any) -> Breaks:
    if isinstance(value, Mapping):
        table = _table(where, "breaks", value, _BREAK_KEYS)
        return Breaks(
            _break(where, "breaks.between_runs", table.get("between_runs", 0.0)),
            _break(where, "breaks.between_conditions", table.get("between_conditions", 0.0)),
        )
    both = _break(where, "breaks", value)
    return Breaks(both, both)


def _template(where: str, key: str, value: Any, fields: Sequence[str]) -> str:
    text = _text(where, key, value)
    try:
        names = [name for _, name, _, _ in string.Formatter().parse(text) if name is not None]
    except ValueError as error:
        raise _error(where, f"{key}: {error} in {_show(text)} (write {{{{ for a brace)") from None
    unknown = sorted({name for name in names if name not in fields})
    if unknown or "" in names:
        shown = unknown or ["{}"]
        raise _error(
            where,
            f"{key} uses unknown placeholder(s) {shown} in {_show(text)}; allowed: "
            + ", ".join("{" + name + "}" for name in fields),
        )
    return text


def _instructions(where: str, value: Any) -> Instructions:
    if isinstance(value, str):
        return Instructions(
            before_condition=_template(where, "instructions", value, CONDITION_FIELDS)
        )
    table = _table(where, "instructions", value, _INSTRUCTION_KEYS)
    return Instructions(
        _template(
            where,
            "instructions.before_condition",
            table.get("before_condition", DEFAULT_BEFORE_CONDITION),
            CONDITION_FIELDS,
        ),
        _template(
            where,
            "instructions.before_run",
            table.get("before_run", DEFAULT_BEFORE_RUN),
            RUN_FIELDS,
        ),
    )


def _input(value: Any, where: str) -> InputSettings:
    if isinstance(value, str):
        value = {"device": value}
    table = _table(where, "input", value, _INPUT_KEYS)
    device = table.get("device", "mouse")
    if device not in _DEVICES:
        raise _error(
            where, f"input.device must be one of {', '.join(_DEVICES)}, got {_show(device)}"
        )
    range_ = table.get("range")
    if range_ is not None:
        range_ = _number(where, "input.range", range_, above=0)
    dead_zone = table.get("dead_zone")
    if dead_zone is not None:
        dead_zone = _number(where, "input.dead_zone", dead_zone)
        if not 0.0 <= dead_zone < 1.0:
            raise _error(where, f"input.dead_zone must be a number in [0, 1), got {dead_zone!r}")
    axis = _whole(where, "input.joystick_axis", table.get("joystick_axis", 0), 0)
    if axis and device != "joystick":
        raise _error(where, f"input.joystick_axis applies to the joystick, not the {device}")
    settings = InputSettings(device, range_, dead_zone, axis)
    try:
        settings.make()
    except (TypeError, ValueError) as error:
        raise _error(where, f"input: {error}") from None
    return settings


def _realisation_list(where: str, key: str, value: Any) -> tuple[int, ...]:
    if not isinstance(value, list) or not value:
        raise _error(
            where, f"{key} must be a non-empty list of whole numbers >= 0, got {_show(value)}"
        )
    return tuple(_whole(where, key, item, 0) for item in value)


def _forcing_pair(table: Mapping[str, Any]) -> Any:
    data: dict[str, Any] = {"kind": "forcing_pair", "name": table.get("name", "custom")}
    for source in ("target", "disturbance"):
        if table.get(source) is not None:
            data[source] = {"kind": "multisine", **table[source]}
    return ForcingPair.from_dict(data)


def _forcing(where: str, value: Any) -> Any:
    if isinstance(value, str):
        if value not in FORCING_PRESETS:
            raise _error(
                where,
                f"forcing must be one of {', '.join(map(repr, FORCING_PRESETS))} or a table "
                f"of multisines (target, disturbance), got {value!r}",
            )
        return value
    table = _table(where, "forcing", value, _FORCING_KEYS)
    if "target" not in table and "disturbance" not in table:
        raise _error(where, "forcing as a table needs a target or a disturbance multisine")
    if "name" in table:
        _text(where, "forcing.name", table["name"])
    for source in ("target", "disturbance"):
        if source in table:
            _table(where, f"forcing.{source}", table[source], _MULTISINE_KEYS)
    try:
        _forcing_pair(table)
    except (TypeError, ValueError, KeyError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        raise _error(where, f"forcing: {message}") from None
    return json.loads(json.dumps(table))


def _check_lines_apart(where: str, task: str, forcing: Any) -> None:
    """Refuse target and disturbance lines on one harmonic where the display shows both.

    A pursuit or preview display's describing function is read at the disturbance's
    lines, where the target is still; at a harmonic both drive, ``U/E`` mixes the pilot's
    two responses and the line is left out of every run's analysis. A protocol that
    loses its lines that way is refused before anyone flies it.
    """
    if isinstance(forcing, str) or not task_named(task).shows_target:
        return
    pair = _forcing_pair(forcing)
    if pair.target is None or pair.disturbance is None:
        return
    shared = sorted(set(pair.target.harmonics.tolist()) & set(pair.disturbance.harmonics.tolist()))
    if shared:
        period = pair.target.measurement_time
        listed = ", ".join(f"{2.0 * math.pi * h / period:.3g}" for h in shared[:5])
        raise _error(
            where,
            f"forcing: the target and the disturbance share {len(shared)} harmonic(s) "
            f"({listed} rad/s): a {task} display's describing function cannot tell the "
            "pilot's responses to the two apart there; put the disturbance's lines between "
            "the target's",
        )


def _env_message(message: str) -> str:
    """An environment's complaint, said with the protocol's key."""
    for key, keyword in _ENV_KEYWORDS.items():
        if message.startswith(keyword):
            return key + message[len(keyword) :]
    return message


def _condition(
    where: str, raw: Any, defaults: Mapping[str, Any], names: Sequence[str]
) -> Condition:
    if not isinstance(raw, Mapping):
        raise _error(where, f"each [[condition]] must be a table, got {_show(raw)}")
    raw = dict(raw)
    if "name" not in raw:
        raise _error(where, "missing key 'name'")
    name = raw["name"]
    if not isinstance(name, str) or not _NAME.match(name):
        raise _error(
            where,
            "name must be letters, digits, '-' or '_', starting with a letter or digit (run "
            f"files are named after it), got {_show(name)}",
        )
    where = f"{where} ({name})"
    if name in names:
        raise _error(where, f"name {name!r} is used by an earlier condition; names must be unique")
    task = raw.get("task")
    if task is None:
        raise _error(where, "missing key 'task'")
    if task not in TASKS:
        raise _error(where, f"task must be one of {', '.join(TASKS)}, got {_show(task)}")
    tracking = task != "lane-keeping"
    allowed = (*_COMMON_KEYS, *(_TRACKING_KEYS if tracking else _LANE_KEYS))
    unknown = sorted(set(raw) - set(allowed))
    if unknown:
        other = _LANE_KEYS if tracking else _TRACKING_KEYS
        misplaced = [key for key in unknown if key in other]
        if misplaced:
            kind = "lane keeping" if tracking else "the tracking tasks"
            raise _error(where, f"{misplaced[0]} applies to {kind}, not task {task!r}")
        raise _error(where, f"unknown key(s) {unknown}; allowed: {sorted(allowed)}")
    options: dict[str, Any] = {}
    if tracking:
        for key in ("element", "forcing"):
            if key not in raw:
                raise _error(where, f"missing key {key!r} (a tracking task states its {key})")
        try:
            make_element(raw["element"])
        except (TypeError, ValueError, KeyError) as error:
            message = error.args[0] if isinstance(error, KeyError) and error.args else error
            raise _error(where, f"element {_show(raw['element'])}: {message}") from None
        options["element"] = json.loads(json.dumps(raw["element"]))
        options["forcing"] = _forcing(where, raw["forcing"])
        _check_lines_apart(where, task, options["forcing"])
        if "realisation" in raw and "realisations" in raw:
            raise _error(where, "give realisation or realisations, not both")
        if "realisation" in raw:
            realisations: tuple[int, ...] = (_whole(where, "realisation", raw["realisation"], 0),)
        else:
            realisations = _realisation_list(where, "realisations", raw.get("realisations", [0]))
        practice_realisations = (
            _realisation_list(where, "practice_realisations", raw["practice_realisations"])
            if "practice_realisations" in raw
            else realisations
        )
    else:
        realisations = practice_realisations = ()
    for key in ("measurement_time", "dt", "speed"):
        if key in raw:
            options[key] = _number(where, key, raw[key], above=0)
    for key in ("run_in", "available_preview"):
        if key in raw:
            options[key] = _number(where, key, raw[key])
            if options[key] < 0:
                raise _error(where, f"{key} must be a number >= 0 (seconds), got {options[key]!r}")
    if "loss_of_control" in raw:
        options["loss_of_control"] = _number(
            where, "loss_of_control", raw["loss_of_control"], above=0
        )
    if "postview" in raw:
        options["postview"] = _number(where, "postview", raw["postview"], above=0)
    for key in ("disturbance_at", "steering"):
        if key in raw:
            options[key] = _text(where, key, raw[key])
    for key in ("gap", "road", "vehicle"):
        if key in raw:
            options[key] = json.loads(json.dumps(raw[key]))
    scale = _number(where, "scale", raw["scale"], above=0) if "scale" in raw else None
    if "practice" in raw:
        practice = _practice(where, raw["practice"])
    else:
        practice = defaults["practice"]
    if "measurement_runs" in raw:
        measurement_runs = _whole(where, "measurement_runs", raw["measurement_runs"], 1)
    elif defaults["measurement_runs"] is not None:
        measurement_runs = defaults["measurement_runs"]
    else:
        raise _error(
            where, "missing key 'measurement_runs' (give it at the top level or in each condition)"
        )
    instructions = (
        _template(where, "instructions", raw["instructions"], CONDITION_FIELDS)
        if "instructions" in raw
        else None
    )
    condition = Condition(
        name=name,
        task=task,
        options=options,
        realisations=realisations,
        practice_realisations=practice_realisations,
        practice=practice,
        measurement_runs=measurement_runs,
        scale=scale,
        instructions=instructions,
    )
    _check_env(where, condition)
    return condition


def _check_env(where: str, condition: Condition) -> None:
    """Build the condition's environment once: what only it can say is said at load."""
    try:
        env = condition.make_env()
    except (TypeError, ValueError, KeyError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else str(error)
        raise _error(where, _env_message(str(message))) from None
    try:
        base = env.unwrapped
        if condition.tracking:
            for key, listed in (
                ("realisations", condition.realisations),
                ("practice_realisations", condition.practice_realisations),
            ):
                for realisation in listed:
                    try:
                        base.check_realisation(realisation)
                    except ValueError as error:
                        raise _error(where, f"{key}: {error}") from None
        try:
            DeviceAction(env, condition.scale)
        except (TypeError, ValueError) as error:
            raise _error(where, f"scale: {error}") from None
    finally:
        env.close()


def parse_protocol(
    data: Mapping[str, Any], source: str = "<table>", *, text: str | None = None
) -> Protocol:
    """Validate a protocol given as a (TOML-parsed) table; every message names the key."""
    where = source
    if not isinstance(data, Mapping):
        raise _error(where, f"a protocol must be a table, got {_show(data)}")
    unknown = sorted(set(data) - set(_TOP_KEYS))
    if unknown:
        raise _error(where, f"unknown top-level key(s) {unknown}; allowed: {sorted(_TOP_KEYS)}")
    default_name = Path(source).stem if source != "<table>" else "protocol"
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name.strip():
        raise _error(where, f"name must be a non-empty string, got {_show(name)}")
    description = _text(where, "description", data.get("description", ""))
    participant = data.get("participant")
    if participant is not None:
        try:
            check_participant(participant)
        except ValueError as error:
            raise _error(where, str(error)) from None
    order = data.get("order", "as-listed")
    if order not in ORDERS:
        raise _error(
            where, f"order must be one of {', '.join(map(repr, ORDERS))}, got {_show(order)}"
        )
    seed = data.get("seed")
    if order == "random":
        if seed is None:
            raise _error(where, "order = 'random' needs a seed (a whole number >= 0)")
        seed = _whole(where, "seed", seed, 0)
    elif seed is not None:
        raise _error(
            where, f"seed applies to order = 'random' only, not {order!r}; got seed = {_show(seed)}"
        )
    show_score = data.get("show_score", True)
    if not isinstance(show_score, bool):
        raise _error(where, f"show_score must be true or false, got {_show(show_score)}")
    defaults = {
        "practice": _practice(where, data.get("practice", 0)),
        "measurement_runs": (
            _whole(where, "measurement_runs", data["measurement_runs"], 1)
            if "measurement_runs" in data
            else None
        ),
    }
    breaks = _breaks(where, data.get("breaks", 0.0))
    instructions = _instructions(where, data.get("instructions", {}))
    settings = _input(data.get("input", {}), where)
    raw_conditions = data.get("condition")
    if not isinstance(raw_conditions, list) or not raw_conditions:
        raise _error(
            where,
            "a protocol needs at least one [[condition]] table, got condition = "
            f"{_show(raw_conditions)}",
        )
    conditions: list[Condition] = []
    for i, raw in enumerate(raw_conditions):
        conditions.append(
            _condition(f"{source}: condition {i + 1}", raw, defaults, [c.name for c in conditions])
        )
    return Protocol(
        name=name,
        conditions=tuple(conditions),
        order=order,
        seed=seed,
        breaks=breaks,
        instructions=instructions,
        input=settings,
        show_score=show_score,
        participant=participant,
        description=description,
        source=source,
        text=text,
    )


def load_protocol(path: str | Path) -> Protocol:
    """Read and validate the protocol file ``path`` (TOML); see the module docstring."""
    path = Path(path)
    if not path.is_file():
        raise ProtocolError(f"{path}: no such protocol file")
    try:
        text = path.read_text(encoding="utf-8")
        data = tomllib.loads(text)
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise ProtocolError(f"{path}: not valid TOML: {error}") from None
    return parse_protocol(data, str(path), text=text)
