"""Sampled tracking-run signals: the one currency between simulation, envs and estimators.

A :class:`Recording` holds the signals of one tracking run sampled at a fixed sample time
``dt``, the true pilot-parameter traces when they are known (simulation), and JSON
metadata. It is immutable: arrays are read-only float64 copies and mappings are read-only
views, so a recording can be shared between an env, an estimator and a benchmark without
anyone changing it under the others' feet. Derived copies (:meth:`Recording.slice_time`,
:meth:`Recording.with_signals`, ...) return new recordings.

Signal names (``DESIGN.md``):

======  ===========================================================================
``t``   time (s), strictly uniform with spacing ``dt``
``ft``  target forcing function
``fd``  disturbance forcing function, added at the controlled-element (CE) output
``y``   CE output
``e``   tracking error ``ft - y``
``u``   pilot control output (stick)
``n``   remnant as injected
======  ===========================================================================

Extra signals (``u_model``, ``ft_preview``, ...) may be added under identifier-like names.
``t``, ``ft``, ``fd``, ``n`` and parameter traces must be finite; the measured signals
``y``, ``e``, ``u`` and extra signals may hold NaN to mark dropped samples, never ``inf``.

Files
-----
:meth:`Recording.save` writes ``.npz``, ``.csv`` or MATLAB ``.mat`` and
:meth:`Recording.load` reads them back bit for bit (signals, parameters, ``dt``,
metadata). Layout, the same information in each format:

* ``.npz`` -- one array per signal under its name, one per parameter under
  ``param__<name>``, a 0-d float ``dt``, and 0-d strings ``metadata`` (JSON) and
  ``recording_format`` (``"manualcontrol.recording/1"``). Read with ``allow_pickle=False``.
* ``.csv`` -- comment lines ``# recording_format: ...``, ``# dt: <repr>`` and
  ``# metadata: <JSON>``, then a header row (signals, then ``param:<name>`` columns) and
  one row per sample, floats written with ``repr`` (shortest exact form), NaN as ``nan``.
* ``.mat`` -- MATLAB 5 file with one column vector per signal, ``param__<name>`` per
  parameter, a double ``dt`` and char variables ``metadata`` and ``recording_format``.
  Experiment files may instead hold a scalar struct (its fields are read as columns,
  ``trial.u`` or plain ``u``) or a matrix of columns (``data:1``, ``data:2``, ...:
  MATLAB's 1-based column numbers, mapped with ``columns=``).

Files from tracking experiments (one trial per file, flat columns under varied names) are
read too: columns are matched to signals through :data:`FILE_ALIASES` (exact names first,
then ignoring case), ``columns={our_name: file_name}`` overrides or extends the matching,
``dt`` is inferred from the time column, and columns named ``param:<name>`` or
``param__<name>`` become parameter traces. Other columns of such files are ignored unless
mapped. A missing error signal is not invented; see :meth:`Recording.with_error_signal`.
Files written by :meth:`Recording.save` carry the ``recording_format`` tag and are read
literally (no aliases; every column comes back under its own name).
"""

from __future__ import annotations

import csv
import json
import math
import numbers
import os
import re
import zipfile
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np
import scipy.io
import scipy.io.matlab
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._files import atomic_write
from manualcontrol.envs._validation import check_choice, check_int, check_positive, check_real

__all__ = [
    "FILE_ALIASES",
    "FILE_FORMATS",
    "FORMAT_TAG",
    "MEASURED_SIGNALS",
    "SIGNAL_NAMES",
    "MissingSignalError",
    "Recording",
    "load_recording",
    "save_recording",
]

FloatArray = NDArray[np.float64]

SIGNAL_NAMES: tuple[str, ...] = ("t", "ft", "fd", "y", "e", "u", "n")
"""The standard signal names, in the order recordings list them."""

MEASURED_SIGNALS: tuple[str, ...] = ("y", "e", "u")
"""Signals measured in an experiment; they (and extra signals) may hold NaN for dropped samples."""

FILE_FORMATS: tuple[str, ...] = ("npz", "csv", "mat")
"""File formats :meth:`Recording.save` writes and :meth:`Recording.load` reads."""

FORMAT_TAG = "manualcontrol.recording/1"
"""Value of the ``recording_format`` entry in files written by :meth:`Recording.save`."""

FILE_ALIASES: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        "t": ("t", "time", "T"),
        "ft": ("ft", "f_t", "target", "fofu_t"),
        "fd": ("fd", "f_d", "disturbance"),
        "y": ("y", "x", "output", "ce_output", "theta"),
        "e": ("e", "error"),
        "u": ("u", "stick", "control", "delta"),
        "n": ("n", "remnant"),
    }
)
"""Column names recognised for each standard signal in files from other sources, in order."""

_NAME_PATTERN = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")
_RESERVED_NAMES = ("dt", "metadata", "recording_format")
_PARAMETER_PREFIXES = ("param:", "param__")
_FINITE_SIGNALS = ("t", "ft", "fd", "n")
_MAT_NAME_LIMIT = 63  # MATLAB namelengthmax
_SLICE_TOLERANCE = 1e-6  # fraction of a sample forgiven when cutting by time


class MissingSignalError(KeyError, AttributeError):
    """A signal the recording does not have.

    It is a ``KeyError`` for ``recording["n"]`` and an ``AttributeError`` for
    ``recording.n``, so ``hasattr(recording, "n")`` is ``False`` for an absent signal.
    """

    def __init__(self, name: str, present: tuple[str, ...]) -> None:
        super().__init__(f"Recording has no signal {name!r}; it has: {', '.join(present)}")
        self.name = name

    def __str__(self) -> str:
        return str(self.args[0])


# ------------------------------------------------------------------------- validation


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"array of shape {value.shape} and dtype {value.dtype}"
    text = repr(value)
    return text if len(text) <= 60 else f"{type(value).__name__} {text[:57]}..."


def _check_name(kind: str, name: Any) -> str:
    """Return ``name`` if it is a valid signal or parameter name."""
    if not isinstance(name, str):
        raise TypeError(f"{kind} names must be strings, got {name!r}")
    if not _NAME_PATTERN.match(name):
        raise ValueError(
            f"{kind} name {name!r} is not allowed: names start with a letter and contain "
            "only ASCII letters, digits and underscores"
        )
    if kind == "signal" and (name in _RESERVED_NAMES or name.startswith("param__")):
        raise ValueError(
            f"signal name {name!r} is reserved for the file formats "
            f"({', '.join(_RESERVED_NAMES)} and the prefix 'param__')"
        )
    return name


def _frozen_vector(
    label: str, value: Any, *, allow_nan: bool, length: int | None = None
) -> FloatArray:
    """Validate ``value`` as a real 1-D array and return a read-only float64 copy."""
    raw = value if isinstance(value, np.ndarray) else np.asarray(value)
    if raw.dtype.kind not in "biuf":
        raise TypeError(f"{label} must be a 1-D array of real numbers, got {_describe(value)}")
    if raw.ndim != 1:
        raise ValueError(f"{label} must be 1-D, got shape {raw.shape}")
    if length is not None and raw.shape[0] != length:
        raise ValueError(f"{label} has length {raw.shape[0]} but t has length {length}")
    array = np.array(raw, dtype=np.float64, copy=True)
    nan = np.isnan(array)
    if not allow_nan and nan.any():
        index = int(np.flatnonzero(nan)[0])
        raise ValueError(
            f"{label} must be finite, found {int(nan.sum())} NaN value(s), the first at index "
            f"{index}; only y, e, u and extra signals may mark dropped samples with NaN"
        )
    infinite = np.isinf(array)
    if infinite.any():
        index = int(np.flatnonzero(infinite)[0])
        raise ValueError(
            f"{label} must not hold infinite values, found {int(infinite.sum())}, the first at "
            f"index {index} ({float(array[index])!r})"
        )
    array.flags.writeable = False
    return array


def _first_time_deviation(t: FloatArray, dt: float) -> int | None:
    """Index of the first sample of ``t`` off the grid ``t[0] + i dt``, or None."""
    expected = t[0] + np.arange(t.shape[0]) * dt
    off = np.abs(t - expected) > 1e-9 * np.maximum(1.0, np.abs(t))
    return int(np.flatnonzero(off)[0]) if off.any() else None


def _check_uniform(t: FloatArray, dt: float) -> None:
    index = _first_time_deviation(t, dt)
    if index is not None:
        expected = t[0] + index * dt
        raise ValueError(
            f"t is not uniformly sampled at dt={dt!r}, first deviation at index {index} "
            f"(t[{index}]={float(t[index])!r}, expected {float(expected)!r})"
        )


def _validate_signals(signals: Any, dt: float) -> Mapping[str, FloatArray]:
    if not isinstance(signals, Mapping):
        raise TypeError(
            f"signals must be a mapping from signal name to 1-D array, got {_describe(signals)}"
        )
    for name in signals:
        _check_name("signal", name)
    if "t" not in signals:
        present = ", ".join(signals) if signals else "no signals"
        raise ValueError(f"signals must contain 't' (time in s); got: {present}")
    t = _frozen_vector("signal 't'", signals["t"], allow_nan=False)
    if t.shape[0] == 0:
        raise ValueError("signal 't' must hold at least one sample, got 0")
    _check_uniform(t, dt)
    order = [name for name in SIGNAL_NAMES if name in signals]
    order += [name for name in signals if name not in SIGNAL_NAMES]
    stored = {"t": t}
    for name in order[1:]:
        stored[name] = _frozen_vector(
            f"signal {name!r}",
            signals[name],
            allow_nan=name not in _FINITE_SIGNALS,
            length=t.shape[0],
        )
    return MappingProxyType(stored)


def _validate_parameters(parameters: Any, length: int) -> Mapping[str, FloatArray]:
    if not isinstance(parameters, Mapping):
        raise TypeError(
            "parameters must be a mapping from parameter name to 1-D array, "
            f"got {_describe(parameters)}"
        )
    stored = {}
    for name, value in parameters.items():
        _check_name("parameter", name)
        stored[name] = _frozen_vector(f"parameter {name!r}", value, allow_nan=False, length=length)
    return MappingProxyType(stored)


def _freeze_json(value: Any, where: str) -> Any:
    """Return a read-only copy of a JSON-able value, or raise naming ``where``.

    Mappings become read-only mappings and sequences tuples; numpy scalars and arrays
    become plain Python numbers and tuples.
    """
    if value is None or isinstance(value, bool):
        return value
    if isinstance(value, str):
        return str(value)
    if isinstance(value, np.generic):
        return _freeze_json(value.item(), where)
    if isinstance(value, numbers.Integral):
        return int(value)
    if isinstance(value, numbers.Real):
        number = float(value)
        if not math.isfinite(number):
            raise ValueError(f"{where} must be finite to be stored as JSON, got {number!r}")
        return number
    if isinstance(value, np.ndarray):
        return _freeze_json(value.tolist(), where)
    if isinstance(value, Mapping):
        frozen = {}
        for key, item in value.items():
            if not isinstance(key, str):
                raise TypeError(f"{where} has key {key!r}; JSON object keys must be strings")
            frozen[key] = _freeze_json(item, f"{where}[{key!r}]")
        return MappingProxyType(frozen)
    if isinstance(value, (list, tuple)):
        return tuple(_freeze_json(item, f"{where}[{i}]") for i, item in enumerate(value))
    raise TypeError(f"{where} is not JSON-serialisable: got {_describe(value)}")


def _thaw_json(value: Any) -> Any:
    """Inverse of :func:`_freeze_json`: plain dicts and lists for ``json.dumps``."""
    if isinstance(value, Mapping):
        return {key: _thaw_json(item) for key, item in value.items()}
    if isinstance(value, tuple):
        return [_thaw_json(item) for item in value]
    return value


def _validate_metadata(metadata: Any) -> Mapping[str, Any]:
    if not isinstance(metadata, Mapping):
        raise TypeError(f"metadata must be a mapping with string keys, got {_describe(metadata)}")
    frozen = {}
    for key, item in metadata.items():
        if not isinstance(key, str):
            raise TypeError(f"metadata keys must be strings, got {key!r}")
        frozen[key] = _freeze_json(item, f"metadata[{key!r}]")
    return MappingProxyType(frozen)


def _signal_property(name: str, doc: str) -> property:
    def getter(self: Recording) -> FloatArray:
        return self[name]

    getter.__name__ = name
    return property(getter, doc=doc)


# -------------------------------------------------------------------------- Recording


@dataclass(frozen=True, eq=False, repr=False)
class Recording:
    """Sampled signals of one tracking run, with true parameter traces and metadata.

    Parameters
    ----------
    signals : Mapping[str, array_like]
        Signal name -> samples, each 1-D of the same length. Must contain ``t`` (s),
        strictly uniform with spacing ``dt`` (tolerance ``1e-9 * max(1, |t|)``). Other
        names: the standard ones in :data:`SIGNAL_NAMES` and extra identifier-like names
        (letters, digits, underscores, starting with a letter; not ``dt``, ``metadata``,
        ``recording_format`` or ``param__...``). ``t``, ``ft``, ``fd`` and ``n`` must be
        finite; ``y``, ``e``, ``u`` and extra signals may hold NaN for dropped samples.
    dt : float
        Sample time (s), finite and > 0.
    parameters : Mapping[str, array_like], optional
        True parameter traces (``K_p``, ``tau_v``, ...) sampled at ``t``; finite.
    metadata : Mapping[str, JSON-able], optional
        Free description (seed, pilot, scenario). Values must be JSON-serialisable
        (numpy scalars and arrays are converted; NaN and infinities are refused); nested
        mappings are stored read-only and lists as tuples.

    Attributes
    ----------
    signals, parameters : Mapping[str, ndarray]
        Read-only mappings of read-only float64 arrays, standard signals first in
        :data:`SIGNAL_NAMES` order, then extra signals in the order given.
    dt : float
        Sample time (s).
    metadata : Mapping[str, Any]
        Read-only metadata.

    Notes
    -----
    ``==`` compares exactly (see :meth:`equals`); recordings are not hashable.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(5) * 0.01
    >>> rec = Recording({"t": t, "u": [0.0, 0.1, np.nan, 0.3, 0.2]}, dt=0.01)
    >>> rec.dropped_stretches("u")
    [(2, 1)]
    >>> hasattr(rec, "n")
    False

    """

    signals: Mapping[str, FloatArray]
    dt: float
    parameters: Mapping[str, FloatArray] = field(default_factory=dict)
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        dt = check_positive("dt", self.dt)
        signals = _validate_signals(self.signals, dt)
        parameters = _validate_parameters(self.parameters, signals["t"].shape[0])
        metadata = _validate_metadata(self.metadata)
        object.__setattr__(self, "dt", dt)
        object.__setattr__(self, "signals", signals)
        object.__setattr__(self, "parameters", parameters)
        object.__setattr__(self, "metadata", metadata)

    # ------------------------------------------------------------------ access

    t = _signal_property("t", "Time (s), shape (n,).")
    ft = _signal_property("ft", "Target forcing function, shape (n,).")
    fd = _signal_property("fd", "Disturbance forcing function (added at the CE output), (n,).")
    y = _signal_property("y", "Controlled-element output, shape (n,); NaN = dropped sample.")
    e = _signal_property("e", "Tracking error ``ft - y``, shape (n,); NaN = dropped sample.")
    u = _signal_property("u", "Pilot control output (stick), shape (n,); NaN = dropped sample.")
    n = _signal_property("n", "Remnant as injected, shape (n,).")

    def __getitem__(self, name: str) -> FloatArray:
        try:
            return self.signals[name]
        except KeyError:
            raise MissingSignalError(name, self.signal_names) from None

    def __contains__(self, name: object) -> bool:
        return name in self.signals

    def __len__(self) -> int:
        return int(self.signals["t"].shape[0])

    __iter__ = None  # a recording is not a sequence; iterate over signal_names

    @property
    def signal_names(self) -> tuple[str, ...]:
        """Names of the signals present, standard ones first."""
        return tuple(self.signals)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Names of the parameter traces present."""
        return tuple(self.parameters)

    @property
    def duration(self) -> float:
        """Time covered by the samples, ``len(self) * dt`` (s).

        One sample interval longer than ``t[-1] - t[0]``: 8192 samples at 0.01 s give
        the 81.92 s measurement time of a multisine period.
        """
        return len(self) * self.dt

    def dropped_samples(self, name: str = "u") -> NDArray[np.bool_]:
        """Boolean mask, shape (n,), True where signal ``name`` is NaN (dropped)."""
        return np.isnan(self[name])

    def dropped_stretches(self, name: str = "u") -> list[tuple[int, int]]:
        """Return the runs of dropped samples of ``name`` as ``(start_index, length)`` pairs."""
        mask = np.isnan(self[name]).astype(np.int8)
        edges = np.diff(np.concatenate(([0], mask, [0])))
        starts = np.flatnonzero(edges == 1)
        stops = np.flatnonzero(edges == -1)
        return [(int(a), int(b - a)) for a, b in zip(starts, stops, strict=True)]

    # ---------------------------------------------------------- derived copies

    def slice_samples(self, i0: int, i1: int | None = None) -> Recording:
        """Return samples ``i0 <= i < i1`` (``i1=None``: to the end) as a new recording.

        Raises
        ------
        ValueError
            Unless ``0 <= i0 < i1 <= len(self)``.

        """
        count = len(self)
        i0 = check_int("i0", i0)
        i1 = count if i1 is None else check_int("i1", i1)
        if not 0 <= i0 < i1 <= count:
            raise ValueError(f"slice_samples needs 0 <= i0 < i1 <= {count}, got i0={i0}, i1={i1}")
        return Recording(
            {name: array[i0:i1] for name, array in self.signals.items()},
            self.dt,
            {name: array[i0:i1] for name, array in self.parameters.items()},
            self.metadata,
        )

    def slice_time(self, start: float, stop: float | None = None) -> Recording:
        """Return the samples with ``start <= t < stop`` as a new recording.

        Use it to cut the run-in of a simulation: ``rec.slice_time(10.0)``. Times keep
        their values (they are not shifted to start at zero) and ``dt`` is kept. Sample
        times within a millionth of a sample of ``start`` or ``stop`` count as equal.

        Parameters
        ----------
        start : float
            First time kept (s), inclusive.
        stop : float, optional
            End time (s), exclusive; None keeps everything from ``start``.

        Raises
        ------
        ValueError
            If ``stop <= start`` or no sample lies in the interval.

        """
        start = check_real("start", start)
        if stop is not None:
            stop = check_real("stop", stop)
            if stop <= start:
                raise ValueError(f"stop must be > start, got start={start!r}, stop={stop!r}")
        t = self.t
        count = len(self)

        def first_index_at_or_after(time: float) -> int:
            index = math.ceil((time - t[0]) / self.dt - _SLICE_TOLERANCE)
            return min(count, max(0, index))

        i0 = first_index_at_or_after(start)
        i1 = count if stop is None else first_index_at_or_after(stop)
        if i0 >= i1:
            raise ValueError(
                f"slice_time(start={start!r}, stop={stop!r}) selects no samples; the "
                f"recording has t from {float(t[0])!r} to {float(t[-1])!r}"
            )
        return self.slice_samples(i0, i1)

    def with_signals(self, **arrays: ArrayLike | None) -> Recording:
        """Return a copy with signals added or replaced; ``name=None`` removes one.

        Examples
        --------
        ``rec.with_signals(u_model=u_hat, n=None)`` adds ``u_model`` and drops the
        remnant (which an estimator must not see).

        """
        signals: dict[str, Any] = dict(self.signals)
        for name, value in arrays.items():
            if value is not None:
                signals[name] = value
            elif name == "t":
                raise ValueError("signal 't' cannot be removed")
            elif name not in signals:
                raise MissingSignalError(name, self.signal_names)
            else:
                del signals[name]
        return Recording(signals, self.dt, self.parameters, self.metadata)

    def with_parameters(self, **arrays: ArrayLike | None) -> Recording:
        """Return a copy with parameter traces added or replaced; ``name=None`` removes one."""
        parameters: dict[str, Any] = dict(self.parameters)
        for name, value in arrays.items():
            if value is not None:
                parameters[name] = value
            elif name not in parameters:
                present = ", ".join(self.parameters) or "none"
                raise KeyError(f"Recording has no parameter {name!r}; it has: {present}")
            else:
                del parameters[name]
        return Recording(self.signals, self.dt, parameters, self.metadata)

    def with_metadata(self, **items: Any) -> Recording:
        """Return a copy with metadata items added or replaced (JSON-able values)."""
        return Recording(self.signals, self.dt, self.parameters, {**self.metadata, **items})

    def with_error_signal(self, *, overwrite: bool = False) -> Recording:
        """Return a copy with the tracking error ``e = ft - y`` computed from ``ft`` and ``y``.

        The disturbance ``fd`` is added at the CE output, so ``y`` already contains it and
        ``ft - y`` is the error a compensatory display shows. A sample dropped in ``y``
        stays dropped (NaN) in ``e``. For a disturbance-only task add ``ft`` as zeros first.

        Parameters
        ----------
        overwrite : bool, optional
            Replace an ``e`` that is already present; by default that is an error.

        Raises
        ------
        ValueError
            If ``ft`` or ``y`` is missing, or ``e`` is present and ``overwrite`` is False.

        """
        missing = [name for name in ("ft", "y") if name not in self]
        if missing:
            raise ValueError(
                f"with_error_signal needs signals 'ft' and 'y' to compute e = ft - y; the "
                f"recording lacks {', '.join(map(repr, missing))} (it has: "
                f"{', '.join(self.signal_names)})"
            )
        if "e" in self and not overwrite:
            raise ValueError(
                "Recording already has signal 'e'; pass overwrite=True to recompute it as ft - y"
            )
        return self.with_signals(e=self.ft - self.y)

    # -------------------------------------------------------------- comparison

    def _same_layout(self, other: Recording) -> bool:
        return (
            set(self.signals) == set(other.signals)
            and set(self.parameters) == set(other.parameters)
            and len(self) == len(other)
            and _thaw_json(self.metadata) == _thaw_json(other.metadata)
        )

    def equals(self, other: object) -> bool:
        """Exact equality of ``dt``, signals, parameters and metadata (NaN equals NaN)."""
        if not isinstance(other, Recording) or not self._same_layout(other):
            return False
        return (
            self.dt == other.dt
            and all(
                np.array_equal(array, other.signals[name], equal_nan=True)
                for name, array in self.signals.items()
            )
            and all(
                np.array_equal(array, other.parameters[name])
                for name, array in self.parameters.items()
            )
        )

    def allclose(self, other: object, *, rtol: float = 1e-5, atol: float = 1e-8) -> bool:
        """Equality within ``|a - b| <= atol + rtol |b|`` for ``dt``, signals and parameters.

        Names, lengths, NaN positions and metadata must match exactly.
        """
        rtol = check_positive("rtol", rtol, allow_zero=True)
        atol = check_positive("atol", atol, allow_zero=True)
        if not isinstance(other, Recording) or not self._same_layout(other):
            return False
        pairs = [(array, other.signals[name]) for name, array in self.signals.items()]
        pairs += [(array, other.parameters[name]) for name, array in self.parameters.items()]
        return abs(self.dt - other.dt) <= atol + rtol * abs(other.dt) and all(
            np.allclose(a, b, rtol=rtol, atol=atol, equal_nan=True) for a, b in pairs
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Recording):
            return NotImplemented
        return self.equals(other)

    __hash__ = None  # type: ignore[assignment]

    # ---------------------------------------------------------- presentation

    def metadata_json(self) -> str:
        """Return the metadata as a JSON object string (the form stored in files)."""
        return json.dumps(_thaw_json(self.metadata), allow_nan=False)

    def __repr__(self) -> str:
        t = self.t
        return (
            f"Recording({len(self)} samples, dt={self.dt!r}, t={float(t[0])!r}..{float(t[-1])!r}, "
            f"signals=({', '.join(self.signal_names)}), "
            f"parameters=({', '.join(self.parameter_names)}), "
            f"metadata=({', '.join(self.metadata)}))"
        )

    def __reduce__(self) -> tuple[Any, ...]:
        # Read-only mapping views cannot be pickled; rebuild from plain containers.
        return (
            Recording,
            (dict(self.signals), self.dt, dict(self.parameters), _thaw_json(self.metadata)),
        )

    # ------------------------------------------------------------------- files

    def save(self, path: str | os.PathLike[str], format: str | None = None) -> Path:
        """Write the recording to ``path`` atomically and return the path.

        Parameters
        ----------
        path : str or PathLike
            Destination; its suffix (``.npz``, ``.csv`` or ``.mat``) picks the format
            unless ``format`` is given. An existing file is replaced only once the new
            one is complete; on failure it is left untouched and no temporary file remains.
        format : {"npz", "csv", "mat"}, optional
            File format, overriding the suffix.

        Returns
        -------
        Path
            The file written.

        Raises
        ------
        ValueError
            For an unknown suffix or format, or (``.mat``) names beyond MATLAB's 63
            characters.

        """
        target = Path(path)
        kind = _file_format(target, format)
        writers: dict[str, Callable[[Recording, Path], None]] = {
            "npz": _write_npz,
            "csv": _write_csv,
            "mat": _write_mat,
        }
        if kind == "mat":
            _check_mat_names(self)
        writer = writers[kind]
        return atomic_write(target, lambda temporary: writer(self, temporary))

    @classmethod
    def load(
        cls,
        path: str | os.PathLike[str],
        columns: Mapping[str, str] | None = None,
        dt: float | None = None,
        time_column: str | None = None,
        format: str | None = None,
    ) -> Recording:
        """Read a recording from a ``.npz``, ``.csv`` or ``.mat`` file and validate it.

        Parameters
        ----------
        path : str or PathLike
            File to read; the suffix picks the format unless ``format`` is given.
        columns : Mapping[str, str], optional
            ``{our_name: file_column}`` overriding or extending the matching of
            :data:`FILE_ALIASES`; ``our_name`` may be a standard signal, an extra signal
            name, or ``"param:<name>"`` for a parameter trace.
        dt : float, optional
            Sample time (s). Required when the file has neither a time column nor a
            ``dt`` entry; otherwise taken from the file (a ``dt`` entry, else inferred
            from the time column). The time axis is then ``arange(n) * dt`` if the file
            has no time column.
        time_column : str, optional
            Name of the time column, shorthand for ``columns={"t": ...}``.
        format : {"npz", "csv", "mat"}, optional
            File format, overriding the suffix.

        Returns
        -------
        Recording

        Raises
        ------
        FileNotFoundError
            If ``path`` does not exist.
        ValueError
            Naming the file and the problem: unknown suffix, unreadable file, missing
            column, columns of different lengths, no time and no ``dt``, non-uniform
            time, infinite values, or any other check of :class:`Recording`.

        """
        return _load(Path(path), columns, dt, time_column, format)


# ------------------------------------------------------------------------------ files


def save_recording(
    recording: Recording,
    path: str | os.PathLike[str],
    format: str | None = None,
) -> Path:
    """Write ``recording`` to ``path``; see :meth:`Recording.save`."""
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {_describe(recording)}")
    return recording.save(path, format)


def load_recording(
    path: str | os.PathLike[str],
    columns: Mapping[str, str] | None = None,
    dt: float | None = None,
    time_column: str | None = None,
    format: str | None = None,
) -> Recording:
    """Read a recording from ``path``; see :meth:`Recording.load`."""
    return Recording.load(path, columns=columns, dt=dt, time_column=time_column, format=format)


def _file_format(path: Path, format: str | None) -> str:
    if format is not None:
        return check_choice("format", format, FILE_FORMATS)
    kind = path.suffix.lower().lstrip(".")
    if kind not in FILE_FORMATS:
        raise ValueError(
            f"{path}: cannot tell the file format from the suffix {path.suffix!r}; allowed "
            "suffixes: .npz, .csv, .mat (or pass format='npz', 'csv' or 'mat')"
        )
    return kind


def _check_mat_names(recording: Recording) -> None:
    names = list(recording.signal_names) + [f"param__{p}" for p in recording.parameter_names]
    for name in names:
        if len(name) > _MAT_NAME_LIMIT:
            raise ValueError(
                f"cannot save to .mat: variable name {name!r} has {len(name)} characters, "
                f"MATLAB allows at most {_MAT_NAME_LIMIT}"
            )


def _file_entries(recording: Recording) -> dict[str, FloatArray]:
    entries = dict(recording.signals)
    entries.update({f"param__{name}": array for name, array in recording.parameters.items()})
    return entries


def _write_npz(recording: Recording, path: Path) -> None:
    entries: dict[str, np.ndarray] = {
        "recording_format": np.array(FORMAT_TAG),
        "dt": np.array(recording.dt, dtype=np.float64),
        "metadata": np.array(recording.metadata_json()),
        **_file_entries(recording),
    }
    # numpy.savez would take entry names such as "file" or "allow_pickle" as its own
    # keywords, so the archive is written directly in the same layout.
    with zipfile.ZipFile(path, mode="w", compression=zipfile.ZIP_STORED, allowZip64=True) as zf:
        for name, array in entries.items():
            with zf.open(f"{name}.npy", mode="w", force_zip64=True) as member:
                np.lib.format.write_array(member, array, allow_pickle=False)


def _write_csv(recording: Recording, path: Path) -> None:
    header = list(recording.signal_names) + [f"param:{p}" for p in recording.parameter_names]
    table = np.column_stack(list(_file_entries(recording).values()))
    with open(path, "w", encoding="utf-8", newline="\n") as handle:
        handle.write(f"# recording_format: {FORMAT_TAG}\n")
        handle.write(f"# dt: {recording.dt!r}\n")
        handle.write(f"# metadata: {recording.metadata_json()}\n")
        handle.write(",".join(header) + "\n")
        # repr of a float is its shortest exact form, so the text reads back bit for bit.
        handle.writelines(",".join(map(repr, row)) + "\n" for row in table.tolist())


def _write_mat(recording: Recording, path: Path) -> None:
    variables: dict[str, Any] = {
        "recording_format": FORMAT_TAG,
        "dt": np.float64(recording.dt),
        "metadata": recording.metadata_json(),
        **_file_entries(recording),
    }
    with open(path, "wb") as handle:
        scipy.io.savemat(handle, variables, format="5", oned_as="column", do_compression=False)


# ----------------------------------------------------------------------------- loading


@dataclass
class _FileTable:
    """What a reader found: data column names in file order, a fetcher, header items."""

    names: list[str]
    fetch: Callable[[str], np.ndarray]
    header: dict[str, Any]


def _load(
    path: Path,
    columns: Mapping[str, str] | None,
    dt: float | None,
    time_column: str | None,
    format: str | None,
) -> Recording:
    explicit = _check_columns(columns, time_column)
    if dt is not None:
        dt = check_positive("dt", dt)
    kind = _file_format(path, format)
    if not path.is_file():
        raise FileNotFoundError(f"no such recording file: {path}")
    if kind == "npz":
        try:
            archive = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            raise ValueError(f"{path} is not a readable .npz file: {error}") from error
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise ValueError(f"{path} holds a single array, not named entries (.npz archive)")
        with archive:
            return _assemble(path, _npz_table(path, archive), explicit, dt)
    if kind == "csv":
        return _assemble(path, _read_csv(path), explicit, dt)
    return _assemble(path, _read_mat(path), explicit, dt)


def _check_columns(columns: Mapping[str, str] | None, time_column: str | None) -> dict[str, str]:
    if columns is None:
        columns = {}
    if not isinstance(columns, Mapping):
        raise TypeError(
            f"columns must be a mapping {{our_name: file_column}}, got {_describe(columns)}"
        )
    explicit: dict[str, str] = {}
    for ours, theirs in columns.items():
        if isinstance(ours, str) and ours.startswith("param:"):
            _check_name("parameter", ours[len("param:") :])
        else:
            _check_name("signal", ours)
        if not isinstance(theirs, str):
            raise TypeError(f"columns[{ours!r}] must be a column name (str), got {theirs!r}")
        explicit[ours] = theirs
    if time_column is not None:
        if not isinstance(time_column, str):
            raise TypeError(f"time_column must be a column name (str), got {time_column!r}")
        if explicit.get("t", time_column) != time_column:
            raise ValueError(
                f"time_column={time_column!r} conflicts with columns['t']={explicit['t']!r}"
            )
        explicit["t"] = time_column
    return explicit


def _header_string(value: np.ndarray) -> str | None:
    if value.dtype.kind == "U" and value.size == 1:
        return str(value.reshape(-1)[0])
    return None


def _split_header(names: list[str], fetch: Callable[[str], np.ndarray]) -> dict[str, Any]:
    """Move ``dt``, ``metadata`` and ``recording_format`` entries from ``names`` to a header."""
    header: dict[str, Any] = {}
    for key in _RESERVED_NAMES:
        if key not in names:
            continue
        value = fetch(key)
        if key == "dt":
            if value.dtype.kind in "iuf" and value.size == 1:
                header[key] = float(value.reshape(-1)[0])
        else:
            text = _header_string(value)
            if text is not None:
                header[key] = text
        if key in header:
            names.remove(key)
    return header


def _npz_table(path: Path, archive: Any) -> _FileTable:
    def fetch(name: str) -> np.ndarray:
        try:
            return np.asarray(archive[name])
        except (OSError, ValueError, zipfile.BadZipFile) as error:
            raise ValueError(f"{path}: entry {name!r} cannot be read: {error}") from error

    names = list(archive.files)
    header = _split_header(names, fetch)
    return _FileTable(names, fetch, header)


def _read_mat(path: Path) -> _FileTable:
    try:
        variables = scipy.io.loadmat(path, squeeze_me=False, chars_as_strings=True)
    except NotImplementedError as error:
        raise ValueError(
            f"{path} is a MATLAB v7.3 (HDF5) file, which scipy.io.loadmat cannot read; "
            "save it in MATLAB with save(..., '-v7')"
        ) from error
    except (OSError, ValueError, TypeError, scipy.io.matlab.MatReadError) as error:
        raise ValueError(f"{path} is not a readable .mat file: {error}") from error
    contents: dict[str, np.ndarray] = {}
    for name, value in variables.items():
        if name.startswith("__") or not isinstance(value, np.ndarray):
            continue
        contents.update(_mat_columns(name, value))
    names = list(contents)
    header = _split_header(names, contents.__getitem__)
    return _FileTable(names, contents.__getitem__, header)


def _mat_columns(name: str, value: np.ndarray) -> dict[str, np.ndarray]:
    """The columns a MATLAB variable offers.

    A vector is one column under its name. A matrix of several columns (a lab's
    ``data = [t u e]``) offers each column as ``name:1``, ``name:2``, ... (MATLAB's
    1-based numbering; map them with ``columns=``/``--column u=data:2``). A scalar struct
    (``trial.u``, ``trial.t``) offers each field under the field's own name and as
    ``struct.field`` (where two have the same plain name, the first found keeps it),
    recursively for vectors and matrices inside.
    """
    if value.dtype.names is not None:
        if value.size != 1:
            return {}  # struct arrays hold several trials: not one recording
        record = value.reshape(-1)[0]
        out: dict[str, np.ndarray] = {}
        for field in value.dtype.names:
            item = record[field]
            item = np.asarray(item)
            if item.dtype == object and item.size == 1:
                item = np.asarray(item.reshape(-1)[0])
            for key, column in _mat_columns(field, item).items():
                out[f"{name}.{key}"] = column
                out.setdefault(key, column)
        return out
    if value.dtype.kind in "iuf" and value.ndim == 2 and min(value.shape) > 1:
        rows = value if value.shape[0] >= value.shape[1] else value.T
        # the whole matrix stays under its name, so a name that is also a signal's says so
        columns = {name: value}
        columns.update({f"{name}:{j + 1}": rows[:, j] for j in range(rows.shape[1])})
        return columns
    return {name: value}


def _parse_float(path: Path, number: int, column: str, token: str) -> float:
    token = token.strip()
    if not token:
        return math.nan
    try:
        return float(token)
    except ValueError:
        raise ValueError(
            f"{path} line {number}, column {column!r}: cannot read {token!r} as a number"
        ) from None


def _read_csv(path: Path) -> _FileTable:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as error:
        raise ValueError(f"{path} is not a UTF-8 text file: {error}") from error
    header: dict[str, Any] = {}
    names: list[str] | None = None
    delimiter = ","
    numbers_: list[int] = []
    data: list[str] = []
    for number, line in enumerate(lines, start=1):
        stripped = line.strip()
        if not stripped:
            continue
        if stripped.startswith("#"):
            key, colon, value = stripped[1:].partition(":")
            if colon and key.strip() in _RESERVED_NAMES:
                header[key.strip()] = value.strip()
            continue
        if names is None:
            delimiter = next((d for d in (",", ";", "\t") if d in stripped), ",")
            names = [name.strip() for name in next(csv.reader([stripped], delimiter=delimiter))]
            _check_csv_header(path, number, names)
        else:
            numbers_.append(number)
            data.append(line)
    if names is None:
        raise ValueError(f"{path} has no header row naming its columns")
    if "dt" in header:
        try:
            header["dt"] = float(header["dt"])
        except ValueError:
            raise ValueError(
                f"{path}: cannot read the '# dt:' header {header['dt']!r} as a number"
            ) from None
    width = len(names)
    rows: list[list[float]] = []
    for number, row in zip(numbers_, csv.reader(data, delimiter=delimiter), strict=True):
        if len(row) != width:
            raise ValueError(
                f"{path} line {number} has {len(row)} fields but the header names {width} columns"
            )
        rows.append(
            [
                _parse_float(path, number, name, token)
                for name, token in zip(names, row, strict=True)
            ]
        )
    table = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    contents = {name: table[:, j] for j, name in enumerate(names)}
    return _FileTable(names, contents.__getitem__, header)


def _check_csv_header(path: Path, number: int, names: list[str]) -> None:
    seen: set[str] = set()
    for name in names:
        if not name:
            raise ValueError(f"{path} line {number}: the header row has an empty column name")
        if name in seen:
            raise ValueError(f"{path} line {number}: the header row names column {name!r} twice")
        seen.add(name)
    try:
        [float(name) for name in names]
    except ValueError:
        return
    raise ValueError(f"{path} has no header row naming its columns (line {number} holds numbers)")


def _parameter_name(column: str) -> str | None:
    for prefix in _PARAMETER_PREFIXES:
        if column.startswith(prefix) and len(column) > len(prefix):
            return column[len(prefix) :]
    return None


def _find_column(
    candidates: tuple[str, ...], names: list[str], used: set[str], ignore_case: bool
) -> str | None:
    free = [name for name in names if name not in used]
    for candidate in candidates:
        if candidate in free:
            return candidate
    if ignore_case:
        folded: dict[str, str] = {}
        for name in free:
            folded.setdefault(name.lower(), name)
        for candidate in candidates:
            if candidate.lower() in folded:
                return folded[candidate.lower()]
    return None


def _column_vector(path: Path, table: _FileTable, column: str, what: str) -> np.ndarray:
    raw = table.fetch(column)
    if raw.dtype.kind not in "biuf":
        raise ValueError(f"{path}: column {column!r} for {what} is not numeric ({_describe(raw)})")
    if raw.ndim > 1 and sum(size != 1 for size in raw.shape) <= 1:
        raw = raw.reshape(-1)  # MATLAB column (n, 1) or row (1, n) vectors
    if raw.ndim != 1:
        hint = ""
        if raw.ndim == 2:
            hint = f" (pick one of its columns: '{column}:1' .. '{column}:{min(raw.shape)}')"
        raise ValueError(
            f"{path}: column {column!r} for {what} must be a vector, got shape {raw.shape}{hint}"
        )
    return raw


def _infer_dt(path: Path, t: np.ndarray, column: str) -> float:
    if t.shape[0] < 2:
        raise ValueError(
            f"{path}: cannot infer dt from the time column {column!r} with {t.shape[0]} "
            "sample(s); pass dt="
        )
    finite = np.isfinite(t)
    if not finite.all():
        index = int(np.flatnonzero(~finite)[0])
        raise ValueError(
            f"{path}: the time column {column!r} must be finite, found {float(t[index])!r} "
            f"at index {index}"
        )
    t = t.astype(np.float64)
    step = float((t[-1] - t[0]) / (t.shape[0] - 1))
    if not step > 0.0:
        raise ValueError(
            f"{path}: cannot infer dt from the time column {column!r}: it does not increase "
            f"(first {float(t[0])!r}, last {float(t[-1])!r})"
        )
    # Times written as decimals (0.01, 0.02, ...) give a step a few ulps off 0.01;
    # prefer the 12-digit rounding when the time column is uniform at it.
    rounded = float(f"{step:.12g}")
    return rounded if _first_time_deviation(t, rounded) is None else step


def _assemble(
    path: Path, table: _FileTable, explicit: dict[str, str], dt: float | None
) -> Recording:
    tag = table.header.get("recording_format")
    if tag is not None and tag != FORMAT_TAG:
        raise ValueError(
            f"{path} is tagged recording_format={tag!r}; this version reads {FORMAT_TAG!r}"
        )
    literal = tag is not None  # written by Recording.save: names are ours, no aliases
    metadata: Any = {}
    if "metadata" in table.header:
        try:
            metadata = json.loads(table.header["metadata"])
        except ValueError as error:
            raise ValueError(f"{path}: metadata is not valid JSON: {error}") from error
        if not isinstance(metadata, dict):
            raise ValueError(f"{path}: metadata must be a JSON object, got {_describe(metadata)}")
    signal_columns: dict[str, str] = {}
    parameter_columns: dict[str, str] = {}
    used: set[str] = set()
    present = ", ".join(table.names) or "none"
    for ours, theirs in explicit.items():
        parameter = ours[len("param:") :] if ours.startswith("param:") else None
        what = f"parameter {parameter!r}" if parameter else f"signal {ours!r}"
        if theirs not in table.names:
            raise ValueError(
                f"{path} has no column {theirs!r} for {what}; columns present: {present}"
            )
        if parameter:
            parameter_columns[parameter] = theirs
        else:
            signal_columns[ours] = theirs
        used.add(theirs)
    for name in SIGNAL_NAMES:
        if name not in signal_columns:
            candidates = (name,) if literal else FILE_ALIASES[name]
            found = _find_column(candidates, table.names, used, ignore_case=not literal)
            if found is not None:
                signal_columns[name] = found
                used.add(found)
    for column in table.names:
        if column in used:
            continue
        parameter = _parameter_name(column)
        if parameter is not None and parameter not in parameter_columns:
            parameter_columns[parameter] = column
        elif literal and parameter is None and column not in signal_columns:
            signal_columns[column] = column

    signals = {
        name: _column_vector(path, table, column, f"signal {name!r}")
        for name, column in signal_columns.items()
    }
    parameters = {
        name: _column_vector(path, table, column, f"parameter {name!r}")
        for name, column in parameter_columns.items()
    }
    everything = [(signal_columns[k], v) for k, v in signals.items()]
    everything += [(parameter_columns[k], v) for k, v in parameters.items()]
    if not everything:
        raise ValueError(f"{path} has no column that could be read as a signal; columns: {present}")
    reference, first = (signal_columns["t"], signals["t"]) if "t" in signals else everything[0]
    role = "the time column" if "t" in signals else "column"
    for column, values in everything:
        if values.shape[0] != first.shape[0]:
            raise ValueError(
                f"{path}: column {column!r} has length {values.shape[0]} but {role} "
                f"{reference!r} has length {first.shape[0]}"
            )

    if dt is None:
        dt = table.header.get("dt")
    if "t" not in signals:
        if dt is None:
            raise ValueError(
                f"{path} has no time column (looked for {', '.join(FILE_ALIASES['t'])}) and no "
                "dt; pass dt= to build the time axis, or name the time column with time_column="
            )
        signals = {"t": np.arange(first.shape[0]) * dt, **signals}
    elif dt is None:
        dt = _infer_dt(path, signals["t"], signal_columns["t"])

    try:
        return Recording(signals, dt, parameters, metadata)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: {error}") from error
