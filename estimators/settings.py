"""The base every estimator's settings dataclass shares: plain-data form, checks, pickling.

A member's settings are a frozen dataclass (vary them with their ``replace`` or the member's
``configure``). Results, suite files and ``--set`` carry them as plain JSON data, so
each settings class needs the same three things, written here once
(:class:`SettingsRecord`):

- ``to_dict()``: JSON-able data (tuples as lists, read-only mappings as dicts,
  infinities as the strings ``"inf"``/``"-inf"``, which JSON has no number for);
- ``from_dict(data)``: its inverse, refusing unknown keys by name (a misspelt key in a
  suite file is an error, not a silently ignored setting);
- pickling through that plain form (read-only mappings do not pickle).

Past about fifteen fields a flat record hides the few settings a user needs among the
research knobs, so a member groups the knobs of one concern into a nested record (a
field holding another :class:`SettingsRecord`: ``noise=``, ``guard=``, ``remnant=``,
``drift=``). Suite files, ``--set`` and keyword arguments still accept each nested
field by its flat key (``drift_gain=20`` for ``drift=DriftSettings(gain=20)``), the
spelling those surfaces have always used; :meth:`SettingsRecord.build`,
:meth:`SettingsRecord.replace` and :meth:`SettingsRecord.from_dict` take either form,
and a value given both ways is refused. ``to_dict`` writes the nested form.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar

from manualcontrol.envs._validation import check_positive, reject_unknown

__all__ = ["GuardSettings", "SettingsRecord", "from_json_value", "limit_pair", "to_json_value"]


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


class _SettingsType(type):
    """Lets a settings class's constructor take flat keys and group tables too.

    ``RMLSettings(drift_gain=20)`` is what scripts and tests wrote before the drift
    settings were grouped; the dataclass constructor takes fields only, so a call with
    anything else goes through :meth:`SettingsRecord.build`, which resolves it and
    calls the constructor with fields alone.
    """

    def __call__(cls, *args: Any, **kwargs: Any) -> Any:
        groups = cls.groups  # type: ignore[attr-defined]
        if groups and not args:
            fields = {item.name for item in dataclasses.fields(cls)}  # type: ignore[arg-type]
            if any(
                key not in fields or (key in groups and not isinstance(value, SettingsRecord))
                for key, value in kwargs.items()
            ):
                return cls.build(**kwargs)  # type: ignore[attr-defined]
        return super().__call__(*args, **kwargs)


class SettingsRecord(metaclass=_SettingsType):
    """Plain-data form, checks and pickling of a frozen settings dataclass.

    A subclass names the fields whose JSON lists are tuples in the settings
    (:attr:`tuple_fields`) and the mappings whose values are pairs
    (:attr:`pair_mapping_fields`, e.g. ``limits``).
    """

    #: Fields held as tuples (JSON gives lists).
    tuple_fields: ClassVar[tuple[str, ...]] = ("estimated",)
    #: Mapping fields whose values are tuples (``{"K_p": (low, high)}``).
    pair_mapping_fields: ClassVar[tuple[str, ...]] = ()
    #: Fields holding a nested record (each with a record as its default).
    groups: ClassVar[tuple[str, ...]] = ()
    #: A nested record's flat key for each field whose flat key is not its own name
    #: (``{"gain": "drift_gain"}``); the flat key names it in error messages too.
    flat_names: ClassVar[Mapping[str, str]] = {}

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (nested records as tables); :meth:`from_dict` inverts it."""
        return {
            item.name: (
                value.to_dict()
                if isinstance(value := getattr(self, item.name), SettingsRecord)
                else to_json_value(value)
            )
            for item in dataclasses.fields(self)  # type: ignore[arg-type]
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Any:
        """Inverse of :meth:`to_dict`, flat keys accepted; an unknown key raises, naming it."""
        if not isinstance(data, Mapping):
            raise TypeError(f"{cls.__name__}.from_dict needs a mapping of settings, got {data!r}")
        return cls._assemble(f"{cls.__name__}.from_dict", data, None, plain=True)

    @classmethod
    def build(cls, **changes: Any) -> Any:
        """The defaults with ``changes`` (fields, nested records or tables, or flat keys)."""
        return cls._assemble(cls.__name__, changes, None, plain=False)

    def replace(self, **changes: Any) -> Any:
        """A copy with ``changes`` (as :meth:`build` takes them); a table merges into a group."""
        return self._assemble(type(self).__name__, changes, self, plain=False)

    @classmethod
    def flat_keys(cls) -> dict[str, tuple[str, str]]:
        """Each nested field's flat key: ``{"drift_gain": ("drift", "gain"), ...}``."""
        keys = {}
        for group in cls.groups:
            kind = type(cls._default_of(group))
            for item in dataclasses.fields(kind):
                keys[kind.flat_names.get(item.name, item.name)] = (group, item.name)
        return keys

    @classmethod
    def known_keys(cls) -> tuple[str, ...]:
        """Every key a settings table may hold: the fields and the flat keys."""
        names = [item.name for item in dataclasses.fields(cls)]  # type: ignore[arg-type]
        return (*names, *(key for key in cls.flat_keys() if key not in names))

    def _require_groups(self, names: tuple[str, ...]) -> None:
        """Raise unless each named group holds its record type (the default's type)."""
        for group in names:
            kind = type(type(self)._default_of(group))
            if not isinstance(getattr(self, group), kind):
                raise TypeError(
                    f"{group} must be a {kind.__name__} (or its fields by name), "
                    f"got {getattr(self, group)!r}"
                )

    @classmethod
    def _default_of(cls, name: str) -> Any:
        item = next(item for item in dataclasses.fields(cls) if item.name == name)  # type: ignore[arg-type]
        if item.default_factory is not dataclasses.MISSING:
            return item.default_factory()
        return item.default

    @classmethod
    def _plain_items(cls, data: Mapping[str, Any]) -> dict[str, Any]:
        """JSON values of ``data`` as the fields hold them (tuples, pairs, infinities)."""
        items = {key: from_json_value(value) for key, value in data.items()}
        for key in cls.tuple_fields:
            if isinstance(items.get(key), list):
                items[key] = tuple(items[key])
        for key in cls.pair_mapping_fields:
            if isinstance(items.get(key), Mapping):
                items[key] = {name: tuple(pair) for name, pair in items[key].items()}
        return items

    @classmethod
    def _assemble(cls, where: str, data: Mapping[str, Any], base: Any, *, plain: bool) -> Any:
        """``data`` (fields, groups as records or tables, flat keys) over ``base`` or defaults.

        A group's table or flat keys change that group's fields and keep its others (from
        the group's record where one is given, else from ``base``, else from this class's
        default record, whose defaults may differ from the record type's own), so
        ``dataclasses.replace(settings, q2=0.1)`` works as ``settings.replace(q2=0.1)``;
        a value given both in a table and by its flat key is refused, naming both.
        """
        flat = cls.flat_keys()
        reject_unknown(where, data, cls.known_keys())
        items: dict[str, Any] = {}
        changes: dict[str, dict[str, Any]] = {group: {} for group in cls.groups}
        spelled: dict[tuple[str, str], str] = {}
        records: dict[str, Any] = {}
        for key, value in data.items():
            if key in cls.groups and isinstance(value, SettingsRecord):
                records[key] = value
            elif key in cls.groups and isinstance(value, Mapping):
                kind = type(cls._default_of(key))
                reject_unknown(
                    f"{where} {key}", value, [item.name for item in dataclasses.fields(kind)]
                )
                for name, item in value.items():
                    changes[key][name] = item
                    spelled[(key, name)] = f"{key}.{name}"
            elif key in flat:
                group, name = flat[key]
                if (group, name) in spelled:
                    raise ValueError(
                        f"{where} got {key} and {spelled[(group, name)]}, one setting given "
                        "twice: give one of them"
                    )
                changes[group][name] = value
                spelled[(group, name)] = key
            elif key in cls.groups:
                raise TypeError(
                    f"{where}: {key} must be a table of its settings or a "
                    f"{type(cls._default_of(key)).__name__}, got {value!r}"
                )
            else:
                items[key] = value
        if plain:
            items = cls._plain_items(items)
        for group in cls.groups:
            record = records.get(group)
            if record is None:
                record = getattr(base, group) if base is not None else cls._default_of(group)
            if changes[group]:
                given = type(record)._plain_items(changes[group]) if plain else changes[group]
                record = dataclasses.replace(record, **given)
            items[group] = record
        if base is not None:
            return dataclasses.replace(base, **items)
        return cls(**items)

    def __reduce__(self) -> tuple[Any, ...]:
        # read-only mappings do not pickle: rebuild from the plain dict
        return (type(self).from_dict, (self.to_dict(),))


@dataclasses.dataclass(frozen=True)
class GuardSettings(SettingsRecord):
    """The numerical guards of a member's filter: what keeps it running, what stops it.

    Parameters
    ----------
    jitter : float
        Added to every covariance diagonal after each correction (>= 0; 0 = off): keeps
        covariances positive definite when estimates stall.
    max_covariance : float
        A covariance diagonal above this counts as divergence (stops the filter).
    pinned_time : float
        A parameter at a limit in at least 90 % of the samples of the last
        ``pinned_time`` seconds is reported as divergence (the filter goes on); ``inf``
        never reports.
    """

    jitter: float = 0.0
    max_covariance: float = 1e8
    pinned_time: float = 30.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "jitter", check_positive("jitter", self.jitter, allow_zero=True))
        object.__setattr__(
            self, "max_covariance", check_positive("max_covariance", self.max_covariance)
        )
        pinned = float(self.pinned_time)
        if math.isnan(pinned) or pinned <= 0.0:
            raise ValueError(f"pinned_time must be > 0 s (inf: never), got {self.pinned_time!r}")
        object.__setattr__(self, "pinned_time", pinned)
