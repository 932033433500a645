"""Scenarios and suites: benchmark runs as data.

A :class:`Scenario` is one simulated run plus the estimator applied to it: task,
controlled element, forcing realisation, pilot and its schedules, remnant and its
power ratio, run-in and measurement time, sample time, estimator and its settings,
and the remnant seed. A :class:`Suite` is a named list of *batches*, each a scenario
template crossed with forcing realisations and remnant seeds, plus (optionally) the
paper's numbers for the batch so reports can put ours beside them.

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
    score_from = 0.0           # metrics from this time (s) of the measurement on

    [[batch]]
    name = "preview-SI"
    task = "preview"           # compensatory | pursuit | preview | lane-keeping
                               # (lane keeping reads the keys as bench.driving says)
    element = "SI"             # preset name or a table {kind = ..., ...}
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
    name = "dekf"              # see bench.runner.ESTIMATORS
    anticipation_time = 0.9    # every other key is an estimator setting

    [batch.reference]          # optional: the paper's numbers for this batch
    source = "thesis Table II"
    [batch.reference.parameters]
    tau_f = {rel_bias = 0.312, nrmse = 0.252}
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.resources
import json
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from manualcontrol.envs._validation import check_choice, check_int, check_positive
from manualcontrol.envs.elements import make_element
from manualcontrol.envs.signals import FORCING_PRESETS, preset_realisation_count
from manualcontrol.pilots import Pilot, make_remnant
from manualcontrol.pilots.simulation import LOOPS, TASKS

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = ["BUILTIN_SUITES", "Batch", "Scenario", "Suite", "SuiteError", "load_suite"]

_SUITE_FOLDER = "suites"
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
    "reference",
    "quick",
    "dt",
    "run_in",
    "measurement_time",
    "loop",
    "score_from",
}
_DEFAULT_KEYS = {"dt", "run_in", "measurement_time", "loop", "available_preview", "score_from"}
_PILOT_KEYS = {"model", "parameters", "remnant", "delay_order", "near_view"}


class SuiteError(ValueError):
    """A suite file or table that does not describe a valid suite."""


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

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-able description."""
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @property
    def key(self) -> str:
        """Stable identifier: batch, realisation, seed and a hash of the whole scenario.

        Resuming a suite skips scenarios whose key already has a result; editing any
        setting of a scenario changes its key, so it is run again.
        """
        digest = hashlib.sha256(json.dumps(self.to_dict(), sort_keys=True).encode()).hexdigest()[
            :12
        ]
        return f"{self.batch}-r{self.realisation}-s{self.remnant_seed}-{digest}"

    def build_pilot(self) -> Pilot:
        """The :class:`~manualcontrol.pilots.Pilot` of this scenario (lane keeping: the driver)."""
        if self.task == "lane-keeping":
            from manualcontrol.bench.driving import build_driver

            return build_driver(self.pilot)  # type: ignore[return-value]
        return _pilot_from(self.pilot)


@dataclass(frozen=True)
class Batch:
    """A scenario template crossed with realisations and seeds, plus the paper's numbers."""

    name: str
    template: Mapping[str, Any]
    realisations: tuple[int, ...]
    remnant_seeds: tuple[int, ...]
    quick_realisations: tuple[int, ...]
    quick_remnant_seeds: tuple[int, ...]
    reference: Mapping[str, Any] = field(default_factory=dict)


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
                    out.append(
                        Scenario(
                            suite=self.name,
                            batch=batch.name,
                            realisation=realisation,
                            remnant_seed=seed,
                            **batch.template,
                        )
                    )
        return out

    def batch(self, name: str) -> Batch:
        """The batch called ``name``."""
        for batch in self.batches:
            if batch.name == name:
                return batch
        raise KeyError(f"suite {self.name!r} has no batch {name!r}")


def _pilot_from(data: Mapping[str, Any]) -> Pilot:
    from manualcontrol.envs.schedules import Schedule
    from manualcontrol.pilots import make_model

    options = {"near_view": bool(data["near_view"])} if "near_view" in data else {}
    model = make_model(data["model"], **options)
    parameters = {
        name: Schedule.from_dict(value) for name, value in dict(data.get("parameters", {})).items()
    }
    return Pilot(model, parameters, make_remnant(data.get("remnant")), data.get("delay_order"))


def _fail(where: str, message: str) -> SuiteError:
    return SuiteError(f"{where}: {message}")


def _int_list(where: str, key: str, value: Any) -> tuple[int, ...]:
    if not isinstance(value, list) or not value:
        raise _fail(where, f"{key} must be a non-empty list of integers, got {value!r}")
    try:
        return tuple(check_int(key, item, minimum=0) for item in value)
    except (TypeError, ValueError) as error:
        raise _fail(where, str(error)) from None


def _parse_batch(where: str, raw: Mapping[str, Any], defaults: Mapping[str, Any]) -> Batch:
    unknown = sorted(set(raw) - _BATCH_KEYS)
    if unknown:
        raise _fail(where, f"unknown key(s) {unknown}; allowed: {sorted(_BATCH_KEYS)}")
    merged = {**defaults, **raw}
    if "available_preview" not in raw and raw.get("task") != "preview":
        merged.pop("available_preview", None)  # a suite-wide preview concerns preview batches
    for key in ("name", "task", "element", "forcing", "realisations", "pilot", "estimator"):
        if key not in merged:
            raise _fail(where, f"missing key {key!r}")
    name = merged["name"]
    if not isinstance(name, str) or not name.replace("-", "").replace("_", "").isalnum():
        raise _fail(where, f"name must be letters, digits, '-' or '_', got {name!r}")
    if merged["task"] == "lane-keeping":
        from manualcontrol.bench.driving import parse_lane_keeping_batch

        return parse_lane_keeping_batch(where, merged)
    where = f"{where} ({name})"
    try:
        check_choice("task", merged["task"], TASKS)
        make_element(merged["element"])
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
    except (TypeError, ValueError) as error:
        raise _fail(where, str(error)) from None
    count = preset_realisation_count(merged["forcing"])
    realisations = _int_list(where, "realisations", merged["realisations"])
    if max(realisations) >= count:
        raise _fail(
            where,
            f"realisations must lie in [0, {count - 1}] for forcing {merged['forcing']!r}, "
            f"got {max(realisations)}",
        )
    seeds = _int_list(where, "remnant_seeds", merged.get("remnant_seeds", [0]))
    quick = dict(merged.get("quick", {}))
    unknown = sorted(set(quick) - {"realisations", "remnant_seeds"})
    if unknown:
        raise _fail(where, f"quick has unknown key(s) {unknown}")
    quick_realisations = _int_list(
        where, "quick.realisations", quick.get("realisations", [realisations[0]])
    )
    quick_seeds = _int_list(where, "quick.remnant_seeds", quick.get("remnant_seeds", [seeds[0]]))
    pilot = dict(merged["pilot"])
    unknown = sorted(set(pilot) - _PILOT_KEYS)
    if unknown:
        raise _fail(where, f"pilot has unknown key(s) {unknown}; allowed: {sorted(_PILOT_KEYS)}")
    if "model" not in pilot:
        raise _fail(where, "pilot needs a model")
    try:
        built = _pilot_from(pilot)
    except (TypeError, ValueError, KeyError) as error:
        raise _fail(where, f"pilot: {error}") from None
    if built.model.task != "compensatory" and merged["task"] == "compensatory":
        raise _fail(where, f"task 'compensatory' does not fit pilot model {pilot['model']!r}")
    estimator = dict(merged["estimator"])
    if "name" not in estimator:
        raise _fail(where, "estimator needs a name")
    from manualcontrol.bench.runner import ESTIMATORS, make_estimator

    try:
        check_choice("estimator name", estimator["name"], tuple(ESTIMATORS))
        make_estimator(estimator)
    except (TypeError, ValueError) as error:
        raise _fail(where, f"estimator: {error}") from None
    template = {
        "task": merged["task"],
        "element": merged["element"],
        "forcing": merged["forcing"],
        "pilot": pilot,
        "dt": dt,
        "run_in": run_in,
        "measurement_time": measurement_time,
        "loop": loop,
        "available_preview": preview,
        "estimator": estimator,
        "score_from": score_from,
    }
    return Batch(
        name,
        template,
        realisations,
        seeds,
        quick_realisations,
        quick_seeds,
        dict(merged.get("reference", {})),
    )


def parse_suite(data: Mapping[str, Any], source: str = "<table>") -> Suite:
    """Validate a suite given as a (TOML-parsed) table."""
    unknown = sorted(set(data) - {"name", "description", "defaults", "batch"})
    if unknown:
        raise _fail(
            source,
            f"unknown top-level key(s) {unknown}; allowed: batch, defaults, description, name",
        )
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise _fail(source, f"name must be a non-empty string, got {name!r}")
    defaults = dict(data.get("defaults", {}))
    unknown = sorted(set(defaults) - _DEFAULT_KEYS)
    if unknown:
        raise _fail(
            source, f"defaults has unknown key(s) {unknown}; allowed: {sorted(_DEFAULT_KEYS)}"
        )
    raw_batches = data.get("batch")
    if not isinstance(raw_batches, list) or not raw_batches:
        raise _fail(source, "a suite needs at least one [[batch]]")
    batches = tuple(
        _parse_batch(f"{source}: batch {i + 1}", raw, defaults) for i, raw in enumerate(raw_batches)
    )
    names = [batch.name for batch in batches]
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise _fail(source, f"batch names must be unique, repeated: {duplicated}")
    return Suite(name, str(data.get("description", "")), batches, source)


def _builtin_names() -> tuple[str, ...]:
    folder = importlib.resources.files("manualcontrol.bench").joinpath(_SUITE_FOLDER)
    return tuple(
        sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml"))
    )


#: Names of the suites shipped with the package.
BUILTIN_SUITES: tuple[str, ...] = _builtin_names()


def load_suite(spec: str | Path) -> Suite:
    """A built-in suite by name, or a suite file (``.toml``) by path."""
    path = Path(spec)
    if isinstance(spec, str) and spec in BUILTIN_SUITES:
        resource = importlib.resources.files("manualcontrol.bench").joinpath(
            _SUITE_FOLDER, f"{spec}.toml"
        )
        return parse_suite(tomllib.loads(resource.read_text()), f"suite {spec}")
    if not path.is_file():
        raise SuiteError(
            f"suite must be a built-in name ({', '.join(BUILTIN_SUITES)}) or a .toml file, "
            f"got {str(spec)!r}"
        )
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as error:
        raise SuiteError(f"{path}: not valid TOML: {error}") from None
    return parse_suite(data, str(path))


def scenario_from_dict(data: Mapping[str, Any]) -> Scenario:
    """Inverse of :meth:`Scenario.to_dict`."""
    return Scenario(**dict(data))


def describe(scenarios: Sequence[Scenario]) -> str:
    """One line per batch: its size."""
    counts: dict[str, int] = {}
    for scenario in scenarios:
        counts[scenario.batch] = counts.get(scenario.batch, 0) + 1
    return ", ".join(f"{name}: {count}" for name, count in counts.items())
