"""Sampled tracking-run signals: the one currency between simulation, envs and estimators.

A :class:`Recording` holds the signals of one tracking run sampled at a fixed sample time
``dt``, the true pilot-parameter traces when they are known (simulation), and JSON
metadata. It is immutable: arrays are read-only float64 copies and mappings are read-only
views, so a recording can be shared between an env, an estimator and a benchmark without
anyone changing it under the others' feet. Derived copies (:meth:`Recording.slice_time`,
:meth:`Recording.with_signals`, ...) return new recordings.

Signal names (one spelling across the package):

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
``param__<name>`` become parameter traces. Other columns of such files are not read (an
unknown column is not a signal: its meaning and units are unknown); their names are listed
in the metadata under ``"ignored_columns"`` so that a column left out by a misspelt name
shows. A missing error signal is not invented; see :meth:`Recording.with_error_signal`.
Files written by :meth:`Recording.save` carry the ``recording_format`` tag and are read
literally (no aliases; every column comes back under its own name).

What laboratories' own files need, and how it is read:

* a CSV header written as a comment (``# t,target,stick``): the last comment line before
  the first row of numbers names the columns when that row would otherwise be the header;
* a trailing separator on every line (``t,u,``): the empty, unnamed last column is dropped;
* text of another separator or suffix: ``;``, tab or aligned spaces between columns, under
  ``.tsv``, ``.txt`` or ``.dat`` as well as ``.csv``; where the separator is not a comma
  and no number has a point, decimal commas (``0,25``, a European spreadsheet's export)
  are read as points;
* time stamps rounded when written (float32, few decimals): stamps within 1 % of ``dt`` of
  the uniform grid ``t[0] + i dt`` are read as that grid; stamps off by more (a logging
  clock's jitter) are refused with the jitter measured, or, with ``resample=True``, every
  signal is interpolated onto a uniform grid and the metadata say so (``"resampled"``);
* a time column in milliseconds: ``time_unit="ms"``; a time column whose step would be
  1-100 s (10-1000 Hz if read as milliseconds) is refused with that hint unless the unit
  is given.
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
from numpy.typing import ArrayLike, NDArray

from manualcontrol.envs._files import atomic_write
from manualcontrol.envs._validation import check_choice, check_int, check_positive, check_real

__all__ = [
    "FILE_ALIASES",
    "FILE_FORMATS",
    "FORMAT_TAG",
    "MEASURED_SIGNALS",
    "SIGNAL_NAMES",
    "TIME_UNITS",
    "MissingColumnError",
    "MissingSignalError",
    "NonUniformTimeError",
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

TEXT_SUFFIXES: tuple[str, ...] = ("tsv", "txt", "dat")
"""Suffixes :meth:`Recording.load` also reads as delimited text, the ``"csv"`` format:
labs' loggers write tab- or space-separated columns under these names."""

FORMAT_TAG = "manualcontrol.recording/1"
"""Value of the ``recording_format`` entry in files written by :meth:`Recording.save`."""

FILE_ALIASES: Mapping[str, tuple[str, ...]] = MappingProxyType(
    {
        # a logger's time column often names its unit: seconds alone, as these say (one
        # in milliseconds is named with columns= and read with time_unit="ms"); not
        # "t_s", which ignoring case is T_s, the sample period
        "t": ("t", "time", "T", "time_s", "time [s]", "time (s)"),
        "ft": ("ft", "f_t", "target", "fofu_t"),
        "fd": ("fd", "f_d", "disturbance"),
        "y": ("y", "x", "output", "ce_output", "theta"),
        "e": ("e", "error"),
        "u": ("u", "stick", "control", "delta"),
        "n": ("n", "remnant"),
    }
)
"""Column names recognised for each standard signal in files from other sources, in order."""

TIME_UNITS: tuple[str, ...] = ("s", "ms")
"""Units :meth:`Recording.load` accepts for a file's time column (``time_unit=``)."""

_PER_SECOND = {"s": 1.0, "ms": 1000.0}  # divisors: x / 1000 is exact where x * 1e-3 is not

_SIGNAL_ROLES = {
    "t": "time",
    "ft": "target forcing function",
    "fd": "disturbance forcing function",
    "y": "controlled-element output",
    "e": "tracking error",
    "u": "pilot control output",
    "n": "remnant",
}

# Time stamps of a file within this fraction of dt of the uniform grid t[0] + i dt are
# taken as rounding of the stamps and read as the grid; farther off, the samples were not
# taken at a fixed rate. The bound is relative to dt, not to |t|: a bound relative to |t|
# lets clock time stamps (t ~ 1.7e9 s since 1970) through with any jitter. 1 % of dt is
# far below what the identification notices (a phase error of 0.01 dt w, 1e-3 rad at
# 1.6 Hz and 60 Hz sampling) and covers float32 stamps (half an ulp is 2**(k - 24) s below
# 2**k s: trials up to 34 min at 60 Hz, 17 min at 100 Hz, 2 min at 1 kHz); a logging
# clock's jitter of 0.4 ms at 60 Hz (2.4 % of dt) is refused.
_GRID_TOLERANCE = 0.01
# Sample times at most 1-100 s apart are 10-1000 Hz if the time column is in milliseconds.
_MILLISECOND_STEPS = (1.0, 100.0)

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


class MissingColumnError(MissingSignalError, ValueError):
    """A file with no column for a signal that :meth:`Recording.load` was asked to require.

    A :class:`MissingSignalError` (so a ``KeyError``) and a ``ValueError``, so callers that
    catch either for a missing signal or a bad file still do. The message lists the file's
    columns and says how to map one; :meth:`explain` words the mapping for another
    interface (the command line's ``--column u=COLUMN``).

    Attributes
    ----------
    path : Path
        The file.
    name : str
        The signal missing.
    looked_for : tuple of str
        The column names tried (:data:`FILE_ALIASES`).
    columns : tuple of str
        The file's columns, in file order.
    unmatched : tuple of str
        The columns no signal or parameter reads.

    """

    def __init__(
        self,
        path: Path,
        name: str,
        looked_for: tuple[str, ...],
        columns: tuple[str, ...],
        unmatched: tuple[str, ...],
    ) -> None:
        self.path = path
        self.name = name
        self.looked_for = looked_for
        self.columns = columns
        self.unmatched = unmatched
        Exception.__init__(self, self.explain(f"columns={{{name!r}: 'COLUMN'}}"))

    def explain(self, mapping: str) -> str:
        """The message, with ``mapping`` as the way to map a column to the signal."""
        role = _SIGNAL_ROLES.get(self.name)
        what = f"signal {self.name!r}" + (f" ({role})" if role else "")
        found = ", ".join(self.columns) or "none"
        text = (
            f"{self.path} has no column for {what}: looked for "
            f"{', '.join(self.looked_for)}, in any case; columns in the file: {found}"
        )
        if self.unmatched and len(self.unmatched) < len(self.columns):
            text += f" (read as no signal: {', '.join(self.unmatched)})"
        return f"{text}; map one with {mapping}"


class NonUniformTimeError(ValueError):
    """A file whose time stamps are not on a uniform grid (beyond rounding of the stamps).

    The message states the jitter measured: the largest deviation from the grid
    ``t[0] + i dt`` and where it is. :meth:`explain` words the remedy (resampling on
    request) for another interface (the command line's ``--resample``).

    Attributes
    ----------
    path : Path
        The file.
    dt : float
        The sample time of the grid (s): given, or inferred from the first and last stamps.
    max_deviation : float
        Largest ``|t[i] - (t[0] + i dt)|`` (s).
    max_index : int
        Sample where it occurs.
    spacing : float
        Interval of the grid resampling would use (s): ``dt`` when given, else the median
        interval of the stamps.

    """

    def __init__(
        self,
        path: Path,
        column: str,
        t: np.ndarray,
        dt: float,
        spacing: float,
        spacing_given: bool,
    ) -> None:
        deviation = np.abs(t - (t[0] + np.arange(t.shape[0]) * dt))
        self.path = path
        self.column = column
        self.start = float(t[0])
        self.dt = dt
        self.spacing = spacing
        self.spacing_given = spacing_given
        self.first_index = int(np.flatnonzero(deviation > _GRID_TOLERANCE * dt)[0])
        self.first_time = float(t[self.first_index])
        self.max_index = int(np.argmax(deviation))
        self.max_time = float(t[self.max_index])
        self.max_deviation = float(deviation[self.max_index])
        super().__init__(self.explain("pass resample=True"))

    def explain(self, remedy: str) -> str:
        """The message, with ``remedy`` as the way to ask for resampling."""
        index = self.first_index
        grid = (
            f"dt={self.spacing!r}"
            if self.spacing_given
            else f"the median sample interval ({self.spacing:.6g} s)"
        )
        return (
            f"{self.path}: t is not uniformly sampled at dt={self.dt!r}, first deviation at "
            f"index {index} (t[{index}]={self.first_time!r}, expected "
            f"{self.start + index * self.dt!r}): the time stamps of column {self.column!r} "
            f"deviate from the uniform grid t[0] + i*dt by up to "
            f"{1e3 * self.max_deviation:.3g} ms (sample {self.max_index}, "
            f"t={self.max_time!r}), more than the {1e3 * _GRID_TOLERANCE * self.dt:.3g} ms "
            f"(1 % of dt) that rounding of the stamps explains: the samples were not taken at "
            f"a fixed rate; {remedy} to interpolate every signal linearly onto a uniform grid "
            f"at {grid} from the first time stamp"
        )


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
    """Index of the first sample of ``t`` off the grid ``t[0] + i dt``, or None.

    The tolerance, ``1e-9 * max(1, |t|)``, forgives the rounding of ``t[0] + i dt`` in
    floating point; it is capped at ``_GRID_TOLERANCE * dt`` (1 % of a sample) so that
    large clock times (``t`` ~ 1.7e9 s) do not let a jittery time axis through.
    """
    expected = t[0] + np.arange(t.shape[0]) * dt
    tolerance = np.minimum(1e-9 * np.maximum(1.0, np.abs(t)), _GRID_TOLERANCE * dt)
    off = np.abs(t - expected) > tolerance
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
        strictly uniform with spacing ``dt`` (tolerance ``1e-9 * max(1, |t|)``, at most
        ``0.01 dt``). Other names: the standard ones in :data:`SIGNAL_NAMES` and extra
        identifier-like names
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
        *,
        time_unit: str | None = None,
        resample: bool = False,
        require: tuple[str, ...] | list[str] = (),
    ) -> Recording:
        """Read a recording from a ``.npz``, ``.csv`` or ``.mat`` file and validate it.

        Files from elsewhere (not written by :meth:`save`) are read as the module
        docstring describes: aliases, a ``#``-commented CSV header, a dropped empty
        trailing column, time stamps within 1 % of ``dt`` of the uniform grid read as the
        grid. Their columns that no signal or parameter reads are listed in the metadata
        under ``"ignored_columns"``.

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
        time_unit : {"s", "ms"}, optional
            Unit of the file's time column and of its ``dt`` entry (``dt=`` is always in
            seconds); ``"ms"`` divides them by 1000. Not for files written by :meth:`save`
            (seconds). By default seconds, and a time column whose inferred step lies in
            1-100 (10-1000 Hz in milliseconds) is refused with a hint to give the unit:
            nothing is rescaled on a guess.
        resample : bool, optional
            If the time stamps are off the uniform grid by more than rounding explains
            (1 % of ``dt``), interpolate every signal and parameter trace linearly onto a
            uniform grid from the first stamp to the last, spaced by ``dt`` when given
            (argument or file entry), else by the median interval of the stamps; nothing
            else is changed (the times are not shifted). The metadata record it under
            ``"resampled"`` (``from_jitter_ms``: the largest deviation measured, ``dt``,
            ``samples_in_file``, ``method``). Samples next to a NaN become NaN. Without
            ``resample`` such a file is refused; a uniform file is read as it is.
        require : sequence of str, optional
            Standard signals (:data:`SIGNAL_NAMES`) the file must provide; a missing one
            raises :class:`MissingColumnError` listing the file's columns.

        Returns
        -------
        Recording

        Raises
        ------
        FileNotFoundError
            If ``path`` does not exist.
        MissingColumnError
            If a signal of ``require`` has no column (a ``ValueError`` and a ``KeyError``).
        NonUniformTimeError
            If the time stamps are off the uniform grid and ``resample`` is False (a
            ``ValueError``).
        ValueError
            Naming the file and the problem: unknown suffix, unreadable file, missing
            column, columns of different lengths, no time and no ``dt``, non-uniform
            time, a time step that looks like milliseconds, infinite values, or any other
            check of :class:`Recording`.

        """
        options = _LoadOptions.checked(time_unit, resample, require)
        return _load(Path(path), columns, dt, time_column, format, options)


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
    *,
    time_unit: str | None = None,
    resample: bool = False,
    require: tuple[str, ...] | list[str] = (),
) -> Recording:
    """Read a recording from ``path``; see :meth:`Recording.load`."""
    return Recording.load(
        path,
        columns=columns,
        dt=dt,
        time_column=time_column,
        format=format,
        time_unit=time_unit,
        resample=resample,
        require=require,
    )


def _file_format(path: Path, format: str | None, reading: bool = False) -> str:
    """The format ``format`` names, else the suffix's (``reading``: :data:`TEXT_SUFFIXES` too)."""
    if format is not None:
        return check_choice("format", format, FILE_FORMATS)
    kind = path.suffix.lower().lstrip(".")
    if reading and kind in TEXT_SUFFIXES:
        return "csv"
    if kind not in FILE_FORMATS:
        allowed = ".npz, .csv, .mat" + (", or text as .tsv, .txt, .dat" if reading else "")
        spreadsheet = (
            " (a spreadsheet workbook: save it as CSV)" if kind in ("xlsx", "xls", "ods") else ""
        )
        raise ValueError(
            f"{path}: cannot tell the file format from the suffix {path.suffix!r}{spreadsheet}; "
            f"allowed suffixes: {allowed} (or pass format='npz', 'csv' or 'mat')"
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
    import scipy.io  # only for .mat files: a tenth of a second of every start-up otherwise

    with open(path, "wb") as handle:
        scipy.io.savemat(handle, variables, format="5", oned_as="column", do_compression=False)


# ----------------------------------------------------------------------------- loading


@dataclass
class _FileTable:
    """What a reader found: data column names in file order, a fetcher, header items.

    ``sources`` gives, for names that are not columns of their own, the column they are
    another name of (a struct field's plain name -> ``struct.field``) or None (a whole
    matrix, whose columns are offered as ``name:1``, ...): what "ignored columns" counts.
    """

    names: list[str]
    fetch: Callable[[str], np.ndarray]
    header: dict[str, Any]
    sources: dict[str, str | None] = field(default_factory=dict)
    #: A plain name more than one variable offers (``u`` of ``a.u`` and ``b.u``), and the
    #: columns it would stand for: which one is meant, only the user can say.
    ambiguous: dict[str, list[str]] = field(default_factory=dict)


@dataclass(frozen=True)
class _LoadOptions:
    """The keyword-only choices of :meth:`Recording.load`, checked."""

    time_unit: str | None = None
    resample: bool = False
    require: tuple[str, ...] = ()

    @classmethod
    def checked(cls, time_unit: Any, resample: Any, require: Any) -> _LoadOptions:
        if time_unit is not None:
            check_choice("time_unit", time_unit, TIME_UNITS)
        if not isinstance(resample, (bool, np.bool_)):
            raise TypeError(f"resample must be True or False, got {_describe(resample)}")
        if isinstance(require, str) or not isinstance(require, (tuple, list)):
            raise TypeError(
                f"require must be a list or tuple of signal names, got {_describe(require)}"
            )
        for name in require:
            check_choice("each name in require", name, SIGNAL_NAMES)
        return cls(time_unit, bool(resample), tuple(require))


def _load(
    path: Path,
    columns: Mapping[str, str] | None,
    dt: float | None,
    time_column: str | None,
    format: str | None,
    options: _LoadOptions | None = None,
) -> Recording:
    if options is None:
        options = _LoadOptions()
    explicit = _check_columns(columns, time_column)
    if dt is not None:
        dt = check_positive("dt", dt)
    if path.is_dir():
        raise IsADirectoryError(
            f"{path} is a directory, not a recording file (give a .csv, .mat or .npz file, "
            "or text as .tsv, .txt, .dat)"
        )
    kind = _file_format(path, format, reading=True)
    if not path.is_file():
        raise FileNotFoundError(f"no such recording file: {path}")
    if kind == "npz":
        try:
            archive = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError, zipfile.BadZipFile) as error:
            raise ValueError(
                f"{path} is not a readable .npz file, so not a recording: "
                f"{_npz_problem(path, error)}"
            ) from error
        if not isinstance(archive, np.lib.npyio.NpzFile):
            raise ValueError(f"{path} holds a single array, not named entries (.npz archive)")
        with archive:
            return _assemble(path, _npz_table(path, archive), explicit, dt, options)
    if kind == "csv":
        return _assemble(path, _read_csv(path), explicit, dt, options)
    return _assemble(path, _read_mat(path), explicit, dt, options)


def _npz_problem(path: Path, error: BaseException) -> str:
    """What numpy found wrong with an ``.npz`` file, in the words of someone who gave one.

    numpy reads a file that is neither a zip archive nor a ``.npy`` array as a pickle,
    and refuses that with advice to load pickles unsafely: not what a recording needs.
    """
    try:
        size = path.stat().st_size
    except OSError:
        size = None
    if size == 0:
        return "the file is empty"
    if isinstance(error, zipfile.BadZipFile):
        return f"it is not a valid zip archive ({error}); it may be damaged or truncated"
    if isinstance(error, EOFError) or "pickle" in str(error):
        return (
            "its bytes are not a .npz archive (a zip of arrays, as manualcontrol and numpy "
            "write it); it may be another format renamed .npz, or damaged"
        )
    return str(error)


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
    import scipy.io  # only for .mat files: a tenth of a second of every start-up otherwise
    import scipy.io.matlab

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
    sources: dict[str, str | None] = {}
    offered_by: dict[str, str] = {}
    ambiguous: dict[str, list[str]] = {}
    for name, value in variables.items():
        if name.startswith("__") or not isinstance(value, np.ndarray):
            continue
        columns, aliases = _mat_columns(name, value)
        for key, column in columns.items():
            meant = aliases.get(key) or key
            if key in offered_by and offered_by[key] != name:
                # two variables offer the name (two structs' u): neither is taken for it
                ambiguous.setdefault(key, [sources.get(key) or key]).append(meant)
                contents.pop(key, None)
                sources.pop(key, None)
                continue
            if key in ambiguous:
                ambiguous[key].append(meant)
                continue
            offered_by[key] = name
            contents[key] = column
            if key in aliases:
                sources[key] = aliases[key]
            else:
                sources.pop(key, None)
    names = list(contents)
    header = _split_header(names, contents.__getitem__)
    return _FileTable(names, contents.__getitem__, header, sources, ambiguous)


def _mat_columns(
    name: str, value: np.ndarray
) -> tuple[dict[str, np.ndarray], dict[str, str | None]]:
    """The columns a MATLAB variable offers, and which of them are other names.

    A vector is one column under its name. A matrix of several columns (a lab's
    ``data = [t u e]``) offers each column as ``name:1``, ``name:2``, ... (MATLAB's
    1-based numbering; map them with ``columns=``/``--column u=data:2``). A scalar struct
    (``trial.u``, ``trial.t``) offers each field under the field's own name and as
    ``struct.field`` (where two have the same plain name, the first found keeps it),
    recursively for vectors and matrices inside.

    The second mapping names the column each other name stands for (a plain field name
    -> ``struct.field``), or None for a whole matrix (its columns are the columns).
    """
    if value.dtype.names is not None:
        if value.size != 1:
            return {}, {}  # struct arrays hold several trials: not one recording
        record = value.reshape(-1)[0]
        out: dict[str, np.ndarray] = {}
        aliases: dict[str, str | None] = {}
        for field_name in value.dtype.names:
            item = record[field_name]
            item = np.asarray(item)
            if item.dtype == object and item.size == 1:
                item = np.asarray(item.reshape(-1)[0])
            inner, inner_aliases = _mat_columns(field_name, item)
            for key, column in inner.items():
                qualified = f"{name}.{key}"
                out[qualified] = column
                if key in inner_aliases:
                    source = inner_aliases[key]
                    aliases[qualified] = None if source is None else f"{name}.{source}"
                if key not in out:
                    out[key] = column
                    aliases[key] = aliases.get(qualified, qualified)
        return out, aliases
    if value.dtype.kind in "iuf" and value.ndim == 2 and min(value.shape) > 1:
        rows = value if value.shape[0] >= value.shape[1] else value.T
        # the whole matrix stays under its name, so a name that is also a signal's says so
        columns = {name: value}
        columns.update({f"{name}:{j + 1}": rows[:, j] for j in range(rows.shape[1])})
        return columns, {name: None}
    return {name: value}, {}


def _number(token: str, decimal_comma: bool) -> float:
    """``float(token)``; with ``decimal_comma``, ``0,25`` too (one comma, no point)."""
    try:
        return float(token)
    except ValueError:
        if decimal_comma and token.count(",") == 1 and "." not in token:
            return float(token.replace(",", "."))
        raise


def _parse_float(path: Path, number: int, column: str, token: str, decimal_comma: bool) -> float:
    token = token.strip()
    if not token:
        return math.nan
    try:
        return _number(token, decimal_comma)
    except ValueError:
        raise ValueError(
            f"{path} line {number}, column {column!r}: cannot read {token!r} as a number"
        ) from None


def _read_csv(path: Path) -> _FileTable:
    """Read a CSV file: ``# key: value`` header items, a header row, rows of numbers.

    Comment lines start with ``#``; those naming ``recording_format``, ``dt`` or
    ``metadata`` are header items, the others are skipped, except that the last one before
    the first row of numbers names the columns when no header row precedes that row
    (``# t,target,stick``). The separator is the first of ``,``, ``;``, tab found in the
    header, else runs of spaces (columns aligned by a logger). Where it is not a comma
    and no number has a point, a decimal comma is read as one (``0,25``: a European
    spreadsheet's export; :func:`_decimal_comma`). An empty field is a dropped sample
    (NaN). One empty field more than the header names, at the end of a line (a trailing
    separator), is dropped, and so is an unnamed last header column that holds no value
    in any row.
    """
    try:
        lines = path.read_text(encoding="utf-8-sig").splitlines()  # -sig: drop a BOM
    except UnicodeDecodeError as error:
        raise ValueError(f"{path} is not a UTF-8 text file: {error}") from error
    header: dict[str, Any] = {}
    names: list[str] | None = None
    delimiter = ","
    comment: tuple[int, str] | None = None  # last plain comment line before the header
    header_line, header_text = 0, ""  # where the header row is, and its text
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
            elif names is None:
                comment = (number, stripped.lstrip("#").strip())
            continue
        if names is not None:
            if not data and delimiter == " " and len(stripped.split()) != len(names):
                # not aligned columns but one column whose name has a space ("stick pos")
                single = _csv_fields(header_text, ",")
                if _width(_csv_fields(stripped, ",")) == _width(single):
                    delimiter, names = ",", single
                    _check_csv_header(path, header_line, names, False)
            numbers_.append(number)
            data.append(line)
            continue
        delimiter = _csv_delimiter(stripped)
        names = _csv_fields(stripped, delimiter)
        header_line, header_text = number, stripped
        if comment is not None:
            # "# t,target,stick" above a first row of numbers in the comment's separator
            # (read that way first: "0,5;1" is two numbers under "# t;u", not "0" and "5;1")
            separator = _csv_delimiter(comment[1])
            row = _csv_fields(stripped, separator)
            commented = _csv_fields(comment[1], separator)
            if (
                _all_numbers(row, _decimal_comma(separator, [stripped]))
                and _width(commented) == _width(row)
                and not _all_numbers(commented, False)
            ):
                delimiter, names, header_line = separator, commented, comment[0]
                numbers_.append(number)
                data.append(line)
        _check_csv_header(path, header_line, names, _decimal_comma(delimiter, [stripped]))
    if names is None:
        raise ValueError(f"{path} has no header row naming its columns")
    decimal_comma = _decimal_comma(delimiter, data)
    if "dt" in header:
        try:
            header["dt"] = _number(header["dt"], decimal_comma)
        except ValueError:
            raise ValueError(
                f"{path}: cannot read the '# dt:' header {header['dt']!r} as a number"
            ) from None
    unnamed_last = len(names) > 1 and names[-1] == ""
    if unnamed_last:
        names = names[:-1]
    width = len(names)
    rows: list[list[float]] = []
    split = (
        (line.split() for line in data)
        if delimiter == " "
        else csv.reader(data, delimiter=delimiter)
    )
    for number, row in zip(numbers_, split, strict=True):
        if len(row) == width + 1 and not row[-1].strip():
            row = row[:-1]  # a trailing separator: an empty, unnamed last column
        elif unnamed_last and len(row) == width + 1:
            raise ValueError(
                f"{path} line {number}: the last column has no name in the header but holds "
                f"{row[-1].strip()!r} here; name it in the header row (only an unnamed "
                "column that is empty in every row is dropped)"
            )
        if len(row) != width:
            shown = width + 1 if unnamed_last else width
            raise ValueError(
                f"{path} line {number} has {len(row)} fields but the header names {shown} columns"
            )
        rows.append(
            [
                _parse_float(path, number, name, token, decimal_comma)
                for name, token in zip(names, row, strict=True)
            ]
        )
    table = np.array(rows, dtype=np.float64).reshape(len(rows), width)
    contents = {name: table[:, j] for j, name in enumerate(names)}
    return _FileTable(names, contents.__getitem__, header)


def _csv_delimiter(line: str) -> str:
    """The first of ``,``, ``;``, tab in ``line``; else ``" "`` (runs of spaces) if it has any."""
    found = next((d for d in (",", ";", "\t") if d in line), None)
    if found is None:
        return " " if len(line.split()) > 1 else ","
    return found


def _decimal_comma(delimiter: str, lines: list[str]) -> bool:
    """Whether numbers in ``lines`` are written with a decimal comma (``0,25``).

    Only where the separator is not a comma, and only where no line holds a point: a
    file has one decimal mark, and beside points a comma is something else (a
    thousands separator, ``1,234``), which is refused rather than read as ``1.234``.
    """
    return delimiter != "," and not any("." in line for line in lines)


def _csv_fields(line: str, delimiter: str) -> list[str]:
    if delimiter == " ":
        return line.split()
    return [name.strip() for name in next(csv.reader([line], delimiter=delimiter))]


def _width(fields: list[str]) -> int:
    """Number of fields, an empty last one (a trailing separator) not counted."""
    return len(fields) - 1 if len(fields) > 1 and fields[-1] == "" else len(fields)


def _all_numbers(fields: list[str], decimal_comma: bool) -> bool:
    """Whether the fields are a row of data: numbers, or empty (dropped samples)."""
    filled = [field_ for field_ in fields if field_]
    try:
        [_number(field_, decimal_comma) for field_ in filled]
    except ValueError:
        return False
    return bool(filled)


def _check_csv_header(path: Path, number: int, names: list[str], decimal_comma: bool) -> None:
    if _all_numbers(names, decimal_comma):
        raise ValueError(
            f"{path} has no header row naming its columns (line {number} holds numbers)"
        )
    seen: set[str] = set()
    for position, name in enumerate(names):
        if not name and not (position == len(names) - 1 and position > 0):
            raise ValueError(f"{path} line {number}: the header row has an empty column name")
        if name in seen:
            raise ValueError(f"{path} line {number}: the header row names column {name!r} twice")
        seen.add(name)


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


def _time_values(path: Path, t: np.ndarray, column: str) -> FloatArray:
    """The time column as float64, refused unless finite."""
    finite = np.isfinite(t)
    if not finite.all():
        index = int(np.flatnonzero(~finite)[0])
        raise ValueError(
            f"{path}: the time column {column!r} must be finite, found {float(t[index])!r} "
            f"at index {index}"
        )
    return t.astype(np.float64)


def _infer_dt(path: Path, t: FloatArray, column: str) -> float:
    """Sample time from the first and last stamps of a finite time column.

    The step between the end stamps, not the median interval: rounding of single stamps
    averages out over the run, and a uniform grid through the end stamps is the one its
    stamps deviate least from (the deviation is then measured against it).
    """
    if t.shape[0] < 2:
        raise ValueError(
            f"{path}: cannot infer dt from the time column {column!r} with {t.shape[0]} "
            "sample(s); pass dt="
        )
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


def _check_time_order(path: Path, column: str, t: FloatArray) -> None:
    """Refuse time stamps that go back or repeat: rows out of order, not a clock's jitter."""
    back = np.flatnonzero(np.diff(t) <= 0.0)
    if back.size:
        i = int(back[0])
        raise ValueError(
            f"{path}: the time column {column!r} must increase, but t[{i + 1}]="
            f"{float(t[i + 1])!r} follows t[{i}]={float(t[i])!r} ({back.size} such step(s)): "
            "rows out of order or repeated; sort or mend them"
        )


def _check_time_step(path: Path, column: str, dt: float) -> None:
    """Refuse a time column whose step reads as milliseconds, when no unit was given."""
    low, high = _MILLISECOND_STEPS
    if low <= dt <= high:
        raise ValueError(
            f"{path}: the time column {column!r} steps by {dt:g} per sample; in seconds "
            f"that is {1.0 / dt:.3g} Hz, far slower than manual-control data are sampled, "
            f"and in milliseconds {1e3 / dt:.4g} Hz: it looks like milliseconds: pass "
            "time_unit='ms' (or time_unit='s' if the file really is in seconds)"
        )


def _on_grid(
    path: Path,
    column: str,
    t: FloatArray,
    dt: float,
    dt_given: bool,
    resample: bool,
) -> tuple[FloatArray, float, dict[str, Any] | None]:
    """The time axis a recording gets from a file's time stamps ``t``.

    Returns ``(t, dt, resampled)``: the stamps as they are when uniform to the
    :class:`Recording` tolerance; the grid ``t[0] + i dt`` when they are within
    ``_GRID_TOLERANCE * dt`` of it (rounding of the stamps); otherwise, with ``resample``,
    a uniform grid at ``dt`` (given) or the median interval (inferred) over the stamps'
    span, and what to record of it in the metadata. Otherwise raise
    :class:`NonUniformTimeError`.
    """
    count = t.shape[0]
    if _first_time_deviation(t, dt) is None:
        return t, dt, None
    grid = t[0] + np.arange(count) * dt
    deviation = np.abs(t - grid)
    if float(deviation.max()) <= _GRID_TOLERANCE * dt:
        return grid, dt, None
    steps = np.diff(t)
    spacing = dt if dt_given else float(np.median(steps))
    if not resample:
        raise NonUniformTimeError(path, column, t, dt, spacing, dt_given)
    back = np.flatnonzero(steps <= 0.0)
    if back.size:
        i = int(back[0])
        raise ValueError(
            f"{path}: cannot resample: the time column {column!r} must increase, but "
            f"t[{i + 1}]={float(t[i + 1])!r} follows t[{i}]={float(t[i])!r}"
        )
    points = math.floor((t[-1] - t[0]) / spacing * (1.0 + 1e-12)) + 1
    resampled = {
        "from_jitter_ms": float(1e3 * deviation.max()),
        "dt": spacing,
        "samples_in_file": int(count),
        "method": "linear interpolation",
    }
    return t[0] + np.arange(points) * spacing, spacing, resampled


def _missing_column(
    path: Path,
    name: str,
    literal: bool,
    table: _FileTable,
    ignored: list[str],
) -> MissingColumnError:
    looked_for = (name,) if literal else FILE_ALIASES[name]
    return MissingColumnError(path, name, looked_for, tuple(table.names), tuple(ignored))


def _ignored_columns(table: _FileTable, taken: set[str]) -> list[str]:
    """The file's columns that no signal or parameter reads, each once, in file order."""
    groups: dict[str, bool] = {}
    for name in table.names:
        source = table.sources.get(name, name)
        if source is not None:
            groups[source] = groups.get(source, False) or name in taken
    return [source for source, read in groups.items() if not read]


def _assemble(
    path: Path,
    table: _FileTable,
    explicit: dict[str, str],
    dt: float | None,
    options: _LoadOptions,
) -> Recording:
    tag = table.header.get("recording_format")
    if tag is not None and tag != FORMAT_TAG:
        raise ValueError(
            f"{path} is tagged recording_format={tag!r}; this version reads {FORMAT_TAG!r}"
        )
    literal = tag is not None  # written by Recording.save: names are ours, no aliases
    if literal and options.time_unit not in (None, "s"):
        raise ValueError(
            f"{path} was written by Recording.save, which stores time in seconds; a time "
            f"unit of {options.time_unit!r} is for files from elsewhere"
        )
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
            clash = [c for c in candidates if c in table.ambiguous]
            if clash:
                meant = table.ambiguous[clash[0]]
                raise ValueError(
                    f"{path}: signal {name!r} ({clash[0]!r}) is in more than one variable "
                    f"({', '.join(meant)}): say which, e.g. columns={{'{name}': "
                    f"'{meant[0]}'}}"
                )
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
    ignored = _ignored_columns(
        table, set(signal_columns.values()) | set(parameter_columns.values())
    )
    for name in options.require:
        if name not in signal_columns and not (name == "t" and dt is not None):
            raise _missing_column(path, name, literal, table, ignored)

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

    if first.shape[0] == 0:
        raise ValueError(
            f"{path} has no samples: its columns ({', '.join(c for c, _ in everything)}) hold "
            "no rows of numbers"
        )
    per_second = _PER_SECOND[options.time_unit or "s"]
    dt_source = "dt="
    if dt is None and "dt" in table.header:
        dt = table.header["dt"] / per_second  # the file's entry, in the file's time unit
        dt_source = "the file's dt entry"
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"{path}: the file's dt entry must be a number > 0, got {dt!r}")
    if ignored and not literal:
        metadata["ignored_columns"] = ignored
    if "t" not in signals:
        if dt is None:
            raise ValueError(
                f"{path} has no time column (looked for {', '.join(FILE_ALIASES['t'])}) and no "
                "dt; pass dt= to build the time axis, or name the time column with time_column="
            )
        signals = {"t": np.arange(first.shape[0]) * dt, **signals}
    else:
        column = signal_columns["t"]
        stamps = _time_values(path, signals["t"], column)
        if per_second != 1.0:
            stamps = stamps / per_second
        dt_given = dt is not None
        if dt is None:
            dt = _infer_dt(path, stamps, column)
            if options.time_unit is None and not literal:
                _check_time_step(path, column, dt)
        _check_time_order(path, column, stamps)
        if dt_given and stamps.shape[0] > 1:
            own = float((stamps[-1] - stamps[0]) / (stamps.shape[0] - 1))
            index = np.arange(stamps.shape[0])
            off_given = np.abs(stamps - (stamps[0] + index * dt)).max() > _GRID_TOLERANCE * dt
            on_own = np.abs(stamps - (stamps[0] + index * own)).max() <= _GRID_TOLERANCE * own
            if off_given and on_own:
                given, remedy = (
                    (f"dt={dt!r}", "leave dt= out")
                    if dt_source == "dt="
                    else (f"the file's dt entry {dt!r} s", "mend or remove the entry")
                )
                raise ValueError(
                    f"{path}: {given} contradicts the time column {column!r}, which steps "
                    f"uniformly by {own:.6g} s: {remedy} (the column gives the sample time)"
                )
        t, dt, resampled = _on_grid(path, column, stamps, dt, dt_given, options.resample)
        if resampled is None:
            signals = {**signals, "t": t}
        else:
            signals = {
                name: t if name == "t" else np.interp(t, stamps, values.astype(np.float64))
                for name, values in signals.items()
            }
            parameters = {
                name: np.interp(t, stamps, values.astype(np.float64))
                for name, values in parameters.items()
            }
            metadata["resampled"] = resampled

    try:
        return Recording(signals, dt, parameters, metadata)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: {error}") from error
