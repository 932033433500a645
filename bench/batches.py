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

__all__ = ["Batch", "SuiteError", "as_table", "batch_estimators", "int_list", "suite_error"]


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
            make_estimator(spec)
        except (TypeError, ValueError) as error:
            raise suite_error(where, f"{label} ({entry['name']}): {error}") from None
        specs.append(spec)
    names = [spec["name"] for spec in specs]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise suite_error(where, f"estimators must not repeat a name, repeated: {repeated}")
    return shared, tuple(specs)
