"""Recursive delay identifier (RDI): Boer & Kenyon (1998).

An extended Kalman filter over the coefficients and the fractional, time-varying delay
of an ARMAX model (Sec. III). The coefficients are random walks (eqs. 1a-b), identified
by the EKF of eqs. 2a-b with ``f`` the identity; the model (Sec. III-D, ARMAX(n_a, n_b, 0))
predicts the output ``y`` (e.g. the stick ``u``) from its own past and the input ``r``
(e.g. the error ``e`` or the target ``ft``) read ``d`` seconds back::

    y_hat_n = a_1 y_{n-1} + .. + a_na y_{n-na} + b_0 r(n - d) + .. + b_nb r(n - nb - d)

``theta = [d, a_1 .., a_na, b_0 .., b_nb]``, the delay always first. The default
orders (1, 1) are the paper's ARMAX(1,1,0); ``n_a = 0, n_b = 0`` is the pure gain and
delay ``b_0 r(t - d)`` of its gap-postview and critical-task experiments (Secs. V-VI).
The compiled step is :mod:`~manualcontrol.estimators.members._rdi_core`.

Choices where the paper leaves room or contradicts itself
---------------------------------------------------------
* The delay is a positive lag: ``q^-d`` in the simulation model (Sec. IV-A) but a
  regressor ``r_{n+d}`` in Sec. III-D; we read ``r(t - d)``, so ``dy_hat/dd`` is
  *minus* the sum of ``b_m`` times the input's slope at the delayed instants
  (Sec. III-D's ``H[0]`` with the sign of the lag).
* Sub-sample values and slopes: the Keys cubic-convolution kernel of the Appendix (the
  paper calls it "bilinear" and prints the derivative weights without their signs and
  the ``1/T_s`` factor); see :mod:`manualcontrol.envs._interpolation`.
* Decimation (Sec. III-D): with ``decimation = lambda`` the ARMAX shift is ``lambda``
  samples and the coefficients are corrected every ``lambda`` samples, while the input
  is interpolated on the undecimated series. The delay is held in seconds inside the
  filter, so ``H``'s delay entry is the slope per second; the paper's ``lambda dh/dd``
  (delay in decimated samples) is the same filter in other units. The estimate is held
  over the samples between identification steps (one result row per sample).
* Units of ``Q_d`` and ``P0_d`` (Sec. III-G): squared *decimated* samples
  (``lambda dt`` seconds each) per identification step; ``Q_c``, ``P0_c`` in squared
  coefficient units per step. The paper's ``Q_d = 40 x 0.1^2 = 0.4`` for its
  simulation mixes 600-Hz samples into that sum; we take the 0.4 as given.
* Sign constraints (Sec. III-F), on by default: at an identification step where the
  measured output or its rate (the backward difference over one sample) has the
  opposite sign of the prediction's (at the same ``theta``), the correction is
  skipped and the time update kept. A zero on either side is no disagreement.
* Known coefficients (not in ``estimated``) are removed from the filter and their
  contribution kept in the prediction: Sec. III-E's remedy for the singular ``P + Q``
  a zero ``Q`` entry gives the smoother.
* RTS smoothing (Sec. III-E) is the family's random-walk smoother
  (:mod:`~manualcontrol.estimators.filters.smoothers`) over the identification steps,
  from the *posterior* ``P`` (the paper's stored ``P_n = (I - K H) P_{n-1} + Q`` is the
  next prior; the smoother adds ``Q`` itself). ``smooth=True`` (a setting, because the
  paper used it in some experiments and not others) returns the smoothed result.
* Sample rates: nothing is rescaled with the rate, and what that means differs by
  quantity. The delay ``d`` is in seconds, read at any fractional position of the
  undecimated input (there is no delay grid), and ``delay_limits`` are seconds. The
  ARMAX model is discrete by construction: its coefficients act on shifts of one
  identification step ``lambda dt``, so the same pilot has other ``a_i`` and ``b_m``
  at another rate (a pole at ``-p`` rad/s is ``a_1 = exp(-p lambda dt)``) and only the
  gain-delay model (``n_a = n_b = 0``, ``b_0`` a gain) means the same at every rate;
  runs at two rates compare with equal ``lambda dt`` (the paper's 60 Hz with
  ``lambda = 4`` is 120 Hz with 8) or through their frequency responses. ``Q_c`` and
  ``P0_c`` are per identification step. ``Q_d`` (squared steps, so ``Q_d (lambda
  dt)^2`` s^2 a step) keeps the delay's tracking time, about ``sqrt(R/Q_d)`` over the
  slope term of ``H``, the same at every ``lambda dt`` (``R`` is a sample's variance),
  as the pilot filters' ``Gamma = I dt`` does; ``P0_d``'s start does not (one step is
  17 ms at 60 Hz, 1 ms at 1 kHz). The defaults are the paper's, at 60 Hz.
* The RDI is causal: the prediction at sample ``k`` reads only samples up to ``k``. Near
  the newest sample (delays under two samples) the input is read with the one-sided
  cubic through the last four samples, so a zero delay still has a slope to learn
  from. Negative delays (anticipation, Sec. IV-A's figures) would need the future input
  and are outside ``delay_limits`` (lower limit >= 0).
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._lazy import LazyKernel
from manualcontrol.envs._validation import (
    check_bool,
    check_int,
    check_positive,
    check_real,
)
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators.analysis.metrics import hold_last_finite
from manualcontrol.estimators.filters.kalman import kalman_work
from manualcontrol.estimators.members import _rdi_core as core
from manualcontrol.estimators.members import _rdi_native
from manualcontrol.estimators.offline.smoothing import SmootherBlock, SmootherInputs
from manualcontrol.estimators.protocol import (
    EstimationResult,
    sample_values,
    summarise_health,
)
from manualcontrol.estimators.settings import SettingsRecord
from manualcontrol.estimators.shell import REASONS, FilterShell, output_arrays, trace_arrays

__all__ = ["RDI", "RDISettings", "ResolvedRDI", "parameter_symbols"]

FloatArray = NDArray[np.float64]

_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]*\Z")

#: Default initial values of the symbols: a typical human delay, unit gain, no dynamics.
_DEFAULT_DELAY = 0.2


def parameter_symbols(n_a: int, n_b: int) -> tuple[str, ...]:
    """``("d", "a_1", .., "a_na", "b_0", .., "b_nb")``: the order of ``theta``."""
    return ("d", *(f"a_{i}" for i in range(1, n_a + 1)), *(f"b_{m}" for m in range(n_b + 1)))


def _mapping(name: str, value: Any, convert: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise TypeError(f"{name} must be a mapping of parameter names, got {value!r}")
    out = {}
    for key, item in value.items():
        if not isinstance(key, str):
            raise TypeError(f"{name} keys must be parameter names, got {key!r}")
        out[key] = convert(f"{name}[{key!r}]", item)
    return MappingProxyType(out)


def _signal_name(name: str, value: Any) -> str:
    if not isinstance(value, str) or not _NAME.match(value):
        raise ValueError(f"{name} must be a signal name (letters, digits, '_'), got {value!r}")
    return value


@dataclass(frozen=True)
class RDISettings(SettingsRecord):
    """Settings of the :class:`RDI` (frozen; vary with its ``replace``).

    Parameters
    ----------
    n_a, n_b : int
        ARMAX orders: ``a_1 .. a_na`` on past outputs, ``b_0 .. b_nb`` on the delayed
        input (>= 0; the paper's example (1, 1); (0, 0) is gain and delay).
    decimation : int
        ``lambda`` (>= 1): samples per identification step and per ARMAX shift
        (Sec. III-D; the paper's simulation used 4 at 60 Hz).
    input, output : str
        The recorded signals ``r`` and ``y`` (``"e"`` and ``"u"``: a compensatory
        pilot; ``"ft"`` and ``"u"``: pursuit, postview and the open-loop simulation).
    initial : Mapping[str, float]
        Initial values by symbol (``d`` in s); missing: ``d`` 0.2 s, ``b_0`` 1, the
        others 0.
    estimated : tuple of str or None
        Symbols to estimate (None: all); the others are known, held at ``initial`` and
        removed from the filter (Sec. III-E).
    Q_d, Q_c : float
        Process-noise variances per identification step (>= 0): ``Q_d`` in squared
        decimated samples, ``Q_c`` in squared coefficient units (Sec. III-G).
    R : float
        Measurement-noise variance (> 0), output units squared.
    P0_d, P0_c : float
        Initial variances (> 0), units as ``Q_d`` and ``Q_c``.
    delay_limits : (float, float)
        ``d`` is projected into ``[low, high]`` s, ``0 <= low < high`` (causal reads).
    sign_constraints : bool
        Sec. III-F's holds (module docstring).
    smooth : bool
        :meth:`RDI.estimate` returns the RTS-smoothed result (Sec. III-E).
    report_names : Mapping[str, str]
        Names to report symbols under, e.g. ``{"d": "tau_v", "b_0": "K_p"}`` to compare
        with a gain-delay pilot's parameter traces.
    jitter : float
        Added to the covariance diagonal after each correction (>= 0).
    max_covariance : float
        A variance above this (internal units: s^2 for ``d``) counts as divergence.

    """

    tuple_fields: ClassVar[tuple[str, ...]] = ("estimated", "delay_limits")

    n_a: int = 1
    n_b: int = 1
    decimation: int = 1
    input: str = "e"
    output: str = "u"
    initial: Mapping[str, float] = field(default_factory=dict)
    estimated: tuple[str, ...] | None = None
    Q_d: float = 0.4
    Q_c: float = 1e-6
    R: float = 0.1
    P0_d: float = 1.0
    P0_c: float = 1.0
    delay_limits: tuple[float, float] = (0.0, 1.5)
    sign_constraints: bool = True
    smooth: bool = False
    report_names: Mapping[str, str] = field(default_factory=dict)
    jitter: float = 0.0
    max_covariance: float = 1e8

    def __post_init__(self) -> None:
        object.__setattr__(self, "n_a", check_int("n_a", self.n_a, minimum=0))
        object.__setattr__(self, "n_b", check_int("n_b", self.n_b, minimum=0))
        object.__setattr__(self, "decimation", check_int("decimation", self.decimation, minimum=1))
        _signal_name("input", self.input)
        _signal_name("output", self.output)
        if self.input == self.output:
            raise ValueError(f"input and output must be different signals, both are {self.input!r}")
        symbols = self.symbols
        known = ", ".join(symbols)

        def check_symbols(what: str, keys: Any) -> None:
            unknown = [key for key in keys if key not in symbols]
            if unknown:
                raise ValueError(
                    f"{what}: unknown parameter(s) {', '.join(map(repr, unknown))} for "
                    f"ARMAX({self.n_a}, {self.n_b}); its parameters are {known}"
                )

        initial = _mapping("initial", self.initial, check_real)
        check_symbols("initial", initial)
        object.__setattr__(self, "initial", initial)
        if self.estimated is not None:
            if isinstance(self.estimated, str):
                raise TypeError(
                    f"estimated must be a tuple of parameter names, got {self.estimated!r}"
                )
            estimated = tuple(self.estimated)
            check_symbols("estimated", estimated)
            if len(set(estimated)) != len(estimated):
                raise ValueError(f"estimated names a parameter twice: {estimated}")
            if not estimated:
                raise ValueError("estimated must name at least one parameter (or be None: all)")
            object.__setattr__(self, "estimated", estimated)
        for name in ("Q_d", "Q_c"):
            object.__setattr__(
                self, name, check_positive(name, getattr(self, name), allow_zero=True)
            )
        for name in ("R", "P0_d", "P0_c", "max_covariance"):
            object.__setattr__(self, name, check_positive(name, getattr(self, name)))
        object.__setattr__(self, "jitter", check_positive("jitter", self.jitter, allow_zero=True))
        try:
            low, high = self.delay_limits
        except (TypeError, ValueError):
            raise TypeError(
                f"delay_limits must be a (low, high) pair in s, got {self.delay_limits!r}"
            ) from None
        low = check_positive("delay_limits low", low, allow_zero=True)
        high = check_real("delay_limits high", high)
        if not high > low:
            raise ValueError(f"delay_limits must satisfy low < high, got ({low!r}, {high!r})")
        object.__setattr__(self, "delay_limits", (low, high))
        d0 = self.initial_values["d"]
        if not low <= d0 <= high:
            raise ValueError(
                f"initial d must lie within delay_limits [{low:g}, {high:g}] s, got {d0!r}"
            )
        for name in ("sign_constraints", "smooth"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise TypeError(f"{name} must be True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        names = _mapping("report_names", self.report_names, _signal_name)
        check_symbols("report_names", names)
        reported = [names.get(symbol, symbol) for symbol in symbols]
        if len(set(reported)) != len(reported):
            raise ValueError(f"report_names gives two parameters one name: {reported}")
        object.__setattr__(self, "report_names", names)

    @property
    def symbols(self) -> tuple[str, ...]:
        """The parameter symbols in ``theta`` order."""
        return parameter_symbols(self.n_a, self.n_b)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """The names results report the symbols under (``report_names`` applied)."""
        return tuple(self.report_names.get(symbol, symbol) for symbol in self.symbols)

    @property
    def estimated_symbols(self) -> tuple[str, ...]:
        """The symbols in the filter, in ``theta`` order."""
        chosen = self.symbols if self.estimated is None else self.estimated
        return tuple(symbol for symbol in self.symbols if symbol in chosen)

    @property
    def initial_values(self) -> dict[str, float]:
        """Every symbol's initial value (``initial`` or the default)."""
        values = {symbol: 0.0 for symbol in self.symbols}
        values["d"] = _DEFAULT_DELAY
        values["b_0"] = 1.0
        values.update(self.initial)
        return values


@dataclass(frozen=True)
class ResolvedRDI:
    """What a reset resolved.

    The estimated parameters and every initial value (by their reported names), and the
    numbers in the filter's units (``Q``, ``P0`` in s^2 for the delay, the history length).
    """

    estimated: tuple[str, ...]
    initial: Mapping[str, float]
    numbers: Mapping[str, Any]

    def to_dict(self) -> dict[str, Any]:
        """JSON-able form."""
        return dict(self.numbers)


class RDI(FilterShell):
    """Recursive delay identifier (Boer & Kenyon 1998); see the module docstring.

    Parameters
    ----------
    settings
        An :class:`RDISettings`; keyword arguments replace its fields (or build one).

    Examples
    --------
    >>> import numpy as np
    >>> from manualcontrol.envs.recording import Recording
    >>> t = np.arange(0.0, 20.0, 1 / 60)
    >>> r = np.sin(2.0 * t) + 0.5 * np.sin(5.3 * t)
    >>> u = 1.5 * (np.sin(2.0 * (t - 0.25)) + 0.5 * np.sin(5.3 * (t - 0.25)))
    >>> recording = Recording({"t": t, "e": r, "u": u}, dt=1 / 60)
    >>> rdi = RDI(n_a=0, n_b=0, R=0.01, Q_d=0.01, Q_c=1e-4, initial={"d": 0.15})
    >>> final = rdi.estimate(recording).final()
    >>> round(final["d"], 2), round(final["b_0"], 2)
    (0.25, 1.5)

    """

    name = "rdi"
    settings_type = RDISettings

    #: The binding of this member's C port (envs/_native.py builds it).
    _native_binding = _rdi_native
    #: numba's one-sample step, read only where the C port does not take it.
    _step_kernel = LazyKernel("manualcontrol.estimators.members._rdi_kernels", "rdi_step")

    def __init__(self, settings: RDISettings | None = None, **changes: Any) -> None:
        super().__init__(settings, **changes)
        # the input and the output signal
        self._sample_keys = (self._settings.input, self._settings.output)
        self.outputs = (self._settings.output,)

    @property
    def parameter_names(self) -> tuple[str, ...]:
        """Reported parameter names, in ``theta`` order."""
        return self._settings.parameter_names

    def _repr_fields(self) -> Mapping[str, Any]:
        s = self._settings
        return {"n_a": s.n_a, "n_b": s.n_b, "decimation": s.decimation}

    # ---------------------------------------------------------- run length

    def first_identification(self, dt: float, decimation: int | None = None) -> int:
        """Index of the first sample at which the filter can identify (0-based).

        The compiled step (:func:`~manualcontrol.estimators.members._rdi_core.rdi_step`)
        identifies at sample ``k`` when ``k`` is a multiple of ``decimation``, the
        ``n_a`` past outputs lie in the record (``k >= n_a decimation``) and so does the
        oldest delayed input read with its interpolation stencil (``floor(k - n_b
        decimation - d/dt) >= 1``, with ``d`` the initial delay); a run of fewer than
        this index + 1 samples never corrects its starting values. ``decimation``
        defaults to the setting's.
        """
        dt = check_positive("dt", dt)
        s = self._settings
        lam = s.decimation if decimation is None else check_int("decimation", decimation, minimum=1)
        lag = s.initial_values["d"] / dt

        def identifies(k: int) -> bool:  # the step's test, in the same arithmetic
            return k >= s.n_a * lam and math.floor(k - float(s.n_b) * lam - lag) - 1.0 >= 0.0

        lowest = max(s.n_a * lam, s.n_b * lam + lag + 1.0)
        k = lam * max(math.ceil(lowest / lam) - 1, 0)
        while not identifies(k):
            k += lam
        return k

    def check_length(self, samples: int, dt: float) -> None:
        """Raise ``ValueError`` if ``samples`` at ``dt`` leave no identification step.

        :meth:`estimate` calls it: a run that never identifies would return its
        starting values as the estimate, healthy. The message names ``decimation``, its
        value, the recording's length and the largest decimation the recording allows.
        """
        s = self._settings
        needed = self.first_identification(dt) + 1
        if samples >= needed:
            return
        order = f"ARMAX({s.n_a}, {s.n_b})"
        d0 = s.initial_values["d"]
        largest = self._largest_decimation(samples, dt)
        if largest is None:
            allowed = (
                f"no decimation fits this recording: even decimation = 1 needs "
                f"{self.first_identification(dt, 1) + 1} samples; give a longer recording "
                f"(or a smaller initial d)"
            )
        else:
            allowed = (
                f"the largest decimation this recording allows is {largest} "
                f"(or give a longer recording)"
            )
        raise ValueError(
            f"decimation = {s.decimation} leaves the filter no identification step in a "
            f"recording of {samples} samples (dt = {dt:g} s): {order} from the initial "
            f"delay d = {d0:g} s first identifies at sample index {needed - 1}, so it needs at "
            f"least {needed} samples; {allowed}"
        )

    def _largest_decimation(self, samples: int, dt: float) -> int | None:
        """The largest decimation (below the setting's) that identifies within ``samples``."""
        s = self._settings
        # a decimation identifies no earlier than max(n_a, n_b + 1) decimated samples in
        lam = min(s.decimation - 1, (samples - 1) // max(s.n_a, s.n_b + 1, 1))
        while lam >= 1:
            if self.first_identification(dt, lam) < samples:
                return lam
            lam -= 1
        return None

    # ----------------------------------------------------------------- reset

    @property
    def resolved(self) -> ResolvedRDI:
        """The numbers of the last :meth:`reset` (as the pilot filters report theirs)."""
        self._require_reset()
        names = dict(zip(self._settings.symbols, self.parameter_names, strict=True))
        return ResolvedRDI(
            estimated=self._reported_estimated(),
            initial={names[k]: v for k, v in self._resolved["initial"].items()},
            numbers=dict(self._resolved),
        )

    def _resolve(self, dt: float) -> dict[str, Any]:
        """Every number a run at sample time ``dt`` uses, in the filter's units."""
        s = self._settings
        step = s.decimation * dt
        symbols = s.symbols
        estimated = s.estimated_symbols
        q = [s.Q_d * step * step if name == "d" else s.Q_c for name in estimated]
        p0 = [s.P0_d * step * step if name == "d" else s.P0_c for name in estimated]
        history = math.ceil(s.delay_limits[1] / dt) + s.decimation * max(s.n_a, s.n_b) + 8
        return {
            "dt": dt,
            "identification_step": step,
            "symbols": list(symbols),
            "estimated": list(estimated),
            "initial": s.initial_values,
            "Q": dict(zip(estimated, q, strict=True)),
            "P0": dict(zip(estimated, p0, strict=True)),
            "history_samples": history,
        }

    def reset(self, dt: float = 1.0 / 60.0, *, t0: float = 0.0) -> None:
        """Start from the initial belief for samples ``dt`` seconds apart, the first at ``t0``."""
        s = self._settings
        dt = check_positive("dt", dt)
        t0 = check_real("t0", t0)
        if s.delay_limits[0] + 0.0 < 0.0:  # pragma: no cover - validated in the settings
            raise ValueError("delay_limits low must be >= 0")
        resolved = self._resolve(dt)
        symbols = s.symbols
        estimated = s.estimated_symbols
        n_p, n_s = len(symbols), len(estimated)
        initial = resolved["initial"]
        p = np.array([initial[name] for name in symbols], dtype=np.float64)
        state_param = np.array([symbols.index(name) for name in estimated], dtype=np.int64)
        lo = np.full(n_p, -np.inf)
        hi = np.full(n_p, np.inf)
        lo[0], hi[0] = s.delay_limits
        limit = np.array([0 if name == "d" else -1 for name in estimated], dtype=np.int64)
        cfg = np.zeros(core.CFG_SIZE)
        cfg[core.CFG_DT] = dt
        cfg[core.CFG_LAMBDA] = s.decimation
        cfg[core.CFG_R] = s.R
        cfg[core.CFG_SIGN] = 1.0 if s.sign_constraints else 0.0
        cfg[core.CFG_JITTER] = s.jitter
        cfg[core.CFG_MAX_COV] = s.max_covariance
        cfg[core.CFG_NA] = s.n_a
        cfg[core.CFG_NB] = s.n_b
        config = core.RDIConfig(
            cfg=cfg,
            q=np.array([resolved["Q"][name] for name in estimated], dtype=np.float64),
            state_param=state_param,
            limit=limit,
            lo=lo,
            hi=hi,
        )
        history = resolved["history_samples"]
        sc = np.zeros(core.SC_SIZE)
        sc[core.SC_DIV_INDEX] = -1.0
        belief = core.RDIBelief(
            x=p[state_param].copy(),
            P=np.diag([resolved["P0"][name] for name in estimated]).reshape(n_s, n_s),
            p=p,
            ring_r=np.zeros(history),
            ring_y=np.zeros(history),
            sc=sc,
        )
        scratch = core.RDIScratch(
            H=np.zeros((1, n_s)),
            R=np.zeros((1, 1)),
            r=np.zeros(1),
            work=kalman_work(n_s, 1),
            variance=np.zeros(n_p),
            gradient=np.zeros(n_p),
            flags=np.zeros(6, dtype=np.bool_),
        )
        self._resolved = resolved
        self._begin((config, belief, scratch), dt, t0, self._reported_estimated())

    def _new_output(self, n: int, store: bool) -> core.RDIOutput:
        n_p = len(self._settings.symbols)
        n_s = len(self._settings.estimated_symbols)
        rows = n if store else 0
        return core.RDIOutput(
            **output_arrays(n, n_p, flags=6),
            **trace_arrays(rows, n_s),
        )

    # ---------------------------------------------------------------- update

    def _step_sample(self, sample: Mapping[str, float]) -> None:
        """Step on one sample of the input and output signals.

        NaN in either signal marks a dropped sample: no correction (the input's NaN
        also spoils the predictions that read it, which are then skipped too).
        """
        keys = self._sample_keys
        values = sample_values(self._where, sample, keys, (*keys, "t"))
        self._call_step(
            "_step_kernel", (*self._records, values[keys[0]], values[keys[1]], 0, self._row)
        )

    # The C port of the compiled path (_rdi_native.c) runs wherever it builds: the same
    # numbers bit for bit as the numba kernels, which run elsewhere (envs/_native.py).

    def _run(self, r: FloatArray, y: FloatArray, out: core.RDIOutput) -> None:
        native = self._native_records(out)
        if native is None:
            core.rdi_run(*self._records, r, y, out)
        else:
            native.run(r, y)
            self._native = None  # the binding would keep a whole run's output alive

    def _call_step(self, kernel: Any, arguments: tuple) -> None:
        """One sample through the C port where it runs (else numba's, as the shell does).

        The online path (``update``: the one-row output) then calls the C step directly
        for the rest of the reset (``_entry``, as numba's entry point).
        """
        if self._entry is not None:
            self._entry(*arguments)
            return
        *_, r, y, row, out = arguments
        native = self._native_records(out)
        if native is None:
            super()._call_step(kernel, arguments)
            return
        native.step(r, y, row)
        if out is self._row and row == 0:
            self._entry = native.entry()

    def _reported_estimated(self) -> tuple[str, ...]:
        s = self._settings
        return tuple(s.report_names.get(symbol, symbol) for symbol in s.estimated_symbols)

    # -------------------------------------------------------------- estimate

    def signals(self, recording: Recording) -> tuple[FloatArray, FloatArray]:
        """The input and output series :meth:`estimate` feeds the filter."""
        if not isinstance(recording, Recording):
            raise TypeError(f"recording must be a Recording, got {recording!r}")
        s = self._settings
        for role, name in (("input", s.input), ("output", s.output)):
            if name not in recording:
                if name == "e" and "ft" in recording and "y" in recording:
                    recording = recording.with_error_signal()
                    continue
                raise ValueError(
                    f"the recording has no {role} signal {name!r} (RDISettings.{role}); "
                    f"it has {', '.join(recording.signal_names)}"
                )
        return (
            np.ascontiguousarray(recording[s.input], dtype=np.float64),
            np.ascontiguousarray(recording[s.output], dtype=np.float64),
        )

    def estimate(
        self,
        recording: Recording,
        *,
        smoother_inputs: bool = False,
        smooth: bool | None = None,
    ) -> EstimationResult:
        """Run the RDI over a recording from a fresh reset.

        Parameters
        ----------
        recording
            Holds the ``input`` and ``output`` signals of the settings.
        smoother_inputs
            Keep what :func:`~manualcontrol.estimators.offline.smoothing.smooth` needs.
        smooth
            Return the RTS-smoothed result; None: the ``smooth`` setting.

        Raises ``ValueError`` when the recording is too short for one identification
        step at this ``decimation`` (:meth:`check_length`). Online (:meth:`reset`, then
        :meth:`update`), the estimates before sample :meth:`first_identification` are
        the starting values: the stream's length is not known there, so nothing is
        refused.

        """
        r, y = self.signals(recording)
        if len(recording) < 2:
            raise ValueError(f"the recording must have at least 2 samples, got {len(recording)}")
        self.check_length(len(recording), recording.dt)
        self.reset(recording.dt, t0=float(recording.t[0]))
        smooth = self._settings.smooth if smooth is None else check_bool("smooth", smooth)
        store = bool(smoother_inputs or smooth)
        out = self._new_output(len(recording), store=store)
        self._run(r, y, out)
        self._k = len(recording)
        return self._finish(self._result(np.asarray(recording.t), out, store), smooth)

    def _health(self, t: FloatArray, flag: NDArray[np.bool_], pinned: NDArray[np.bool_]) -> Any:
        sc = self._records[1].sc
        reason = REASONS.get(int(sc[core.SC_DIV_REASON]), "")
        return summarise_health(
            t,
            self._dt,
            flag[:, 2],
            pinned,
            self.parameter_names,
            reason=reason,
            divergence_index=int(sc[core.SC_DIV_INDEX]),
            stopped=bool(reason),
        )

    def _result(self, t: FloatArray, out: core.RDIOutput, store: bool) -> EstimationResult:
        sc = self._records[1].sc
        steps = int(sc[core.SC_STEPS])
        resolved = dict(self._resolved)
        resolved["identification_steps"] = steps
        resolved["held_fraction"] = float(sc[core.SC_HELD]) / steps if steps else 0.0
        return self._assemble(
            t, out, store, settings={"settings": self._settings.to_dict(), "resolved": resolved}
        )

    def _smoother_inputs(self, out: core.RDIOutput) -> Any:

        s = self._settings
        names = self.parameter_names
        config = self._records[0]
        block = SmootherBlock.of_trace(
            "random-walk",
            out,
            None,
            parameters={
                s.report_names.get(symbol, symbol): i
                for i, symbol in enumerate(s.estimated_symbols)
            },
        )
        return SmootherInputs(
            blocks=(block,),
            parameter_names=names,
            report_offset=np.zeros(len(names)),
            report_sign=np.ones(len(names)),
            lower=config.lo.copy(),
            upper=config.hi.copy(),
        )


def resimulate(result: EstimationResult, recording: Recording) -> FloatArray:
    """The identified model's output from the recorded input alone (output error).

    The ARMAX model of ``result`` with its parameter traces, fed back its own past
    outputs instead of the measured ones (so a good one-step prediction with poor
    dynamics shows here), started at rest; the RDI's counterpart of the pilot models'
    isolated-pilot resimulation (thesis eq. 38).
    """
    try:
        settings = RDISettings.from_dict(result.settings["settings"])
    except (KeyError, TypeError) as error:
        raise ValueError(f"the result's settings are not an RDI's: {error}") from None
    if len(result) != len(recording):
        raise ValueError(
            f"result and recording must have the same samples: {len(result)} != {len(recording)}"
        )
    r, _ = RDI(settings).signals(recording)
    p = np.ascontiguousarray(
        np.column_stack([result.mean_of(name) for name in settings.parameter_names])
    )
    held = np.ascontiguousarray(hold_last_finite(r))
    orders = (recording.dt, settings.decimation, settings.n_a, settings.n_b)
    lib = _rdi_native.library()  # the C port where it builds, the same numbers as numba's
    if lib is not None and p.dtype == np.float64 and held.dtype == np.float64:
        return _rdi_native.simulate_output(lib, p, held, *orders)
    return core.simulate_output(p, held, *orders)
