"""The estimator protocol: what every online estimator of pilot parameters provides.

An estimator is configured with a frozen settings dataclass, then

* ``reset(dt, ...)`` starts it (an unconfigured or un-reset estimator refuses to run),
* ``update(sample) -> Estimate`` consumes one sample (a mapping of signal values),
* ``estimate(recording, ...) -> EstimationResult`` runs a whole recording.

``update`` and ``estimate`` give identical numbers for the same samples and settings.

:class:`Estimate` is one sample's answer: mean and standard deviation of *every*
parameter of the pilot model (estimated or held constant; a constant has standard
deviation 0), the one-step prediction of each measured output, the innovations and
their covariance, and health flags. :class:`EstimationResult` holds the same as traces
over a run, with fixed named fields, the settings used and a :class:`HealthSummary`;
it saves to and loads from ``.npz`` (written atomically, validated on load).

Measurements may have ``m`` outputs (``outputs`` names the recorded signal each one
predicts: ``("u",)`` for the pilot filters, ``("u", "y")`` for Schiess-Roland's stick
and plant output). The first output is the *primary* one: ``prediction``,
``innovation`` and ``innovation_variance`` are its traces, so code written for
one-output estimators reads every estimator alike. Estimators may also record their
state traces (``state_names``, ``states``), iterate over a run (``passes``, with each
pass's final estimates in ``pass_mean``/``pass_std``), and a filtered result may be
turned into a smoothed one (:func:`manualcontrol.estimators.offline.smoothing.smooth`), marked
``smoothed``.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
from collections.abc import Callable, Iterator, Mapping
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any, Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._files import atomic_write
from manualcontrol.envs._validation import check_choice, reject_unknown
from manualcontrol.envs.recording import Recording

__all__ = [
    "RESULT_FORMAT",
    "Estimate",
    "EstimateHealth",
    "EstimationResult",
    "Estimator",
    "HealthSummary",
    "ParameterValues",
    "load_result",
    "report_progress",
    "reporting_progress",
    "sample_floats",
    "sample_values",
    "summarise_health",
]

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

#: Value of the ``result_format`` entry of saved results (version 2: m outputs, state
#: traces, passes, smoothing). Version 1 files (one output) still load.
RESULT_FORMAT = "manualcontrol.estimation/2"
_OLDER_FORMATS = ("manualcontrol.estimation/1",)

#: Who hears how a long offline computation goes (a line each step); nobody by default.
_PROGRESS: ContextVar[Callable[[str], None] | None] = ContextVar(
    "manualcontrol_progress", default=None
)


def report_progress(line: str) -> None:
    """Say how a long computation goes, to whoever :func:`reporting_progress` named.

    The offline members take minutes on a long run (a cross-validation passes the run
    ten times per scale, a schedule fit runs an optimiser per start); a library stays
    silent by default, and the command line listens, so a person sees it is working.
    """
    listener = _PROGRESS.get()
    if listener is not None:
        listener(line)


@contextlib.contextmanager
def reporting_progress(listener: Callable[[str], None] | None) -> Iterator[None]:
    """Within the block, :func:`report_progress` lines go to ``listener`` (None: nowhere)."""
    token = _PROGRESS.set(listener)
    try:
        yield
    finally:
        _PROGRESS.reset(token)


_FLAGS_1D = ("finite", "covariance_ok", "dropped", "diverged")
_ARRAYS = (
    "t",
    "predictions",
    "innovations",
    "innovation_covariance",
    *_FLAGS_1D,
    "mean",
    "std",
    "pinned",
    "states",
    "pass_mean",
    "pass_std",
)


def _readonly(array: Any, dtype: type) -> NDArray[Any]:
    out = np.array(array, dtype=dtype, copy=True)
    out.flags.writeable = False
    return out


# ---------------------------------------------------------------------- one sample


@dataclass(frozen=True)
class EstimateHealth:
    """Health of the estimator after one sample.

    Attributes
    ----------
    finite : bool
        States, parameters and covariances are finite.
    covariance_ok : bool
        Every covariance diagonal is positive and below the divergence threshold.
    pinned : tuple of str
        Estimated parameters sitting at a limit (estimate projection, thesis eqs. 20, 25).
    dropped : bool
        The sample was dropped (NaN in ``u`` or an input): corrections were skipped.
    diverged : bool
        Divergence has been detected at or before this sample.

    """

    finite: bool
    covariance_ok: bool
    pinned: tuple[str, ...]
    dropped: bool
    diverged: bool

    @property
    def ok(self) -> bool:
        """True when finite, covariances fine and not diverged."""
        return self.finite and self.covariance_ok and not self.diverged

    def as_dict(self) -> dict[str, Any]:
        """Plain values, new each call (``pinned`` a list): what an observer reports."""
        return {
            "finite": self.finite,
            "covariance_ok": self.covariance_ok,
            "pinned": list(self.pinned),
            "dropped": self.dropped,
            "diverged": self.diverged,
        }


class ParameterValues(Mapping):
    """A read-only mapping of parameter names to one sample's values (a row copy).

    What :class:`Estimate` holds for ``mean`` and ``std`` when an estimator builds it:
    the values stay in an array, and nothing per parameter is built unless read (an
    online update at 100 Hz pays for the copy only).
    """

    __slots__ = ("_index", "_values")

    def __init__(self, index: Mapping[str, int], values: FloatArray) -> None:
        self._index = index
        self._values = values

    def __getitem__(self, name: str) -> float:
        return float(self._values[self._index[name]])

    def __iter__(self) -> Any:
        return iter(self._index)

    def __len__(self) -> int:
        return len(self._index)

    def __repr__(self) -> str:
        return repr(dict(self))

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle (and copy) as a plain index and the values."""
        return (type(self), (dict(self._index), self._values))

    def as_dict(self) -> dict[str, float]:
        """A plain dict of the values, built at once (not name by name)."""
        return dict(zip(self._index, self._values.tolist(), strict=True))


@dataclass(frozen=True)
class Estimate:
    """One sample's estimate.

    Attributes
    ----------
    t : float
        Time of the sample (s).
    mean, std : Mapping[str, float]
        Mean and standard deviation of every model parameter, in model order;
        parameters held constant report their value and a standard deviation of 0.
    estimated : tuple of str
        The parameters being estimated.
    prediction : float
        One-step prediction of the primary output, e.g. ``g(x^-, theta^-)`` for ``u``
        (NaN after divergence).
    innovation, innovation_variance : float
        Primary output minus its prediction (NaN for a dropped sample) and its
        predicted variance.
    health : EstimateHealth
        Flags.
    outputs : tuple of str
        The measured outputs, primary first (default ``("u",)``).
    predictions, innovations : tuple of float
        Per output (default: the primary output's values alone).
    innovation_covariance : tuple of tuple of float
        ``(m, m)`` predicted covariance of the innovations.

    """

    t: float
    mean: Mapping[str, float]
    std: Mapping[str, float]
    estimated: tuple[str, ...]
    prediction: float
    innovation: float
    innovation_variance: float
    health: EstimateHealth
    outputs: tuple[str, ...] = ("u",)
    predictions: tuple[float, ...] = ()
    innovations: tuple[float, ...] = ()
    innovation_covariance: tuple[tuple[float, ...], ...] = ()

    @classmethod
    def of_one_output(
        cls,
        t: float,
        mean: ParameterValues,
        std: ParameterValues,
        estimated: tuple[str, ...],
        prediction: float,
        innovation: float,
        innovation_variance: float,
        health: EstimateHealth,
    ) -> Estimate:
        """The estimate of a filter with the one output ``u``, built without checks.

        Equal to ``Estimate(t, mean, std, ...)`` with these fields, for an online update
        at 100 Hz: the dataclass's frozen ``__init__`` and ``__post_init__`` cost more
        than the compiled filter step. The caller guarantees the types (floats, a tuple,
        :class:`ParameterValues` snapshots).
        """
        estimate = object.__new__(cls)
        object.__setattr__(
            estimate,
            "__dict__",
            {
                "t": t,
                "mean": mean,
                "std": std,
                "estimated": estimated,
                "prediction": prediction,
                "innovation": innovation,
                "innovation_variance": innovation_variance,
                "health": health,
                "outputs": ("u",),
                "predictions": (prediction,),
                "innovations": (innovation,),
                "innovation_covariance": ((innovation_variance,),),
            },
        )
        return estimate

    def __post_init__(self) -> None:
        if not isinstance(self.mean, ParameterValues):
            object.__setattr__(self, "mean", MappingProxyType(dict(self.mean)))
        if not isinstance(self.std, ParameterValues):
            object.__setattr__(self, "std", MappingProxyType(dict(self.std)))
        if (
            self.outputs == ("u",)
            and not self.predictions
            and not self.innovations
            and not self.innovation_covariance
        ):
            # one output (every online update of the pilot filters): nothing to check
            object.__setattr__(self, "predictions", (self.prediction,))
            object.__setattr__(self, "innovations", (self.innovation,))
            object.__setattr__(self, "innovation_covariance", ((self.innovation_variance,),))
            return
        object.__setattr__(self, "outputs", tuple(self.outputs))
        m = len(self.outputs)
        if not self.predictions:
            object.__setattr__(self, "predictions", (self.prediction,) * min(m, 1))
        if not self.innovations:
            object.__setattr__(self, "innovations", (self.innovation,) * min(m, 1))
        if not self.innovation_covariance:
            object.__setattr__(self, "innovation_covariance", ((self.innovation_variance,),))
        for name in ("predictions", "innovations"):
            values = tuple(float(v) for v in getattr(self, name))
            if len(values) != m:
                raise ValueError(f"{name} must have one value per output {self.outputs}")
            object.__setattr__(self, name, values)
        covariance = tuple(tuple(float(v) for v in row) for row in self.innovation_covariance)
        if len(covariance) != m or any(len(row) != m for row in covariance):
            raise ValueError(f"innovation_covariance must be {m} x {m}")
        object.__setattr__(self, "innovation_covariance", covariance)


# ---------------------------------------------------------------------- whole runs


@dataclass(frozen=True)
class HealthSummary:
    """Health of a whole run.

    Attributes
    ----------
    diverged : bool
        Divergence was detected.
    divergence_time : float
        Time of detection (s), NaN when none.
    divergence_reason : str
        ``"non-finite values"``, ``"covariance blow-up"``, ``"dynamics beyond the
        sample rate"`` (Schiess & Roland's filter, whose exact flow would split a sample
        past its cap), ``"<name> pinned at a limit for <s> s"``, or ``""``.
    stopped : bool
        The filter stopped at the divergence (non-finite values, a covariance blow-up,
        dynamics beyond the sample rate); later samples repeat the last finite estimate
        and report NaN predictions. A pinned parameter only reports, and so does a
        multi-UKF's fast member that diverged (the fusion goes on): the filter goes
        on.
    dropped_samples : int
        Number of dropped samples.
    dropped_stretches : tuple of (float, float)
        ``(start time, duration)`` of each stretch of dropped samples (s).
    pinned_fraction : Mapping[str, float]
        Fraction of samples each parameter spent at a limit.

    """

    diverged: bool
    divergence_time: float
    divergence_reason: str
    stopped: bool
    dropped_samples: int
    dropped_stretches: tuple[tuple[float, float], ...]
    pinned_fraction: Mapping[str, float]

    def __post_init__(self) -> None:
        object.__setattr__(self, "pinned_fraction", MappingProxyType(dict(self.pinned_fraction)))
        stretches = tuple((float(a), float(b)) for a, b in self.dropped_stretches)
        object.__setattr__(self, "dropped_stretches", stretches)

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form (NaN divergence time as None)."""
        return {
            "diverged": self.diverged,
            "divergence_time": None if math.isnan(self.divergence_time) else self.divergence_time,
            "divergence_reason": self.divergence_reason,
            "stopped": self.stopped,
            "dropped_samples": self.dropped_samples,
            "dropped_stretches": [list(s) for s in self.dropped_stretches],
            "pinned_fraction": dict(self.pinned_fraction),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> HealthSummary:
        """Inverse of :meth:`to_dict`."""
        time = data["divergence_time"]
        return cls(
            diverged=bool(data["diverged"]),
            divergence_time=math.nan if time is None else float(time),
            divergence_reason=str(data["divergence_reason"]),
            stopped=bool(data["stopped"]),
            dropped_samples=int(data["dropped_samples"]),
            dropped_stretches=tuple(tuple(s) for s in data["dropped_stretches"]),
            pinned_fraction={str(k): float(v) for k, v in data["pinned_fraction"].items()},
        )


def sample_values(where: str, sample: Any, keys: tuple[str, ...], allowed: Any) -> dict[str, float]:
    """The floats of ``keys`` in one :meth:`Estimator.update` sample, checked.

    ``sample`` must be a mapping holding every key (more from ``allowed`` are tolerated);
    each value a real number, finite or NaN (a dropped sample), never infinite. Errors
    name ``where`` and the key.
    """
    return dict(zip(keys, sample_floats(where, sample, keys, allowed), strict=True))


def sample_floats(where: str, sample: Any, keys: tuple[str, ...], allowed: Any) -> list[float]:
    """:func:`sample_values` as a list in the order of ``keys``.

    A plain dict of floats, each finite or NaN, is read as it is (the online case at
    100 Hz); anything else is checked value by value.
    """
    allowed = allowed if isinstance(allowed, (set, frozenset)) else frozenset(allowed)
    if type(sample) is dict and sample.keys() <= allowed:
        try:
            values = [sample[key] for key in keys]
        except KeyError:
            values = None
        if values is not None:
            for value in values:
                # a float, finite or NaN (v - v is 0 for finite, NaN for NaN and inf)
                if type(value) is not float or (value - value != 0.0 and value == value):
                    break
            else:
                return values
    if not isinstance(sample, Mapping):
        raise TypeError(f"sample must be a mapping of signal values, got {sample!r}")
    reject_unknown(where, sample, allowed)
    missing = [key for key in keys if key not in sample]
    if missing:
        raise ValueError(
            f"{where} lacks {', '.join(map(repr, missing))}; it needs {', '.join(map(repr, keys))}"
        )
    values = []
    for key in keys:
        value = sample[key]
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise TypeError(f"sample[{key!r}] must be a number, got {value!r}")
        value = float(value)
        if math.isinf(value):
            raise ValueError(f"sample[{key!r}] must be finite or NaN (dropped), got {value!r}")
        values.append(value)
    return values


def summarise_health(
    t: FloatArray,
    dt: float,
    dropped: BoolArray,
    pinned: BoolArray,
    parameter_names: tuple[str, ...],
    *,
    reason: str,
    divergence_index: int,
    stopped: bool,
) -> HealthSummary:
    """A run's :class:`HealthSummary` from its per-sample flags.

    ``reason`` is empty when the run did not diverge; ``divergence_index`` is the row of
    the detection (-1: none); ``dropped`` (n,) and ``pinned`` (n, p) are the flags.
    """
    edges = np.diff(np.concatenate(([0], dropped.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    stretches = tuple(
        (float(t[a]), float((b - a) * dt)) for a, b in zip(starts, stops, strict=True)
    )
    diverged = bool(reason)
    index = divergence_index
    return HealthSummary(
        diverged=diverged,
        divergence_time=float(t[index]) if diverged and 0 <= index < len(t) else math.nan,
        divergence_reason=reason,
        stopped=stopped,
        dropped_samples=int(dropped.sum()),
        dropped_stretches=stretches,
        pinned_fraction={
            n: float(pinned[:, j].mean()) if len(t) else 0.0 for j, n in enumerate(parameter_names)
        },
    )


@dataclass(frozen=True, eq=False)
class EstimationResult:
    """Traces of a whole estimation run, with fixed named fields.

    Attributes
    ----------
    estimator : str
        Name of the estimator (``"dekf"``, ``"joint-ukf"``, ...).
    t : ndarray, shape (n,)
        Sample times (s).
    parameter_names : tuple of str
        Every model parameter, in model order (columns of ``mean`` and ``std``).
    estimated : tuple of str
        The parameters that were estimated; the others were held constant.
    mean, std : ndarray, shape (n, p)
        Parameter means and standard deviations after each sample (smoothed ones in a
        smoothed result).
    outputs : tuple of str
        The m measured outputs, primary first (the recorded signal each predicts).
    predictions : ndarray, shape (n, m)
        One-step prediction of each output before each correction.
    innovations : ndarray, shape (n, m)
        Output minus prediction (NaN where dropped or after divergence).
    innovation_covariance : ndarray, shape (n, m, m)
        Predicted covariance of the innovations.
    finite, covariance_ok, dropped, diverged : ndarray of bool, shape (n,)
        Per-sample health flags (see :class:`EstimateHealth`).
    pinned : ndarray of bool, shape (n, p)
        Parameter at a limit after the sample.
    settings : Mapping[str, Any]
        The settings used, JSON-able: the estimator's settings and every value
        resolved from them (initial values, covariances, limits, variances).
    health : HealthSummary
        Summary, including the divergence time if any.
    state_names : tuple of str
        Names of the recorded state traces (empty when the estimator records none).
    states : ndarray, shape (n, len(state_names))
        State means after each sample.
    passes : int
        Passes over the run (1 for filters that run once); the traces are the last pass's.
    pass_mean, pass_std : ndarray, shape (passes, p)
        Each pass's final parameter means and standard deviations.
    smoothed : bool
        The traces are fixed-interval smoothed (the innovations stay the filter's).
    smoother_inputs : object or None
        What :func:`~manualcontrol.estimators.offline.smoothing.smooth` needs (stored priors,
        posteriors and links of the run); kept in memory only, never saved or compared.

    """

    estimator: str
    t: FloatArray
    parameter_names: tuple[str, ...]
    estimated: tuple[str, ...]
    mean: FloatArray
    std: FloatArray
    outputs: tuple[str, ...]
    predictions: FloatArray
    innovations: FloatArray
    innovation_covariance: FloatArray
    finite: BoolArray
    covariance_ok: BoolArray
    dropped: BoolArray
    diverged: BoolArray
    pinned: BoolArray
    settings: Mapping[str, Any]
    health: HealthSummary
    state_names: tuple[str, ...] = ()
    states: FloatArray | None = None
    passes: int = 1
    pass_mean: FloatArray | None = None
    pass_std: FloatArray | None = None
    smoothed: bool = False
    smoother_inputs: Any = None

    def __post_init__(self) -> None:
        if not isinstance(self.estimator, str) or not self.estimator:
            raise TypeError(f"estimator must be a non-empty string, got {self.estimator!r}")
        names = tuple(str(name) for name in self.parameter_names)
        if len(set(names)) != len(names):
            raise ValueError(f"parameter_names must be unique, got {names}")
        object.__setattr__(self, "parameter_names", names)
        estimated = tuple(str(name) for name in self.estimated)
        unknown = sorted(set(estimated) - set(names))
        if unknown:
            raise ValueError(f"estimated names {unknown} are not in parameter_names {names}")
        object.__setattr__(self, "estimated", estimated)
        outputs = tuple(str(name) for name in self.outputs)
        if not outputs or len(set(outputs)) != len(outputs):
            raise ValueError(f"outputs must be unique names, at least one, got {outputs}")
        object.__setattr__(self, "outputs", outputs)
        t = _readonly(self.t, np.float64)
        if t.ndim != 1:
            raise ValueError(f"t must be 1-D, got shape {t.shape}")
        n, p, m = t.shape[0], len(names), len(outputs)
        object.__setattr__(self, "t", t)
        state_names = tuple(str(name) for name in self.state_names)
        object.__setattr__(self, "state_names", state_names)
        passes = self.passes
        if isinstance(passes, bool) or not isinstance(passes, (int, np.integer)) or passes < 1:
            raise ValueError(f"passes must be an integer >= 1, got {passes!r}")
        object.__setattr__(self, "passes", int(passes))
        if self.states is None:
            object.__setattr__(self, "states", np.zeros((n, len(state_names))))
        mean = np.asarray(self.mean, dtype=np.float64)
        std = np.asarray(self.std, dtype=np.float64)
        if self.pass_mean is None:
            object.__setattr__(self, "pass_mean", mean[-1:] if n else np.zeros((1, p)))
        if self.pass_std is None:
            object.__setattr__(self, "pass_std", std[-1:] if n else np.zeros((1, p)))
        shapes = {
            "predictions": ((n, m), np.float64),
            "innovations": ((n, m), np.float64),
            "innovation_covariance": ((n, m, m), np.float64),
            "mean": ((n, p), np.float64),
            "std": ((n, p), np.float64),
            "pinned": ((n, p), np.bool_),
            "states": ((n, len(state_names)), np.float64),
            "pass_mean": ((self.passes, p), np.float64),
            "pass_std": ((self.passes, p), np.float64),
            **{name: ((n,), np.bool_) for name in _FLAGS_1D},
        }
        for name, (shape, dtype) in shapes.items():
            array = _readonly(getattr(self, name), dtype)
            if array.shape != shape:
                raise ValueError(f"{name} must have shape {shape}, got {array.shape}")
            object.__setattr__(self, name, array)
        object.__setattr__(self, "smoothed", bool(self.smoothed))
        if not isinstance(self.health, HealthSummary):
            raise TypeError(f"health must be a HealthSummary, got {self.health!r}")
        settings = json.loads(json.dumps(dict(self.settings), allow_nan=False))
        object.__setattr__(self, "settings", MappingProxyType(settings))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    # ----------------------------------------------------------- primary output

    @property
    def prediction(self) -> FloatArray:
        """Trace of the primary output's one-step prediction, shape (n,)."""
        return self.predictions[:, 0]

    @property
    def innovation(self) -> FloatArray:
        """Trace of the primary output's innovation, shape (n,)."""
        return self.innovations[:, 0]

    @property
    def innovation_variance(self) -> FloatArray:
        """Trace of the primary output's innovation variance, shape (n,)."""
        return self.innovation_covariance[:, 0, 0]

    def _output(self, name: str) -> int:
        check_choice("output", name, self.outputs)
        return self.outputs.index(name)

    def prediction_of(self, output: str) -> FloatArray:
        """Trace of the one-step prediction of ``output``, shape (n,)."""
        return self.predictions[:, self._output(output)]

    def innovation_of(self, output: str) -> FloatArray:
        """Trace of the innovation of ``output``, shape (n,)."""
        return self.innovations[:, self._output(output)]

    def _column(self, name: str) -> int:
        check_choice("parameter", name, self.parameter_names)
        return self.parameter_names.index(name)

    def mean_of(self, name: str) -> FloatArray:
        """Trace of the mean of parameter ``name``, shape (n,)."""
        return self.mean[:, self._column(name)]

    def std_of(self, name: str) -> FloatArray:
        """Trace of the standard deviation of parameter ``name``, shape (n,)."""
        return self.std[:, self._column(name)]

    def state_of(self, name: str) -> FloatArray:
        """Trace of the state ``name``, shape (n,)."""
        check_choice("state", name, self.state_names)
        return self.states[:, self.state_names.index(name)]

    def final(self) -> dict[str, float]:
        """Mean of every parameter after the last sample."""
        return {name: float(self.mean[-1, j]) for j, name in enumerate(self.parameter_names)}

    def equals(self, other: object) -> bool:
        """Exact equality of every field but the smoother inputs (NaN equal to NaN)."""
        if not isinstance(other, EstimationResult):
            return False
        scalars = ("estimator", "parameter_names", "estimated", "outputs", "state_names")
        scalars += ("passes", "smoothed")
        if any(getattr(self, name) != getattr(other, name) for name in scalars):
            return False
        if dict(self.settings) != dict(other.settings):
            return False
        if self.health.to_dict() != other.health.to_dict():  # NaN-safe
            return False
        for name in _ARRAYS:
            if not np.array_equal(getattr(self, name), getattr(other, name), equal_nan=True):
                return False
        return True

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, EstimationResult):
            return NotImplemented
        return self.equals(other)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        kind = ", smoothed" if self.smoothed else ""
        return (
            f"EstimationResult(estimator={self.estimator!r}, {len(self)} samples, "
            f"estimated={self.estimated}, outputs={self.outputs}, "
            f"diverged={self.health.diverged}{kind})"
        )

    # ----------------------------------------------------------------- files

    def save(self, path: str | os.PathLike[str]) -> Path:
        """Write the result to ``path`` (``.npz``) atomically and return the path.

        Layout: one array per trace under its field name, and 0-d strings
        ``result_format`` (:data:`RESULT_FORMAT`), ``estimator``, ``parameter_names``,
        ``estimated``, ``outputs``, ``state_names``, ``passes``, ``smoothed``,
        ``settings`` and ``health`` (JSON). Read back with :meth:`load`
        (``allow_pickle=False``). The smoother inputs are not saved.
        """
        target = Path(path)
        if target.suffix.lower() != ".npz":
            raise ValueError(f"{target}: results are saved as .npz, got suffix {target.suffix!r}")
        entries: dict[str, Any] = {name: getattr(self, name) for name in _ARRAYS}
        entries.update(
            {
                "result_format": np.array(RESULT_FORMAT),
                "estimator": np.array(self.estimator),
                "parameter_names": np.array(json.dumps(list(self.parameter_names))),
                "estimated": np.array(json.dumps(list(self.estimated))),
                "outputs": np.array(json.dumps(list(self.outputs))),
                "state_names": np.array(json.dumps(list(self.state_names))),
                "passes": np.array(self.passes),
                "smoothed": np.array(self.smoothed),
                "settings": np.array(json.dumps(dict(self.settings), allow_nan=False)),
                "health": np.array(json.dumps(self.health.to_dict(), allow_nan=False)),
            }
        )

        def write(temporary: Path) -> None:
            with open(temporary, "wb") as handle:
                np.savez(handle, **entries)

        return atomic_write(target, write)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> EstimationResult:
        """Read a result written by :meth:`save` (this or an older format), validating it.

        Raises
        ------
        ValueError
            For a file that is not a saved result (missing or unknown ``result_format``,
            missing entries, inconsistent shapes).

        """
        source = Path(path)
        try:
            archive = np.load(source, allow_pickle=False)
        except (OSError, ValueError, EOFError) as error:
            raise ValueError(f"{source}: not a readable .npz file ({error})") from error
        with archive:
            names = set(archive.files)
            tag = str(archive["result_format"]) if "result_format" in names else None
            if tag not in (RESULT_FORMAT, *_OLDER_FORMATS):
                raise ValueError(
                    f"{source}: not a saved EstimationResult (result_format {tag!r}, "
                    f"expected one of {[RESULT_FORMAT, *_OLDER_FORMATS]})"
                )
            if tag == RESULT_FORMAT:
                required = (*_ARRAYS, "estimator", "parameter_names", "estimated", "outputs")
                required += ("state_names", "passes", "smoothed", "settings", "health")
            else:
                required = ("t", "prediction", "innovation", "innovation_variance", "mean")
                required += ("std", "pinned", *_FLAGS_1D, "estimator", "parameter_names")
                required += ("estimated", "settings", "health")
            missing = [name for name in required if name not in names]
            if missing:
                raise ValueError(f"{source}: saved result lacks entries {missing}")
            try:
                fields: dict[str, Any] = {
                    "estimator": str(archive["estimator"]),
                    "t": archive["t"],
                    "parameter_names": tuple(json.loads(str(archive["parameter_names"]))),
                    "estimated": tuple(json.loads(str(archive["estimated"]))),
                    "mean": archive["mean"],
                    "std": archive["std"],
                    "pinned": archive["pinned"],
                    "settings": json.loads(str(archive["settings"])),
                    "health": HealthSummary.from_dict(json.loads(str(archive["health"]))),
                    **{name: archive[name] for name in _FLAGS_1D},
                }
                if tag == RESULT_FORMAT:
                    fields.update(
                        outputs=tuple(json.loads(str(archive["outputs"]))),
                        predictions=archive["predictions"],
                        innovations=archive["innovations"],
                        innovation_covariance=archive["innovation_covariance"],
                        state_names=tuple(json.loads(str(archive["state_names"]))),
                        states=archive["states"],
                        passes=int(archive["passes"]),
                        pass_mean=archive["pass_mean"],
                        pass_std=archive["pass_std"],
                        smoothed=bool(archive["smoothed"]),
                    )
                else:  # version 1: one output, u
                    fields.update(
                        outputs=("u",),
                        predictions=np.asarray(archive["prediction"])[:, None],
                        innovations=np.asarray(archive["innovation"])[:, None],
                        innovation_covariance=np.asarray(archive["innovation_variance"])[
                            :, None, None
                        ],
                    )
                return cls(**fields)
            except (KeyError, TypeError, ValueError) as error:
                raise ValueError(f"{source}: invalid saved result: {error}") from error


def load_result(path: str | os.PathLike[str]) -> EstimationResult:
    """Read an :class:`EstimationResult`; see :meth:`EstimationResult.load`."""
    return EstimationResult.load(path)


# ---------------------------------------------------------------------- protocol


@runtime_checkable
class Estimator(Protocol):
    """What every online estimator provides (structural type).

    ``settings`` is a frozen dataclass; ``configure(**changes)`` returns a new
    estimator with some settings replaced; ``reset`` must be called before
    ``update``; ``estimate`` runs a recording from a fresh reset.
    """

    @property
    def name(self) -> str:
        """Short name, stored in results."""

    @property
    def settings(self) -> Any:
        """The frozen settings dataclass."""

    def configure(self, **changes: Any) -> Estimator:
        """A new estimator with the given settings replaced."""

    def reset(self, dt: float, **kwargs: Any) -> None:
        """Start from the initial belief for samples ``dt`` seconds apart."""

    def update(self, sample: Mapping[str, float]) -> Estimate:
        """Consume one sample and return the estimate after it."""

    def estimate(self, recording: Recording, **kwargs: Any) -> EstimationResult:
        """Run a whole recording and return the traces."""
