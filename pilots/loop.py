"""The closed loop of a simulation: its validated set-up and its block diagram.

:class:`SimulationSetup` is a simulation problem with every input resolved and checked;
:func:`closed_loop` and :func:`discrete_pilot` connect its pilot, controlled element
and remnant filter (:func:`pilot_diagram`, :func:`continuous_loop`). The simulation
(:mod:`~manualcontrol.pilots.simulation`), the stability checks
(:mod:`~manualcontrol.pilots.stability`) and the controller acting in the
environments all build on it.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import (
    check_choice,
    check_duration,
    check_positive,
    check_real,
)
from manualcontrol.envs.dynamics import (
    Block,
    DelayChannel,
    Discretization,
    Interconnection,
    StateSpace,
    discretize,
    interconnect,
    pade,
    tf_to_ccf,
)
from manualcontrol.envs.elements import ControlledElement, make_element
from manualcontrol.envs.postview import (
    DEFAULT_GAP,
    DEFAULT_POSTVIEW,
    check_gap,
    edge_perceptions,
    postview_samples,
)
from manualcontrol.envs.schedules import Schedule, as_schedule
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.envs.tasks import (
    DISTURBANCE_POINTS,
    available_preview_for,
    check_preview_time,
    measurement_time_for,
    resolve_forcing,
    sample_counts,
    task_metadata,
    task_named,
)
from manualcontrol.pilots.models import CROSSOVER_RANGE, PilotModel, element_gain_ranges
from manualcontrol.pilots.remnant import Remnant
from manualcontrol.pilots.spec import HumanLimitWarning, PilotSpec

__all__ = [
    "LOOP_OUTPUTS",
    "PilotDiagram",
    "SimulationSetup",
    "closed_loop",
    "continuous_loop",
    "discrete_pilot",
    "element_sums",
    "loop_inputs",
    "pilot_diagram",
]

FloatArray = NDArray[np.float64]


def __getattr__(name: str) -> object:
    """The numba kernel ``interpolate_at``, imported on first use (PEP 562).

    :func:`read_preview` reads the target ahead without it, so a simulation never
    imports numba.
    """
    if name == "interpolate_at":
        from manualcontrol.envs._interpolation import interpolate_at

        globals()[name] = interpolate_at
        return interpolate_at
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def read_preview(
    target: FloatArray, positions: FloatArray, window: int
) -> tuple[FloatArray, FloatArray]:
    """Target value and rate at ``positions`` samples ahead, within the visible window.

    Sample ``k`` sees ``target[k : k + window]`` (what a preview display shows);
    reading near its far edge repeats the last visible sample instead of looking
    beyond it, exactly as a pilot reading the display would. Each sample is
    :func:`~manualcontrol.envs._interpolation.interpolate_at` of its window (the
    bicubic read of Boer & Kenyon 1998, Appendix), here for every sample at once in
    numpy: the same IEEE operations in the same order, so the same bytes
    (tests/pilots/test_simulation.py compares them), without numba, whose kernel this
    replaced so that a simulation never imports it.
    """
    positions = np.asarray(positions, dtype=np.float64)
    k = np.arange(positions.shape[0])
    # the last visible sample of each window, relative to its first
    last = np.minimum(window, target.shape[0] - k) - 1
    below = positions <= 0.0
    above = ~below & (positions >= last)
    inside = ~(below | above)
    position = np.where(inside, positions, 0.0)
    n = np.floor(position).astype(np.int64)
    d = position - n
    at = k + n
    before = k + np.maximum(n - 1, 0)
    after = k + np.minimum(n + 1, last)
    second = k + np.minimum(n + 2, last)
    e = 1.0 - d
    weights = (-0.5 * d * e * e, 1.5 * d * d * d - 2.5 * d * d + 1.0)
    weights += (1.5 * e * e * e - 2.5 * e * e + 1.0, -0.5 * d * d * e)
    x = 1.0 + d
    y = 2.0 - d
    slopes = (-1.5 * x * x + 5.0 * x - 4.0, 4.5 * d * d - 5.0 * d)
    slopes += (-(4.5 * e * e - 5.0 * e), -(-1.5 * y * y + 5.0 * y - 4.0))
    samples = (target[before], target[at], target[after], target[second])
    value = weights[0] * samples[0] + weights[1] * samples[1]
    value = value + weights[2] * samples[2] + weights[3] * samples[3]
    slope = slopes[0] * samples[0] + slopes[1] * samples[1]
    slope = slope + slopes[2] * samples[2] + slopes[3] * samples[3]
    value = np.where(below, target[k], np.where(above, target[k + last], value))
    slope = np.where(inside, slope, 0.0)
    return value, slope


@dataclass(frozen=True)
class SimulationSetup:
    """A validated simulation problem: everything :func:`simulate` resolved from its inputs.

    Built by :meth:`create`; :func:`simulate` and the environments use it so that the
    same checks and the same sampled signals serve every loop.
    """

    pilot: PilotSpec
    element: ControlledElement
    forcing: ForcingPair
    task: str
    available_preview: float
    dt: float
    run_in: float
    measurement_time: float
    gap: Schedule | None = None
    postview: float = DEFAULT_POSTVIEW
    start_time: float = 0.0
    disturbance_at: str = "output"

    @classmethod
    def create(
        cls,
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
        gap: float | Schedule | None = None,
        postview: float | None = None,
        start_time: float = 0.0,
        disturbance_at: str = "output",
    ) -> SimulationSetup:
        """Resolve names to objects and check that they fit together.

        ``gap`` and ``postview`` (s) belong to the postview task
        (:mod:`manualcontrol.envs.postview`; defaults 0.4 and 1 s); ``disturbance_at``
        is one of :data:`~manualcontrol.envs.tasks.DISTURBANCE_POINTS`.
        """
        if not isinstance(pilot, PilotSpec):
            raise TypeError(f"pilot must be a Pilot, got {pilot!r}")
        element = make_element(element)
        forcing = resolve_forcing(forcing, realisation)
        model_task = pilot.model.task
        if task is None:
            task = model_task
        display = task_named(task)
        if not display.fits_models_for(task_named(model_task)):
            raise ValueError(
                f"task {task!r} does not fit the {pilot.model.name!r} pilot model, "
                f"which is a {model_task} model"
            )
        if display.shows_postview:
            postview = check_positive(
                "postview", DEFAULT_POSTVIEW if postview is None else postview
            )
            try:
                gap = as_schedule(DEFAULT_GAP if gap is None else gap)
            except TypeError as error:
                raise TypeError(f"gap: {error}") from None
        elif gap is not None or postview is not None:
            raise ValueError(
                f"gap and postview belong to the postview task, not {task!r}; "
                f"got gap={gap!r}, postview={postview!r}"
            )
        else:
            postview = DEFAULT_POSTVIEW
        preview = available_preview_for(task, available_preview)
        dt = check_positive("dt", dt)
        run_in = check_positive("run_in", run_in, allow_zero=True)
        measurement_time = measurement_time_for(forcing, measurement_time)
        check_duration("measurement_time", measurement_time, dt)
        start_time = check_real("start_time", start_time)
        disturbance_at = check_choice("disturbance_at", disturbance_at, DISTURBANCE_POINTS)
        setup = cls(
            pilot,
            element,
            forcing,
            task,
            preview,
            dt,
            run_in,
            measurement_time,
            gap,
            postview,
            start_time,
            disturbance_at,
        )
        if gap is not None:
            check_gap(gap, setup.time, postview)
        return setup

    @property
    def n_run_in(self) -> int:
        """Samples of run-in."""
        return sample_counts(self.dt, self.run_in, self.measurement_time)[0]

    @property
    def n_samples(self) -> int:
        """Samples simulated, run-in included."""
        return sample_counts(self.dt, self.run_in, self.measurement_time)[1]

    @property
    def time(self) -> FloatArray:
        """Simulation times, ``t = start_time`` (default 0) at the start of the measurement."""
        return self.start_time + (np.arange(self.n_samples) - self.n_run_in) * self.dt

    @property
    def preview_window(self) -> int:
        """Target samples visible ahead of the cursor, the current one included."""
        return round(self.available_preview / self.dt) + 1

    def _check_gains(self, traces: Mapping[str, FloatArray]) -> None:
        """Warn where ``K_p`` or ``K_v`` leave the gains humans use on this element."""
        ranges = element_gain_ranges(self.element, float(self.time[0]))
        for name, (low, high) in ranges.items():
            if name not in traces:
                continue
            values = traces[name]
            if np.any(values < low) or np.any(values > high):
                extreme = float(values.min() if np.any(values < low) else values.max())
                warnings.warn(
                    f"pilot parameter {name} = {extreme:g} is outside the gains humans use on "
                    f"the element {self.element.describe()}: [{low:.3g}, {high:.3g}], a "
                    f"crossover between {CROSSOVER_RANGE[0]:g} and {CROSSOVER_RANGE[1]:g} rad/s",
                    HumanLimitWarning,
                    stacklevel=4,
                )

    def parameter_traces(self) -> dict[str, FloatArray]:
        """Pilot parameters at every simulated sample, with the task's constraints checked."""
        traces = self.pilot.parameter_traces(self.time)
        self._check_gains(traces)
        for name in ("tau_f", "tau_n"):
            if name in traces:
                check_preview_time(name, traces[name], self.available_preview, self.task)
        return traces

    def sampled_forcing(self) -> tuple[FloatArray, FloatArray]:
        """``ft`` over the run and the preview window beyond it, and ``fd``."""
        n = self.n_samples
        t0 = self.start_time - self.n_run_in * self.dt
        return self.forcing.sample((n + self.preview_window - 1) * self.dt, self.dt, t0)

    def forcing_signals(
        self,
        traces: Mapping[str, FloatArray],
        sampled: tuple[FloatArray, FloatArray] | None = None,
    ) -> dict[str, FloatArray]:
        """Sampled ``ft`` and ``fd`` and, for preview models, what the pilot reads ahead.

        ``sampled`` is :meth:`sampled_forcing` when already computed (the forcing's
        sines are most of the cost).
        """
        n = self.n_samples
        window = self.preview_window
        target_ahead, fd = self.sampled_forcing() if sampled is None else sampled
        signals = {"ft": target_ahead[:n].copy(), "fd": fd[:n].copy()}
        if "ft_far" in self.pilot.model.perceptions:
            target_ahead = np.ascontiguousarray(target_ahead)
            signals["ft_far"] = read_preview(target_ahead, traces["tau_f"] / self.dt, window)[0]
        if "ft_near_rate" in self.pilot.model.perceptions:
            rates = read_preview(target_ahead, traces["tau_n"] / self.dt, window)[1]
            signals["ft_near_rate"] = rates / self.dt
        if "ft_edge" in self.pilot.model.perceptions:
            # the postview display's rules, as the environment applies them
            time = self.time
            samples = postview_samples(
                self.forcing.target, time, self.gap_trace(), self.dt, self.postview, 3
            )
            signals["ft_edge"], signals["ft_edge_rate"] = edge_perceptions(samples, self.dt)
        return signals

    def gap_trace(self) -> FloatArray:
        """The postview gap at every simulated sample (postview task only)."""
        if self.gap is None:
            raise ValueError(f"a {self.task} task has no gap")
        return check_gap(self.gap, self.time, self.postview)

    def metadata(self) -> dict[str, Any]:
        """What a recording of this setup says about how it was made."""
        shared = task_metadata(
            self.task,
            self.element,
            self.forcing,
            self.available_preview,
            self.run_in,
            self.measurement_time,
            self.disturbance_at,
        )
        postview = (
            {"gap": self.gap.to_dict(), "postview": self.postview} if self.gap is not None else {}
        )
        return {
            "task": shared.pop("task"),
            "pilot": self.pilot.to_dict(),
            **shared,
            **postview,
            "start_time": self.start_time,
        }


# --------------------------------------------------------------------- block diagram


@dataclass(frozen=True)
class PilotDiagram:
    """A pilot's blocks, junctions and delay channels (:func:`pilot_diagram`)."""

    blocks: tuple[Block, ...]
    sums: dict[str, dict[str, float]]
    delays: tuple[DelayChannel, ...]


def pilot_diagram(
    pilot: PilotSpec,
    values: Mapping[str, FloatArray],
    remnant: Remnant | None,
    sources: Mapping[str, str],
) -> PilotDiagram:
    """Blocks and junctions of the pilot, from its perceptions to ``u``.

    ``sources`` names the signal each perception is read from; the remnant ``n``
    enters at its injection point. The model delay is a delay channel ``v_c -> w_c``
    (exact) or a Padé block.
    """
    model = pilot.model
    injection = None if remnant is None else remnant.injection
    seen = {}
    sums: dict[str, dict[str, float]] = {}
    for perception, source in sources.items():
        name = f"{perception}_seen"
        sums[name] = {source: 1.0}
        if injection == "feedback" and perception == "e":
            sums[name]["n"] = -1.0  # e = ft - (y + n)
        if injection == "feedback" and perception == "y":
            sums[name]["n"] = 1.0
        seen[perception] = name
    blocks: list[Block] = []
    delays: list[DelayChannel] = []
    u_terms: dict[str, float] = {}
    for c, channel in enumerate(model.channels(values)):
        v, w, u = f"v{c}", f"w{c}", f"u{c}"
        sums[v] = {}
        for b, branch in enumerate(channel.branches):
            out = f"pre{c}_{b}"
            blocks.append(Block(tf_to_ccf(branch.num, branch.den), (seen[branch.signal],), (out,)))
            sums[v][out] = 1.0
        if injection == "input" and c == 0:
            sums[v]["n"] = 1.0
        if pilot.delay_order is None:
            delays.append(DelayChannel(v, w))
        else:
            tau = values[model.delay_parameter]
            blocks.append(Block(tf_to_ccf(*pade(tau, pilot.delay_order)), (v,), (w,)))
        blocks.append(Block(tf_to_ccf(channel.num, channel.den), (w,), (u,)))
        u_terms[u] = 1.0
    if injection == "output":
        u_terms["n"] = 1.0
    sums["u"] = u_terms
    return PilotDiagram(tuple(blocks), sums, tuple(delays))


def _remnant_block(remnant: Remnant | None) -> list[Block]:
    if remnant is None:
        return []
    return [Block(tf_to_ccf(*remnant.shape()), ("noise",), ("n",))]


#: Outputs of the closed loop's state-space models, in order.
LOOP_OUTPUTS = ("u", "y", "e", "n")


def element_sums(disturbance_at: str) -> dict[str, dict[str, float]]:
    """The junctions around the element block ``u_ce -> x_ce``, and the error.

    The disturbance joins the element's input (``u_ce = u + fd``, ``y = x_ce``) or its
    output (``u_ce = u``, ``y = x_ce + fd``); ``e = ft - y`` either way.
    """
    if disturbance_at == "input":
        return {"u_ce": {"u": 1.0, "fd": 1.0}, "y": {"x_ce": 1.0}, "e": {"ft": 1.0, "y": -1.0}}
    return {"u_ce": {"u": 1.0}, "y": {"x_ce": 1.0, "fd": 1.0}, "e": {"ft": 1.0, "y": -1.0}}


def continuous_loop(
    setup: SimulationSetup,
    values: Mapping[str, FloatArray],
    element_model: StateSpace,
    remnant: Remnant | None,
) -> Interconnection:
    """Pilot, element and remnant filter connected into one continuous loop.

    ``values`` (the pilot's parameters) and ``element_model`` carry one leading batch
    axis; inputs :func:`loop_inputs`, outputs :data:`LOOP_OUTPUTS`. The loop of
    :func:`closed_loop`, of the simulation's continuous loop and of its initial state.
    """
    model = setup.pilot.model
    pilot = pilot_diagram(setup.pilot, values, remnant, {p: p for p in model.perceptions})
    return interconnect(
        [*pilot.blocks, Block(element_model, ("u_ce",), ("x_ce",)), *_remnant_block(remnant)],
        inputs=loop_inputs(model, remnant),
        outputs=LOOP_OUTPUTS,
        sums={
            **pilot.sums,
            **element_sums(setup.disturbance_at),
            **({} if remnant is not None else {"n": {}}),
        },
        delays=pilot.delays,
    )


def loop_inputs(model: PilotModel, remnant: Remnant | None) -> tuple[str, ...]:
    """External inputs of the loop: ``ft, fd``, ``noise`` with a remnant, the previews."""
    forcing_inputs = tuple(p for p in model.perceptions if p not in ("e", "y"))
    noise_input = ("noise",) if remnant is not None else ()
    return ("ft", "fd", *noise_input, *forcing_inputs)


def closed_loop(setup: SimulationSetup, t: float = 0.0) -> Interconnection:
    """The continuous closed loop at time ``t`` as one state-space model.

    Inputs ``ft, fd`` (``fd`` at the element's output or input, as
    ``setup.disturbance_at`` says), ``noise`` (when the pilot has a remnant; unit white
    noise into the remnant filter with its gain ``K_r``) and the pilot's forcing perceptions
    (``ft_far``, ...); outputs ``u, y, e, n``. With the pilot's exact delay the model
    has a delay channel (see :class:`~manualcontrol.envs.dynamics.Interconnection`);
    with a Padé delay it is an ordinary linear model, e.g. for frequency responses.
    """
    values = {name: np.atleast_1d(schedule(t)) for name, schedule in setup.pilot.parameters.items()}
    remnant = setup.pilot.remnant
    loop = continuous_loop(setup, values, setup.element.state_space(np.atleast_1d(t)), remnant)
    if remnant is not None and remnant.K_r != 1.0:
        B = loop.system.B.copy()
        B[..., loop.inputs.index("noise")] *= remnant.K_r
        loop = loop._replace(system=StateSpace(loop.system.A, B, loop.system.C, loop.system.D))
    squeezed = StateSpace(
        *(matrix[0] for matrix in (loop.system.A, loop.system.B, loop.system.C, loop.system.D))
    )
    return loop._replace(system=squeezed)


def discrete_pilot(
    setup: SimulationSetup, values: Mapping[str, FloatArray], remnant: Remnant | None
) -> tuple[Interconnection, Discretization, tuple[DelayChannel, ...]]:
    """The pilot alone, discretised for the sampled loop.

    Inputs: its perceptions, then ``noise`` (when it has a remnant), then the delay
    channel targets; outputs ``u``, ``n``, then the delay channel sources. Perceptions
    and noise are held over each sample; the delayed signals follow
    :func:`~manualcontrol.envs.dynamics.simulate_lpv`. ``values`` carry one leading
    batch axis (one entry per distinct parameter set).
    """
    model = setup.pilot.model
    noise_input = ("noise",) if remnant is not None else ()
    pilot = pilot_diagram(setup.pilot, values, remnant, {p: p for p in model.perceptions})
    system = interconnect(
        [*pilot.blocks, *_remnant_block(remnant)],
        inputs=(*model.perceptions, *noise_input),
        outputs=("u", "n"),
        sums={**pilot.sums, **({} if remnant is not None else {"n": {}})},
        delays=pilot.delays,
    )
    exact = discretize(system.system.A, system.system.B, setup.dt, system.delay_inputs)
    return system, exact, pilot.delays
