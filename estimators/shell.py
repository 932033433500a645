"""The one shell every member of the estimator family subclasses.

A member of the family is its settings, its model and a compiled step with a loop over
it for whole runs. The
protocol around them is the same for every member and lives here once
(:class:`FilterShell`): building from settings or keyword changes, ``configure``,
pickling as a fresh estimator, the ``t``/``dt``/sample-count bookkeeping, the online
step (with numba's dispatcher bypassed after the first call), the estimate of the
one-row output the step wrote, the plain-dict form the online observer reports
(:meth:`FilterShell.update_plain`), the health of a run, and the assembly of an
:class:`~manualcontrol.estimators.protocol.EstimationResult` from the kernels' output
records.

Every compiled kernel of the family writes an output record with the same leading
fields: ``mean``, ``std`` (n, p), ``scalar`` (n, 3: prediction, innovation and its
variance of the primary output), ``flag`` (n, 4+: finite, covariance ok, dropped,
diverged) and ``pinned`` (n, p); members with several outputs add ``predictions``,
``innovations`` (n, m) and ``S`` (n, m, m). A member provides:

- ``name``, ``settings_type`` and :attr:`FilterShell.outputs`;
- ``reset(dt, ..., t0=...)``, which builds its records and ends with
  :meth:`FilterShell._begin`;
- ``_new_output(n, store)``, its output records for ``n`` rows (with smoother storage
  or without);
- ``_step_sample(sample)``, which reads one sample and calls its compiled step on the
  one-row output (through :meth:`FilterShell._call_step`); the filters on pilot models
  replace :meth:`FilterShell._consume`, which calls it, whole instead (their sample is
  read into a prepared input vector, and the C port's entry steps it);
- ``parameter_names`` and ``signals(recording)``;
- ``estimate(recording, ...)``, which runs its compiled loop over the recording and returns
  :meth:`FilterShell._assemble`'s result (smoothed by :meth:`FilterShell._finish`);
- for smoothing, ``_smoother_inputs(out)``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_bool
from manualcontrol.estimators import _pilot_core as core
from manualcontrol.estimators.filters import monitor
from manualcontrol.estimators.offline.smoothing import smooth as smooth_result
from manualcontrol.estimators.protocol import (
    Estimate,
    EstimateHealth,
    EstimationResult,
    HealthSummary,
    ParameterValues,
    sample_values,
    summarise_health,
)

__all__ = [
    "REASONS",
    "FilterShell",
    "compiled_entry",
    "health_summary",
    "output_arrays",
    "read_sample",
    "trace_arrays",
    "two_output_arrays",
]

FloatArray = NDArray[np.float64]

#: Words for the divergence codes of :mod:`~manualcontrol.estimators.filters.monitor`.
REASONS = {
    monitor.REASON_NONFINITE: "non-finite values",
    monitor.REASON_COVARIANCE: "covariance blow-up",
    monitor.REASON_BEYOND_SAMPLE_RATE: "dynamics beyond the sample rate",
}


def compiled_entry(kernel: Any, arguments: tuple) -> Any:
    """Call ``kernel`` on ``arguments`` through numba's dispatcher; return its entry point.

    The dispatcher types every argument on every call: for a filter's records (some
    forty to sixty arrays in namedtuples) that costs more than the filter's step. The
    records keep their types from one call to the next, so a caller calls the overload
    found here directly afterwards (``entry(*arguments)``).
    """
    kernel(*arguments)
    types = tuple(kernel.typeof_pyval(argument) for argument in arguments)
    return kernel.overloads[types].entry_point


#: Distinct row healths kept per filter (one per combination of flags and pins).
_HEALTH_CACHE = 1024


def read_sample(sample: Any, keys: Sequence[str], where: str) -> dict[str, float]:
    """The values of ``keys`` in ``sample`` (``t`` may be present too), checked."""
    keys = tuple(keys)
    return sample_values(where, sample, keys, (*keys, "t"))


def health_summary(
    sc: NDArray[np.float64],
    t: NDArray[np.float64],
    dt: float,
    flag: NDArray[np.bool_],
    pinned: NDArray[np.bool_],
    names: Sequence[str],
    pinned_time: float,
) -> HealthSummary:
    """A run's :class:`HealthSummary` from the kernel's scalar state and per-sample flags.

    ``sc`` is laid out as ``SC_*`` of :mod:`~manualcontrol.estimators._pilot_core`;
    ``flag[:, 2]`` marks dropped samples; ``pinned`` (n, p) the parameters at a limit.
    """
    reason_code = int(sc[core.SC_DIV_REASON])
    if reason_code == monitor.REASON_PINNED:
        reason = f"{names[int(sc[core.SC_DIV_PARAM])]} pinned at a limit for {pinned_time:g} s"
    else:
        reason = REASONS.get(reason_code, "")
    return summarise_health(
        t,
        dt,
        flag[:, 2],
        pinned,
        tuple(names),
        reason=reason,
        divergence_index=int(sc[core.SC_DIV_INDEX]),
        stopped=bool(sc[core.SC_FROZEN] > 0.0),
    )


def output_arrays(n: int, p: int, flags: int = 4) -> dict[str, FloatArray]:
    """The leading fields of every member's output record (module docstring), zeroed.

    ``mean``, ``std`` and ``pinned`` (n, p), ``scalar`` (n, 3) and ``flag`` (n, flags):
    a member's ``_new_output`` spreads them into its record beside its own fields.
    """
    return {
        "mean": np.zeros((n, p)),
        "std": np.zeros((n, p)),
        "scalar": np.zeros((n, 3)),
        "flag": np.zeros((n, flags), dtype=np.bool_),
        "pinned": np.zeros((n, p), dtype=np.bool_),
    }


def two_output_arrays(n: int) -> dict[str, FloatArray]:
    """``predictions``, ``innovations`` (n, 2) and ``S`` (n, 2, 2) of a two-output member."""
    return {
        "predictions": np.zeros((n, 2)),
        "innovations": np.zeros((n, 2)),
        "S": np.zeros((n, 2, 2)),
    }


def trace_arrays(rows: int, size: int) -> dict[str, FloatArray]:
    """A filter's stored run for the smoother, zeroed (``rows`` 0: nothing stored).

    ``x_prior``/``x_post`` (rows, size) and ``P_prior``/``P_post`` (rows, size, size).
    """
    return {
        "x_prior": np.zeros((rows, size)),
        "P_prior": np.zeros((rows, size, size)),
        "x_post": np.zeros((rows, size)),
        "P_post": np.zeros((rows, size, size)),
    }


class FilterShell:
    """The estimator protocol around a member's compiled filter (see the module docstring).

    Parameters
    ----------
    settings
        The member's settings (``settings_type``); keyword arguments replace its fields,
        or build one from the defaults.
    """

    name: ClassVar[str] = ""
    settings_type: ClassVar[type] = object
    #: The measured outputs, primary first.
    outputs: ClassVar[tuple[str, ...]] = ("u",)
    #: The binding module of the member's C port (``members/_<member>_native.py``:
    #: ``library()``, ``NativeRecords``), or None. Where its library builds, the member's
    #: kernel calls go to C instead, the same numbers bit for bit
    #: (:mod:`~manualcontrol.envs._native`).
    _native_binding: ClassVar[Any] = None
    #: Keys :meth:`update` reads (a member sets it, on the class or at construction).
    _sample_keys: tuple[str, ...] = ()

    def __init__(self, settings: Any = None, **changes: Any) -> None:
        kind = self.settings_type
        if settings is None:
            settings = kind.build(**changes)
        elif not isinstance(settings, kind):
            raise TypeError(f"settings must be {kind.__name__}, got {settings!r}")
        elif changes:
            settings = settings.replace(**changes)
        self._settings = settings
        self._records: Any = None
        self._row: Any = None
        self._entry: Any = None
        # the C port bound to (records, output) of this reset, where the member has one
        self._native: tuple[Any, ...] | None = None
        self._estimated: tuple[str, ...] = ()
        self._healths: dict[bytes, EstimateHealth] = {}
        self._where = f"{type(self).__name__}.update sample"
        self._t0 = 0.0
        self._dt = 0.01
        self._k = 0

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> Any:
        """The member built from a plain settings table (a suite file's, ``--set``'s)."""
        return cls(cls.settings_type.from_dict(dict(settings)))

    # ----------------------------------------------------------------- access

    @property
    def settings(self) -> Any:
        """The frozen settings."""
        return self._settings

    @property
    def sample_keys(self) -> tuple[str, ...]:
        """Keys :meth:`update` needs (optionally with ``t``)."""
        return self._sample_keys

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Reported parameter names, in the order of the results' columns."""
        raise NotImplementedError

    def configure(self, **changes: Any) -> Any:
        """A new estimator of this kind with some settings replaced."""
        return type(self)(self._settings.replace(**changes))

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle (and deep copy) as a fresh estimator with the same settings, without run state."""
        return (type(self), (self._settings,))

    def __repr__(self) -> str:
        fields = ", ".join(f"{name}={value!r}" for name, value in self._repr_fields().items())
        return f"{type(self).__name__}({fields})"

    def _repr_fields(self) -> Mapping[str, Any]:
        return {}

    # ----------------------------------------------------------------- reset

    def _require_reset(self) -> Any:
        if self._records is None:
            raise RuntimeError(f"the {type(self).__name__} has not been reset; call reset() first")
        return self._records

    def _begin(self, records: Any, dt: float, t0: float, estimated: Sequence[str]) -> None:
        """End a reset: the member's compiled ``records``, a one-row output, time zero."""
        self._records = records
        self._estimated = tuple(estimated)
        self._row = self._new_output(1, store=False)
        self._entry = None
        self._healths.clear()
        self._columns = MappingProxyType({n: j for j, n in enumerate(self.parameter_names)})
        self._t0, self._dt, self._k = t0, dt, 0

    def _new_output(self, n: int, store: bool) -> Any:
        raise NotImplementedError

    # ---------------------------------------------------------------- update

    def update(self, sample: Mapping[str, float]) -> Estimate:
        """Consume one sample and return the estimate after it.

        ``sample`` maps :attr:`sample_keys` to floats, optionally with ``t`` (else the
        time follows from the reset's ``t0`` and ``dt``).
        """
        return self._estimate_of_row(self._consume(sample))

    def update_quiet(self, sample: Mapping[str, float]) -> float:
        """:meth:`update` without building its answer; the sample's time.

        The estimate stays in the filter's output row: :meth:`latest` gives views of its
        means and standard deviations, :meth:`latest_plain` the dicts of
        :meth:`update_plain`, each built only when asked (the online observer's thin
        path: no per-step dicts).
        """
        return self._consume(sample)

    def latest(self) -> tuple[FloatArray, FloatArray]:
        """Views of the means and standard deviations after the last sample.

        Columns in :attr:`parameter_names` order; the next sample overwrites them (copy
        what is kept).
        """
        return self._row.mean[0], self._row.std[0]

    def latest_plain(self, t: float) -> dict[str, Any]:
        """The last sample's estimate as :meth:`update_plain` gives it (``t`` its time)."""
        return self._plain_of_row(t)

    def update_plain(self, sample: Mapping[str, float]) -> dict[str, Any]:
        """:meth:`update` as plain data: the online observer's report of the estimate.

        Plain dicts, lists and floats, new each call, built straight from the output
        row (:class:`~manualcontrol.estimators.observer.EstimatorObserver` reports one
        a step): ``t``, ``mean``, ``std``, ``innovation``, ``innovation_variance``,
        ``prediction`` (of the primary output) and ``health``.
        """
        return self._plain_of_row(self._consume(sample))

    def _plain_of_row(self, t: float) -> dict[str, Any]:
        row = self._row
        columns = self._columns
        prediction, innovation, variance = self._primary_of_row()
        return {
            "t": t,
            "mean": dict(zip(columns, row.mean[0].tolist(), strict=True)),
            "std": dict(zip(columns, row.std[0].tolist(), strict=True)),
            "innovation": innovation,
            "innovation_variance": variance,
            "prediction": prediction,
            "health": self._health_of_row(row.flag[0], row.pinned[0]).as_dict(),
        }

    def _consume(self, sample: Mapping[str, float]) -> float:
        """Check one sample and step the filter on it; return its time."""
        self._require_reset()
        self._step_sample(sample)
        t = sample.get("t")
        t = self._t0 + self._k * self._dt if t is None else float(t)
        self._k += 1
        return t

    def _step_sample(self, sample: Mapping[str, float]) -> None:
        raise NotImplementedError

    def _call_step(self, kernel: Any, arguments: tuple) -> None:
        """Call the compiled one-sample ``kernel``, bypassing numba's dispatcher after once.

        The dispatcher's typing of the records was 16 of the 22 us an ``update()`` cost
        (:func:`compiled_entry`). ``kernel`` may be the name of the class attribute that
        holds it (a :class:`~manualcontrol.envs._lazy.LazyKernel`): it is read here
        alone, where numba runs, so a member whose C port takes the step instead never
        imports numba online.
        """
        if self._entry is None:
            if isinstance(kernel, str):
                kernel = getattr(type(self), kernel)
            self._entry = compiled_entry(kernel, arguments)
        else:
            self._entry(*arguments)

    def _native_records(self, out: Any) -> Any:
        """The member's C port bound to this reset's records and ``out``, or None.

        None where the member has no C port or its library did not build (numba runs).
        Decided once per reset and output record: a step pays no lookup.
        """
        binding = type(self)._native_binding
        if binding is None:
            return None
        bound = self._native
        if bound is None or bound[0] is not self._records or bound[1] is not out:
            lib = binding.library()
            native = None if lib is None else binding.NativeRecords(lib, self._records, out)
            bound = (self._records, out, native)
            self._native = bound
        return bound[2]

    def _primary_of_row(self) -> tuple[float, float, float]:
        """Prediction, innovation and its variance of the primary output in the row."""
        row = self._row
        if hasattr(row, "S"):
            return float(row.predictions[0, 0]), float(row.innovations[0, 0]), float(row.S[0, 0, 0])
        prediction, innovation, variance = row.scalar[0].tolist()
        return prediction, innovation, variance

    def _health_of_row(self, flag: NDArray[np.bool_], pinned: NDArray[np.bool_]) -> EstimateHealth:
        """The (immutable, shared) health of the row's flags: one per combination."""
        key = flag.tobytes() + pinned.tobytes()
        health = self._healths.get(key)
        if health is None:
            finite, covariance_ok, dropped, diverged = flag.tolist()[:4]
            names = self.parameter_names
            health = EstimateHealth(
                finite=finite,
                covariance_ok=covariance_ok,
                pinned=tuple(n for n, at in zip(names, pinned.tolist(), strict=True) if at),
                dropped=dropped,
                diverged=diverged,
            )
            if len(self._healths) < _HEALTH_CACHE:
                self._healths[key] = health
        return health

    def _estimate_of_row(self, t: float) -> Estimate:
        """The :class:`Estimate` held in the one-row output the last step wrote."""
        row = self._row
        prediction, innovation, variance = self._primary_of_row()
        health = self._health_of_row(row.flag[0], row.pinned[0])
        if self.outputs == ("u",) and not hasattr(row, "S"):
            return Estimate.of_one_output(
                t,
                ParameterValues(self._columns, row.mean[0].copy()),
                ParameterValues(self._columns, row.std[0].copy()),
                self._estimated,
                prediction,
                innovation,
                variance,
                health,
            )
        names = self.parameter_names
        multi = hasattr(row, "S")
        return Estimate(
            t=t,
            mean=dict(zip(names, row.mean[0].tolist(), strict=True)),
            std=dict(zip(names, row.std[0].tolist(), strict=True)),
            estimated=self._estimated,
            prediction=prediction,
            innovation=innovation,
            innovation_variance=variance,
            health=health,
            outputs=self.outputs,
            predictions=tuple(row.predictions[0].tolist()) if multi else (prediction,),
            innovations=tuple(row.innovations[0].tolist()) if multi else (innovation,),
            innovation_covariance=(
                tuple(tuple(r) for r in row.S[0].tolist()) if multi else ((variance,),)
            ),
        )

    # -------------------------------------------------------------- estimate

    def _health(self, t: FloatArray, flag: NDArray[np.bool_], pinned: NDArray[np.bool_]) -> Any:
        """The run's health from the scalar state ``sc`` of the member's records."""
        return health_summary(
            self._records[1].sc,
            t,
            self._dt,
            flag,
            pinned,
            self.parameter_names,
            self._settings.guard.pinned_time,
        )

    def _assemble(
        self, t: FloatArray, out: Any, store: bool, *, settings: Mapping[str, Any], **extra: Any
    ) -> EstimationResult:
        """The :class:`EstimationResult` of a run from its output records.

        ``settings`` is the result's record of what ran; ``extra`` sets further fields
        (``health`` replaces the run's own, ``state_names``/``states``, ``passes``...).
        """
        multi = hasattr(out, "S")
        fields = {
            "health": None,
            "smoother_inputs": self._smoother_inputs(out) if store else None,
            **extra,
        }
        if fields["health"] is None:
            fields["health"] = self._health(t, out.flag, out.pinned)
        return EstimationResult(
            estimator=self.name,
            t=t,
            parameter_names=self.parameter_names,
            estimated=self._estimated,
            mean=out.mean,
            std=out.std,
            outputs=self.outputs,
            predictions=out.predictions if multi else out.scalar[:, 0:1],
            innovations=out.innovations if multi else out.scalar[:, 1:2],
            innovation_covariance=out.S if multi else out.scalar[:, 2, None, None],
            finite=out.flag[:, 0],
            covariance_ok=out.flag[:, 1],
            dropped=out.flag[:, 2],
            diverged=out.flag[:, 3],
            pinned=out.pinned,
            settings=settings,
            **fields,
        )

    def _smoother_inputs(self, out: Any) -> Any:
        raise NotImplementedError

    @staticmethod
    def _finish(result: EstimationResult, smooth: bool) -> EstimationResult:
        """``result``, fixed-interval smoothed when ``smooth``."""
        if check_bool("smooth", smooth):
            return smooth_result(result)
        return result
