"""Gymnasium environments for compensatory, pursuit and preview tracking tasks.

A participant (or an agent) moves a stick ``u``; the controlled element (CE) turns it
into the output ``y``; a disturbance ``fd`` is added to that output or, with
``disturbance_at="input"``, to the stick before the element (a force on the stick, a
gust); the task is to keep ``y`` on the target ``ft``. The display type decides what is
seen:

==============  ======================================================================
task            observation (float64)
==============  ======================================================================
compensatory    ``[e]``, the tracking error ``e = ft - y``
pursuit         ``[ft, y]``, target and output
preview         ``[ft(t), ft(t + dt), ..., ft(t + tau_p), y]``: the target over the
                preview window (``round(tau_p/dt) + 1`` samples) and the output
==============  ======================================================================

With ``include_rates=True`` the backward-difference rates of the observed signals are
appended (compensatory ``e'``; pursuit ``ft', y'``; preview ``ft'(t), y'``), with
``include_previous_action=True`` the stick of the previous step. Rates are zero on the
first observation.

Stepping: the stick is held over each sample (zero-order hold) and the element is
advanced by its exact discretisation. With the disturbance at the element's output
(``disturbance_at="output"``, default), ``x[k+1] = Phi_k x[k] + Gamma_k u[k]`` and
``y[k] = C_k x[k] + fd[k]``; at its input (``"input"``), the element is driven by the
sum, ``x[k+1] = Phi_k x[k] + Gamma_k (u[k] + fd[k])`` and ``y[k] = C_k x[k]`` (exact for
a time-varying element too: no pre-filtered disturbance). An element with direct
feedthrough, such as a pure gain, shows ``D`` times its previous input (``D u[k-1]``,
or ``D (u[k-1] + fd[k-1])``): the stick reaches the display one frame later. This is
the sampled loop of :func:`manualcontrol.pilots.simulate` (``loop="sampled"``, the same
``disturbance_at``), so a cybernetic pilot acting through
:meth:`~manualcontrol.pilots.Pilot.act` reproduces that simulation. Time is ``t = (k -
n_run_in) dt``: zero at the start of the measurement.

Action: ``Box(-action_bound, action_bound, (1,), float64)``; actions outside are
clipped and counted in ``info["clipped_actions"]``; non-finite actions raise.

Reward (``reward=``): ``"squared_error"`` (default) ``-e^2/var(ft)``;
``"absolute_error"`` ``-|e|/std(ft)``; ``"squared_error_and_effort"``
``-(e^2 + effort_weight u^2)/var(ft)``; ``"bounded"`` ``var(ft)/(var(ft) + e^2)`` in
(0, 1], 1 at zero error (positive, so ending an episode early never pays: use it with a
loss-of-control limit when training agents). ``e`` is the error after the step, the
variance that of the target forcing function (of the disturbance without a target).

Episodes start at rest (all states zero) and are truncated after
``round((run_in + measurement_time)/dt)`` steps. They terminate on loss of control,
``|e| > loss_of_control``, where a limit is given (by default only for an unstable
element such as the critical tracking task: 10 forcing standard deviations). Once an
episode has terminated or been truncated, ``step`` raises ``RuntimeError`` until
:meth:`~TrackingEnv.reset`; the recording ends with the episode's last step (the sample
whose error exceeded the limit is the observation after it, not recorded).

``info`` after each step: ``t, ft, fd, y, e`` of the new observation, the applied
stick ``u``, ``clipped_actions`` so far, and ``element``: the CE parameters at that
step. :meth:`TrackingEnv.recording` returns the episode as a
:class:`~manualcontrol.envs.recording.Recording` (``fd`` as injected; its metadata say
where, ``"disturbance_at"``).

Rendering (``render_mode``): ``"rgb_array"`` returns the participant's display as a
``(400, 600, 3)`` uint8 frame; ``"human"`` shows it in a pygame window. Compensatory:
the error marker moving about a fixed centre; pursuit: target and cursor; preview: the
target track ahead of the cursor over the preview window (time runs up the screen).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, ClassVar, NamedTuple

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.envs.registration import EnvSpec
from numpy.typing import NDArray

from manualcontrol.envs._render import close_window, render_display
from manualcontrol.envs._validation import (
    check_bool,
    check_choice,
    check_duration,
    check_int,
    check_options,
    check_positive,
    clip_action,
    step_action,
)
from manualcontrol.envs.elements import ControlledElement, UnstableFirstOrder, make_element
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import ForcingPair, forcing_preset, preset_realisation_count
from manualcontrol.envs.tasks import (
    DISTURBANCE_POINTS,
    available_preview_for,
    measurement_time_for,
    resolve_forcing,
    sample_counts,
    task_metadata,
    task_named,
)

__all__ = [
    "REWARDS",
    "CompensatoryTracking",
    "LoopState",
    "PreviewTracking",
    "PursuitTracking",
    "TrackingEnv",
]

FloatArray = NDArray[np.float64]

#: Reward choices, see the module docstring.
REWARDS: tuple[str, ...] = (
    "squared_error",
    "absolute_error",
    "squared_error_and_effort",
    "bounded",
)

_SCREEN = (600, 400)
_RESET_OPTIONS = ("realisation",)


class LoopState(NamedTuple):
    """The tracking loop at one sample as the simulation knows it (``TrackingEnv.loop_state``)."""

    #: The element's states, ``TrackingEnv.element_order`` of them.
    element_state: tuple[float, ...]
    #: The element's output ``y`` (with a disturbance at the output, including it).
    output: float
    #: The error ``ft - y``, without any observation noise.
    error: float


class TrackingEnv(gym.Env[FloatArray, FloatArray]):
    """Common machinery of the three tracking tasks; use a subclass.

    Parameters
    ----------
    controlled_element
        Preset name (``"SI"`` 1.5/s, ``"DI"`` 5/s^2, ``"popovici2017"``,
        ``"popovici2017-tv"``, ``"critical-task"``, ...), a transfer function in ``s``
        written as text (``"1/s"``, ``"1/(s(s+1))"``, ``"num=[1]; den=[1, 1, 0]"``: see
        :func:`~manualcontrol.envs.elements.parse_element`), a
        :class:`~manualcontrol.envs.elements.ControlledElement` (parameters may be
        schedules), or its saved dict.
    forcing
        Forcing preset name (``"vanderel-bw4"``, ``"popovici2017"``,
        ``"plaetinck2018"``, ``"schiess-roland1975"``) or a
        :class:`~manualcontrol.envs.signals.ForcingPair`.
    realisation
        Realisation index of a preset, or None to draw one per episode from the
        environment's generator. ``reset(options={"realisation": i})`` picks one for
        a single episode.
    dt
        Sample time (s), default 0.01 (100 Hz).
    measurement_time
        Measured part of an episode (s); default the forcing period ``T_m``.
    run_in
        Run-in before the measurement (s), part of the episode, default 0.
    available_preview
        Preview shown ahead (s), preview task only (default 1 s).
    action_bound
        Stick limit, ``> 0`` (default 10).
    reward, effort_weight
        Reward choice (:data:`REWARDS`) and the stick weight of
        ``"squared_error_and_effort"``.
    include_rates, include_previous_action
        Optional observation extras, off by default.
    loss_of_control
        ``|e|`` beyond which the episode terminates, or None for the default.
    disturbance_at
        Where ``fd`` enters: ``"output"`` (default, added to the element's output) or
        ``"input"`` (added to the stick, driving the element); see Stepping in the
        module docstring.
    render_mode
        None, ``"rgb_array"`` or ``"human"``.

    Attributes
    ----------
    element_order
        Number of the element's states (of its exact discretisation).
    forcing
        The episode's :class:`~manualcontrol.envs.signals.ForcingPair` (before the first
        reset, the pair as given: a preset's realisations share its frequencies).
    """

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["human", "rgb_array"], "render_fps": 100}
    task: ClassVar[str] = ""
    _spec: EnvSpec | None = None

    def __init__(
        self,
        controlled_element: str | ControlledElement | Mapping[str, Any] = "SI",
        forcing: str | ForcingPair = "vanderel-bw4",
        realisation: int | None = 0,
        *,
        dt: float = 0.01,
        measurement_time: float | None = None,
        run_in: float = 0.0,
        available_preview: float | None = None,
        action_bound: float = 10.0,
        reward: str = "squared_error",
        effort_weight: float = 0.0,
        include_rates: bool = False,
        include_previous_action: bool = False,
        loss_of_control: float | None = None,
        disturbance_at: str = "output",
        render_mode: str | None = None,
    ) -> None:
        if not self.task:
            raise TypeError(
                "TrackingEnv is abstract: use CompensatoryTracking, PursuitTracking "
                "or PreviewTracking"
            )
        self.element = make_element(controlled_element)
        forcing_pair = resolve_forcing(forcing)
        self._preset: str | None = forcing if isinstance(forcing, str) else None
        self._realisations = preset_realisation_count(forcing) if self._preset else 1
        if realisation is not None:
            realisation = self.check_realisation(realisation)
        self._forcing = forcing_pair
        # the episode's pair once reset; before, the pair as given (the realisations of
        # a preset share its frequencies and variance)
        self.forcing = forcing_pair
        self.realisation = realisation
        self.dt = check_positive("dt", dt)
        self.measurement_time = measurement_time_for(forcing_pair, measurement_time)
        self.run_in = check_positive("run_in", run_in, allow_zero=True)
        self._display = task_named(self.task)
        self.available_preview = available_preview_for(self.task, available_preview)
        self.action_bound = check_positive("action_bound", action_bound)
        self.reward_kind = check_choice("reward", reward, REWARDS)
        self.effort_weight = check_positive("effort_weight", effort_weight, allow_zero=True)
        self.include_rates = check_bool("include_rates", include_rates)
        self.include_previous_action = check_bool(
            "include_previous_action", include_previous_action
        )
        if loss_of_control is None and isinstance(self.element, UnstableFirstOrder):
            loss_of_control = 10.0 * math.sqrt(self._forcing_variance(forcing_pair))
        self.loss_of_control = (
            None if loss_of_control is None else check_positive("loss_of_control", loss_of_control)
        )
        self.disturbance_at = check_choice("disturbance_at", disturbance_at, DISTURBANCE_POINTS)
        self._disturbance_at_input = disturbance_at == "input"
        if render_mode is not None:
            check_choice("render_mode", render_mode, self.metadata["render_modes"])
        self.render_mode = render_mode

        check_duration("measurement_time", self.measurement_time, self.dt)
        # "human" mode plays one frame per sample, in real time
        self.metadata = {**type(self).metadata, "render_fps": 1.0 / self.dt}
        self.n_run_in, self.episode_steps = sample_counts(
            self.dt, self.run_in, self.measurement_time
        )
        self.preview_window = round(self.available_preview / self.dt) + 1
        self.time_origin = -self.n_run_in * self.dt
        self._time = self.time_origin + np.arange(self.episode_steps + 1) * self.dt
        self._prepare_element()

        bound = self.action_bound
        self.action_space = spaces.Box(-bound, bound, shape=(1,), dtype=np.float64)
        n_obs = self._base_size() + (self._rate_size() if self.include_rates else 0)
        low = np.full(n_obs + self.include_previous_action, -np.inf)
        high = -low
        if self.include_previous_action:
            low[-1], high[-1] = -bound, bound
        self.observation_space = spaces.Box(low, high, dtype=np.float64)
        self._screen = None
        self._clock = None
        self._k = -1
        # why the episode ended (terminated or truncated), None while it runs
        self._ended: str | None = None

    @property
    def spec(self) -> EnvSpec | None:
        """The registration spec; ``max_episode_steps`` is this env's own episode length.

        The length depends on the keywords (run-in + measurement time over dt), so it
        cannot be registered; the env truncates itself and says so here.
        """
        return self._spec

    @spec.setter
    def spec(self, value: EnvSpec | None) -> None:
        if value is not None and value.max_episode_steps is None:
            value = dataclasses.replace(value, max_episode_steps=self.episode_steps)
        self._spec = value

    # ------------------------------------------------------------------ set-up

    @staticmethod
    def _forcing_variance(pair: ForcingPair) -> float:
        signal = pair.target if pair.target is not None else pair.disturbance
        return 1.0 if signal is None else float(signal.variance)

    def _prepare_element(self) -> None:
        """Discretise the element once per distinct parameter set of the episode."""
        element = self.element
        times = self._time
        if element.is_time_varying:
            exact, model = element.discretize(self.dt, times)
            self._element_values = element.parameters_at(times)
        else:
            exact, model = element.discretize(self.dt, 0.0)
            self._element_values = None
        self._phi = exact.phi
        self._gamma = exact.gamma[..., 0]
        self._c = model.C[..., 0, :]
        self._d = model.D[..., 0, 0]
        self.element_order = model.A.shape[-1]
        constant = {
            name: float(value[0]) for name, value in element.parameters_at(np.zeros(1)).items()
        }
        self._constant_info = None if element.is_time_varying else constant
        if not element.is_time_varying:
            self._phi_rows = tuple(tuple(float(v) for v in row) for row in self._phi)
            self._gamma_row = tuple(float(v) for v in self._gamma)
            self._c_row = tuple(float(v) for v in self._c)
            self._d_value = float(self._d)

    @property
    def times(self) -> FloatArray:
        """Time of every observation of an episode, ``t_k = (k - n_run_in) dt`` (read-only)."""
        view = self._time.view()
        view.setflags(write=False)
        return view

    @property
    def sample_index(self) -> int:
        """Index ``k`` of the present observation's sample: ``k`` steps after :meth:`reset`.

        -1 before the first reset.
        """
        return self._k

    def forcing_samples(self) -> tuple[FloatArray, FloatArray]:
        """The episode's target and disturbance at every sample (read-only views).

        Index ``k`` is sample ``k`` of the episode; both run a preview window past its
        last sample (zero where the pair has no such signal). Loop state a display may
        not show: for a critic that reads the forcing ahead (training only), never for
        the operator. Raises ``RuntimeError`` before :meth:`reset`.
        """
        if self._k < 0:
            raise RuntimeError("forcing_samples() needs an episode: call reset() first")
        views = (self._ft.view(), self._fd.view())
        for view in views:
            view.setflags(write=False)
        return views

    def loop_state(self) -> LoopState:
        """The loop's state at the present sample, behind what the display shows.

        The element's states (the exact discretisation's, ``element_order`` of them),
        its output and the error without any observation noise. For a critic that
        reads the hidden state (:class:`~manualcontrol.agents.critic.CriticInformation`),
        never for the operator. Raises ``RuntimeError`` before :meth:`reset`.
        """
        k = self._k
        if k < 0:
            raise RuntimeError("loop_state() needs an episode: call reset() first")
        return LoopState(tuple(self._x), float(self._y[k]), float(self._e[k]))

    def check_realisation(self, realisation: Any) -> int:
        """``realisation`` as a valid index of this environment's forcing, or raise."""
        realisation = check_int("realisation", realisation, minimum=0)
        if realisation >= self._realisations:
            raise ValueError(
                f"realisation must lie in [0, {self._realisations - 1}] for this forcing, "
                f"got {realisation!r}"
            )
        return realisation

    def _base_size(self) -> int:
        display = self._display
        if display.shows_error_only:
            return 1  # e
        return (self.preview_window if display.shows_preview else 1) + 1  # ft (ahead), y

    def _rate_size(self) -> int:
        return 1 if self._display.shows_error_only else 2

    # ------------------------------------------------------------------- API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Start an episode at rest; ``options={"realisation": i}`` picks the realisation."""
        super().reset(seed=seed)
        options = check_options(options, _RESET_OPTIONS)
        realisation = options.get("realisation", self.realisation)
        if realisation is None:
            realisation = int(self.np_random.integers(self._realisations))
        realisation = self.check_realisation(realisation)
        pair = forcing_preset(self._preset, realisation) if self._preset else self._forcing
        self.forcing = pair
        n = self.episode_steps
        ft, fd = pair.sample((n + self.preview_window) * self.dt, self.dt, self.time_origin)
        self._ft = ft
        self._fd = fd
        self._inverse_variance = 1.0 / self._forcing_variance(pair)
        self._inverse_std = math.sqrt(self._inverse_variance)
        self._k = 0
        self._x = [0.0] * self.element_order
        self._u = np.zeros(n)
        self._y = np.zeros(n + 1)
        self._e = np.zeros(n + 1)
        self._previous_u = 0.0
        self._clipped = 0
        self._ended = None
        # at rest: only a disturbance at the output shows before the first step
        y = 0.0 if self._disturbance_at_input else float(fd[0])
        self._y[0] = y
        self._e[0] = float(ft[0]) - y
        observation = self._observe(0)
        if self.render_mode == "human":
            self.render()
        return observation, self._info(0, 0.0)

    def step(self, action: FloatArray) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:
        """Apply the stick ``action[0]`` over one sample; see the module docstring.

        Raises ``RuntimeError`` before :meth:`reset` and after the episode has
        terminated or been truncated.
        """
        k = self._k
        u = step_action(action, k, self._ended)
        bound = self.action_bound
        if not -bound <= u <= bound:
            u = clip_action(u, bound, action)
            self._clipped += 1
        self._u[k] = u
        x = self._x
        # what drives the element: the stick, plus the disturbance where it enters there
        drive = u + float(self._fd[k]) if self._disturbance_at_input else u
        if self._constant_info is not None:
            # plain float loops: for the few states of an element, generator sums cost
            # three times as much (the same additions, in the same order)
            advanced = []
            for row, g in zip(self._phi_rows, self._gamma_row, strict=True):
                acc = 0.0
                for p, v in zip(row, x, strict=True):
                    acc += p * v
                advanced.append(acc + g * drive)
            x = advanced
            acc = 0.0
            for c, v in zip(self._c_row, x, strict=True):
                acc += c * v
            y = acc + self._d_value * drive
        else:
            i = k if self._phi.ndim == 3 else 0
            x = (self._phi[i] @ np.asarray(x) + self._gamma[i] * drive).tolist()
            j = k + 1
            y = float(self._c[j] @ np.asarray(x)) + float(self._d[j]) * drive
        self._x = x
        k += 1
        self._k = k
        if not self._disturbance_at_input:
            y += float(self._fd[k])
        e = float(self._ft[k]) - y
        self._y[k] = y
        self._e[k] = e
        self._previous_u = u
        if self.reward_kind == "squared_error":
            reward = -e * e * self._inverse_variance
        elif self.reward_kind == "absolute_error":
            reward = -abs(e) * self._inverse_std
        elif self.reward_kind == "bounded":
            reward = 1.0 / (1.0 + e * e * self._inverse_variance)
        else:
            reward = -(e * e + self.effort_weight * u * u) * self._inverse_variance
        terminated = self.loss_of_control is not None and abs(e) > self.loss_of_control
        truncated = k >= self.episode_steps
        if terminated or truncated:
            self._ended = self._end_reason(k, terminated, e)
        observation = self._observe(k)
        if self.render_mode == "human":
            self.render()
        return observation, reward, terminated, truncated, self._info(k, u)

    def _end_reason(self, k: int, terminated: bool, e: float) -> str:
        """Why the episode ended after ``k`` steps, for the error of a later ``step``."""
        t = float(self._time[k])
        if not terminated:
            return f"truncated after {k} steps, at t = {t:g} s"
        limit = self.loss_of_control
        return f"terminated at t = {t:g} s: |e| = {abs(e):g} > loss_of_control = {limit:g}"

    def _observe(self, k: int) -> FloatArray:
        display = self._display
        if display.shows_error_only:
            base = [self._e[k]]
            if self.include_rates:
                base.append(0.0 if k == 0 else (self._e[k] - self._e[k - 1]) / self.dt)
        elif not display.shows_preview:  # the target and the output
            base = [self._ft[k], self._y[k]]
            if self.include_rates:
                base += (
                    [0.0, 0.0]
                    if k == 0
                    else [
                        (self._ft[k] - self._ft[k - 1]) / self.dt,
                        (self._y[k] - self._y[k - 1]) / self.dt,
                    ]
                )
        else:
            window = self.preview_window
            extra = (2 if self.include_rates else 0) + self.include_previous_action
            observation = np.empty(window + 1 + extra)
            observation[:window] = self._ft[k : k + window]
            observation[window] = self._y[k]
            if self.include_rates:
                observation[window + 1] = (
                    0.0 if k == 0 else (self._ft[k] - self._ft[k - 1]) / self.dt
                )
                observation[window + 2] = 0.0 if k == 0 else (self._y[k] - self._y[k - 1]) / self.dt
            if self.include_previous_action:
                observation[-1] = self._previous_u
            return observation
        if self.include_previous_action:
            base.append(self._previous_u)
        return np.array(base, dtype=np.float64)

    def _info(self, k: int, u: float) -> dict[str, Any]:
        if self._constant_info is not None:
            element = dict(self._constant_info)
        else:
            element = {name: float(values[k]) for name, values in self._element_values.items()}
        return {
            "t": float(self._time[k]),
            "ft": float(self._ft[k]),
            "fd": float(self._fd[k]),
            "y": float(self._y[k]),
            "e": float(self._e[k]),
            "u": u,
            "clipped_actions": self._clipped,
            "element": element,
        }

    def recording(self, include_run_in: bool = False) -> Recording:
        """The steps taken so far as a Recording (``t, ft, fd, y, e, u``; run-in cut)."""
        steps = self._k
        if steps <= 0:
            raise RuntimeError("no steps taken yet: reset() and step() first")
        start = 0 if include_run_in else min(self.n_run_in, steps - 1)
        window = slice(start, steps)
        parameters = {}
        if self._element_values is not None:
            parameters = {
                f"element_{name}": values[window] for name, values in self._element_values.items()
            }
        return Recording(
            signals={
                "t": self._time[window],
                "ft": self._ft[window],
                "fd": self._fd[window],
                "y": self._y[window],
                "e": self._e[window],
                "u": self._u[window],
            },
            dt=self.dt,
            parameters=parameters,
            metadata={
                **task_metadata(
                    self.task,
                    self.element,
                    self.forcing,
                    self.available_preview,
                    self.run_in,
                    self.measurement_time,
                    self.disturbance_at,
                ),
                "dt": self.dt,
                "clipped_actions": self._clipped,
                "source": f"manualcontrol.envs.tracking.{type(self).__name__}",
            },
        )

    # -------------------------------------------------------------- rendering

    def render(self) -> NDArray[np.uint8] | None:
        """Draw the participant's display (see the module docstring)."""
        return render_display(self, _SCREEN)

    def _draw(self, canvas: Any, pygame: Any) -> None:
        width, height = _SCREEN
        canvas.fill((20, 20, 28))
        scale = 0.4 * width / (3.0 / self._inverse_std)  # 3 std of the forcing to 40 % of the width
        centre = width / 2
        k = max(self._k, 0)
        grey, target_colour, cursor_colour = (90, 90, 100), (240, 200, 60), (80, 200, 255)
        pygame.draw.line(canvas, grey, (centre, 0), (centre, height), 1)
        cursor_row = int(0.8 * height)
        display = self._display
        if display.shows_error_only:
            # a fixed reference bracket; the marker is displaced by the error alone
            row = height // 2
            white = (230, 230, 230)
            for side in (-1, 1):
                pygame.draw.line(
                    canvas, white, (centre + side * 30, row - 25), (centre + side * 30, row + 25), 2
                )
            x = centre + scale * float(self._e[k])
            pygame.draw.line(canvas, cursor_colour, (x - 20, row), (x + 20, row), 4)
            pygame.draw.line(canvas, cursor_colour, (x, row - 20), (x, row + 20), 4)
            return
        y_position = centre + scale * float(self._y[k])
        if not display.shows_preview:  # the target where it is now
            t_position = centre + scale * float(self._ft[k])
            pygame.draw.circle(canvas, target_colour, (int(t_position), cursor_row), 10, 3)
        else:
            window = self.preview_window
            track = self._ft[k : k + window]
            rows = cursor_row - np.arange(window) * (0.75 * height / max(window - 1, 1))
            points = [
                (centre + scale * float(v), float(r)) for v, r in zip(track, rows, strict=True)
            ]
            if len(points) > 1:
                pygame.draw.lines(canvas, target_colour, False, points, 3)
            else:
                pygame.draw.circle(canvas, target_colour, (int(points[0][0]), cursor_row), 10, 3)
        pygame.draw.line(
            canvas, cursor_colour, (y_position - 20, cursor_row), (y_position + 20, cursor_row), 4
        )
        pygame.draw.line(
            canvas, cursor_colour, (y_position, cursor_row - 12), (y_position, cursor_row + 12), 4
        )

    def close(self) -> None:
        """Close the pygame window, if any."""
        close_window(self)


class CompensatoryTracking(TrackingEnv):
    """Compensatory tracking: the display shows only the error ``e = ft - y``.

    See the module docstring of :mod:`manualcontrol.envs.tracking` for spaces, reward,
    termination, ``info`` and arguments. Example::

        >>> import gymnasium as gym
        >>> import manualcontrol.envs
        >>> env = gym.make("ManualControl/CompensatoryTracking-v0", controlled_element="DI")
        >>> observation, info = env.reset(seed=0)
        >>> observation.shape
        (1,)
        >>> observation, reward, terminated, truncated, info = env.step(env.action_space.sample())
        >>> round(info["t"], 2)
        0.01
    """

    task: ClassVar[str] = "compensatory"


class PursuitTracking(TrackingEnv):
    """Pursuit tracking: the display shows the target and the output, no preview.

    Observation ``[ft, y]``; see :mod:`manualcontrol.envs.tracking`.
    """

    task: ClassVar[str] = "pursuit"


class PreviewTracking(TrackingEnv):
    """Preview tracking: the target ahead over ``available_preview`` seconds and the output.

    Observation ``[ft(t), ..., ft(t + available_preview), y]``; see
    :mod:`manualcontrol.envs.tracking`.
    """

    task: ClassVar[str] = "preview"
