"""The base every estimator's settings dataclass shares: plain-data form, checks, pickling.

A member's settings are a frozen dataclass (vary them with ``dataclasses.replace`` or
``configure``). Results, suite files and ``--set`` carry them as plain JSON data, so
each settings class needs the same three things, written here once
(:class:`SettingsRecord`):

- ``to_dict()``: JSON-able data (tuples as lists, read-only mappings as dicts,
  infinities as the strings ``"inf"``/``"-inf"``, which JSON has no number for);
- ``from_dict(data)``: its inverse, refusing unknown keys by name (a misspelt key in a
  suite file is an error, not a silently ignored setting);
- pickling through that plain form (read-only mappings do not pickle).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar

from manualcontrol.envs._validation import reject_unknown

__all__ = ["SettingsRecord", "from_json_value", "limit_pair", "to_json_value"]


def to_json_value(value: Any) -> Any:
    """``value`` as JSON data: mappings as dicts, sequences as lists, infinities as text."""
    if isinstance(value, Mapping):
        return {key: to_json_value(item) for key, item in value.items()}
    if isinstance(value, (tuple, list)):
        return [to_json_value(item) for item in value]
    if isinstance(value, float) and math.isinf(value):
        return "inf" if value > 0 else "-inf"
    return value


def from_json_value(value: Any) -> Any:
    """Inverse of :func:`to_json_value` for numbers (lists stay lists, see ``from_dict``)."""
    if isinstance(value, Mapping):
        return {key: from_json_value(item) for key, item in value.items()}
    if isinstance(value, list):
        return [from_json_value(item) for item in value]
    if isinstance(value, str) and value in ("inf", "-inf"):
        return float(value)
    return value


def limit_pair(name: str, value: Any) -> tuple[float, float]:
    """``value`` as a ``(low, high)`` pair of floats, ``low < high``; else an error naming it."""
    try:
        low, high = value
    except (TypeError, ValueError):
        raise TypeError(f"{name} must be a (low, high) pair, got {value!r}") from None
    low, high = float(low), float(high)
    if math.isnan(low) or math.isnan(high) or not low < high:
        raise ValueError(f"{name} must satisfy low < high, got ({low!r}, {high!r})")
    return (low, high)


class SettingsRecord:
    """Plain-data form, checks and pickling of a frozen settings dataclass.

    A subclass names the fields whose JSON lists are tuples in the settings
    (:attr:`tuple_fields`) and the mappings whose values are pairs
    (:attr:`pair_mapping_fields`, e.g. ``limits``).
    """

    #: Fields held as tuples (JSON gives lists).
    tuple_fields: ClassVar[tuple[str, ...]] = ("estimated",)
    #: Mapping fields whose values are tuples (``{"K_p": (low, high)}``).
    pair_mapping_fields: ClassVar[tuple[str, ...]] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form; :meth:`from_dict` inverts it (infinities as strings)."""
        return {
            item.name: to_json_value(getattr(self, item.name))
            for item in dataclasses.fields(self)  # type: ignore[arg-type]
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Any:
        """Inverse of :meth:`to_dict`; an unknown key raises, naming it and the known ones."""
        if not isinstance(data, Mapping):
            raise TypeError(f"{cls.__name__}.from_dict needs a mapping of settings, got {data!r}")
        names = [item.name for item in dataclasses.fields(cls)]  # type: ignore[arg-type]
        reject_unknown(f"{cls.__name__}.from_dict", data, names)
        items = {key: from_json_value(value) for key, value in data.items()}
        for key in cls.tuple_fields:
            if isinstance(items.get(key), list):
                items[key] = tuple(items[key])
        for key in cls.pair_mapping_fields:
            if isinstance(items.get(key), Mapping):
                items[key] = {name: tuple(pair) for name, pair in items[key].items()}
        return cls(**items)

    def __reduce__(self) -> tuple[Any, ...]:
        # read-only mappings do not pickle: rebuild from the plain dict
        return (type(self).from_dict, (self.to_dict(),))
