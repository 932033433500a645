"""The built-in suites by name, and what each holds, read without building anything.

``manualcontrol suites`` is a listing: it answers in a fraction of a second because it
reads the shipped suite files as plain tables and counts their runs, where
:func:`~manualcontrol.bench.scenarios.load_suite` validates every batch deeply (it builds
the pilots, the estimators and a lane-keeping drive to check them, which costs seconds).
The shipped files pass that validation in the test suite, and a test holds the counts
here equal to those of the validated suites, so the two readings cannot drift apart.

This module imports the standard library only.
"""

from __future__ import annotations

import importlib.resources
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

__all__ = ["SUITE_FOLDER", "SuiteOutline", "builtin_suite_names", "outline", "read_builtin_suite"]

#: The package folder (of ``manualcontrol.bench``) holding the built-in suite files.
SUITE_FOLDER = "suites"


def builtin_suite_names() -> tuple[str, ...]:
    """Names of the suites shipped with the package, sorted."""
    folder = importlib.resources.files("manualcontrol.bench").joinpath(SUITE_FOLDER)
    return tuple(
        sorted(p.name[: -len(".toml")] for p in folder.iterdir() if p.name.endswith(".toml"))
    )


def read_builtin_suite(name: str) -> dict[str, Any]:
    """The table of the built-in suite ``name``, as its TOML file holds it."""
    resource = importlib.resources.files("manualcontrol.bench").joinpath(
        SUITE_FOLDER, f"{name}.toml"
    )
    return tomllib.loads(resource.read_text(encoding="utf-8"))


@dataclass(frozen=True)
class SuiteOutline:
    """A suite's name, description and run count per batch (full and ``--quick``)."""

    name: str
    description: str
    runs: dict[str, int]
    quick_runs: dict[str, int]


def outline(data: Mapping[str, Any]) -> SuiteOutline:
    """Count the runs of a suite table as :meth:`Suite.scenarios` expands them.

    Each batch (merged over ``defaults``) runs every realisation with every remnant
    seed (default ``[0]``) for every estimator (the ``estimators`` list, else the one
    ``estimator``); ``--quick`` takes the ``quick`` subsets, by default the first
    realisation and the first seed. The table is taken as valid (a shipped suite).
    """
    defaults = dict(data.get("defaults", {}))
    runs: dict[str, int] = {}
    quick_runs: dict[str, int] = {}
    for raw in data["batch"]:
        merged = {**defaults, **raw}
        realisations = list(merged["realisations"])
        seeds = list(merged.get("remnant_seeds", [0]))
        estimators = len(merged["estimators"]) if "estimators" in merged else 1
        quick = dict(merged.get("quick", {}))
        quick_realisations = quick.get("realisations", realisations[:1])
        quick_seeds = quick.get("remnant_seeds", seeds[:1])
        runs[merged["name"]] = len(realisations) * len(seeds) * estimators
        quick_runs[merged["name"]] = len(quick_realisations) * len(quick_seeds) * estimators
    return SuiteOutline(data["name"], data.get("description", ""), runs, quick_runs)
