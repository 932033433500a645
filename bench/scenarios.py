"""Scenarios and suites: benchmark runs as data.

A :class:`Scenario` is one simulated run plus one estimator applied to it: task,
controlled element, forcing realisation, pilot and its schedules, remnant and its
power ratio, run-in and measurement time, sample time, estimator and its settings,
and the remnant seed. A :class:`Suite` is a named list of *batches*, each a scenario
template crossed with forcing realisations, remnant seeds and the batch's estimators,
plus (optionally) the paper's numbers for the batch so reports can put ours beside
them. Scenarios that differ only in their estimator share one simulation
(:attr:`Scenario.simulation_key`): the runner simulates it once and every estimator
reads the same recording.

Suites are TOML files a user can copy and edit (see ``bench/suites/*.toml`` for the
built-in ones, :func:`load_suite` for the schema); everything is validated where it is
read, and errors name the file, the batch and the offending key.

Schema of a suite file::

    name = "my-suite"
    description = "..."

    [defaults]                 # optional, applies to every batch
    dt = 0.01
    run_in = 60.0
    measurement_time = 120.0   # default: the forcing period
    loop = "continuous"        # or "sampled"
    score_from = 0.0           # metrics from this time (s) on: >= 0 and at most the
                               # last measured sample's time, or nothing is scored
    start_time = 0.0           # time of the first measured sample (s)
    measurement_noise = {u = 0.00092, y = 0.00092}   # variances added to recorded signals
    initial_state = {y = [-0.959, -5.64], u = [1.03, 40.5], n = [0.41, 2.55]}
                               # loop outputs and derivatives at the start (see simulate)
    disturbance_at = "output"  # or "input", for every batch (a batch may say otherwise)

    [[batch]]
    name = "preview-SI"
    task = "preview"           # compensatory | pursuit | preview | lane-keeping
                               # (lane keeping reads the keys as bench.driving says)
    element = "SI"             # preset name, transfer function ("1/(s(s+1))") or a
                               # table {kind = ..., ...}
    disturbance_at = "output"  # or "input": where the forcing's fd enters the element
    forcing = "vanderel-bw4"   # forcing preset
    realisations = [0, 1, 2]   # forcing realisations (crossed)
    remnant_seeds = [0]        # remnant seeds (crossed; one run when no remnant)
    available_preview = 1.0    # preview tasks only
    quick = {realisations = [0], remnant_seeds = [0]}   # used by --quick

    [batch.pilot]
    model = "preview"
    delay_order = 5            # optional: Padé delays in the simulation
    remnant = "vertregt2020-SI"   # preset name, a table, or omitted
    [batch.pilot.parameters]
    tau_f = {kind = "sigmoid", start = 0.6, end = 0.3, t_mid = 60.0, transition_time = 20.0}
    K_f = 1.0

    [batch.estimator]
    name = "dekf"              # see `manualcontrol estimators`
    anticipation_time = 0.9    # every other key is an estimator setting

    # or several estimators on the same recordings: [batch.estimator] then holds the
    # settings they share (no name), and each entry names one and adds its own
    [[batch.estimators]]
    name = "dekf"
    total_derivative = "dimensional"
    [[batch.estimators]]
    name = "joint-ukf"         # a plain string "joint-ukf" in a list works too

    [batch.reference]          # optional: the paper's numbers for this batch
    source = "thesis Table II"
    [batch.reference.parameters]
    tau_f = {rel_bias = 0.312, nrmse = 0.252}

Postview batches (``task = "postview"``, :mod:`manualcontrol.envs.postview`) take
``gap = <number or schedule table>``; any closed-loop batch may end at loss of control,
``loss_of_control = <|e| limit>``. An open-loop batch (``task = "open-loop"``,
:func:`manualcontrol.pilots.open_loop.simulate_open_loop`) has no element or pilot but a
``[batch.system]`` table (``a``, ``b``, ``delay``, ``step``, ``noise_std``,
``noise_cutoff_hz``, ``simulation_rate``: an
:class:`~manualcontrol.pilots.open_loop.ARMAXSystem`) driven by the forcing's target;
its ``remnant_seeds`` seed the output noise.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from manualcontrol.bench.batches import (
    Batch,
    SuiteError,
    as_table,
    batch_estimators,
    int_list,
    suite_error,
)
from manualcontrol.bench.driving import build_driver, parse_lane_keeping_batch
from manualcontrol.bench.listing import builtin_suite_names, read_builtin_suite
from manualcontrol.envs._validation import (
    check_choice,
    check_duration,
    check_positive,
    check_real,
    check_vector,
    reject_unknown,
)
from manualcontrol.envs.elements import make_element
from manualcontrol.envs.recording import MEASURED_SIGNALS
from manualcontrol.envs.schedules import Schedule
from manualcontrol.envs.signals import FORCING_PRESETS, preset_realisation_count
from manualcontrol.envs.tasks import (
    DISTURBANCE_POINTS,
    measurement_time_for,
    resolve_forcing,
    task_named,
)
from manualcontrol.estimators.registry import ESTIMATORS, make_estimator
from manualcontrol.pilots import Pilot
from manualcontrol.pilots.open_loop import ARMAXSystem
from manualcontrol.pilots.simulation import INITIAL_STATE_SIGNALS, LOOPS, TASKS, SimulationSetup
from manualcontrol.pilots.stability import check_stable

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = ["BUILTIN_SUITES", "Batch", "Scenario", "Suite", "SuiteError", "load_suite"]

_BATCH_KEYS = {
    "name",
    "task",
    "element",
    "forcing",
    "realisations",
    "remnant_seeds",
    "available_preview",
    "pilot",
    "estimator",
    "estimators",
    "reference",
    "quick",
    "dt",
    "run_in",
    "measurement_time",
    "loop",
    "score_from",
    "system",
    "gap",
    "loss_of_control",
    "start_time",
    "measurement_noise",
    "initial_state",
    "disturbance_at",
}
#: The task of open-loop batches: a system driven by the forcing, no pilot and no loop.
OPEN_LOOP = "open-loop"
_DEFAULT_KEYS = {"dt", "run_in", "measurement_time", "loop", "available_preview", "score_from"}
_DEFAULT_KEYS |= {"start_time", "measurement_noise", "initial_state", "disturbance_at"}
#: Scenario fields added after suites were first stored: left out of the scenario's
#: description (and so of its key) at their defaults, so the keys of scenarios that do
#: not use them stay what they were.
_OPTIONAL_FIELDS = {
    "system": None,
    "gap": None,
    "loss_of_control": None,
    "start_time": 0.0,
    "measurement_noise": None,
    "initial_state": None,
    "disturbance_at": "output",
}
_PILOT_KEYS = {"model", "parameters", "remnant", "delay_order", "near_view"}


@dataclass(frozen=True)
class Scenario:
    """One benchmark run: a simulation and the estimator applied to it (all plain data)."""

    suite: str
    batch: str
    task: str
    element: Any
    forcing: str
    realisation: int
    pilot: Mapping[str, Any]
    remnant_seed: int
    dt: float
    run_in: float
    measurement_time: float | None
    loop: str
    available_preview: float | None
    estimator: Mapping[str, Any]
    score_from: float = 0.0
    system: Mapping[str, Any] | None = None
    gap: Any = None
    loss_of_control: float | None = None
    start_time: float = 0.0
    measurement_noise: Mapping[str, float] | None = None
    initial_state: Mapping[str, Any] | None = None
    disturbance_at: str = "output"

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able description (the optional fields only where set)."""
        data = json.loads(json.dumps(dataclasses.asdict(self)))
        for name, default in _OPTIONAL_FIELDS.items():
            if data.get(name) == default:
                data.pop(name, None)
        return data

    @property
    def key(self) -> str:
        """Stable identifier: batch, realisation, seed, estimator and a hash of it all.

        Resuming a suite skips scenarios whose key already has a result; editing any
        setting of a scenario changes its key, so it is run again.
        """
        digest = _digest(self.to_dict())
        return (
            f"{self.batch}-r{self.realisation}-s{self.remnant_seed}-"
            f"{self.estimator['name']}-{digest}"
        )

    @property
    def simulation_key(self) -> str:
        """Hash of everything but the estimator: scenarios sharing it share a recording."""
        data = self.to_dict()
        del data["estimator"]
        return _digest(data)

    def build_pilot(self) -> Pilot:
        """The :class:`~manualcontrol.pilots.Pilot` of this scenario (lane keeping: the driver)."""
        if self.task == "lane-keeping":
            return build_driver(self.pilot)  # type: ignore[return-value]
        return _pilot_from(self.pilot)

    def build_system(self) -> Any:
        """The :class:`~manualcontrol.pilots.open_loop.ARMAXSystem` of an open-loop scenario."""
        if self.system is None:
            raise ValueError(f"scenario {self.key} is not open-loop: it has no system")
        return ARMAXSystem.from_dict(self.system)

    def build_gap(self) -> Any:
        """The postview gap as a number or schedule (None outside postview tasks)."""
        return None if self.gap is None else Schedule.from_dict(self.gap)


@dataclass(frozen=True)
class Suite:
    """A named set of batches (see the module docstring for the file schema)."""

    name: str
    description: str
    batches: tuple[Batch, ...]
    source: str = ""

    def scenarios(self, quick: bool = False) -> list[Scenario]:
        """Every scenario of the suite (``quick``: each batch's quick subset)."""
        out = []
        for batch in self.batches:
            realisations = batch.quick_realisations if quick else batch.realisations
            seeds = batch.quick_remnant_seeds if quick else batch.remnant_seeds
            for realisation in realisations:
                for seed in seeds:
                    for estimator in batch.estimators:
                        out.append(
                            Scenario(
                                suite=self.name,
                                batch=batch.name,
                                realisation=realisation,
                                remnant_seed=seed,
                                estimator=estimator,
                                **batch.template,
                            )
                        )
        return out

    def with_estimators(self, names: Sequence[str]) -> Suite:
        """The suite with every batch's estimators replaced by ``names``.

        A name the batch lists already keeps its own settings; another gets the batch's
        shared estimator settings. Raises :class:`SuiteError` naming the batch when an
        estimator cannot run there.
        """
        names = list(names)
        if not names:
            raise SuiteError("estimators must name at least one estimator")
        unknown = [name for name in names if name not in ESTIMATORS]
        if unknown:
            raise SuiteError(
                f"estimators names no estimator of the family: {', '.join(unknown)} (the "
                f"family: {', '.join(ESTIMATORS)})"
            )
        if len(set(names)) != len(names):
            raise SuiteError(f"estimators names one twice: {names}")
        batches = []
        for batch in self.batches:
            own = {spec["name"]: spec for spec in batch.estimators}
            specs = []
            for name in names:
                spec = own.get(name, {**batch.shared_estimator_settings, "name": name})
                try:
                    make_estimator(spec)
                except (TypeError, ValueError) as error:
                    raise SuiteError(
                        f"{self.source or self.name}: batch {batch.name}: estimator {name}: {error}"
                    ) from None
                specs.append(dict(spec))
            batches.append(dataclasses.replace(batch, estimators=tuple(specs)))
        return dataclasses.replace(self, batches=tuple(batches))

    def batch(self, name: str) -> Batch:
        """The batch called ``name``."""
        for batch in self.batches:
            if batch.name == name:
                return batch
        raise KeyError(f"suite {self.name!r} has no batch {name!r}")


def _digest(data: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:12]


def _pilot_from(data: Mapping[str, Any]) -> Pilot:
    """The pilot of a suite's ``[batch.pilot]`` table, built by :meth:`Pilot.from_dict`.

    The suite table is :meth:`Pilot.to_dict`'s layout with ``near_view`` written at the
    top level (the only model option) instead of under ``model_options``.
    """
    data = dict(data)
    options = {"near_view": data.pop("near_view")} if "near_view" in data else {}
    return Pilot.from_dict({**data, "model_options": options})


def _measurement_noise(value: Any) -> dict[str, float] | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise TypeError(f"measurement_noise must be a table of variances, got {value!r}")
    reject_unknown("measurement_noise", value, MEASURED_SIGNALS)
    return {
        name: check_positive(f"measurement_noise.{name}", variance, allow_zero=True)
        for name, variance in value.items()
    }


def _initial_state(value: Any) -> dict[str, list[float]] | None:
    if value is None:
        return None
    if not isinstance(value, Mapping):
        raise TypeError(
            f"initial_state must be a table of signal = [value, rate, ...], got {value!r}"
        )
    reject_unknown("initial_state", value, INITIAL_STATE_SIGNALS)
    return {
        name: [float(v) for v in check_vector(f"initial_state.{name}", entries, min_length=1)]
        for name, entries in value.items()
    }


def _check_subset(where: str, key: str, subset: tuple[int, ...], full: tuple[int, ...]) -> None:
    outside = sorted(set(subset) - set(full))
    if outside:
        raise suite_error(
            where, f"quick.{key} must be taken from {key} {list(full)}, got {outside}"
        )


def _parse_batch(where: str, raw: Any, defaults: Mapping[str, Any]) -> Batch:
    raw = as_table(where, "each [[batch]]", raw)
    unknown = sorted(set(raw) - _BATCH_KEYS)
    if unknown:
        raise suite_error(where, f"unknown key(s) {unknown}; allowed: {sorted(_BATCH_KEYS)}")
    merged = {**defaults, **raw}
    if "available_preview" not in raw and raw.get("task") != "preview":
        merged.pop("available_preview", None)  # a suite-wide preview concerns preview batches
    open_loop = merged.get("task") == OPEN_LOOP
    needed = ("system",) if open_loop else ("element", "pilot")
    for key in ("name", "task", "forcing", "realisations", *needed):
        if key not in merged:
            raise suite_error(where, f"missing key {key!r}")
    name = merged["name"]
    if not isinstance(name, str) or not name.replace("-", "").replace("_", "").isalnum():
        raise suite_error(where, f"name must be letters, digits, '-' or '_', got {name!r}")
    if merged["task"] == "lane-keeping":
        return parse_lane_keeping_batch(where, merged)
    where = f"{where} ({name})"
    try:
        check_choice("task", merged["task"], (*TASKS, OPEN_LOOP))
        extra = _check_extras(merged, open_loop)
        if not open_loop:
            try:
                make_element(merged["element"])
            except (TypeError, ValueError, KeyError) as error:
                raise ValueError(f"element: {error}") from None
        check_choice("forcing", merged["forcing"], FORCING_PRESETS)
        loop = check_choice("loop", merged.get("loop", "continuous"), LOOPS)
        dt = check_positive("dt", merged.get("dt", 0.01))
        run_in = check_positive("run_in", merged.get("run_in", 60.0), allow_zero=True)
        measurement_time = merged.get("measurement_time")
        if measurement_time is not None:
            measurement_time = check_positive("measurement_time", measurement_time)
        preview = merged.get("available_preview")
        if preview is not None:
            preview = check_positive("available_preview", preview, allow_zero=True)
        score_from = check_positive("score_from", merged.get("score_from", 0.0), allow_zero=True)
        start_time = check_real("start_time", merged.get("start_time", 0.0))
        noise = _measurement_noise(merged.get("measurement_noise"))
        initial_state = _initial_state(merged.get("initial_state"))
    except (TypeError, ValueError) as error:
        raise suite_error(where, str(error)) from None
    count = preset_realisation_count(merged["forcing"])
    realisations = int_list(where, "realisations", merged["realisations"])
    if max(realisations) >= count:
        raise suite_error(
            where,
            f"realisations must lie in [0, {count - 1}] for forcing {merged['forcing']!r}, "
            f"got {max(realisations)}",
        )
    seeds = int_list(where, "remnant_seeds", merged.get("remnant_seeds", [0]))
    quick = as_table(where, "quick", merged.get("quick", {}))
    unknown = sorted(set(quick) - {"realisations", "remnant_seeds"})
    if unknown:
        raise suite_error(
            where, f"quick has unknown key(s) {unknown}; allowed: ['realisations', 'remnant_seeds']"
        )
    quick_realisations = int_list(
        where, "quick.realisations", quick.get("realisations", [realisations[0]])
    )
    quick_seeds = int_list(where, "quick.remnant_seeds", quick.get("remnant_seeds", [seeds[0]]))
    _check_subset(where, "realisations", quick_realisations, realisations)
    _check_subset(where, "remnant_seeds", quick_seeds, seeds)
    pilot, built = ({}, None) if open_loop else _checked_pilot(where, merged)
    shared, estimators = batch_estimators(where, merged)
    reference = as_table(where, "reference", merged.get("reference", {}))
    template = {
        "task": merged["task"],
        "element": merged.get("element"),
        "forcing": merged["forcing"],
        "pilot": pilot,
        "dt": dt,
        "run_in": run_in,
        "measurement_time": measurement_time,
        "loop": loop,
        "available_preview": preview,
        "score_from": score_from,
        **extra,
        "start_time": start_time,
        "measurement_noise": noise,
        "initial_state": initial_state,
    }
    if built is not None:
        _check_runs(where, built, template, realisations[0])
    _check_score_from(where, template, open_loop)
    return Batch(
        name,
        template,
        realisations,
        seeds,
        quick_realisations,
        quick_seeds,
        reference,
        estimators,
        shared,
    )


def _check_runs(where: str, pilot: Pilot, template: Mapping[str, Any], realisation: int) -> None:
    """What would otherwise fail only at run time: the task, the pilot's schedules, the loop.

    The whole simulation set-up is resolved once per batch (task and model, preview
    times within the available preview, measurement time against dt) and the closed
    loop's stability checked, so a suite that cannot run stops at load, not as a
    column of failed rows.
    """
    try:
        setup = SimulationSetup.create(
            pilot,
            template["element"],
            template["forcing"],
            realisation=realisation,
            task=template["task"],
            available_preview=template["available_preview"],
            dt=template["dt"],
            run_in=template["run_in"],
            measurement_time=template["measurement_time"],
            gap=None if template.get("gap") is None else Schedule.from_dict(template["gap"]),
        )
        setup.parameter_traces()
        if "loss_of_control" not in template:  # a run that may end at the loss is not judged
            check_stable(setup)
    except (TypeError, ValueError) as error:
        raise suite_error(where, str(error)) from None


def _check_score_from(where: str, template: Mapping[str, Any], open_loop: bool) -> None:
    """A ``score_from`` that leaves at least one measured sample to score, or an error.

    Rows are scored over ``t >= score_from``; the measured samples run from the start
    time (0 for an open-loop batch, which has none) for the measurement time (the
    forcing period by default; 60 s for an open-loop batch, as the runner does).
    """
    dt = template["dt"]
    measurement_time = template["measurement_time"]
    if measurement_time is None:
        if open_loop:
            measurement_time, said = 60.0, " (the default)"
        else:
            forcing = resolve_forcing(template["forcing"], 0)
            measurement_time = measurement_time_for(forcing, None)
            said = " (the forcing period)"
    else:
        said = ""
    try:
        check_duration("measurement_time", measurement_time, dt)
    except ValueError as error:
        raise suite_error(where, str(error)) from None
    start = 0.0 if open_loop else template["start_time"]
    last = start + (round(measurement_time / dt) - 1) * dt
    score_from = template["score_from"]
    if score_from > last + 1e-9:  # the scoring window's tolerance (bench.scoring)
        begins = "" if start == 0.0 else f"start_time = {start:g} s, "
        raise suite_error(
            where,
            f"score_from must lie in [0, {last:g}] s, the times of the measured samples "
            f"(t = {start:g} to {last:g} s: {begins}measurement_time = {measurement_time:g} s"
            f"{said} at dt = {dt:g} s), got {score_from!r}: it would leave nothing to score",
        )


def _checked_pilot(where: str, merged: Mapping[str, Any]) -> tuple[dict[str, Any], Pilot]:
    """The batch's pilot table, checked, and the pilot it builds."""
    pilot = as_table(where, "pilot", merged["pilot"])
    unknown = sorted(set(pilot) - _PILOT_KEYS)
    if unknown:
        raise suite_error(
            where, f"pilot has unknown key(s) {unknown}; allowed: {sorted(_PILOT_KEYS)}"
        )
    if "model" not in pilot:
        raise suite_error(where, "pilot needs a model")
    if "parameters" in pilot:
        as_table(where, "pilot.parameters", pilot["parameters"])
    try:
        built = _pilot_from(pilot)
    except (TypeError, ValueError, KeyError) as error:
        raise suite_error(where, f"pilot: {error}") from None
    display, written_for = task_named(merged["task"]), task_named(built.model.task)
    if display.shows_error_only and not written_for.shows_error_only:
        raise suite_error(where, f"task 'compensatory' does not fit pilot model {pilot['model']!r}")
    if display.shows_postview != written_for.shows_postview:
        raise suite_error(
            where, f"task {merged['task']!r} does not fit pilot model {pilot['model']!r}"
        )
    return pilot, built


def _check_extras(merged: Mapping[str, Any], open_loop: bool) -> dict[str, Any]:
    """The keys of postview, loss-of-control, disturbance-point and open-loop batches, checked."""
    extra: dict[str, Any] = {}
    if open_loop:
        for key in (
            "element",
            "pilot",
            "gap",
            "loss_of_control",
            "available_preview",
            "disturbance_at",
        ):
            if key in merged:
                raise ValueError(f"{key} does not apply to an open-loop batch (it has a system)")
        try:
            extra["system"] = ARMAXSystem.from_dict(merged["system"]).to_dict()
        except (TypeError, ValueError, KeyError) as error:
            raise type(error)(f"system: {error}") from None
        return extra
    if "system" in merged:
        raise ValueError(f"system belongs to open-loop batches, not task {merged['task']!r}")
    if "gap" in merged:
        if not task_named(merged["task"]).shows_postview:
            raise ValueError(f"gap belongs to postview batches, not task {merged['task']!r}")
        gap = merged["gap"]
        try:
            Schedule.from_dict(gap)
        except (TypeError, ValueError) as error:
            raise type(error)(f"gap: {error}") from None
        extra["gap"] = gap
    if "loss_of_control" in merged:
        extra["loss_of_control"] = check_positive("loss_of_control", merged["loss_of_control"])
    if "disturbance_at" in merged:
        extra["disturbance_at"] = check_choice(
            "disturbance_at", merged["disturbance_at"], DISTURBANCE_POINTS
        )
    return extra


def parse_suite(data: Mapping[str, Any], source: str = "<table>") -> Suite:
    """Validate a suite given as a (TOML-parsed) table; every message names the key."""
    if not data:
        raise suite_error(
            source,
            "the file holds no suite: it needs name = ..., and at least one [[batch]] table "
            "(see a built-in suite: `manualcontrol suites`)",
        )
    unknown = sorted(set(data) - {"name", "description", "defaults", "batch"})
    if unknown:
        raise suite_error(
            source,
            f"unknown top-level key(s) {unknown}; allowed: batch, defaults, description, name",
        )
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise suite_error(source, f"name must be a non-empty string, got {name!r}")
    description = data.get("description", "")
    if not isinstance(description, str):
        raise suite_error(source, f"description must be a string, got {description!r}")
    defaults = as_table(source, "defaults", data.get("defaults", {}))
    unknown = sorted(set(defaults) - _DEFAULT_KEYS)
    if unknown:
        raise suite_error(
            source, f"defaults has unknown key(s) {unknown}; allowed: {sorted(_DEFAULT_KEYS)}"
        )
    raw_batches = data.get("batch")
    if not isinstance(raw_batches, list) or not raw_batches:
        raise suite_error(
            source, f"a suite needs at least one [[batch]] table, got batch = {raw_batches!r}"
        )
    batches = tuple(
        _parse_batch(f"{source}: batch {i + 1}", raw, defaults) for i, raw in enumerate(raw_batches)
    )
    names = [batch.name for batch in batches]
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise suite_error(source, f"batch names must be unique, repeated: {duplicated}")
    return Suite(name, description, batches, source)


#: Names of the suites shipped with the package.
BUILTIN_SUITES: tuple[str, ...] = builtin_suite_names()


def load_suite(spec: str | Path) -> Suite:
    """A built-in suite by name, or a suite file (``.toml``) by path."""
    path = Path(spec)
    if isinstance(spec, str) and spec in BUILTIN_SUITES:
        return parse_suite(read_builtin_suite(spec), f"suite {spec}")
    if not path.is_file():
        raise SuiteError(
            f"suite must be a built-in name ({', '.join(BUILTIN_SUITES)}) or a .toml file, "
            f"got {str(spec)!r}"
        )
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as error:
        raise SuiteError(f"{path}: not valid TOML: {error}") from None
    return parse_suite(data, str(path))


def scenario_from_dict(data: Mapping[str, Any]) -> Scenario:
    """Inverse of :meth:`Scenario.to_dict`."""
    return Scenario(**dict(data))
