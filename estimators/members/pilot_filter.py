"""The shell shared by the filters on pilot internal models: settings, resolution, I/O.

The DEKF (:mod:`~manualcontrol.estimators.members.dekf`), the joint and the dual UKF
(:mod:`~manualcontrol.estimators.members.ukf`) run on the same internal model (the pilot
structure's one definition with Padé delays,
:mod:`~manualcontrol.estimators.members.internal_model`),
with the same noise rules (``R = r^2 var(u)``, chain-input process noise ``q^2 var(e)``
over a 5-s window, Popovici eqs. 24-25, thesis eqs. 29-30), the same initial values,
covariances and limits (Popovici eqs. 25-34, thesis Sec. V-B and Table I), and the
same way of reading samples and reporting results. That is written once, here:

* :class:`PilotFilterSettings`, :func:`resolve_settings` and :class:`ParameterMap`
  (:mod:`~manualcontrol.estimators.members.pilot_rules`, re-exported here): the settings every
  member takes, the rules that resolve them into every number a run uses, and the
  conversion between internal and reported parameter values;
* :class:`PilotFilter`: the estimator protocol around a compiled step (``reset``,
  ``update``, ``estimate``, ``signals``, results, smoothing).

Restarts (offline)
------------------
A filter started far from the pilot, or knocked off in its first seconds (on the double
integrator the 0.01-rad/s remnant drifts the output while the covariances are still
wide), can sit at a limit for a minute before it finds its way, and a smoother cannot
repair what the filter never saw. Offline the run can be passed again: with
``restarts = m`` :meth:`PilotFilter.estimate` runs the filter ``m`` more times, each
from the median of the previous pass's smoothed estimate over the last half of the run
(the estimated parameters; the held ones, ``P0`` and ``Q`` stay the first pass's), and
keeps a restarted pass where its innovations are clearly more likely than those of the
pass kept so far: the per-sample costs ``ln S + nu^2 / S`` after the first ``window``
(:func:`~manualcontrol.estimators.analysis.metrics.innovation_cost` is their mean), paired
sample by sample, lower by more than :data:`EVIDENCE` = 2 standard errors of their
mean difference (batch means over ``window``-long stretches, because the differences
of two slowly parting parameter tracks are correlated): a choice among starting points
by likelihood (multi-start), with the papers' single pass kept unless the data say
otherwise. Why a test and not the smaller cost: most restarts land where the first
pass was, and their costs differ in the fourth digit; choosing by that noise moved the
errors both ways (``remnant-robustness``, all-free preview SI: ``K_p`` NRMSE 0.052 ->
0.070). Why a restart may be worse at all: a pilot that changes (Popovici's gain step)
starts the second pass at its late values, a poor start the first pass did not have.
``result.passes``, ``pass_mean``/``pass_std`` (each pass's final estimate) and
``result.settings["restarts"]`` (each pass's start, cost, evidence against the kept
pass in standard errors, the pass chosen and why the restarts ended) record what
happened. Measured figures: docs/estimators.md.
"""

from __future__ import annotations

import ctypes
import dataclasses
import math
import weakref
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._lazy import has_kernel
from manualcontrol.envs._native import array_address
from manualcontrol.envs._validation import (
    check_bool,
    check_positive,
    check_real,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import _online_native
from manualcontrol.estimators import _pilot_core as core
from manualcontrol.estimators.analysis.frequency import fit_describing_function
from manualcontrol.estimators.analysis.metrics import innovation_cost_terms, paired_cost_evidence
from manualcontrol.estimators.members._recording_checks import check_estimable
from manualcontrol.estimators.members._targets import target_function
from manualcontrol.estimators.members.internal_model import (
    InternalModel,
)
from manualcontrol.estimators.members.pilot_rules import (
    CE_TYPES,
    CROSSOVER_RANGE,
    DESCRIBED_START,
    DI_FAR_BREAK,
    GENERIC_INITIAL,
    HUMAN_RANGES,
    INITIAL_VARIANCE_MODES,
    LIMIT_CHOICES,
    MAX_DELAY_ORDER,
    NOISE_INPUTS,
    PRESETS,
    TABLE_I,
    TAU_F_MARGIN,
    GenericValuesWarning,
    ParameterMap,
    PilotFilterSettings,
    ResolvedSettings,
    default_limits,
    element_type,
    held_by_design,
    held_without_values,
    human_limits,
    internal_model,
    resolve_settings,
    run_describing_function,
    warn_held_without_values,
)
from manualcontrol.estimators.offline.smoothing import smooth as smooth_result
from manualcontrol.estimators.protocol import (
    Estimate,
    EstimationResult,
    sample_floats,
)
from manualcontrol.estimators.shell import FilterShell, compiled_entry, health_summary

__all__ = [
    "CE_TYPES",
    "CROSSOVER_RANGE",
    "DI_FAR_BREAK",
    "EVIDENCE",
    "GENERIC_INITIAL",
    "HUMAN_RANGES",
    "INITIAL_VARIANCE_MODES",
    "LIMIT_CHOICES",
    "MAX_DELAY_ORDER",
    "NOISE_INPUTS",
    "PRESETS",
    "TABLE_I",
    "TAU_F_MARGIN",
    "CommonArrays",
    "GenericValuesWarning",
    "ParameterMap",
    "PilotFilter",
    "PilotFilterSettings",
    "ResolvedSettings",
    "element_type",
    "held_by_design",
    "held_without_values",
    "human_limits",
    "resolve_settings",
    "run_describing_function",
]

FloatArray = NDArray[np.float64]


#: Standard errors by which a restarted pass's innovations must be more likely than the
#: kept pass's before it replaces it (about the one-sided 2.5 % level).
EVIDENCE = 2.0


def _restart_point(result: EstimationResult, names: tuple[str, ...]) -> dict[str, float] | None:
    """Median of each of ``names`` over the last half of ``result`` (None if not finite).

    The last half: a filter lost in its run-in has found its way by then (the reason
    to restart), and a median, unlike the final value, ignores the end's excursions.
    """
    half = len(result) // 2
    start = {name: float(np.median(result.mean_of(name)[half:])) for name in names}
    return start if all(math.isfinite(value) for value in start.values()) else None


# ----------------------------------------------------------------------- resolution


@dataclass
class CommonArrays:
    """The records every pilot filter's compiled step reads (see ``_pilot_core``)."""

    cfg: FloatArray
    sc: FloatArray
    monitor: core.PilotMonitor
    report: core.PilotReport
    p: FloatArray
    estimated: NDArray[np.bool_]
    parameter_map: ParameterMap


class PilotFilter(FilterShell):
    """The shell of the members on a pilot internal model (DEKF, RML, joint and dual UKF).

    On top of :class:`~manualcontrol.estimators.shell.FilterShell`: the settings
    resolution of the pilot models (limits, starting values, noise), the start from the
    describing function and the restarts. Subclasses set :attr:`name` and
    :attr:`settings_type` and implement ``_start`` (build their records from the
    resolved settings), ``_new_output`` (output records for ``n`` rows, with smoother
    storage or without), the compiled kernels (``_step_kernel``, ``_step_many_kernel``;
    ``_native_binding``, their C port) and, for smoothing, ``_smoother_inputs``.
    """

    settings_type: ClassVar[type[PilotFilterSettings]] = PilotFilterSettings
    #: The compiled one-sample kernel, ``kernel(*records, inputs, u, e, row, out)``
    #: (a ``staticmethod``: numba's dispatchers bind to instances like functions; or a
    #: :class:`~manualcontrol.envs._lazy.LazyKernel`, which imports it and numba on first
    #: read, so a filter whose C port runs never does).
    _step_kernel: ClassVar[Any] = None
    #: The same step over a stack of filters (:class:`~manualcontrol.estimators.batch.
    #: FilterBatch`), ``kernel(*stacked_records, inputs, u, e, active, rows, out_rows,
    #: stacked_out)``; also this filter's :meth:`update_block` (a stack of one, every
    #: row 0) and its whole run in ``estimate`` (a stack of one, sample ``k`` into output
    #: row ``k``): numba compiles one loop around the step, not one for each use.
    _step_many_kernel: ClassVar[Any] = None

    def __init__(self, settings: PilotFilterSettings | None = None, **changes: Any) -> None:
        super().__init__(settings, **changes)
        settings = self._settings
        self._internal = internal_model(settings.model, settings.delay_order, settings.pursuit)
        assumed = held_without_values(
            self._internal.parameter_names,
            settings.estimated,
            settings.initial,
            settings.ce_type,
            settings.pursuit,
        )
        warn_held_without_values(type(self).__name__, assumed)
        keys = list(self._internal.input_names)
        keys += [name for name in ("e", "u") if name not in keys]
        self._sample_keys = tuple(keys)
        self._allowed_sample_keys = frozenset((*keys, "t"))
        self._columns = MappingProxyType(
            {name: j for j, name in enumerate(self._internal.parameter_names)}
        )
        self._inputs = np.zeros(len(self._internal.input_names))
        self._u_at, self._e_at = keys.index("u"), keys.index("e")
        # update() calls the kernel itself only where _step is this class's own call
        self._direct = type(self)._step is PilotFilter._step
        self._common: CommonArrays | None = None
        self._resolved: ResolvedSettings | None = None
        # update_block's (records, row, their stack of one, compiled entry) of this reset
        self._block: tuple[Any, Any, Any, Any] | None = None
        # the C port's online step of this reset (_online_native), False where none runs
        self._online: Any = None

    # ----------------------------------------------------------------- access

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The internal model's parameters, in the results' column order."""
        return self._internal.parameter_names

    @property
    def internal_model(self) -> InternalModel:
        """The internal model (f, g) the filter runs on."""
        return self._internal

    def estimated_names(self, dt: float) -> tuple[str, ...]:
        """The parameters a reset at ``dt`` estimates, found on a twin (this one is left as is).

        The rules resolve them at reset: e.g. the single integrator's holds ``K_v``.
        """
        twin = self.configure()
        twin.reset(dt)
        return tuple(twin.resolved.estimated)

    @property
    def resolved(self) -> ResolvedSettings:
        """Numbers resolved at the last :meth:`reset`."""
        if self._resolved is None:
            raise RuntimeError(f"the {type(self).__name__} has not been reset; call reset() first")
        return self._resolved

    def _repr_fields(self) -> Mapping[str, Any]:
        return {"model": self._settings.model, "ce": self._settings.ce}

    # ----------------------------------------------------------------- reset

    def reset(
        self,
        dt: float = 0.01,
        *,
        var_u0: float | None = None,
        var_e0: float | None = None,
        t0: float = 0.0,
    ) -> None:
        """Start from the initial belief.

        Parameters
        ----------
        dt
            Sample time (s) of the samples to come.
        var_u0, var_e0
            Variances of ``u`` and ``e`` over the first ``window`` (Popovici eq. 34):
            required with ``initial_variance="first-window"``, and by the generic
            ``K_p0 = sigma_u/sigma_e`` (eq. 27) when ``initial`` has no ``K_p``.
        t0
            Time of the first sample (s).

        """
        settings = self._settings
        if settings.start != "generic":
            raise ValueError(
                f"start={settings.start!r} fits the whole run's describing function before "
                "the filter starts: offline only (estimate); online give start='generic' "
                "or the values (initial=)"
            )
        dt = check_positive("dt", dt)
        t0 = check_real("t0", t0)
        n_window = round(settings.noise.window / dt)
        if n_window < 1:
            raise ValueError(
                f"window must be at least one sample ({dt:g} s), got {settings.noise.window!r}"
            )
        for name, value in (("var_u0", var_u0), ("var_e0", var_e0)):
            if value is not None:
                check_positive(name, value, allow_zero=True)
        if settings.noise.initial_variance == "first-window" and (var_u0 is None or var_e0 is None):
            raise ValueError(
                "reset needs var_u0 and var_e0 with initial_variance='first-window' (the "
                "variances of u and e over the first window, Popovici eq. 34); "
                "estimate() computes them from the recording"
            )
        internal = self._internal
        resolved = resolve_settings(settings, internal, var_u0, var_e0)
        names = internal.parameter_names
        n_p = len(names)
        parameter_map = ParameterMap.of(settings, internal)
        lo = np.full(n_p, -np.inf)
        hi = np.full(n_p, np.inf)
        for name, (low, high) in resolved.limits.items():
            j = names.index(name)
            lo[j], hi[j] = parameter_map.internal_limits(name, low, high)
        offset, sign = parameter_map.report_transform()
        cfg = np.zeros(core.CFG_SIZE)
        cfg[core.CFG_DT] = dt
        cfg[core.CFG_Q2] = resolved.q2
        cfg[core.CFG_R2] = resolved.r2
        cfg[core.CFG_R2_PARAMETER] = resolved.r2_parameter
        cfg[core.CFG_WINDOW] = n_window
        cfg[core.CFG_FIRST_WINDOW] = (
            1.0 if settings.noise.initial_variance == "first-window" else 0.0
        )
        cfg[core.CFG_FLOOR] = settings.noise.variance_floor
        cfg[core.CFG_JITTER] = settings.guard.jitter
        cfg[core.CFG_MAX_COV] = settings.guard.max_covariance
        cfg[core.CFG_FIXED_R] = settings.noise.fixed_R or 0.0
        cfg[core.CFG_FIXED_QE] = settings.noise.fixed_Q_error or 0.0
        cfg[core.CFG_ERROR_STATE] = internal.input_states[0]
        cfg[core.CFG_GAMMA2] = dt * dt if settings.noise.noise_input == "euler" else 1.0
        sc = np.zeros(core.SC_SIZE)
        sc[core.SC_VAR_U0] = var_u0 if var_u0 is not None else 0.0
        sc[core.SC_VAR_E0] = var_e0 if var_e0 is not None else 0.0
        sc[core.SC_DIV_INDEX] = -1.0
        sc[core.SC_DIV_PARAM] = -1.0
        n_pin = (
            0
            if math.isinf(settings.guard.pinned_time)
            else max(1, round(settings.guard.pinned_time / dt))
        )
        watch = core.PilotMonitor(
            np.full(n_window + 1, np.nan),
            np.full(n_window + 1, np.nan),
            np.zeros(n_p, dtype=np.int64),
            np.zeros((n_p, n_pin), dtype=np.int64),
            np.array([resolved.initial[n] for n in names], dtype=np.float64),  # last reported
            np.zeros(n_p),
            np.zeros(n_p, dtype=np.bool_),
        )
        self._common = CommonArrays(
            cfg=cfg,
            sc=sc,
            monitor=watch,
            report=core.PilotReport(lo, hi, offset, sign),
            p=np.array([parameter_map.internal(n, resolved.initial[n]) for n in names]),
            estimated=np.array([n in resolved.estimated for n in names], dtype=np.bool_),
            parameter_map=parameter_map,
        )
        self._resolved = resolved
        self._start(resolved, self._common)
        self._begin(self._records, dt, t0, resolved.estimated)
        row = self._row
        self._row_views = (row.mean[0], row.std[0], row.scalar[0], row.flag[0], row.pinned[0])
        self._online = None  # bound on the first online sample of this reset

    def _start(self, resolved: ResolvedSettings, common: CommonArrays) -> None:
        raise NotImplementedError

    def _batch_state(self) -> tuple[tuple, Any]:
        """The records and one-row output a batched kernel stacks (after :meth:`reset`)."""
        return self._require_reset(), self._row

    def _new_output(self, n: int, store: bool) -> Any:
        raise NotImplementedError

    def _step(self, inputs: FloatArray, u: float, e: float, out: Any) -> None:
        self._call_step("_step_kernel", (*self._records, inputs, u, e, 0, out))

    def _run(self, inputs: FloatArray, u: FloatArray, e: FloatArray, out: Any) -> None:
        """Every sample in order, sample ``k``'s estimate into row ``k`` of ``out``.

        The C port's run where it runs, else the batched kernel on this filter's records
        and ``out`` as a stack of one (:attr:`_step_many_kernel`).
        """
        native = self._native_records(out)
        if native is not None:
            native.run(inputs, u, e)
            self._native = None  # the binding would keep a whole run's output alive
            return
        from manualcontrol.estimators.filters.batch import one_filter_loop, stack_of_one

        stacked = stack_of_one((self._records, out))
        rows = np.arange(len(u), dtype=np.int64)  # sample k into row k
        type(self)._step_many_kernel(*one_filter_loop(stacked, inputs, u, e, rows))

    # ------------------------------------------------------------------ C ports

    def _call_step(self, kernel: Any, arguments: tuple) -> None:
        """One sample through the C port where it runs, else numba's step (the shell's).

        The online path (``update``, on this filter's own input vector and row, where
        ``_step`` is this class's) then calls the C step directly for the rest of the
        reset (``_entry``, as numba's entry point).
        """
        *_, inputs, u, e, _, out = arguments
        native = self._native_records(out)
        if native is None:
            super()._call_step(kernel, arguments)
            return
        native.step(inputs, u, e)
        if self._direct and inputs is self._inputs and out is self._row:
            self._entry = native.entry(inputs)

    def _native_batch(self, stacked: tuple, out: Any, n: int) -> Any:
        """The C port's batched step over ``n`` stacked filters, or None (numba runs).

        :class:`~manualcontrol.estimators.batch.FilterBatch` steps it where it is given.
        """
        binding = type(self)._native_binding
        lib = None if binding is None else binding.library()
        return None if lib is None else binding.NativeBatch(lib, stacked, out, n)

    def _smoother_inputs(self, out: Any) -> Any:
        raise NotImplementedError

    def _state_traces(self, out: Any) -> tuple[tuple[str, ...], FloatArray | None]:
        return (), None

    # ---------------------------------------------------------------- update

    def update(self, sample: Mapping[str, float]) -> Estimate:
        """Consume one sample and return the estimate after it.

        ``sample`` maps :attr:`sample_keys` (compensatory: ``e``, ``u``; preview:
        ``ft_ahead`` = ``ft(t + tau_a)``, ``y``, ``e``, ``u``) to floats, optionally
        with ``t``. NaN in ``u`` or an input marks a dropped sample.
        """
        return self._estimate_of_row(self._consume(sample))

    def update_plain(self, sample: Mapping[str, float]) -> dict[str, Any]:
        """:meth:`update` as plain data (see the shell's), in one C call where it can be.

        Where the C port runs, a sample given as a plain dict of floats is read, stepped
        and answered by its online step (:mod:`~manualcontrol.estimators._online_native`),
        the same numbers bit for bit; any other goes the checked Python way.
        """
        online = self._online
        if online is None:
            online = self._bind_online()
        if online:  # the C path where it takes the sample (None: not stepped)
            plain = online.plain(sample, self._k)
            if plain is not None:
                self._k += 1
                return plain
        return self._plain_of_row(self._consume(sample))

    def update_quiet(self, sample: Mapping[str, float]) -> float:
        """:meth:`update` without its answer (see the shell's); in one C call where it can be."""
        online = self._online
        if online is None:
            online = self._bind_online()
        if online:
            t = online.quiet(sample, self._k)
            if t is not None:
                self._k += 1
                return t
        return self._consume(sample)

    def _bind_online(self) -> Any:
        """The C port's online step on this reset's records and row, or False (none runs).

        Bound once a reset, on the first online sample, only where what it replaces is
        this class's own: the step (``_direct``), the reading of a sample and the
        building of its answer (a subclass that changes them keeps its Python path);
        where the member's port names its one-sample function (``ONLINE_STEP``); and
        where the port and the online extension are built and take these records.
        """
        self._require_reset()
        self._online = False
        kind = type(self)
        binding = kind._native_binding
        name = getattr(binding, "ONLINE_STEP", None)
        own = (
            kind._consume is PilotFilter._consume
            and kind._plain_of_row is PilotFilter._plain_of_row
            and kind._health_of_row is FilterShell._health_of_row
        )
        if not (self._direct and own) or name is None:
            return False
        native = self._native_records(self._row)
        lib = None if native is None else _online_native.library()
        if lib is None:
            return False
        mean, std, scalar, flag, pinned = self._row_views
        keep: list[Any] = [native, self._row]
        n_p = len(self.parameter_names)
        # the step calls back for the health only when the pins change; through a weak
        # reference, so that the filter and its step are no cycle and go together
        owner = weakref.ref(self)

        def health_of() -> dict[str, Any]:
            return owner()._health_of_row(flag, pinned).as_dict()

        def address(field: str, array: Any, shape: tuple, dtype: Any = np.float64) -> int:
            return array_address(kind.__name__, field, array, shape, keep, dtype)

        try:
            self._online = lib.OnlineStep(
                step=_online_native.function_address(binding.library(), name),
                records=ctypes.addressof(native.struct),
                inputs=address("inputs", self._inputs, (len(self._inputs),)),
                n_inputs=len(self._inputs),
                keys=tuple(self._sample_keys),
                allowed=frozenset(self._allowed_sample_keys),
                u_at=self._u_at,
                e_at=self._e_at,
                mean=address("mean", mean, (n_p,)),
                std=address("std", std, (n_p,)),
                scalar=address("scalar", scalar, (3,)),
                flag=address("flag", flag, (flag.shape[0],), np.bool_),
                pinned=address("pinned", pinned, (n_p,), np.bool_),
                n_flag=flag.shape[0],
                columns=tuple(self._columns),
                health_of=health_of,
                t0=float(self._t0),
                dt=float(self._dt),
                keep=tuple(keep),
            )
        except (TypeError, ValueError):  # a layout the step does not take: Python's path
            self._online = False
        return self._online

    def _plain_of_row(self, t: float) -> dict[str, Any]:
        """:meth:`update_plain`'s answer (see the shell's), from the row views set at reset."""
        mean, std, scalar, flag, pinned = self._row_views
        health = self._health_of_row(flag, pinned)
        prediction, innovation, variance = scalar.tolist()
        columns = self._columns
        return {
            "t": t,
            "mean": dict(zip(columns, mean.tolist(), strict=True)),
            "std": dict(zip(columns, std.tolist(), strict=True)),
            "innovation": innovation,
            "innovation_variance": variance,
            "prediction": prediction,
            "health": health.as_dict(),
        }

    def _consume(self, sample: Mapping[str, float]) -> float:
        """Check one sample and step the filter on it; return its time."""
        self._require_reset()
        values = sample_floats(self._where, sample, self._sample_keys, self._allowed_sample_keys)
        inputs = self._inputs
        for i in range(len(inputs)):
            inputs[i] = values[i]
        u, e = values[self._u_at], values[self._e_at]
        out = self._row
        entry = self._entry
        if entry is None or not self._direct:
            self._step(inputs, u, e, out)
        else:  # what _step calls, without its two Python calls (see _call_step)
            entry(*self._records, inputs, u, e, 0, out)
        t = sample.get("t")
        t = self._t0 + self._k * self._dt if t is None else float(t)
        self._k += 1
        return t

    def update_block(self, values: FloatArray, t: float | None = None) -> float:
        """Consume a block of samples in one compiled call; return the last one's time.

        ``values`` is ``(k, len(sample_keys))``, columns in :attr:`sample_keys` order,
        rows in time order (NaN in ``u`` or an input marks a dropped sample, as in
        :meth:`update`); ``t`` the last sample's time (default: from the reset's ``t0``
        and ``dt``). Each sample goes through the compiled step :meth:`update` calls, in
        order, by the batched loop on this filter's own records as a stack of one
        (:func:`~manualcontrol.estimators.filters.batch.stack_of_one`): the numbers of
        ``k`` calls of :meth:`update`, bit for bit, with one entry into compiled code
        instead of ``k``. The estimate after the last sample is in the row
        (:meth:`latest`, :meth:`latest_plain`). The online observer feeds it the samples
        nobody read an estimate between. A subclass with its own ``_step`` or
        ``_consume`` has them called for every sample, as :meth:`update` calls them (in
        Python, one sample at a time; each sample a dict of :attr:`sample_keys` without
        ``t``).
        """
        reason = self.batchable() if hasattr(self, "batchable") else ""
        if not has_kernel(type(self), "_step_many_kernel") or reason:
            raise ValueError(
                f"{type(self).__name__} cannot step a block of samples in one call: "
                + (reason or "it has no batched step")
            )
        self._require_reset()
        values = np.asarray(values, dtype=np.float64)
        keys = self._sample_keys
        if values.ndim != 2 or values.shape[1] != len(keys):
            raise ValueError(
                f"values must be (k, {len(keys)}): one column per sample key "
                f"{', '.join(map(repr, keys))}, got shape {values.shape}"
            )
        infinite = np.isinf(values)
        if infinite.any():  # NaN marks a dropped sample; inf is a mistake
            row, column = np.argwhere(infinite)[0]
            raise ValueError(f"sample {int(row)} of the block has {keys[column]} infinite")
        k = len(values)
        if not (self._direct and type(self)._consume is PilotFilter._consume):
            t_last = self._t0 + (self._k + k - 1) * self._dt if t is None else float(t)
            for row in values.tolist():
                self._consume(dict(zip(keys, row, strict=True)))
            return t_last
        if k:
            n_inputs = len(self._inputs)
            self._step_block(
                np.ascontiguousarray(values[:, :n_inputs]),
                np.ascontiguousarray(values[:, self._u_at]),
                np.ascontiguousarray(values[:, self._e_at]),
            )
        self._k += k
        return self._t0 + (self._k - 1) * self._dt if t is None else float(t)

    def _step_block(self, inputs: FloatArray, u: FloatArray, e: FloatArray) -> None:
        """Step the filter through the samples in order, in one compiled call, into its row.

        The C port's block where it runs, else the batched kernel on this filter's
        records as a stack of one, every row index 0 (:meth:`update_block`).
        """
        native = self._native_records(self._row)
        if native is not None:
            native.block(inputs, u, e)
            return
        from manualcontrol.estimators.filters.batch import one_filter_loop, stack_of_one

        records = self._records
        block = self._block
        if block is None or block[0] is not records or block[1] is not self._row:
            block = (records, self._row, stack_of_one((records, self._row)), None)
        rows = np.zeros(len(u), dtype=np.int64)  # every sample into the one row
        arguments = one_filter_loop(block[2], inputs, u, e, rows)
        if block[3] is None:
            block = (*block[:3], compiled_entry(type(self)._step_many_kernel, arguments))
        else:
            block[3](*arguments)
        self._block = block

    # -------------------------------------------------------------- estimate

    def signals(
        self,
        recording: Recording,
        *,
        forcing: Any = None,
        target_period: float | None = None,
    ) -> dict[str, FloatArray]:
        """The sample signals :meth:`estimate` feeds the filter (see :meth:`update`)."""
        check_estimable(recording, window=self._settings.noise.window)
        if "u" not in recording:
            raise ValueError("the recording has no control signal u to estimate from")
        if "e" not in recording:
            if "ft" in recording and "y" in recording:
                recording = recording.with_error_signal()
            else:
                raise ValueError("the recording needs the error e (or ft and y to form it)")
        out = {"u": np.asarray(recording.u), "e": np.asarray(recording.e)}
        for name in self._internal.input_names:
            if name == "ft_ahead":
                target = target_function(recording, forcing, target_period)
                tau_a = self._settings.anticipation_time
                out[name] = np.asarray(target(recording.t + tau_a), dtype=np.float64)
            elif name not in out:
                if name not in recording:
                    raise ValueError(
                        f"the recording has no signal {name!r}, which the filter reads"
                    )
                out[name] = np.asarray(recording[name])
        return out

    def estimate(
        self,
        recording: Recording,
        *,
        forcing: Any = None,
        target_period: float | None = None,
        smoother_inputs: bool = False,
        smooth: bool = False,
    ) -> EstimationResult:
        """Run the filter over a recording from a fresh reset.

        Parameters
        ----------
        recording
            Needs ``u`` and ``e`` (or ``ft`` and ``y``); the preview model also ``y``
            and the target ahead of the samples.
        forcing, target_period
            Where the preview model's anticipated target ``ft(t + tau_a)`` comes from:
            the ``forcing`` given (a ForcingPair or callable of time), else
            ``recording.metadata["forcing"]``, else the periodic extension of the
            recorded ``ft`` over ``target_period``; otherwise ``ValueError``.
        smoother_inputs
            Keep what :func:`~manualcontrol.estimators.offline.smoothing.smooth` needs (the
            stored priors, posteriors and links: memory of order ``n`` times the square
            of the state count) in the result.
        smooth
            Return the fixed-interval smoothed result instead of the filtered one.

        With ``restarts`` (settings) the filter runs up to ``restarts + 1`` passes and
        returns the one the likelihood keeps (module docstring, "Restarts"); this
        filter's own state afterwards is the first pass's.
        """
        check_bool("smooth", smooth)
        check_bool("smoother_inputs", smoother_inputs)
        if self._settings.start == "describing-function":
            return self._started_from_describing_function(
                recording,
                forcing=forcing,
                target_period=target_period,
                smoother_inputs=smoother_inputs,
                smooth=smooth,
            )
        signals = self.signals(recording, forcing=forcing, target_period=target_period)
        store = bool(smoother_inputs or smooth)
        restarts = self._settings.restarts
        result = self._pass(recording, signals, store=store or restarts > 0)
        if restarts:
            result = self._restarted(recording, signals, result, store)
        if smooth:
            return smooth_result(result)
        return result

    def _started_from_describing_function(
        self, recording: Recording, **options: Any
    ) -> EstimationResult:
        """The run from the describing-function fit's delay and neuromuscular values."""
        settings = self._settings
        describing = run_describing_function(
            settings,
            recording,
            options.get("forcing"),
            options.get("target_period"),
            f"start={settings.start!r}",
        )
        fit = fit_describing_function(describing, settings.model)
        names = self._internal.parameter_names
        limits = {} if settings.limits == "none" else default_limits(settings, names)
        if isinstance(settings.limits, Mapping):
            limits.update(settings.limits)
        values = {}
        for name in DESCRIBED_START:
            if name in fit.values and name not in settings.initial:
                low, high = limits.get(name, (-math.inf, math.inf))
                values[name] = float(min(max(fit.values[name], low), high))
        started = self.configure(start="generic", initial={**values, **settings.initial})
        result = started.estimate(recording, **options)
        return dataclasses.replace(
            result,
            settings={
                **result.settings,
                "settings": settings.to_dict(),
                "start": {"describing_function": values},
            },
        )

    def _restarted(
        self,
        recording: Recording,
        signals: Mapping[str, FloatArray],
        first: EstimationResult,
        store: bool,
    ) -> EstimationResult:
        """``first`` and ``restarts`` passes after it; the one kept, its record added.

        Every pass runs with the first pass's resolved numbers but the estimated
        parameters' start: its held values, ``P0`` and ``Q`` (the preset's rules derive
        them from the initial values, and the likelihood should compare starts, not
        noise models). A pass that stopped (non-finite values or a covariance blow-up)
        is not chosen, and no pass starts from it.
        """
        resolved = self.resolved
        n_window = round(self._settings.noise.window / recording.dt)

        def terms_of(result: EstimationResult) -> FloatArray:
            """Per-sample costs after the first window (NaN throughout for a stopped pass)."""
            terms = innovation_cost_terms(
                result.innovation[n_window:], result.innovation_variance[n_window:]
            )
            return np.full_like(terms, np.nan) if result.health.stopped else terms

        def cost_of(terms: FloatArray) -> float:
            finite = np.isfinite(terms)
            return float(np.mean(terms[finite])) if finite.any() else math.nan

        def start_of(result: EstimationResult) -> dict[str, float] | None:
            if result.health.stopped:
                return None
            return _restart_point(smooth_result(result), resolved.estimated)

        fixed = {"P0": dict(resolved.P0), "Q": dict(resolved.Q), "restarts": 0}
        starts = [dict(resolved.initial)]
        best_terms = terms_of(first)
        costs = [cost_of(best_terms)]
        finals = [(first.mean[-1], first.std[-1])]
        best, chosen = first, 0
        latest = first
        scores = [math.nan]
        ended = ""
        for number in range(1, self._settings.restarts + 1):
            start = start_of(latest)
            if start is None:
                ended = f"pass {number} stopped or left no finite estimate to start from"
                break
            initial = {**resolved.initial, **start}
            try:
                again = self.configure(initial=initial, **fixed)
                latest = again._pass(recording, signals, store=True)
            except ValueError as error:  # a start the settings refuse (tau_f past tau_a)
                ended = f"pass {number + 1} could not start: {error}"
                break
            starts.append(initial)
            latest_terms = terms_of(latest)
            costs.append(cost_of(latest_terms))
            finals.append((latest.mean[-1], latest.std[-1]))
            score = math.nan
            if math.isfinite(costs[-1]):
                score = paired_cost_evidence(latest_terms, best_terms, block=n_window)
                if best.health.stopped or score < -EVIDENCE:
                    best, best_terms, chosen = latest, latest_terms, number
            scores.append(score)
        record = {
            "chosen": chosen,
            "initial": starts,
            "innovation_cost": [cost if math.isfinite(cost) else None for cost in costs],
            "evidence": [score if math.isfinite(score) else None for score in scores],
            "ended": ended,
        }
        return dataclasses.replace(
            best,
            settings={**best.settings, "settings": self._settings.to_dict(), "restarts": record},
            passes=len(starts),
            pass_mean=np.array([mean for mean, _ in finals]),
            pass_std=np.array([std for _, std in finals]),
            smoother_inputs=best.smoother_inputs if store else None,
        )

    def _pass(
        self, recording: Recording, signals: Mapping[str, FloatArray], store: bool
    ) -> EstimationResult:
        """One filter pass over ``recording`` from a fresh reset (filtered).

        The reset gets the first window's variances where the start reads them: the
        papers' ``initial_variance="first-window"``, or Popovici's generic ``K_p0`` (eq.
        27) where ``initial`` has no ``K_p``. A causal start given its ``K_p`` gets none,
        as online, so the run equals the same filter stepped sample by sample.
        """
        dt = recording.dt
        settings = self._settings
        variances: list[float | None] = [None, None]
        if settings.noise.initial_variance == "first-window" or "K_p" not in settings.initial:
            n_window = round(settings.noise.window / dt)
            first = slice(0, n_window + 1)
            for i, name in enumerate(("u", "e")):
                window = signals[name][first]
                with np.errstate(invalid="ignore"):
                    finite = np.any(np.isfinite(window))
                    variances[i] = float(np.nanvar(window)) if finite else 0.0
        self.reset(dt, var_u0=variances[0], var_e0=variances[1], t0=float(recording.t[0]))
        n = len(recording)
        inputs = np.ascontiguousarray(
            np.column_stack([signals[name] for name in self._internal.input_names])
        )
        out = self._new_output(n, store=store)
        self._run(
            inputs,
            np.ascontiguousarray(signals["u"]),
            np.ascontiguousarray(signals["e"]),
            out,
        )
        self._k = n
        return self._result(np.asarray(recording.t), out, store)

    def _health(self, t: FloatArray, flag: NDArray[np.bool_], pinned: NDArray[np.bool_]) -> Any:
        return health_summary(
            self._common.sc,
            t,
            self._dt,
            flag,
            pinned,
            self._internal.parameter_names,
            self._settings.guard.pinned_time,
        )

    def _result(self, t: FloatArray, out: Any, store: bool) -> EstimationResult:
        state_names, states = self._state_traces(out)
        return self._assemble(
            t,
            out,
            store,
            settings={"settings": self._settings.to_dict(), "resolved": self.resolved.to_dict()},
            state_names=state_names,
            states=states,
        )
