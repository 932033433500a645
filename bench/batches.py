"""What every batch of a suite is made of, whatever its task.

:class:`Batch` (a scenario template crossed with realisations, seeds and estimators),
:class:`SuiteError`, and the checks of the keys all batches share. The tracking and
open-loop batches (:mod:`~manualcontrol.bench.scenarios`) and the lane-keeping ones
(:mod:`~manualcontrol.bench.driving`) are both read with them.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from manualcontrol.envs._validation import check_choice, check_int
from manualcontrol.estimators.registry import ESTIMATORS, make_estimator

__all__ = [
    "Batch",
    "SuiteError",
    "as_table",
    "batch_estimators",
    "estimator_misfit",
    "int_list",
    "suite_error",
]


class SuiteError(ValueError):
    """A suite file or table that does not describe a valid suite."""


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
    estimators: tuple[Mapping[str, Any], ...] = ()
    shared_estimator_settings: Mapping[str, Any] = field(default_factory=dict)

    @property
    def estimator_names(self) -> tuple[str, ...]:
        """The batch's estimators, in order."""
        return tuple(spec["name"] for spec in self.estimators)


def suite_error(where: str, message: str) -> SuiteError:
    """A :class:`SuiteError` saying where (file, batch) and what: raise it."""
    return SuiteError(f"{where}: {message}")


def as_table(where: str, key: str, value: Any) -> dict[str, Any]:
    """``value`` as a dict, or an error naming the key (TOML: a table ``{...}`` or ``[key]``)."""
    if not isinstance(value, Mapping):
        raise suite_error(where, f"{key} must be a table ({{...}} or [{key}]), got {value!r}")
    return dict(value)


def int_list(where: str, key: str, value: Any) -> tuple[int, ...]:
    """``value`` as distinct non-negative integers (realisations, seeds), or an error."""
    if not isinstance(value, list) or not value:
        raise suite_error(where, f"{key} must be a non-empty list of integers, got {value!r}")
    try:
        items = tuple(check_int(key, item, minimum=0) for item in value)
    except (TypeError, ValueError) as error:
        raise suite_error(where, str(error)) from None
    repeated = sorted({item for item in items if items.count(item) > 1})
    if repeated:
        # a repeated realisation or seed would run the same scenario twice: duplicate rows
        raise suite_error(where, f"{key} must not repeat a value, repeated: {repeated}")
    return items


#: What the family's own members identify, by the kind of batch whose runs they read: a
#: driver keeping a car in its lane, a system driven open loop, or a pilot in a tracking
#: loop. A twin reads what its member reads; a user's own estimator is not checked.
_MEMBER_KINDS: dict[str, tuple[tuple[str, ...], str]] = {
    "zhao-ukf": (("lane-keeping",), "identifies a driver keeping a car in its lane"),
    "zhao-multi-ukf": (("lane-keeping",), "identifies a driver keeping a car in its lane"),
    "rdi": (
        ("tracking", "open-loop"),
        "identifies a delayed ARMAX system from its input and output",
    ),
    **{
        name: (("tracking",), "identifies a pilot in a tracking loop")
        for name in ("dekf", "schiess-roland", "rml", "sigmoid-fit", "joint-ukf", "dual-ukf")
    },
}


def _batch_kind(task: Any) -> tuple[str, str]:
    """The kind of a batch of ``task`` (as :data:`_MEMBER_KINDS` names it) and its words."""
    if task == "lane-keeping":
        return "lane-keeping", "a lane-keeping batch"
    if task == "open-loop":
        return "open-loop", "an open-loop system batch"
    return "tracking", f"a {task} tracking batch"


def _member_kind(name: str) -> tuple[tuple[str, ...], str] | None:
    entry = ESTIMATORS.get(name)
    if entry is None:
        return None
    return _MEMBER_KINDS.get(entry.base or entry.name)


def estimator_misfit(name: str, batch: str, task: Any) -> str | None:
    """Why estimator ``name`` cannot read the runs of batch ``batch`` (of ``task``), or None.

    A driver-model estimator on a tracking batch, a pilot-model one on a lane-keeping
    batch, ...: said in those words, with the estimators that do read such a batch,
    before the batch's settings (another member's) make a less helpful error.
    """
    reads = _member_kind(name)
    kind, words = _batch_kind(task)
    if reads is None or kind in reads[0]:
        return None
    fits = [
        other
        for other in ESTIMATORS
        if (found := _member_kind(other)) is not None and kind in found[0]
    ]
    members = [other for other in fits if ESTIMATORS[other].base is None]
    twins = [other for other in fits if ESTIMATORS[other].base is not None]
    if len(twins) <= 2:
        listed = ", ".join(members + twins)
    else:
        suffixes = sorted({twin[len(ESTIMATORS[twin].base or "") :] for twin in twins})
        listed = f"{', '.join(members)} and their {' and '.join(suffixes)} twins"
    return f"{name} {reads[1]}; batch {batch!r} is {words} (estimators for it: {listed})"


def batch_estimators(
    where: str, merged: Mapping[str, Any]
) -> tuple[dict[str, Any], tuple[dict[str, Any], ...]]:
    """The batch's shared estimator settings and its estimators (each validated)."""
    shared = as_table(where, "estimator", merged.get("estimator", {}))
    if "estimators" not in merged:
        if "name" not in shared:
            raise suite_error(where, "estimator needs a name (or list the batch's estimators)")
        listed: list[Any] = [shared]
        shared = {key: value for key, value in shared.items() if key != "name"}
    else:
        listed = merged["estimators"]
        if not isinstance(listed, list) or not listed:
            raise suite_error(
                where,
                f"estimators must be a non-empty list of names or tables with a name, got "
                f"{listed!r}",
            )
        if "name" in shared:
            raise suite_error(
                where,
                "with estimators listed, [batch.estimator] holds their shared settings "
                f"and takes no name, got name = {shared['name']!r}",
            )
    specs = []
    for i, item in enumerate(listed):
        label = "estimator" if "estimators" not in merged else f"estimators[{i}]"
        entry = {"name": item} if isinstance(item, str) else as_table(where, label, item)
        if "name" not in entry:
            raise suite_error(where, f"{label} needs a name")
        spec = {**shared, **entry}
        try:
            check_choice("estimator name", spec["name"], tuple(ESTIMATORS))
            misfit = estimator_misfit(spec["name"], merged.get("name"), merged.get("task"))
            if misfit is not None:
                raise ValueError(misfit)
            make_estimator(spec)
        except (TypeError, ValueError) as error:
            raise suite_error(where, f"{label} ({entry['name']}): {error}") from None
        specs.append(spec)
    names = [spec["name"] for spec in specs]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise suite_error(where, f"estimators must not repeat a name, repeated: {repeated}")
    return shared, tuple(specs)
