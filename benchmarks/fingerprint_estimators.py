"""Fingerprints of every number the estimator family produces, to prove a refactor exact.

A change that should change no number (moving code between modules, a shared shell for
the members, a new settings base) is checked by running this before and after and
comparing: every array of every result is hashed bit for bit (dtype, shape and bytes),
every other field through its JSON text, so any difference in any sample shows.

What runs:

- every built-in suite's quick scenarios (the simulations the bench runs, every batch's
  estimators with the suite's settings; a ``-smoothed`` twin through its own
  ``estimate``);
- on the first simulation of each suite, every registered estimator with its default
  settings (the ones that cannot run there are fingerprinted by their error message);
- the online path: on each suite's first simulation, every member that runs online is
  fed the first samples one ``update`` at a time and each estimate is hashed.

Run (one process per core; two files compared key by key)::

    .venv/bin/python benchmarks/fingerprint_estimators.py --out before.json
    .venv/bin/python benchmarks/fingerprint_estimators.py --out after.json
    .venv/bin/python benchmarks/fingerprint_estimators.py --compare before.json after.json
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import inspect
import json
import os
import sys
import warnings
from collections.abc import Mapping
from concurrent.futures import ProcessPoolExecutor
from typing import Any

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

#: Samples fed one at a time on the online path.
ONLINE_SAMPLES = 300


def _digest(value: Any) -> str:
    """A hash of ``value``: arrays bit for bit, other values through canonical JSON."""
    hasher = hashlib.sha256()
    if isinstance(value, np.ndarray):
        array = np.ascontiguousarray(value)
        hasher.update(f"{array.dtype.str}{array.shape}".encode())
        hasher.update(array.tobytes())
    else:
        hasher.update(json.dumps(_plain(value), sort_keys=True, default=repr).encode())
    return hasher.hexdigest()[:16]


def _plain(value: Any) -> Any:
    """``value`` as plain JSON data: any mapping a dict, any sequence a list, numbers floats.

    So a refactor that returns the same numbers in another container type (a read-only
    mapping for a dict, a tuple for a list) keeps its fingerprint.
    """
    if isinstance(value, Mapping):
        return {str(key): _plain(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(item) for item in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def _fields(value: Any, prefix: str, into: dict[str, str]) -> None:
    """Hash ``value``'s fields (dataclasses field by field, arrays whole) into ``into``."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        for field in dataclasses.fields(value):
            _fields(getattr(value, field.name), f"{prefix}.{field.name}", into)
    elif isinstance(value, tuple) and any(
        isinstance(item, np.ndarray) or dataclasses.is_dataclass(item) for item in value
    ):
        for i, item in enumerate(value):
            _fields(item, f"{prefix}[{i}]", into)
    else:
        into[prefix] = _digest(value)


def _result_fingerprint(make: Any, recording: Any, prefix: str, into: dict[str, str]) -> None:
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = make().estimate(recording)
    except Exception as error:  # the error is part of the fingerprint
        into[f"{prefix}:error"] = f"{type(error).__name__}: {error}"
        return
    _fields(result, prefix, into)


def _online_fingerprint(make: Any, recording: Any, prefix: str, into: dict[str, str]) -> None:
    """Hash the first :data:`ONLINE_SAMPLES` estimates of ``update`` over ``recording``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            estimator = make()
            keys, columns = _online_signals(estimator, recording)
            estimator.reset(
                recording.dt, t0=float(recording.t[0]), **_reset_options(estimator, recording)
            )
            for k in range(min(ONLINE_SAMPLES, len(recording))):
                sample = {key: float(column[k]) for key, column in zip(keys, columns, strict=True)}
                _fields(estimator.update(sample), f"{prefix}[{k}]", into)
        except Exception as error:  # the error is part of the fingerprint
            into[f"{prefix}:error"] = f"{type(error).__name__}: {error}"


def _online_signals(estimator: Any, recording: Any) -> tuple[tuple[str, ...], list[Any]]:
    """The keys ``update`` reads and their columns, as ``estimate`` feeds them."""
    keys = getattr(estimator, "sample_keys", None)
    if keys is None:  # the driver-model filters: their signals are the recording's columns
        from manualcontrol.pilots.driver import DRIVER_INPUTS, DRIVER_OUTPUTS

        keys = (*DRIVER_INPUTS, *DRIVER_OUTPUTS)
        return keys, [recording[key] for key in keys]
    signals = estimator.signals(recording)
    if not isinstance(signals, dict):  # input and output arrays, in sample_keys order
        signals = dict(zip(keys, signals, strict=True))
    return tuple(keys), [signals[key] for key in keys]


def _reset_options(estimator: Any, recording: Any) -> dict[str, Any]:
    """What each member's ``reset`` needs online beyond ``dt`` (as ``estimate`` forms it)."""
    parameters = inspect.signature(estimator.reset).parameters
    options: dict[str, Any] = {}
    if "var_u0" in parameters:  # a pilot filter: the first window's variances (eq. 34)
        window = slice(0, round(estimator.settings.noise.window / recording.dt) + 1)
        options["var_u0"] = float(np.nanvar(recording["u"][window]))
        options["var_e0"] = float(np.nanvar(recording.with_error_signal()["e"][window]))
    if "initial_states" in parameters:
        options["initial_states"] = estimator.initial_states_of(recording)
    if "speed" in parameters:
        options["speed"] = recording.metadata.get("speed")
    return options


def _suite_fingerprints(name: str) -> dict[str, str]:
    from manualcontrol.bench.runner import simulate_scenario
    from manualcontrol.bench.scenarios import load_suite
    from manualcontrol.estimators.registry import ESTIMATORS, make_estimator

    into: dict[str, str] = {}
    suite = load_suite(name)
    groups: dict[str, list[Any]] = {}
    for scenario in suite.scenarios(quick=True):
        groups.setdefault(scenario.simulation_key, []).append(scenario)
    for index, group in enumerate(groups.values()):
        recording = simulate_scenario(group[0])
        tag = f"{name}/{group[0].batch}/r{group[0].realisation}s{group[0].remnant_seed}"
        into[f"{tag}/recording"] = _digest(
            np.column_stack([np.asarray(recording[s]) for s in recording.signal_names])
        )
        for scenario in group:
            spec = dict(scenario.estimator)
            _result_fingerprint(
                lambda spec=spec: make_estimator(spec),
                recording,
                f"{tag}/{_digest(spec)}/{spec['name']}",
                into,
            )
        if index:
            continue
        for member, entry in ESTIMATORS.items():
            if member.endswith("-cv"):  # cross-validation: many passes; the suites run it
                continue
            _result_fingerprint(
                lambda entry=entry: entry.build({}), recording, f"{tag}/default/{member}", into
            )
            if member.endswith("-smoothed") or member == "sigmoid-fit":
                continue
            _online_fingerprint(
                lambda entry=entry: entry.build({}), recording, f"{tag}/online/{member}", into
            )
    return into


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", help="write the fingerprints to this JSON file")
    parser.add_argument("--compare", nargs=2, metavar=("BEFORE", "AFTER"))
    parser.add_argument("--suites", help="comma-separated built-in suites (default: all)")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args(argv)
    if args.compare:
        before, after = (json.load(open(path)) for path in args.compare)
        changed = sorted(k for k in before.keys() & after.keys() if before[k] != after[k])
        missing = sorted(before.keys() - after.keys())
        added = sorted(after.keys() - before.keys())
        for label, keys in (("changed", changed), ("missing", missing), ("new", added)):
            for key in keys[:40]:
                print(f"{label}: {key}")
        print(
            f"{len(before)} fingerprints before, {len(after)} after: {len(changed)} changed, "
            f"{len(missing)} missing, {len(added)} new"
        )
        return 1 if changed or missing or added else 0
    if not args.out:
        parser.error("give --out FILE (or --compare BEFORE AFTER)")
    from manualcontrol.bench.scenarios import BUILTIN_SUITES

    names = args.suites.split(",") if args.suites else list(BUILTIN_SUITES)
    into: dict[str, str] = {}
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        for part in pool.map(_suite_fingerprints, names):
            into.update(part)
    with open(args.out, "w") as file:
        json.dump(into, file, indent=0, sort_keys=True)
    errors = sum(1 for key in into if key.endswith(":error"))
    print(f"{len(into)} fingerprints ({errors} errors recorded) -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
