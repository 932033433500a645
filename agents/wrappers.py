"""Wrappers that give an agent the limitations of a human operator.

They pose the human's problem of the optimal control model (Kleinman, Baron & Levison
1970): a perception delay, a neuromuscular lag, observation and motor noise scaled to
the variance of the signals they perturb, and a cost on the rate of control. Each
wrapper acts on the stick (action), the display (observation) or the reward of a
:mod:`~manualcontrol.envs.tracking` (or lane-keeping) environment, validates its
arguments, and stacks with the others in any order:

=====================  ================================================  =====================
wrapper                limitation                                        appended observation
=====================  ================================================  =====================
:class:`ActionDelay`   perception/processing delay: the stick follows    the latest
                       the command ``delay`` seconds late (exact,        ``ceil(max delay/dt)``
                       fractional)                                       commands (optional)
:class:`Neuromuscular  second-order arm/stick dynamics                   stick position and
Filter`                ``omega^2/(s^2 + 2 zeta omega s + omega^2)``      rate
:class:`MotorNoise`    remnant: Levison-filtered white noise on the      nothing (see class)
                       stick at a requested power ratio
:class:`Observation    noisy perception of the display, scaled to each   nothing
Noise`                 signal's variance (OCM, -20 dB) or absolute
:class:`EffortCost`    reward ``-w (du/dt)^2 - r u^2`` of the applied    nothing
                       stick (the OCM's cost on control rate)
:class:`Observation    memory: the last ``length`` observations, so      ``length - 1`` earlier
History`               that a feed-forward policy can adapt              observations
:class:`Efference      the agent's own last command, which a human's     the last command
Copy`                  motor system knows (so that a policy can
                       integrate: lag equalisation on a pure gain)
=====================  ================================================  =====================

Schedules
---------
Every limitation parameter (``delay``, ``omega_nms``, ``zeta_nms``, ``power_ratio``,
``omega_r``, ``ratio``, ``std``, ``rate_weight``, ``stick_weight``) is a number or a
schedule of :mod:`manualcontrol.envs.schedules` (a :class:`~manualcontrol.envs.schedules.
Schedule`, or its saved dict as in a configuration file), the same objects a
:class:`~manualcontrol.pilots.Pilot`'s parameters take. A schedule is a function of the
environment's time ``t_k = times[k]`` (zero at the end of the run-in, negative during
it; ``env.unwrapped.times``), where ``k`` counts the steps since ``reset()``: a reset
restarts it. A parameter is held over each sample at its value at the sample's start,
like the stick. Schedules are evaluated once, on the episode's whole time grid, when
the wrapper is built, and every value is checked there: a value outside the allowed
range raises ``ValueError`` naming the argument, the value, the time and the range.

Hidden state
------------
What a wrapper holds that the agent does not observe (a hidden delay queue, the noise
filters' states, the effort cost's last stick) it reports as ``hidden_size`` numbers by
``hidden_state()``: the loop's state behind the display, for a critic that may read it
in training (:class:`~manualcontrol.agents.critic.CriticInformation`). The policy never
reads it.

Noise
-----
The noise wrappers draw from a :class:`numpy.random.Generator` of their own, seeded at
every ``reset()`` from the environment's generator (``env.np_random``), so
``reset(seed=s)`` reproduces an episode's noise exactly, different seeds give
independent realisations, and stacked noise wrappers draw independent streams. The
policy never draws noise: a trained agent acts with its mean action, and its
variability from trial to trial is the wrappers' noise.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Callable, Mapping
from typing import Any

import gymnasium as gym
import numba
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from manualcontrol.envs._validation import (
    check_bool,
    check_choice,
    check_int,
    check_positive,
    check_range,
)
from manualcontrol.envs.dynamics import discretize
from manualcontrol.envs.schedules import Schedule

__all__ = [
    "WRAPPERS",
    "ActionDelay",
    "EfferenceCopy",
    "EffortCost",
    "MotorNoise",
    "NeuromuscularFilter",
    "ObservationHistory",
    "ObservationNoise",
    "ObservationScale",
    "apply_wrappers",
]

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def _block_sum(values: FloatArray, start: int, count: int) -> float:
    """The sum numpy makes of at most 128 values: eight interleaved partial sums (fewer: a loop)."""
    if count < 8:
        total = 0.0
        for i in range(count):
            total += values[start + i]
        return total
    partial = values[start : start + 8].copy()
    i = 8
    while i < count - count % 8:
        for j in range(8):
            partial[j] += values[start + i + j]
        i += 8
    total = ((partial[0] + partial[1]) + (partial[2] + partial[3])) + (
        (partial[4] + partial[5]) + (partial[6] + partial[7])
    )
    while i < count:
        total += values[start + i]
        i += 1
    return total


@numba.njit(cache=True)
def _pairwise_sum(values: FloatArray) -> float:
    """The pairwise summation numpy's ``add.reduce`` does, step for step (bit-identical).

    numpy halves a run longer than 128 at a multiple of eight and adds the two halves'
    sums; written here with an explicit stack (numba cannot cache recursive kernels).
    """
    starts = np.empty(64, dtype=np.int64)
    counts = np.empty(64, dtype=np.int64)
    stages = np.zeros(64, dtype=np.int64)
    sums = np.empty(64)
    depth, stored = 1, 0
    starts[0], counts[0] = 0, values.shape[0]
    while depth:
        top = depth - 1
        start, count = starts[top], counts[top]
        half = count // 2
        half -= half % 8
        if count <= 128:
            sums[stored] = _block_sum(values, start, count)
            stored += 1
            depth -= 1
        elif stages[top] == 0:  # left half first
            stages[top] = 1
            starts[depth], counts[depth], stages[depth] = start, half, 0
            depth += 1
        elif stages[top] == 1:  # then the right half
            stages[top] = 2
            starts[depth], counts[depth], stages[depth] = start + half, count - half, 0
            depth += 1
        else:  # both done: left + right
            stored -= 1
            sums[stored - 1] = sums[stored - 1] + sums[stored]
            depth -= 1
    return sums[0]


@numba.njit(cache=True)
def _population_variance(values: FloatArray) -> float:
    """``np.var(values)`` with numpy's own operations in numpy's order (bit-identical).

    np.var on a 500-sample window cost ~12 us of Python per step; this is ~1 us.
    """
    count = values.shape[0]
    mean = _pairwise_sum(values) / count
    squares = np.empty(count)
    for i in range(count):
        deviation = values[i] - mean
        squares[i] = deviation * deviation
    return _pairwise_sum(squares) / count


def _dt(env: gym.Env) -> float:
    dt = getattr(env.unwrapped, "dt", None)
    if dt is None:
        raise TypeError(
            f"{type(env.unwrapped).__name__} has no sample time dt: wrap a tracking environment"
        )
    return float(dt)


def _stick_bound(env: gym.Env) -> float:
    return float(np.max(np.abs(env.action_space.high)))


def _extend_box(space: spaces.Space, low: FloatArray, high: FloatArray) -> spaces.Box:
    if not isinstance(space, spaces.Box) or len(space.shape) != 1:
        raise TypeError(f"observation space must be a 1-D Box, got {space}")
    return spaces.Box(
        np.concatenate([space.low, low]), np.concatenate([space.high, high]), dtype=np.float64
    )


def _command(action: Any, bound: float) -> float:
    value = float(np.asarray(action, dtype=np.float64).reshape(-1)[0])
    if not math.isfinite(value):
        raise ValueError(f"action must be finite, got {action!r}")
    return min(max(value, -bound), bound)


def _as_schedule(name: str, value: Any) -> Schedule | None:
    """``value`` as a schedule, or None for a plain number (checked by the caller)."""
    if isinstance(value, Schedule):
        return value
    if isinstance(value, numbers.Real) and not isinstance(value, bool):
        return None
    if isinstance(value, Mapping):
        try:
            return Schedule.from_dict(value)
        except (TypeError, ValueError) as error:
            raise type(error)(f"{name}: {error}") from None
    raise TypeError(
        f"{name} must be a real number or a schedule (manualcontrol.envs.schedules), got {value!r}"
    )


class _Parameter:
    """One limitation parameter: a number or a schedule, sampled on the episode's times.

    ``given`` is what the wrapper reports (the number or the schedule), ``values`` a
    list of one value (constant) or of one value per time of ``env.unwrapped.times``,
    every one checked by ``check(name, value)`` (a range check returning the float).
    """

    __slots__ = ("given", "last", "values")

    def __init__(
        self, env: gym.Env, name: str, value: Any, check: Callable[[str, Any], float]
    ) -> None:
        schedule = _as_schedule(name, value)
        if schedule is None:
            self.given: float | Schedule = check(name, value)
            self.values = [self.given]
        elif schedule.is_constant:
            self.given = schedule
            self.values = [check(name, schedule(0.0))]
        else:
            times = getattr(env.unwrapped, "times", None)
            if times is None:
                raise TypeError(
                    f"{type(env.unwrapped).__name__} has no time grid (times): {name} can "
                    "follow a schedule only on a tracking or lane-keeping environment"
                )
            times = np.asarray(times, dtype=np.float64)
            values = np.asarray(schedule(times), dtype=np.float64).reshape(times.shape)
            # the checks are ranges: the extremes (or the first NaN) decide
            for index in (int(np.argmin(values)), int(np.argmax(values))):
                try:
                    check(name, float(values[index]))
                except ValueError as error:
                    raise ValueError(
                        f"{error} at t = {times[index]:g} s of the schedule {schedule.describe()}"
                    ) from None
            self.given = schedule
            self.values = values.tolist()
        self.last = len(self.values) - 1

    @property
    def varying(self) -> bool:
        """True when the value changes over the episode's samples."""
        return self.last > 0

    def at(self, k: int) -> float:
        """The value over sample ``k`` of the episode (held at the last past the end)."""
        return self.values[k if k < self.last else self.last]


def _range(
    low: float | None, high: float | None = None, *, high_inclusive: bool = True
) -> Callable[[str, Any], float]:
    return lambda name, value: check_range(name, value, low, high, high_inclusive=high_inclusive)


def _positive(allow_zero: bool = False) -> Callable[[str, Any], float]:
    return lambda name, value: check_positive(name, value, allow_zero=allow_zero)


def _given(parameter: _Parameter) -> float | dict[str, Any]:
    """A parameter as a configuration stores it: the number or the schedule's dict."""
    given = parameter.given
    return given.to_dict() if isinstance(given, Schedule) else given


class ActionDelay(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The stick follows the agent's command ``delay`` seconds late.

    With ``delay(t_k)/dt = q + a`` (``q`` whole samples, ``0 <= a < 1``) the stick over
    sample ``k`` is ``(1 - a) c[k-q] + a c[k-q-1]`` of the commands ``c``: the commands,
    joined linearly between samples, read at ``t_k - delay(t_k)``. For a constant delay
    this is exact for held commands and whole-sample delays (and the mean of the
    delayed staircase over the sample otherwise); commands before the episode are zero.

    A scheduled delay is read the same way at its current value, from a queue long
    enough for the schedule's largest delay over the episode, so the stick is
    ``c(t - delay(t))`` at every sample: while the delay changes more slowly than
    1 s/s the commands reach the stick in order, none skipped or repeated (a rising
    delay plays them back slower, a falling one faster, interpolated between samples);
    a step in the delay jumps back (repeating commands) or ahead (passing over them)
    by the step, as ``c(t - delay(t))`` does.

    The observation gains the ``m = ceil(max delay/dt)`` most recent commands (newest
    first), which have not (fully) reached the stick yet: with a constant delay the
    task stays Markov. (With a scheduled delay the agent is not told the current
    delay; :class:`ObservationHistory` lets it infer it.) With
    ``observe_queue=False`` the queue is hidden: the task is then partially observed,
    as for a human who cannot watch his own commands travel; an agent that sees the
    queue can learn to predict through the delay (a Smith predictor) and then
    identifies with a shorter effective delay.

    ``info["command"]`` is the agent's command of the step, ``info["delay"]`` the
    delay applied over it (s).

    Parameters
    ----------
    env
        A tracking environment (possibly wrapped).
    delay
        Delay in seconds, ``0 <= delay <= 2``: a number or a schedule.
    observe_queue
        Append the queued commands to the observation (default True: Markov).
    """

    def __init__(self, env: gym.Env, delay: float | Schedule, observe_queue: bool = True) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, delay=delay, observe_queue=observe_queue)
        gym.Wrapper.__init__(self, env)
        parameter = _Parameter(env, "delay", delay, _range(0.0, 2.0))
        self.delay = parameter.given
        self.observe_queue = bool(observe_queue)
        dt = _dt(env)
        self._delays = parameter
        samples = np.asarray(parameter.values) / dt
        whole = np.floor(samples + 1e-9)
        # a delay within 1e-9 samples of a whole number is that number (0.3/0.01 is
        # 29.999999999999996): no fraction of a sample beyond the queue
        fraction = samples - whole
        fraction[fraction < 1e-9] = 0.0
        self._whole = whole.astype(np.int64).tolist()
        self._fraction = fraction.tolist()
        self._last = parameter.last
        self._queued = int(np.max(whole + (fraction > 0.0)))
        bound = _stick_bound(env)
        self._bound = bound
        shown = self._queued if self.observe_queue else 0
        self.observation_space = _extend_box(
            env.observation_space, np.full(shown, -bound), np.full(shown, bound)
        )
        # newest first: history[0] is this step's command, history[q] came q samples ago
        self._history = np.zeros(self._queued + 1)
        self._k = 0
        #: The queued commands when the agent is not shown them (``observe_queue=False``).
        self.hidden_size = self._queued - shown

    def hidden_state(self) -> FloatArray:
        """The queued commands the agent is not shown, newest first (a read-only view)."""
        view = self._history[: self.hidden_size]
        view.setflags(write=False)
        return view

    def _observe(self, observation: FloatArray) -> FloatArray:
        if not self.observe_queue:
            return observation
        return np.concatenate([observation, self._history[: self._queued]])

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._history = np.zeros(self._queued + 1)
        self._k = 0
        return self._observe(observation), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        history = self._history
        history[1:] = history[:-1]
        history[0] = _command(action, self._bound)
        k = self._k if self._k < self._last else self._last
        self._k += 1
        whole, fraction = self._whole[k], self._fraction[k]
        applied = (1.0 - fraction) * float(history[whole])
        if fraction > 0.0:
            applied += fraction * float(history[whole + 1])
        observation, reward, terminated, truncated, info = self.env.step(np.array([applied]))
        info = {**info, "command": float(history[0]), "delay": self._delays.values[k]}
        return self._observe(observation), reward, terminated, truncated, info


class NeuromuscularFilter(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The stick moves through ``omega^2/(s^2 + 2 zeta omega s + omega^2)`` (thesis eq. 3).

    In the stick's own coordinates, position ``p`` and rate ``v``::

        p' = v,    v' = omega^2 (c - p) - 2 zeta omega v

    with the command ``c`` and the parameters held over each sample (their values at
    the sample's start) and the filter stepped exactly (zero-order hold). The stick
    applied over sample ``k`` is the position at its start, ``p[k]``: the arm cannot
    answer a command within the same sample. Because the state is the stick's
    position and rate, a change of ``omega_nms`` or ``zeta_nms`` changes how the stick
    moves on, never where it is.

    ``[p, v]`` is appended to the observation (the arm's own sense of where it is), or,
    with ``observe_state=False``, hidden: the optimal control model's pilot does not
    sense its limb; it knows the commands it sent and estimates the rest, motor noise
    included, from the display alone (Kleinman, Baron & Levison 1970). A policy that
    reads ``p`` sees noise added to its commands before the display shows it, and can
    cancel it. Hidden, the state is the wrapper's hidden state (module docstring).

    Parameters
    ----------
    env
        A tracking environment (possibly wrapped).
    omega_nms
        Natural frequency (rad/s), ``> 0``: a number or a schedule.
    zeta_nms
        Damping ratio, ``> 0``: a number or a schedule.
    observe_state
        Append the limb's state ``[p, v]`` to the observation (default), or hide it.
    """

    def __init__(
        self,
        env: gym.Env,
        omega_nms: float | Schedule = 10.5,
        zeta_nms: float | Schedule = 0.35,
        observe_state: bool = True,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, omega_nms=omega_nms, zeta_nms=zeta_nms, observe_state=observe_state
        )
        gym.Wrapper.__init__(self, env)
        self.observe_state = check_bool("observe_state", observe_state)
        #: Numbers of the limb's state the policy does not see (module docstring).
        self.hidden_size = 0 if self.observe_state else 2
        omega = _Parameter(env, "omega_nms", omega_nms, _positive())
        zeta = _Parameter(env, "zeta_nms", zeta_nms, _positive())
        self.omega_nms, self.zeta_nms = omega.given, zeta.given
        size = max(len(omega.values), len(zeta.values))
        w = np.broadcast_to(np.asarray(omega.values), (size,))
        z = np.broadcast_to(np.asarray(zeta.values), (size,))
        A = np.zeros((size, 2, 2))
        A[:, 0, 1] = 1.0
        A[:, 1, 0] = -(w**2)
        A[:, 1, 1] = -2.0 * z * w
        B = np.zeros((size, 2, 1))
        B[:, 1, 0] = w**2
        exact = discretize(A, B, _dt(env))  # equal consecutive samples: one exponential
        self._phi, self._gamma = exact.phi, exact.gamma[..., 0]
        self._last = size - 1
        self._bound = _stick_bound(env)
        if self.observe_state:
            self.observation_space = _extend_box(
                env.observation_space, np.full(2, -np.inf), np.full(2, np.inf)
            )
        self._x = np.zeros(2)
        self._k = 0

    def _observe(self, observation: FloatArray) -> FloatArray:
        if not self.observe_state:
            return observation
        return np.concatenate([observation, self._x])

    def hidden_state(self) -> FloatArray:
        """The limb's state ``[p, v]`` where the policy does not see it (else nothing)."""
        return self._x.copy() if self.hidden_size else np.zeros(0)

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._x = np.zeros(2)
        self._k = 0
        return self._observe(observation), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        command = _command(action, self._bound)
        k = self._k if self._k < self._last else self._last
        self._k += 1
        stick = float(self._x[0])
        self._x = self._phi[k] @ self._x + self._gamma[k] * command
        observation, reward, terminated, truncated, info = self.env.step(np.array([stick]))
        return (
            self._observe(observation),
            reward,
            terminated,
            truncated,
            {**info, "command": command},
        )


class MotorNoise(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Remnant on the stick: Levison-filtered white noise, scaled to the commands or not.

    ``n = g K_r/(s + omega_r) w`` (thesis eq. 5) with unit white noise ``w`` per
    sample; scaled to the commands, ``g`` follows their variance over the last 5 s, as
    Popovici et al. track the control variance (eq. 24), so the noise level adapts to
    how hard the agent steers. The stick is ``command + n``. The noise state is not
    observed: like a human's remnant it is a disturbance the agent does not command.
    ``info["remnant"]`` is ``n``, ``info["stick_before_noise"]`` the stick it joined (an
    outer wrapper's own ``info["command"]`` replaces this one's, so the key is its own;
    :class:`EffortCost` ``stick="commanded"`` reads it). The level is given in one of
    three ways:

    ``power_ratio`` (default 0.3)
        ``var(n) / (var(n) + var(command))`` (thesis eq. 6 with the command as the
        noise-free part).
    ``ratio``
        The OCM's motor noise ratio ``rho_u`` (Kleinman, Baron & Levison 1970): white
        noise of intensity ``V_u = pi rho_u var(command)`` per rad/s, as
        :class:`ObservationNoise`'s ``ratio`` and :mod:`~manualcontrol.pilots.ocm`'s
        ``V_u``, low-passed by ``omega_r/(s + omega_r)``. Its variance is then
        ``V_u omega_r / 2``: ``var(n) = (pi rho_u omega_r / 2) var(command)``. Why the
        intensity and not the share of the power: the OCM's -25 dB (``rho_u`` 0.0032)
        is a noise density, and the power it puts into the stick grows with the band
        it is passed in (at ``omega_r`` = 10 rad/s, -25 dB is 5 % of the command's
        power, where a ``power_ratio`` of 0.0032 is 0.3 %).
    ``std``
        The noise's own standard deviation (after its filter, in stick units), whatever
        the commands: a level the agent cannot change by commanding more or less. A
        noise scaled to the commands is one an agent can quieten by commanding less;
        the OCM's controller does not choose its noise (its intensities are held at its
        solution's variances).

    With ``omega_r=None`` the noise is white, unfiltered: a new value each sample, held
    over it, for a filter the stick passes through next to shape (a
    :class:`NeuromuscularFilter` inside this wrapper), as the OCM's motor noise is white
    where it joins the commanded control and its neuromuscular lag shapes it. Its
    per-sample variance is then ``V_u / dt`` under ``ratio`` (a held white sequence of
    that variance has the intensity ``V_u`` below the sample rate), ``std^2`` under
    ``std`` and the share of the power under ``power_ratio``. The Levison filter ahead
    of a limb would shape the noise twice.

    Parameters
    ----------
    env
        A tracking environment (possibly wrapped).
    power_ratio
        Noise share of the stick's power, ``0 <= power_ratio < 1`` (0.3: -3.7 dB of
        noise to command): a number or a schedule. Default 0.3 when neither ``ratio``
        nor ``std`` is given.
    omega_r
        Break frequency of the noise filter (rad/s), ``> 0``: a number or a schedule;
        or None, white noise (above).
    ratio
        The OCM's motor noise ratio ``rho_u``, ``>= 0`` (-25 dB is 0.0032): a number or
        a schedule.
    std
        The noise's standard deviation, ``>= 0``: a number or a schedule. Give one of
        ``power_ratio``, ``ratio`` and ``std``.
    """

    WINDOW = 5.0  # s, Popovici eq. 24

    def __init__(
        self,
        env: gym.Env,
        power_ratio: float | Schedule | None = None,
        omega_r: float | Schedule | None = 3.0,
        *,
        ratio: float | Schedule | None = None,
        std: float | Schedule | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, power_ratio=power_ratio, omega_r=omega_r, ratio=ratio, std=std
        )
        gym.Wrapper.__init__(self, env)
        given = {
            name: value
            for name, value in (("power_ratio", power_ratio), ("ratio", ratio), ("std", std))
            if value is not None
        }
        if len(given) > 1:
            raise ValueError(
                "give MotorNoise one level: a power_ratio (the noise's share of the stick's "
                "power), a ratio (the OCM's noise intensity) or a std (absolute); got "
                + " and ".join(f"{name}={value!r}" for name, value in given.items())
            )
        try:
            omega = None if omega_r is None else _Parameter(env, "omega_r", omega_r, _positive())
        except TypeError as error:  # the noise may also be white
            raise TypeError(f"{error}, or None (white noise)") from None
        self.power_ratio = self.ratio = self.std = None
        if ratio is not None:
            level = _Parameter(env, "ratio", ratio, _positive(allow_zero=True))
            self.ratio = level.given
        elif std is not None:
            level = _Parameter(env, "std", std, _positive(allow_zero=True))
            self.std = level.given
        else:
            level = _Parameter(
                env,
                "power_ratio",
                0.3 if power_ratio is None else power_ratio,
                _range(0.0, 1.0, high_inclusive=False),
            )
            self.power_ratio = level.given
        dt = _dt(env)
        self._dt = dt
        self._level = level
        self._omega = omega
        if omega is None:  # white: the filter's state is the next unit draw itself
            self.omega_r = None
            self._phi, self._gamma, self._unit_std = [0.0], [1.0], [1.0]
            self._last_filter = 0
        else:
            self.omega_r = omega.given
            self._phi = [math.exp(-w * dt) for w in omega.values]
            self._gamma = [(1.0 - p) / w for p, w in zip(self._phi, omega.values, strict=True)]
            # stationary variance of the unit-noise filter state: gamma^2 / (1 - phi^2)
            self._unit_std = [
                g / math.sqrt(1.0 - p**2) for p, g in zip(self._phi, self._gamma, strict=True)
            ]
            self._last_filter = omega.last
        self._bound = _stick_bound(env)
        # the last commands, oldest first once full (a ring of numbers, not a deque
        # converted to an array every step)
        self._window = np.zeros(max(round(self.WINDOW / dt), 2))
        self._filled = 0
        self._state = 0.0
        self._k = 0
        self._rng = np.random.default_rng()

    #: The noise filter's state.
    hidden_size = 1

    def hidden_state(self) -> FloatArray:
        """The noise filter's state at unit intensity, shape (1,): the next noise, unscaled."""
        return np.array((self._state,))

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        # a generator of our own, seeded from the environment's (reproducible per seed)
        self._rng = np.random.default_rng(int(self.env.unwrapped.np_random.integers(2**63)))
        self._state = 0.0
        self._filled = 0
        self._k = 0
        return observation, info

    def _noise_std(self, k: int, variance: float) -> float:
        """The noise's standard deviation over sample ``k`` (the class docstring's forms)."""
        level = self._level.at(k)
        if self.std is not None:
            return level
        if self.ratio is None:
            return math.sqrt(level / (1.0 - level) * variance)
        if self._omega is None:  # white, held over each sample: V_u / dt
            return math.sqrt(math.pi * level / self._dt * variance)
        return math.sqrt(math.pi * level * self._omega.at(k) / 2.0 * variance)

    def _command_variance(self, command: float) -> float:
        """Population variance of the last commands, this one included (as np.var)."""
        window = self._window
        size = window.shape[0]
        if self._filled < size:
            window[self._filled] = command
            self._filled += 1
            recent = window[: self._filled]
        else:
            # the oldest leaves: shift instead of a ring, so the sums run in time order
            # and give the numbers np.var of the deque gave, bit for bit
            window[:-1] = window[1:]
            window[-1] = command
            recent = window
        return _population_variance(recent) if recent.shape[0] > 1 else 0.0

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        command = _command(action, self._bound)
        # an absolute level reads no command variance
        variance = self._command_variance(command) if self.std is None else 0.0
        k = self._k
        self._k += 1
        j = k if k < self._last_filter else self._last_filter
        scale = self._noise_std(k, variance) / self._unit_std[j]
        noise = scale * self._state
        self._state = self._phi[j] * self._state + self._gamma[j] * float(
            self._rng.standard_normal()
        )
        observation, reward, terminated, truncated, info = self.env.step(
            np.array([command + noise])
        )
        return (
            observation,
            reward,
            terminated,
            truncated,
            {**info, "command": command, "remnant": noise, "stick_before_noise": command},
        )


class _WindowVariance:
    """Population variance of each component over its last ``size`` values (np.var's).

    Running sums of the deviations from the episode's first value, added and removed
    as values enter and leave the window, and summed afresh from the window whenever
    it has turned over once, so rounding cannot drift: O(width) per value where np.var
    of the window costs O(size x width).
    """

    def __init__(self, size: int, width: int) -> None:
        self._buffer = np.zeros((size, width))
        self._size = size
        self.reset()

    def reset(self) -> None:
        self._count = 0
        self._next = 0
        self._origin: FloatArray | None = None
        self._sum = np.zeros(self._buffer.shape[1])
        self._squares = np.zeros(self._buffer.shape[1])

    def push(self, values: FloatArray) -> FloatArray:
        """Add one value per component; the variance of the window, this value included."""
        if self._origin is None:
            self._origin = values.copy()
        deviation = values - self._origin
        slot = self._next
        if self._count == self._size:
            leaving = self._buffer[slot]
            self._sum -= leaving
            self._squares -= leaving * leaving
        else:
            self._count += 1
        self._buffer[slot] = deviation
        self._sum += deviation
        self._squares += deviation * deviation
        self._next = (slot + 1) % self._size
        if self._next == 0:
            self._sum = self._buffer.sum(axis=0)
            self._squares = (self._buffer * self._buffer).sum(axis=0)
        mean = self._sum / self._count
        return np.maximum(self._squares / self._count - mean * mean, 0.0)


class ObservationNoise(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Gaussian perception noise on every observed value, scaled to its variance.

    ``ratio`` (default): the OCM's noise-to-signal ratio ``rho`` (Kleinman, Baron &
    Levison 1970): the noise on each observed signal ``y_i`` is white with the
    intensity ``V_i = pi rho var(y_i)``, ``var(y_i)`` the population variance over the
    last 5 s (the samples observed so far early in an episode; no noise on the first
    observation after ``reset()``). Drawn per sample, white noise of intensity ``V``
    has the variance ``V / dt``, so each sample's noise has the standard deviation
    ``sqrt(pi rho var(y_i) / dt)``. Why the intensity and not the per-sample variance:
    the noise's power in the tracking band, which is what degrades the pilot, is then
    the same at every sample rate, as the OCM's noise is (``rho = 0.01``, -20 dB, is
    a per-sample standard deviation of ``1.8 std(y_i)`` at 100 Hz, ``1.4`` at 60 Hz).

    ``std``: an absolute standard deviation, the same for every observed value (in
    the units of the observation).

    Give one of the two. ``omega_r`` (rad/s, optional) passes the noise through the
    first-order low-pass ``omega_r/(s + omega_r)`` (discretised exactly: a first-order
    autoregression per value) instead of leaving it white: its power below ``omega_r``,
    where the tracking loop lives, is the white noise's (``V`` per rad/s), its variance
    ``V omega_r / 2`` rather than ``V / dt``. Why: the OCM's pilot removes the white
    noise's power far above the loop's band with its Kalman filter, and only the power
    in band degrades its tracking; a memoryless policy cannot filter, so white noise at
    the OCM's level swamps each sample it sees (``1.8 std`` at 100 Hz), where the
    band-limited noise poses the in-band part alone.

    The noise is drawn per sample and per value, independently;
    it perturbs what this wrapper's inner environment shows, so put it innermost
    (directly on the environment) to perturb the display only, not the agent's own
    commands or limb state appended by other wrappers. ``info["observation_noise"]``
    (an array) is the noise added to the observation of that step.

    Parameters
    ----------
    env
        An environment with a 1-D Box observation (possibly wrapped).
    ratio
        The OCM's noise-to-signal ratio ``rho``, ``>= 0``; default 0.01 (-20 dB) when
        ``std`` is not given: a number or a schedule.
    std
        Absolute standard deviation, ``>= 0``: a number or a schedule.
    omega_r
        Break frequency of the noise's low-pass, rad/s, ``> 0``; None (default): white.
    """

    WINDOW = 5.0  # s: the variance of each signal over its recent past, as MotorNoise's

    def __init__(
        self,
        env: gym.Env,
        *,
        ratio: float | Schedule | None = None,
        std: float | Schedule | None = None,
        omega_r: float | None = None,
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, ratio=ratio, std=std, omega_r=omega_r)
        gym.Wrapper.__init__(self, env)
        if ratio is not None and std is not None:
            raise ValueError(
                f"give ObservationNoise a ratio (scaled to the signal) or a std (absolute), "
                f"not both; got ratio={ratio!r} and std={std!r}"
            )
        if std is not None:
            level = _Parameter(env, "std", std, _positive(allow_zero=True))
            self.ratio, self.std = None, level.given
        else:
            level = _Parameter(env, "ratio", 0.01 if ratio is None else ratio, _positive(True))
            self.ratio, self.std = level.given, None
        self._level = level
        space = env.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise TypeError(f"observation space must be a 1-D Box, got {space}")
        self._variance = (
            None
            if std is not None
            else _WindowVariance(max(round(self.WINDOW / _dt(env)), 2), space.shape[0])
        )
        self._noise = np.zeros(space.shape[0])
        self._dt = _dt(env)
        self.omega_r = None if omega_r is None else check_positive("omega_r", omega_r)
        # the low-pass's exact step: n_k = phi n_(k-1) + w_k, var(w_k) = (1 - phi^2) var(n)
        self._phi = 0.0 if omega_r is None else math.exp(-self.omega_r * self._dt)
        # the noise's variance per unit of white intensity: 1/dt white, omega_r/2 filtered
        self._bandwidth = 1.0 / self._dt if omega_r is None else 0.5 * self.omega_r
        self._k = 0
        self._rng = np.random.default_rng()
        #: One noise state per observed number.
        self.hidden_size = space.shape[0]

    def hidden_state(self) -> FloatArray:
        """The noise on each observed number at this step (its filter's state; read-only)."""
        view = self._noise.view()
        view.setflags(write=False)
        return view

    def _perturb(self, observation: FloatArray) -> FloatArray:
        level = self._level.at(self._k)
        if self._variance is None:
            scale: float | FloatArray = level
        else:
            variance = self._variance.push(np.asarray(observation, np.float64))
            scale = np.sqrt(math.pi * level * variance * self._bandwidth)
        draw = scale * self._rng.standard_normal(observation.shape)
        if self.omega_r is None:
            self._noise = draw
        elif self._k == 0:
            self._noise = draw  # the filter's state starts in its stationary spread
        else:
            self._noise = self._phi * self._noise + math.sqrt(1.0 - self._phi**2) * draw
        return observation + self._noise

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._rng = np.random.default_rng(int(self.env.unwrapped.np_random.integers(2**63)))
        self._k = 0
        if self._variance is not None:
            self._variance.reset()
        return self._perturb(observation), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._k += 1
        observation = self._perturb(observation)
        return (
            observation,
            reward,
            terminated,
            truncated,
            {
                **info,
                "observation_noise": self._noise,
            },
        )


class EffortCost(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """An effort cost in the reward: the OCM's cost on the rate of control.

    Each step's reward gains ``-(rate_weight udot^2 + stick_weight u^2)`` with the
    stick applied to the environment over that step, in units of its bound
    ``U = action_bound`` (dimensionless), ``u = u_k / U``, and its rate
    ``udot = (u_k - u_{k-1}) / (U dt)`` (1/s; the stick is at rest, 0, before the
    first step). ``rate_weight`` is thus in s^2, ``stick_weight`` dimensionless. The
    applied stick is read from the environment's ``info`` (``"u"`` of the tracking
    tasks, ``"action"`` of lane keeping), so the cost is on the stick that moves the
    element, after any delay, neuromuscular filter or motor noise wrapped inside. With
    ``stick="commanded"`` it is on the stick before the motor noise instead
    (:class:`MotorNoise`'s ``info["stick_before_noise"]``): what the agent commands,
    through whatever wrappers lie between it and the noise (the limb's output, where a
    neuromuscular filter sits outside the noise). Why: the OCM's controller does not
    choose its motor noise, whose rate only adds a constant to its cost; in an agent's
    reward that rate is noise the agent cannot change, which, unsmoothed, can outweigh
    the whole reward.

    Relation to the OCM: the OCM pilot minimises ``J = E{q e^2 + g udot^2}``. A tracking
    task's reward ``-e^2 / var(ft)`` plus this wrapper's ``-rate_weight udot^2`` is,
    per step, ``-(q e^2 + g udot^2)`` in the stick's own units with ``q = 1/var(ft)``
    and ``g = rate_weight / U^2``: the mean reward per step of a long episode is
    ``-J``, and ``g/q = rate_weight var(ft) / U^2`` is the OCM's ratio of weights (the
    larger, the slower the pilot's neuromuscular lag ``tau_n``). ``stick_weight`` adds
    the OCM's optional cost on the control itself, ``r u^2``.

    ``info["effort"]`` is the cost subtracted at that step (>= 0).

    Parameters
    ----------
    env
        A tracking or lane-keeping environment (possibly wrapped).
    rate_weight
        Weight ``w`` on the squared stick rate (s^2), ``>= 0``: a number or a schedule.
    stick_weight
        Weight ``r`` on the squared stick, ``>= 0``: a number or a schedule.
    stick
        ``"applied"`` (default: the stick the element gets) or ``"commanded"`` (the
        stick before the motor noise; a :class:`MotorNoise` must be wrapped inside).
    """

    STICKS: tuple[str, ...] = ("applied", "commanded")

    def __init__(
        self,
        env: gym.Env,
        rate_weight: float | Schedule,
        stick_weight: float | Schedule = 0.0,
        stick: str = "applied",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self, rate_weight=rate_weight, stick_weight=stick_weight, stick=stick
        )
        gym.Wrapper.__init__(self, env)
        self.stick = check_choice("stick", stick, self.STICKS)
        rate = _Parameter(env, "rate_weight", rate_weight, _positive(allow_zero=True))
        stick = _Parameter(env, "stick_weight", stick_weight, _positive(allow_zero=True))
        self.rate_weight, self.stick_weight = rate.given, stick.given
        self._rate_weights, self._stick_weights = rate, stick
        unwrapped = env.unwrapped
        bound = getattr(unwrapped, "action_bound", None)
        self._scale = 1.0 / float(_stick_bound(unwrapped) if bound is None else bound)
        self._rate_scale = self._scale / _dt(env)
        self._previous = 0.0
        self._k = 0

    #: The last stick the cost read (applied or commanded), from which the next rate is taken.
    hidden_size = 1

    def hidden_state(self) -> FloatArray:
        """The stick the cost read over the last step (zero at reset), shape (1,)."""
        return np.array((self._previous,))

    def _costed_stick(self, info: Mapping[str, Any]) -> float:
        if self.stick == "commanded":
            if "stick_before_noise" not in info:
                raise TypeError(
                    "EffortCost(stick='commanded') reads the stick before the motor noise, "
                    "info['stick_before_noise'], which a MotorNoise wrapped inside sets; "
                    f"the environment's info has {sorted(info)}"
                )
            return float(info["stick_before_noise"])
        for key in ("u", "action"):
            if key in info:
                return float(info[key])
        raise TypeError(
            "EffortCost needs the applied stick in info['u'] (tracking) or info['action'] "
            f"(lane keeping); the environment's info has {sorted(info)}"
        )

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._previous = 0.0
        self._k = 0
        return observation, info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        observation, reward, terminated, truncated, info = self.env.step(action)
        stick = self._costed_stick(info)
        k = self._k
        self._k += 1
        rate = (stick - self._previous) * self._rate_scale
        position = stick * self._scale
        self._previous = stick
        effort = (
            self._rate_weights.at(k) * rate * rate + self._stick_weights.at(k) * position * position
        )
        return (
            observation,
            float(reward) - effort,
            terminated,
            truncated,
            {
                **info,
                "effort": effort,
            },
        )


class ObservationHistory(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """The last ``length`` observations side by side, newest first: a memory to adapt with.

    A feed-forward policy (stable-baselines3's ``MlpPolicy``) sees a window of
    ``(length - 1) dt`` seconds of its past observations instead of one sample, from
    which it can infer what a single observation does not show (the current delay,
    the element's changing dynamics, signal rates). The observation is the flat
    ``[o_k, o_{k-1}, ..., o_{k-length+1}]`` of ``length`` times the inner size;
    before the episode the first observation is repeated (the display was at rest).
    ``length = 1`` changes nothing. (A recurrent policy would need sb3-contrib, which
    this package does not depend on.)

    Parameters
    ----------
    env
        An environment with a 1-D Box observation (possibly wrapped).
    length
        Number of observations kept, ``>= 1``.
    """

    def __init__(self, env: gym.Env, length: int) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, length=length)
        gym.ObservationWrapper.__init__(self, env)
        self.length = check_int("length", length, minimum=1)
        space = env.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise TypeError(f"observation space must be a 1-D Box, got {space}")
        self._size = space.shape[0]
        self.observation_space = spaces.Box(
            np.tile(space.low, self.length), np.tile(space.high, self.length), dtype=np.float64
        )
        self._stack = np.zeros(self._size * self.length)

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._stack = np.tile(np.asarray(observation, dtype=np.float64), self.length)
        return self._stack.copy(), info

    def observation(self, observation: FloatArray) -> FloatArray:  # noqa: D102
        stack = self._stack
        stack[self._size :] = stack[: -self._size].copy()
        stack[: self._size] = observation
        return stack.copy()


class EfferenceCopy(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The observation gains the agent's own last command: a copy of what it just sent.

    A human's motor system knows the command it has just issued (its efference copy),
    and the optimal control model's pilot uses its own past commands in its estimator
    and predictor. A feed-forward policy has no such memory: its action is a function
    of what it sees now, so it cannot integrate (McRuer's lag equalisation on a pure
    gain, ``u = K_p e/(T_I s + 1)``, is ``c_k = a c_{k-1} + (1 - a) K_p e_k``: the
    previous command is an input). Only the last command is shown, clipped to the
    stick as the stick takes it: the commands still travelling through an
    :class:`ActionDelay` beyond it stay hidden (put this wrapper outside the delay and
    outside :class:`ObservationHistory`, whose frames would otherwise show the queue).
    Before the episode the last command is 0 (the stick at rest).

    Parameters
    ----------
    env
        An environment with a 1-D Box observation and a scalar stick (possibly wrapped).
    """

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        bound = _stick_bound(env)
        self._bound = bound
        self.observation_space = _extend_box(
            env.observation_space, np.array([-bound]), np.array([bound])
        )
        self._last = 0.0

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._last = 0.0
        return np.append(np.asarray(observation, dtype=np.float64), 0.0), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        command = _command(action, self._bound)
        observation, reward, terminated, truncated, info = self.env.step(action)
        self._last = command
        observation = np.append(np.asarray(observation, dtype=np.float64), command)
        return observation, reward, terminated, truncated, info


class ObservationScale(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Each observed value divided by a fixed scale, so the policy sees numbers of order one.

    A network learns slowly from inputs of order 0.01 (lane keeping's angles in radians)
    beside others of order one. A fixed scale, unlike a running normalisation, is part
    of the configuration: the trained agent sees the same numbers in evaluation and
    after loading, with nothing else to save. Put it outermost but for the history.

    Parameters
    ----------
    env
        An environment with a 1-D Box observation (possibly wrapped).
    scale
        One positive number for every value, or one per value (a list as long as the
        observation).
    """

    def __init__(self, env: gym.Env, scale: float | list[float]) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, scale=scale)
        gym.ObservationWrapper.__init__(self, env)
        space = env.observation_space
        if not isinstance(space, spaces.Box) or len(space.shape) != 1:
            raise TypeError(f"observation space must be a 1-D Box, got {space}")
        values = (
            np.broadcast_to(np.asarray(scale, dtype=np.float64), space.shape)
            if np.ndim(scale) == 0
            else np.asarray(scale, dtype=np.float64)
        )
        if values.shape != space.shape:
            raise ValueError(
                f"scale must be one number or {space.shape[0]} (one per observed value), "
                f"got {len(values)}"
            )
        if not np.all(np.isfinite(values) & (values > 0.0)):
            raise ValueError(f"scale must be finite and > 0, got {list(np.ravel(scale))}")
        self._inverse = 1.0 / values
        self.observation_space = spaces.Box(
            space.low * self._inverse, space.high * self._inverse, dtype=np.float64
        )

    def observation(self, observation: FloatArray) -> FloatArray:  # noqa: D102
        return np.asarray(observation, dtype=np.float64) * self._inverse


#: Wrapper names for configurations: ``{"kind": name, **arguments}``.
WRAPPERS: dict[str, type[gym.Wrapper]] = {
    "action_delay": ActionDelay,
    "neuromuscular": NeuromuscularFilter,
    "motor_noise": MotorNoise,
    "observation_noise": ObservationNoise,
    "effort_cost": EffortCost,
    "observation_history": ObservationHistory,
    "observation_scale": ObservationScale,
    "efference_copy": EfferenceCopy,
}

#: The noise level of each noise wrapper, the argument set to 0 for a noise-free run.
NOISE_LEVELS: dict[str, tuple[str, ...]] = {
    "motor_noise": ("power_ratio", "ratio", "std"),
    "observation_noise": ("ratio", "std"),
}


def spec_to_json(spec: Mapping[str, Any]) -> dict[str, Any]:
    """A wrapper specification with its schedules as their dicts (JSON-able)."""
    return {
        name: value.to_dict() if isinstance(value, Schedule) else value
        for name, value in spec.items()
    }


def apply_wrappers(
    env: gym.Env, wrappers: list[Mapping[str, Any]] | tuple[Mapping[str, Any], ...]
) -> gym.Env:
    """Wrap ``env`` with ``[{"kind": "action_delay", "delay": 0.2}, ...]``, innermost first.

    Arguments are numbers or schedules, a schedule also as its dict
    (``{"kind": "ramp", "start": 0.2, ...}``, as :func:`spec_to_json` writes it).
    """
    for spec in wrappers:
        spec = dict(spec)
        kind = check_choice("wrapper kind", spec.pop("kind", None), tuple(WRAPPERS))
        env = WRAPPERS[kind](env, **spec)
    return env
