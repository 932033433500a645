"""Closed-loop simulation of tracking runs with a cybernetic pilot.

:func:`simulate` turns a :class:`~manualcontrol.pilots.pilot.Pilot`, a controlled
element and a forcing pair into the :class:`~manualcontrol.envs.recording.Recording`
an experiment (or the Gymnasium environments) would produce. The problem it solves
and the loop's block diagram are :mod:`~manualcontrol.pilots.loop`'s.

Discretisation
--------------
The block diagram (pilot channels, delay, controlled element, remnant filter) is
connected into one linear model per sample (thesis Part I eqs. 31-33: the closed loop
in state-space form, parameters frozen over each sample, ``x[k+1] = Phi_k x[k] +
Gamma_k u[k]``):

* ``loop="continuous"`` (default): pilot and controlled element form one continuous
  system, discretised exactly. External inputs (target, previewed target,
  disturbance, remnant noise) are held over each sample. With a Padé delay this is
  the exact zero-order-hold solution of the continuous closed loop, identical to
  ``scipy.signal.lsim(..., interp=False)`` of the analytic closed-loop transfer
  functions (to rounding). With the exact delay (the default), the loop is cut at the
  delay: the delayed signal is read from a delay line by bicubic interpolation and
  taken linear between samples (first-order hold), so its error is second order in
  ``dt``: about ``(omega dt)^2/8`` of a component at ``omega`` rad/s, 2e-5 relative at
  2 rad/s and 100 Hz. Time-varying parameters are frozen over each sample, an error
  of order ``dt`` times their rate of change.
* ``loop="sampled"``: the pilot sees the display only at the samples (its perceptions
  held over each sample) and its control output is sampled and held into the
  controlled element, as in a human-in-the-loop simulator and in the environments.
  Pilot and element are each discretised exactly and connected in discrete time; a
  pilot acting in a :mod:`~manualcontrol.envs.tracking` environment reproduces this
  loop.

Time runs from ``-run_in`` to the measurement time; the run-in is simulated and cut,
so recordings start at ``t = 0`` and parameter schedules are written in that time.

Disturbance
-----------
The disturbance ``fd`` is a junction of the block diagram, not a pre-filtered signal:
with ``disturbance_at="output"`` (default) it is added to the element's output, ``y =
H_c u + fd``; with ``"input"`` to its input, ``y = H_c (u + fd)`` (a force on the
stick, a gust), so the element's state is driven by ``u + fd`` and the run is as exact
for a time-varying element as for a constant one. The recording's ``fd`` is the
disturbance as injected, and its metadata say where (``"disturbance_at"``).
"""

from __future__ import annotations

import contextvars
import dataclasses
import inspect
import math
import warnings
from collections.abc import Callable, Hashable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import (
    check_choice,
    check_positive,
    check_vector,
    reject_unknown,
)
from manualcontrol.envs.dynamics import (
    Block,
    Discretization,
    StateSpace,
    discretize,
    interconnect,
    simulate_lpv,
)
from manualcontrol.envs.elements import ControlledElement
from manualcontrol.envs.recording import MEASURED_SIGNALS, Recording
from manualcontrol.envs.schedules import Schedule
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.envs.tasks import TASKS, resolve_forcing
from manualcontrol.pilots._random import as_generator
from manualcontrol.pilots.loop import (
    LOOP_OUTPUTS,
    SimulationSetup,
    closed_loop,
    continuous_loop,
    discrete_pilot,
    element_sums,
    loop_inputs,
    pilot_diagram,
)
from manualcontrol.pilots.models import PilotModel, make_model
from manualcontrol.pilots.remnant import Remnant
from manualcontrol.pilots.spec import PilotSpec
from manualcontrol.pilots.stability import UnstableLoopWarning, check_growth, check_stable

__all__ = [
    "INITIAL_STATE_SIGNALS",
    "LOOPS",
    "TASKS",
    "SimulationSetup",
    "closed_loop",
    "gain_for_ratio",
    "initial_loop_state",
    "isolated_pilot_output",
    "isolated_pilot_outputs",
    "remnant_power_ratio",
    "simulate",
    "simulate_many",
]

FloatArray = NDArray[np.float64]

LOOPS: tuple[str, ...] = ("continuous", "sampled")
#: Relative deviation of the realised power ratio that triggers a re-calibration
#: (thesis Part II Sec. 4.2.1: "more than 5 %").
POWER_RATIO_TOLERANCE = 0.05


# ------------------------------------------------------------------ discretised loop


@dataclass(frozen=True)
class _Loop:
    """A discretised closed loop ready to be stepped."""

    discretization: Discretization
    C: FloatArray
    D: FloatArray
    inputs: tuple[str, ...]
    outputs: tuple[str, ...]
    delay_inputs: tuple[int, ...]
    delay_outputs: tuple[int, ...]
    held_states: tuple[int, ...] = ()


def distinct_parameter_sets(
    columns: Sequence[FloatArray], n_samples: int
) -> tuple[NDArray[np.int64], NDArray[np.int64] | None]:
    """First sample of each run of equal rows of ``columns`` and the run used at each sample.

    Parameters held over stretches of samples (constants, the flat ends of a sigmoid)
    come in runs, so one loop is built per run; a value that returns after a change
    gets a set of its own. (Sorting the whole table for unique rows cost more than
    the matrices it saved.) The index is None when one set serves every sample.
    """
    if not columns or n_samples <= 1:
        return np.zeros(1, dtype=np.int64), None
    table = np.column_stack(columns)
    changed = np.any(table[1:] != table[:-1], axis=1)
    if not changed.any():
        return np.zeros(1, dtype=np.int64), None
    first = np.concatenate(([0], np.flatnonzero(changed) + 1)).astype(np.int64)
    index = np.concatenate(([0], np.cumsum(changed))).astype(np.int64)
    return first, index


def _assemble(
    setup: SimulationSetup,
    values: Mapping[str, FloatArray],
    element_model: StateSpace,
    remnant: Remnant | None,
    loop: str,
) -> _Loop:
    """Connect and discretise the loop for parameter values with one leading batch axis."""
    model = setup.pilot.model
    inputs = loop_inputs(model, remnant)
    if loop == "continuous":
        diagram = continuous_loop(setup, values, element_model, remnant)
        exact = discretize(diagram.system.A, diagram.system.B, setup.dt, diagram.delay_inputs)
        return _Loop(
            exact,
            diagram.system.C,
            diagram.system.D,
            diagram.inputs,
            diagram.outputs,
            diagram.delay_inputs,
            diagram.delay_outputs,
        )
    # sampled: pilot and element discretised apart, joined in discrete time
    pilot_system, pilot_exact, pilot_delays = discrete_pilot(setup, values, remnant)
    element_exact = discretize(element_model.A, element_model.B, setup.dt, ramp_inputs=())
    pilot_block = Block(
        StateSpace(
            pilot_exact.phi, pilot_exact.gamma, pilot_system.system.C, pilot_system.system.D
        ),
        pilot_system.inputs,
        pilot_system.outputs,
    )
    element_block = Block(
        _display_one_frame_later(
            element_exact.phi, element_exact.gamma, element_model.C, element_model.D
        ),
        ("u_ce",),
        ("x_ce",),
    )
    joined = interconnect(
        [pilot_block, element_block],
        inputs=inputs,
        outputs=LOOP_OUTPUTS,
        sums=element_sums(setup.disturbance_at),
        delays=pilot_delays,
    )
    # The ramp (first-order hold) acts only on the pilot's delayed inputs.
    n_pilot = pilot_exact.phi.shape[-1]
    system = joined.system
    ramp = np.zeros((*system.B.shape[:-2], system.B.shape[-2], system.B.shape[-1]))
    for channel in pilot_delays:
        ramp[..., :n_pilot, joined.inputs.index(channel.target)] = pilot_exact.gamma_ramp[
            ..., :, pilot_system.inputs.index(channel.target)
        ]
    return _Loop(
        Discretization(system.A, system.B, ramp),
        system.C,
        system.D,
        joined.inputs,
        joined.outputs,
        joined.delay_inputs,
        joined.delay_outputs,
        # the pilot perceives the element through the sampled display: held
        tuple(range(n_pilot, system.A.shape[-1])),
    )


def _display_one_frame_later(
    phi: FloatArray, gamma: FloatArray, C: FloatArray, D: FloatArray
) -> StateSpace:
    """The discrete element as the environments step it: feedthrough one frame late.

    An element with direct feedthrough (a pure gain) shows ``D u[k-1]`` at sample ``k``
    in :mod:`manualcontrol.envs.tracking` (the stick reaches the display one frame
    later), so the sampled loop keeps the element's previous input (the stick, plus
    ``fd`` when the disturbance enters there) as an extra state with output ``D``.
    Elements without feedthrough are returned as they are.
    """
    if not np.any(D):
        return StateSpace(phi, gamma, C, D)
    batch = phi.shape[:-2]
    n = phi.shape[-1]
    phi_aug = np.zeros((*batch, n + 1, n + 1))
    phi_aug[..., :n, :n] = phi
    gamma_aug = np.zeros((*batch, n + 1, 1))
    gamma_aug[..., :n, :] = gamma
    gamma_aug[..., n, 0] = 1.0
    C_aug = np.concatenate((C, D), axis=-1)
    return StateSpace(phi_aug, gamma_aug, C_aug, np.zeros_like(D))


def matrix_parameters(setup: SimulationSetup, traces: Mapping[str, FloatArray]) -> list[str]:
    """Parameters that change the loop matrices (delays and preview times are inputs)."""
    model = setup.pilot.model
    skip = {"tau_f", "tau_n"}
    if setup.pilot.delay_order is None:
        skip.add(model.delay_parameter)
    return [name for name in traces if name not in skip]


def _build_loop(
    setup: SimulationSetup,
    traces: Mapping[str, FloatArray],
    remnant: Remnant | None,
    loop: str,
) -> tuple[_Loop, NDArray[np.int64] | None]:
    """Discretise the loop once per distinct set of matrix parameters.

    Returns the loop with a batch axis over the distinct sets and the index of the
    set used at each sample (None when one set serves every sample).
    """
    time = setup.time
    element_traces = setup.element.parameters_at(time)
    names = matrix_parameters(setup, traces)
    first, index = distinct_parameter_sets(
        [traces[name] for name in names] + list(element_traces.values()), len(time)
    )
    values = {name: trace[first] for name, trace in traces.items()}
    element_model = setup.element.state_space(time[first])
    return _assemble(setup, values, element_model, remnant, loop), index


def _run(
    assembled: _Loop,
    index: NDArray[np.int64] | None,
    input_columns: Mapping[str, FloatArray],
    delays: FloatArray | None,
    dt: float,
    x0: FloatArray | None = None,
) -> dict[str, FloatArray]:
    """Step the loop; from a start state ``x0`` the delayed signals' past is their first value."""
    n = len(next(iter(input_columns.values())))
    external = [name for i, name in enumerate(assembled.inputs) if i not in assembled.delay_inputs]
    inputs = np.zeros((n, len(assembled.inputs)))
    for i, name in enumerate(external):
        inputs[:, i] = input_columns[name]

    # every sample its own set (an estimator's traces): the index is 0, 1, ..., n - 1
    # (it rises by 0 or 1 a sample), and a gather would only copy the matrices
    own_sets = index is not None and int(index[-1]) == index.shape[0] - 1

    def expand(array: FloatArray) -> FloatArray:
        if index is None:
            return array[0] if array.ndim == 3 else array
        if own_sets and array.shape[0] == index.shape[0]:
            return array
        return array[index]

    exact = Discretization(*(expand(a) for a in assembled.discretization))
    _, outputs = simulate_lpv(
        exact,
        expand(assembled.C),
        expand(assembled.D),
        inputs,
        dt,
        x0=x0,
        delay_inputs=assembled.delay_inputs,
        delay_outputs=assembled.delay_outputs,
        delays=None
        if not assembled.delay_inputs
        else np.repeat(delays[:, None], len(assembled.delay_inputs), 1),
        held_states=assembled.held_states,
        history="rest" if x0 is None else "initial",
    )
    return {name: outputs[:, i] for i, name in enumerate(assembled.outputs)}


def isolated_pilot_output(
    model: PilotModel | str,
    parameters: Mapping[str, float | FloatArray],
    perceptions: Mapping[str, FloatArray],
    dt: float,
    delay_order: int | None = None,
) -> FloatArray:
    """The pilot model alone, driven by measured perceptions: its modelled stick ``u``.

    The isolated pilot of thesis Fig. 3 / eq. 38: ``perceptions`` holds each of the
    model's perception signals (``e``; or ``ft_far`` and ``y``) sampled at ``dt`` and
    held over each sample; ``parameters`` holds constants or traces of every
    parameter (one value per sample). The delay is exact unless ``delay_order`` asks
    for a Padé approximant. Starts at rest; no remnant.
    """
    return isolated_pilot_outputs(model, parameters, [perceptions], dt, delay_order)[0]


def isolated_pilot_outputs(
    model: PilotModel | str,
    parameters: Mapping[str, float | FloatArray],
    perception_sets: Sequence[Mapping[str, FloatArray]],
    dt: float,
    delay_order: int | None = None,
) -> list[FloatArray]:
    """:func:`isolated_pilot_output` for several sets of perceptions, one model.

    The model with these parameter traces is discretised once (most of the cost: a
    matrix exponential per sample whose parameters changed) and run on each set; the
    outputs equal separate calls bit for bit.
    """
    pilot = PilotSpec(make_model(model), delay_order=delay_order)
    model = pilot.model
    if not perception_sets:
        raise ValueError("perception_sets must hold at least one set of perceptions")
    for perceptions in perception_sets:
        missing = sorted(set(model.perceptions) - set(perceptions))
        if missing:
            raise ValueError(
                f"perceptions must include {', '.join(missing)} for the {model.name} model"
            )
    n = len(next(iter(perception_sets[0].values())))
    lengths = {
        len(np.asarray(signal))
        for perceptions in perception_sets
        for signal in perceptions.values()
    }
    if lengths != {n}:
        raise ValueError(
            f"every perception must have the same samples, got lengths {sorted(lengths)}"
        )
    traces = {}
    for name in model.parameter_names:
        if name not in parameters:
            raise ValueError(f"parameters must include {name!r} for the {model.name} model")
        value = np.asarray(parameters[name], dtype=np.float64)
        traces[name] = np.broadcast_to(value, (n,)).astype(np.float64)
    pilot._check_delay(traces[model.delay_parameter])
    columns = [
        traces[name] for name in traces if name not in (model.delay_parameter, "tau_f", "tau_n")
    ]
    if delay_order is not None:
        columns.append(traces[model.delay_parameter])
    first, index = distinct_parameter_sets(columns, n)
    values = {name: trace[first] for name, trace in traces.items()}
    diagram = pilot_diagram(pilot, values, None, {p: p for p in model.perceptions})
    system = interconnect(
        diagram.blocks,
        inputs=model.perceptions,
        outputs=("u",),
        sums=diagram.sums,
        delays=diagram.delays,
    )
    loop = _Loop(
        discretize(system.system.A, system.system.B, dt, system.delay_inputs),
        system.system.C,
        system.system.D,
        system.inputs,
        system.outputs,
        system.delay_inputs,
        system.delay_outputs,
    )
    delays = traces[model.delay_parameter] if delay_order is None else None
    outputs = []
    for perceptions in perception_sets:
        inputs = {
            name: np.asarray(perceptions[name], dtype=np.float64) for name in model.perceptions
        }
        outputs.append(_run(loop, index, inputs, delays, dt)["u"])
    return outputs


# -------------------------------------------------------------------- power ratio


def remnant_power_ratio(u: FloatArray, u_remnant: FloatArray) -> float:
    """Thesis eq. 6: ``var(u_n)/var(u)`` for the remnant part ``u_n`` of ``u``."""
    return float(np.var(u_remnant) / np.var(u))


def gain_for_ratio(u_forced: FloatArray, u_unit: FloatArray, ratio: float) -> float:
    """Remnant gain ``K`` with ``var(K u_unit) / var(u_forced + K u_unit) = ratio``.

    By linearity the remnant part of ``u`` scales with ``K``; solving
    ``K^2 V_n (1 - P) - 2 P C K - P V_f = 0`` (sample variances ``V``, covariance
    ``C``) gives the positive root. How every simulated loop (tracking and driving)
    meets a requested remnant power ratio ``P_r`` (thesis eq. 6) from a run with the
    forcing alone and one with unit remnant alone.
    """
    forced = u_forced - u_forced.mean()
    unit = u_unit - u_unit.mean()
    v_f, v_n, c = float(forced @ forced), float(unit @ unit), float(forced @ unit)
    if v_n == 0.0:
        raise ValueError("the remnant has no effect on u at this injection point")
    a, b, q = v_n * (1.0 - ratio), -2.0 * ratio * c, -ratio * v_f
    return (-b + math.sqrt(b * b - 4.0 * a * q)) / (2.0 * a)


# ----------------------------------------------------- initial state, measurement noise

#: Loop outputs whose values (and derivatives) may set the initial state.
INITIAL_STATE_SIGNALS: tuple[str, ...] = ("y", "u", "e", "n")


def initial_loop_state(
    setup: SimulationSetup,
    traces: Mapping[str, FloatArray],
    remnant: Remnant | None,
    columns: Mapping[str, FloatArray],
    conditions: Mapping[str, Sequence[float]],
    loop: str = "continuous",
) -> FloatArray:
    """State of the continuous loop at its first sample from output values and derivatives.

    ``conditions[z] = (z, z', z'', ...)`` for loop outputs ``z`` in
    :data:`INITIAL_STATE_SIGNALS`. A run that starts from a state has a past: the
    simulation holds each exactly delayed signal at its first value before the start
    (:func:`~manualcontrol.envs.dynamics.simulate_lpv` with ``history="initial"``), so
    at the start the delayed signal equals its undelayed source, ``C_s x + D_s w_0``.
    With the loop ``x' = A x + B w``, ``z = C x + D w`` and the inputs ``w_0`` held at
    their first samples (remnant noise 0, delay targets as just said, both linear in
    ``x``), the k-th derivative is ``C A^k x + C A^(k-1) B w_0`` (k >= 1) and the value
    ``C x + D w_0``: one linear equation per given entry, solved for ``x``. The entries
    must determine every state exactly once (as many as the loop has states, linearly
    independent).
    """
    if loop != "continuous":
        raise ValueError(
            f"initial_state needs loop='continuous' (its state is solved on the continuous "
            f"loop), got loop={loop!r}"
        )
    if not isinstance(conditions, Mapping):
        raise TypeError(f"initial_state must map signal names to values, got {conditions!r}")
    reject_unknown("initial_state", conditions, INITIAL_STATE_SIGNALS)
    first = {name: trace[:1] for name, trace in traces.items()}
    diagram = continuous_loop(setup, first, setup.element.state_space(setup.time[:1]), remnant)
    system = diagram.system  # one parameter set: drop the batch axis
    A, B, C, D = (m.reshape(m.shape[-2:]) for m in (system.A, system.B, system.C, system.D))
    n_x = A.shape[0]
    # inputs at the start as w_0 = w_c + W_x x: external ones from their first samples,
    # delay targets equal to their sources (which may read the external inputs)
    w_c = np.zeros(len(diagram.inputs))
    W_x = np.zeros((len(diagram.inputs), n_x))
    for i, name in enumerate(diagram.inputs):
        if i not in diagram.delay_inputs and name != "noise":
            w_c[i] = columns[name][0]
    for target, source in zip(diagram.delay_inputs, diagram.delay_outputs, strict=True):
        W_x[target] = C[source]
        w_c[target] = D[source] @ w_c
    rows, rhs = [], []
    for name, values in conditions.items():
        values = check_vector(f"initial_state[{name!r}]", values, min_length=1)
        output = diagram.outputs.index(name)
        power = C[output]
        rows.append(power + D[output] @ W_x)
        rhs.append(values[0] - D[output] @ w_c)
        for derivative in values[1:]:
            forcing = power @ B
            power = power @ A
            rows.append(power + forcing @ W_x)
            rhs.append(derivative - forcing @ w_c)
    M = np.array(rows).reshape(len(rows), n_x)
    rank = np.linalg.matrix_rank(M) if len(rows) else 0
    if len(rows) != n_x or rank != n_x:
        raise ValueError(
            f"initial_state must determine the loop's {n_x} states exactly: it gives "
            f"{len(rows)} values and derivatives of rank {rank}; give each of "
            f"{', '.join(INITIAL_STATE_SIGNALS)} with as many derivatives as its block "
            "has states (e.g. value and rate of y, u and n for a second-order pilot, "
            "element and remnant)"
        )
    return np.linalg.solve(M, np.array(rhs))


def _measurement_noise(noise: Mapping[str, float] | None) -> dict[str, float]:
    """Validated ``{signal: variance}`` in the order of the measured signals."""
    if noise is None:
        return {}
    if not isinstance(noise, Mapping):
        raise TypeError(f"measurement_noise must map signal names to variances, got {noise!r}")
    reject_unknown("measurement_noise", noise, MEASURED_SIGNALS)
    return {
        name: check_positive(f"measurement_noise[{name!r}]", noise[name], allow_zero=True)
        for name in MEASURED_SIGNALS
        if name in noise
    }


# ------------------------------------------------------------------------ simulate


class _SharedWork:
    """What the runs of one :func:`simulate_many` call compute once, by what it depends on.

    Each entry is kept under a key naming everything its computation read that differs
    between those runs: the loop (the pilot's, or its twin at the mean parameter values
    that calibrates the remnant) by the time grid; the forced run of a loop also by the
    forcing realisation; the remnant's run also by the seed. What else a computation
    reads (pilot, element, task, options) is the same for every run of the call.

    The warnings a computation gives (a parameter outside the human range, say) are
    kept with its value and given again to every run that uses it, as each run alone
    would give them.
    """

    def __init__(self) -> None:
        self._kept: dict[Hashable, tuple[Any, list[warnings.WarningMessage]]] = {}

    def get(self, key: Hashable | None, compute: Callable[[], Any]) -> Any:
        """The value kept under ``key``, computed now if it is not; None: never kept."""
        if key is None:
            return compute()
        if key not in self._kept:
            try:
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    value = compute()
            except BaseException:
                _warn_again(caught)  # as the run alone warns before its error
                raise
            self._kept[key] = value, caught
        value, caught = self._kept[key]
        _warn_again(caught)
        return value

    def forget(self, owner: tuple[str, Hashable]) -> None:
        """Drop what no later run needs: the entries of ``owner`` (a :func:`_owner_key`)."""
        for key in [key for key in self._kept if key[1][-1] == owner]:
            del self._kept[key]


def _warn_again(caught: Sequence[warnings.WarningMessage]) -> None:
    """Give recorded warnings again, each as it was (its filters apply now)."""
    for warning in caught:
        warnings.warn(warning.message, warning.category, stacklevel=3)


#: The shared work of the :func:`simulate_many` call this :func:`simulate` belongs to
#: (None outside one: everything is computed for the run alone).
_SHARED: contextvars.ContextVar[_SharedWork | None] = contextvars.ContextVar(
    "shared simulation work", default=None
)


def _keys(
    setup: SimulationSetup, realisation: int, seed: Any, remnant_signal: Any
) -> dict[str, Hashable | None]:
    """The :class:`_SharedWork` keys of one run's loop, forced run and remnant run.

    None where nothing is shared: outside :func:`simulate_many`, and for the remnant
    of a seed that is a generator or None (its noise is its own).
    """
    if _SHARED.get() is None:
        return {"loop": None, "forced": None, "remnant": None}
    grid = (setup.n_samples, float(setup.time[0]), setup.dt)
    if remnant_signal is not None:
        noise: Hashable | None = "signal"  # one signal for every run of the call
    else:
        noise = _seed_key(seed)
    return {
        "loop": grid,
        "forced": (*grid, _owner_key("realisation", realisation)),
        "remnant": None if noise is None else (*grid, noise),
    }


def _owner_key(kind: str, value: Any) -> tuple[str, Hashable]:
    """What ends the key of a realisation's or a seed's shared runs.

    An integer as a Python int, so that ``np.int64(2)`` and ``2`` own the same runs and
    keys compare as plain tuples.
    """
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
        return kind, int(value)
    return kind, value


def _seed_key(seed: Any) -> tuple[str, Hashable] | None:
    """What keys a seed's remnant run: an int seed's value; None for fresh noise."""
    if isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
        return _owner_key("seed", seed)
    return None


def _shared(key: Hashable | None, compute: Callable[[], Any]) -> Any:
    """``compute()``, or what this :func:`simulate_many` call computed under ``key``."""
    work = _SHARED.get()
    return compute() if work is None else work.get(key, compute)


def _tagged(tag: str, key: Hashable | None) -> Hashable | None:
    return None if key is None else (tag, key)


def simulate(
    pilot: PilotSpec,
    element: str | ControlledElement | Mapping[str, Any] = "SI",
    forcing: str | ForcingPair = "vanderel-bw4",
    *,
    realisation: int = 0,
    task: str | None = None,
    available_preview: float | None = None,
    dt: float = 0.01,
    run_in: float = 60.0,
    measurement_time: float | None = None,
    seed: int | np.random.Generator | None = None,
    loop: str = "continuous",
    remnant_signal: Sequence[float] | FloatArray | None = None,
    keep_run_in: bool = False,
    on_unstable: str = "raise",
    gap: float | Schedule | None = None,
    postview: float | None = None,
    loss_of_control: float | None = None,
    start_time: float = 0.0,
    initial_state: Mapping[str, Sequence[float]] | None = None,
    measurement_noise: Mapping[str, float] | None = None,
    disturbance_at: str = "output",
) -> Recording:
    """Simulate a closed-loop tracking run and return its :class:`Recording`.

    Parameters
    ----------
    pilot
        The synthetic pilot (model, schedules, remnant, delay mode).
    element
        Controlled element: preset name, element, or saved dict (default ``"SI"``).
    forcing, realisation
        Forcing preset name and realisation index, or a :class:`ForcingPair`.
    task
        ``"compensatory"``, ``"pursuit"`` or ``"preview"``; defaults to the model's
        (preview models default to ``"preview"``; ``"pursuit"`` shows no preview, so
        ``tau_f`` must be 0).
    available_preview
        Preview shown on the display in a preview task (s, default 1 s); the far and
        near viewpoints must stay within it.
    dt, run_in, measurement_time
        Sample time (s), run-in simulated before ``t = 0`` and cut (default 60 s, as
        the thesis), measurement time (default: the forcing's period ``T_m``).
    seed
        Seed or generator of the remnant noise (the only random input).
    loop
        ``"continuous"`` or ``"sampled"``, see the module docstring.
    remnant_signal
        Instead of the pilot's remnant filter, inject these samples (held over each
        sample; length run-in + measurement) at the pilot remnant's injection point
        (``"output"`` when the pilot has no remnant).
    keep_run_in
        Keep the run-in in the recording (times from ``-run_in``), e.g. to let an
        estimator converge on it as the thesis does; metrics then start at ``t = 0``.
    on_unstable
        A diverging loop (closed-loop poles of a constant pilot and element, else a
        growth check on the run; see :mod:`~manualcontrol.pilots.stability`) raises
        :class:`~manualcontrol.pilots.stability.UnstableLoopError` (``"raise"``,
        default) or warns and sets ``metadata["diverging"]`` to the reason (``"warn"``).
        With ``loss_of_control`` the growth check reads the run up to the loss only.
    gap, postview
        The postview task's gap (s, a number or a schedule; default 0.4) and the past
        track shown (s, default 1), :mod:`manualcontrol.envs.postview`; the recording
        then has the ``gap`` trace among its parameters.
    loss_of_control
        ``|e|`` beyond which the run ends, as in the environments (the recording stops
        before the sample that exceeded it; metadata ``terminated``). None: the run
        goes on to the end (unlike the environments, no default for unstable elements).
    start_time
        Time (s) of the first measured sample (default 0; Schiess & Roland's runs start
        at 0.25 s): recorded times, schedules and forcing all run from it.
    initial_state
        Start the loop (at the first simulated sample) from these values instead of at
        rest: ``{signal: (value, rate, ...)}`` for the loop outputs ``y``, ``u``, ``e``,
        ``n``, each value followed by as many time derivatives as wanted (e.g. Schiess
        & Roland Table I: ``{"y": (c, c'), "u": (delta, delta'), "n": (eta, eta')}``).
        Together they must determine the loop's state uniquely (see
        :func:`initial_loop_state`); continuous loop only.
    measurement_noise
        ``{signal: variance}`` of white Gaussian noise added to the recorded ``y``, ``e``
        or ``u`` after the run (measurement noise: the pilot saw the clean signals;
        Schiess & Roland: 0.00092 V^2 on stick and plant output). Drawn from the same
        generator after the remnant noise, so a seed's remnant is unchanged.
    disturbance_at
        Where ``fd`` enters the loop: ``"output"`` (default, ``y = H_c u + fd``) or
        ``"input"`` (``y = H_c (u + fd)``, e.g. a force on the stick or a gust), see
        the module docstring. The recording's ``fd`` is the disturbance as injected
        and ``metadata["disturbance_at"]`` says where.

    The recording holds ``t, ft, fd, y, e, u, n`` (plus ``ft_far``, the previewed
    target the pilot used, in preview tasks, and ``u_n`` and ``y_n``, the parts of ``u``
    and ``y`` the remnant caused, thesis eq. 6, when there is one: ``u - u_n`` and
    ``y - y_n`` are the remnant-free run), the parameter traces of the pilot, and
    metadata with everything needed to repeat the run, including the calibrated
    remnant gain and the realised remnant power ratio ``P_r`` (thesis eq. 6). When
    the pilot's remnant requests ``P_r``, ``K_r`` is calibrated as in the thesis
    (Part I Sec. IV-D, Part II Sec. 4.2.1): from a linear simulation at the mean
    parameter values, then checked on the time-varying run and re-solved there if the
    ratio is off by more than 5 %.

    """
    setup = SimulationSetup.create(
        pilot,
        element,
        forcing,
        realisation=realisation,
        task=task,
        available_preview=available_preview,
        dt=dt,
        run_in=run_in,
        measurement_time=measurement_time,
        gap=gap,
        postview=postview,
        start_time=start_time,
        disturbance_at=disturbance_at,
    )
    check_choice("loop", loop, LOOPS)
    if loss_of_control is not None:
        loss_of_control = check_positive("loss_of_control", loss_of_control)
    noise_variances = _measurement_noise(measurement_noise)
    rng, seed_used = as_generator(seed)
    x0 = None
    keys = _keys(setup, realisation, seed, remnant_signal)
    # called here when nothing is shared: its warnings point at simulate's caller
    traces = (
        setup.parameter_traces()
        if keys["loop"] is None
        else _shared(_tagged("traces", keys["loop"]), setup.parameter_traces)
    )
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UnstableLoopWarning)
        stable = check_stable(setup, on_unstable=on_unstable)
    sampled, signals = _shared(
        _tagged("forcing", keys["forced"]),
        lambda: (sampled := setup.sampled_forcing(), setup.forcing_signals(traces, sampled)),
    )
    n = setup.n_samples
    remnant = pilot.remnant
    if remnant_signal is not None:
        noise = check_vector("remnant_signal", remnant_signal, length=n)
        remnant = _Passthrough(injection="output" if remnant is None else remnant.injection)
    else:
        noise = rng.standard_normal(n) if remnant is not None else None
    delays = traces[pilot.model.delay_parameter] if pilot.delay_order is None else None
    assembled, index = _shared(
        _tagged("loop", keys["loop"]), lambda: _build_loop(setup, traces, remnant, loop)
    )
    columns = dict(signals)

    def run(forced: bool) -> dict[str, FloatArray]:
        # forced: every input but the remnant's noise; else the noise alone, every input
        # the forcing makes (the target, the disturbance and what the pilot reads of
        # the target: ahead, near, the postview track's edge) at zero
        cols = {name: value if forced else np.zeros(n) for name, value in columns.items()}
        if noise is not None:
            cols["noise"] = np.zeros(n) if forced else noise
        return _run(assembled, index, cols, delays, dt, x0 if forced else None)

    measured = slice(setup.n_run_in, n)
    metadata = setup.metadata()
    metadata.update(
        {"dt": setup.dt, "loop": loop, "seed": seed_used, "delay_order": pilot.delay_order}
    )
    if initial_state is not None:
        x0 = initial_loop_state(setup, traces, remnant, columns, initial_state, loop)
        metadata["initial_state"] = {k: [float(v) for v in vs] for k, vs in initial_state.items()}
    if noise is None:
        outputs = _shared(_tagged("forced", keys["forced"]), lambda: run(True))
    else:
        gain = remnant.K_r
        forced = _shared(_tagged("forced", keys["forced"]), lambda: run(True))
        unit = _shared(_tagged("remnant", keys["remnant"]), lambda: run(False))
        if remnant.P_r is not None and remnant_signal is None:
            gain = _calibrate(
                setup, traces, remnant, noise, columns, sampled, delays, forced, unit, loop, keys
            )
        # the loop is linear and starts at rest: the run with both is their sum (to
        # rounding), one stepping of the loop less
        outputs = {name: forced[name] + gain * unit[name] for name in forced}
        ratio = remnant_power_ratio(outputs["u"][measured], gain * unit["u"][measured])
        remnant_description = (
            remnant.with_gain(gain).to_dict() if remnant_signal is None else "signal"
        )
        metadata.update({"remnant": remnant_description, "remnant_power_ratio": ratio})
    end = n
    if loss_of_control is not None:
        end = _loss_of_control_end(outputs["e"], loss_of_control)
        metadata.update({"loss_of_control": loss_of_control, "terminated": end < n})
        if end <= setup.n_run_in:
            raise ValueError(
                f"control was lost (|e| > {loss_of_control:g}) at t = "
                f"{float(setup.time[end]):g} s, before the measurement started"
            )
    if stable is None:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", UnstableLoopWarning)
            check_growth(
                setup.time[:end],
                outputs["e"][:end],
                float(np.max(np.abs(columns["ft"])) + np.max(np.abs(columns["fd"]))),
                what="the closed loop",
                on_unstable=on_unstable,
            )
    for warning in caught:
        metadata["diverging"] = str(warning.message)
        warnings.warn(warning.message, UnstableLoopWarning, stacklevel=2)
    part = slice(0, end) if keep_run_in else slice(setup.n_run_in, end)
    recorded = {"t": setup.time[part], "ft": columns["ft"][part], "fd": columns["fd"][part]}
    for name in ("y", "e", "u", "n"):
        recorded[name] = outputs[name][part]
    for name in ("ft_far", "ft_near_rate"):
        if name in columns:
            recorded[name] = columns[name][part]
    if noise is not None:
        recorded["u_n"] = gain * unit["u"][part]
        recorded["y_n"] = gain * unit["y"][part]
    parameters = {name: trace[part] for name, trace in traces.items()}
    if setup.gap is not None:
        parameters["gap"] = setup.gap_trace()[part]
    for name, variance in noise_variances.items():
        # drawn for every simulated sample, so the noise does not depend on keep_run_in
        recorded[name] = recorded[name] + math.sqrt(variance) * rng.standard_normal(n)[part]
    if noise_variances:
        metadata["measurement_noise"] = dict(noise_variances)
    return Recording(signals=recorded, dt=setup.dt, parameters=parameters, metadata=metadata)


#: :func:`simulate`'s keywords that :func:`simulate_many` takes for all its runs.
_RUN_OPTIONS: tuple[str, ...] = tuple(
    name
    for name, parameter in inspect.signature(simulate).parameters.items()
    if parameter.kind is inspect.Parameter.KEYWORD_ONLY and name not in ("realisation", "seed")
)


def simulate_many(
    pilot: PilotSpec,
    element: str | ControlledElement | Mapping[str, Any] = "SI",
    forcing: str | ForcingPair = "vanderel-bw4",
    *,
    runs: Sequence[tuple[int, int | None]],
    **options: Any,
) -> Iterator[Recording]:
    """Many runs of one pilot: :func:`simulate` for each ``(realisation, seed)`` of ``runs``.

    A Monte Carlo over forcing realisations and remnant seeds, as a benchmark suite's
    batch or an experiment design runs it. ``options`` are :func:`simulate`'s other
    keywords, the same for every run. The recordings come one at a time, in the order
    of ``runs`` (``list(...)`` for all of them at once), so thousands of runs hold one
    recording in memory, beside the shared runs of the realisations and seeds still to
    come (each dropped after its last run).

    Each recording is bit for bit the one :func:`simulate` returns for its realisation
    and seed; what the runs share is computed once. The loop is linear and starts at
    rest, so a run with remnant is the sum of the loop driven by the forcing alone and
    by the remnant alone. The loop is connected and discretised once for all runs (the
    pilot, the element and the time grid are the same); the forced run is stepped once
    per realisation and the remnant's once per seed (as is the linear loop at the mean
    parameter values that calibrates the remnant's gain). Over 5 realisations and 20
    seeds the loop is stepped 50 times instead of 400. A seed given as None draws
    fresh noise per run, and its remnant run is its own.

    Each pair's realisation and seed are checked when called; ``options`` are checked as
    :func:`simulate` checks them, when the first run is simulated. A run that fails (an
    unstable loop, say) raises from the iteration; the runs before it have been yielded.
    """
    for name in ("realisation", "seed"):
        if name in options:
            raise TypeError(
                f"simulate_many takes each run's realisation and seed in runs, not {name}="
            )
    reject_unknown("simulate_many", options, _RUN_OPTIONS)
    pairs = list(runs) if isinstance(runs, Sequence) and not isinstance(runs, str) else None
    if pairs is None or not all(
        isinstance(pair, (tuple, list)) and len(pair) == 2 for pair in pairs
    ):
        raise TypeError(f"runs must be a sequence of (realisation, seed) pairs, got {runs!r}")
    # each pair checked now, as simulate checks it, not when its turn comes
    resolve_forcing(forcing)
    for i, (realisation, seed) in enumerate(pairs):
        try:
            resolve_forcing(forcing, realisation)
            if not isinstance(seed, np.random.Generator):
                as_generator(seed)
        except (TypeError, ValueError) as error:
            raise type(error)(f"runs[{i}]: {error}") from None
    return _simulations(pilot, element, forcing, pairs, options)


def _simulations(
    pilot: PilotSpec,
    element: str | ControlledElement | Mapping[str, Any],
    forcing: str | ForcingPair,
    pairs: Sequence[Sequence[Any]],
    options: Mapping[str, Any],
) -> Iterator[Recording]:
    work = _SharedWork()
    # the last run that needs each realisation's forced run and each seed's remnant run
    last_of_realisation = {
        _owner_key("realisation", realisation): i for i, (realisation, _) in enumerate(pairs)
    }
    last_of_seed = {_seed_key(seed): i for i, (_, seed) in enumerate(pairs)}
    for i, (realisation, seed) in enumerate(pairs):
        # shared only while this call's own simulate runs: whatever the caller does
        # between two recordings simulates on its own
        token = _SHARED.set(work)
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                recording = simulate(
                    pilot, element, forcing, realisation=realisation, seed=seed, **options
                )
        finally:
            _SHARED.reset(token)
            # each run's warnings, as simulate alone gives them, at the line that
            # iterates (the caller of next())
            for warning in caught:
                warnings.warn(warning.message, warning.category, stacklevel=2)
        if last_of_realisation[owner := _owner_key("realisation", realisation)] == i:
            work.forget(owner)
        if seed_key := _seed_key(seed):
            if last_of_seed[seed_key] == i:
                work.forget(seed_key)
        yield recording


def _loss_of_control_end(e: FloatArray, limit: float) -> int:
    """Samples an environment would have recorded before its loss-of-control end.

    It terminates on the step whose new error exceeds the limit, and that sample is not
    part of its recording.
    """
    beyond = np.flatnonzero(~(np.abs(e[1:]) <= limit))  # NaN or overflow counts too
    return int(beyond[0]) + 1 if beyond.size else int(e.shape[0])


def _calibrate(
    setup: SimulationSetup,
    traces: Mapping[str, FloatArray],
    remnant: Remnant,
    noise: FloatArray,
    columns: Mapping[str, FloatArray],
    sampled: tuple[FloatArray, FloatArray],
    delays: FloatArray | None,
    forced: Mapping[str, FloatArray],
    unit: Mapping[str, FloatArray],
    loop: str,
    keys: Mapping[str, Hashable | None],
) -> float:
    """Remnant gain for the requested power ratio (thesis Part I Sec. IV-D).

    ``keys`` are the run's :func:`_keys`: the linear loop and its runs are shared as
    the time-varying ones are.
    """
    measured = slice(setup.n_run_in, setup.n_samples)
    ratio = float(remnant.P_r)
    if not (setup.pilot.is_time_varying or setup.element.is_time_varying):
        return gain_for_ratio(forced["u"][measured], unit["u"][measured], ratio)
    # Linear simulation at the mean parameter values gives the first gain.
    mean = {name: np.full_like(trace, trace.mean()) for name, trace in traces.items()}
    means = {name: float(trace.mean()) for name, trace in traces.items()}
    linear_pilot = (
        setup.pilot.with_parameters(**means)
        if keys["loop"] is None
        else _shared(
            _tagged("linear pilot", keys["loop"]), lambda: setup.pilot.with_parameters(**means)
        )
    )
    linear_setup = dataclasses.replace(setup, pilot=linear_pilot)
    linear, index = _shared(
        _tagged("linear loop", keys["loop"]),
        lambda: _build_loop(linear_setup, mean, remnant, loop),
    )
    linear_delays = None if delays is None else mean[setup.pilot.model.delay_parameter]
    linear_columns = dict(columns)
    if "ft_far" in columns:
        linear_columns.update(
            _shared(
                _tagged("linear forcing", keys["forced"]),
                lambda: linear_setup.forcing_signals(mean, sampled),
            )
        )
    zero = {name: np.zeros_like(value) for name, value in linear_columns.items()}
    linear_forced = _shared(
        _tagged("linear forced", keys["forced"]),
        lambda: _run(
            linear,
            index,
            {**linear_columns, "noise": np.zeros_like(noise)},
            linear_delays,
            setup.dt,
        ),
    )
    linear_unit = _shared(
        _tagged("linear remnant", keys["remnant"]),
        lambda: _run(linear, index, {**zero, "noise": noise}, linear_delays, setup.dt),
    )
    gain = gain_for_ratio(linear_forced["u"][measured], linear_unit["u"][measured], ratio)
    # Check on the time-varying run; re-solve there when off by more than 5 %.
    realised = remnant_power_ratio(
        forced["u"][measured] + gain * unit["u"][measured], gain * unit["u"][measured]
    )
    if abs(realised - ratio) > POWER_RATIO_TOLERANCE * ratio:
        gain = gain_for_ratio(forced["u"][measured], unit["u"][measured], ratio)
    return gain


@dataclass(frozen=True)
class _Passthrough(Remnant):
    """An injected remnant signal: a static unit 'filter' of the given samples."""

    kind = "signal"

    def shape(self) -> tuple[FloatArray, FloatArray]:
        return np.array([1.0]), np.array([1.0])
