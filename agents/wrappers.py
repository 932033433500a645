"""Wrappers that give an agent the limitations of a human operator.

Each wrapper acts on the stick (action) or the display (observation) of a
:mod:`~manualcontrol.envs.tracking` environment, validates its arguments, and stacks
with the others in any order. Each appends to the observation what the agent needs to
keep the problem Markov, and documents it:

=====================  =====================================================  =====================
wrapper                limitation                                             appended observation
=====================  =====================================================  =====================
:class:`ActionDelay`   perception/processing delay: the stick follows the     the ``ceil(delay/dt)``
                       command ``delay`` seconds late (exact, fractional)      commands still queued
                                                                              (optional)
:class:`Neuromuscular  second-order arm/stick dynamics                        filter position and
Filter`                ``omega^2/(s^2 + 2 zeta omega s + omega^2)``            rate
:class:`MotorNoise`    remnant: Levison-filtered white noise on the stick     nothing (see class)
                       at a requested power ratio
:class:`Observation    noisy perception of the display                        nothing
Noise`
=====================  =====================================================  =====================

Commands are held over each sample, so delaying them by a whole number of samples is
exact; a fractional delay applies the mean of the delayed staircase over the sample
(the linear interpolation of the queued commands), as the exact delays of
:func:`~manualcontrol.pilots.simulate` do for held signals.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numba
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_choice, check_positive, check_range
from manualcontrol.envs.dynamics import discretize, tf_to_ccf

__all__ = [
    "WRAPPERS",
    "ActionDelay",
    "MotorNoise",
    "NeuromuscularFilter",
    "ObservationNoise",
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


class ActionDelay(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The stick follows the agent's command ``delay`` seconds late.

    With ``delay/dt = q + a`` (``q`` whole samples, ``0 <= a < 1``) the stick over
    sample ``k`` is ``(1 - a) c[k-q] + a c[k-q-1]`` of the commands ``c``, exact for
    held commands and whole-sample delays; commands before the episode are zero. The
    observation gains the ``m = ceil(delay/dt)`` most recent commands (newest first),
    which have not (fully) reached the stick yet: with them the task stays Markov.

    With ``observe_queue=False`` the queue is hidden: the task is then partially
    observed, as for a human who cannot watch his own commands travel; an agent that
    sees the queue can learn to predict through the delay (a Smith predictor) and
    then identifies with a shorter effective delay.

    Parameters
    ----------
    env
        A tracking environment (possibly wrapped).
    delay
        Delay in seconds, ``0 <= delay <= 2``.
    observe_queue
        Append the queued commands to the observation (default True: Markov).
    """

    def __init__(self, env: gym.Env, delay: float, observe_queue: bool = True) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, delay=delay, observe_queue=observe_queue)
        gym.Wrapper.__init__(self, env)
        self.delay = check_range("delay", delay, 0.0, 2.0)
        self.observe_queue = bool(observe_queue)
        dt = _dt(env)
        samples = self.delay / dt
        self._whole = math.floor(samples + 1e-9)
        self._fraction = max(samples - self._whole, 0.0)
        self._queued = math.ceil(samples - 1e-9)
        bound = float(np.max(np.abs(env.action_space.high)))
        self._bound = bound
        shown = self._queued if self.observe_queue else 0
        self.observation_space = _extend_box(
            env.observation_space, np.full(shown, -bound), np.full(shown, bound)
        )
        # newest first: history[0] is this step's command, history[q] came q samples ago
        self._history = np.zeros(self._queued + 1)

    def _observe(self, observation: FloatArray) -> FloatArray:
        if not self.observe_queue:
            return observation
        return np.concatenate([observation, self._history[: self._queued]])

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._history = np.zeros(self._queued + 1)
        return self._observe(observation), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        history = self._history
        history[1:] = history[:-1]
        history[0] = _command(action, self._bound)
        applied = (1.0 - self._fraction) * float(history[self._whole])
        if self._fraction > 0.0:
            applied += self._fraction * float(history[self._whole + 1])
        observation, reward, terminated, truncated, info = self.env.step(np.array([applied]))
        info = {**info, "command": float(history[0])}
        return self._observe(observation), reward, terminated, truncated, info


class NeuromuscularFilter(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """The stick moves through ``omega^2/(s^2 + 2 zeta omega s + omega^2)`` (thesis eq. 3).

    The command is held over each sample and the filter stepped exactly (zero-order
    hold). The stick applied over sample ``k`` is the filter output at its start,
    ``C x[k]``: the arm cannot answer a command within the same sample. The filter
    state (canonical coordinates, scaled to stick position and rate) is appended to
    the observation.
    """

    def __init__(self, env: gym.Env, omega_nms: float = 10.5, zeta_nms: float = 0.35) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, omega_nms=omega_nms, zeta_nms=zeta_nms)
        gym.Wrapper.__init__(self, env)
        self.omega_nms = check_positive("omega_nms", omega_nms)
        self.zeta_nms = check_positive("zeta_nms", zeta_nms)
        model = tf_to_ccf(
            [self.omega_nms**2], [1.0, 2 * self.zeta_nms * self.omega_nms, self.omega_nms**2]
        )
        exact = discretize(model.A, model.B, _dt(env))
        self._phi, self._gamma, self._c = exact.phi, exact.gamma[:, 0], model.C[0]
        self._bound = float(np.max(np.abs(env.action_space.high)))
        self.observation_space = _extend_box(
            env.observation_space, np.full(2, -np.inf), np.full(2, np.inf)
        )
        self._x = np.zeros(2)

    def _observe(self, observation: FloatArray) -> FloatArray:
        # position = C x; rate = C A x = omega^2 x_2 for this canonical form
        position = float(self._c @ self._x)
        rate = self.omega_nms**2 * float(self._x[1])
        return np.concatenate([observation, [position, rate]])

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._x = np.zeros(2)
        return self._observe(observation), info

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        command = _command(action, self._bound)
        stick = float(self._c @ self._x)
        self._x = self._phi @ self._x + self._gamma * command
        observation, reward, terminated, truncated, info = self.env.step(np.array([stick]))
        return (
            self._observe(observation),
            reward,
            terminated,
            truncated,
            {**info, "command": command},
        )


class MotorNoise(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Remnant on the stick: Levison-filtered white noise at a requested power ratio.

    ``n = g K_r/(s + omega_r) w`` (thesis eq. 5) with unit white noise ``w`` per
    sample, scaled so that ``var(n) / (var(n) + var(command))`` is ``power_ratio``
    (thesis eq. 6 with the command as the noise-free part): ``g`` follows the
    variance of the commands over the last 5 s, as Popovici et al. track the control
    variance (eq. 24), so the noise level adapts to how hard the agent steers. The
    stick is ``command + n``. The noise state is not observed: like a human's
    remnant it is a disturbance the agent does not command.
    """

    WINDOW = 5.0  # s, Popovici eq. 24

    def __init__(self, env: gym.Env, power_ratio: float = 0.3, omega_r: float = 3.0) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, power_ratio=power_ratio, omega_r=omega_r)
        gym.Wrapper.__init__(self, env)
        self.power_ratio = check_range("power_ratio", power_ratio, 0.0, 1.0, high_inclusive=False)
        self.omega_r = check_positive("omega_r", omega_r)
        dt = _dt(env)
        self._phi = math.exp(-self.omega_r * dt)
        self._gamma = (1.0 - self._phi) / self.omega_r
        # stationary variance of the unit-noise filter state: gamma^2 / (1 - phi^2)
        self._unit_std = self._gamma / math.sqrt(1.0 - self._phi**2)
        self._bound = float(np.max(np.abs(env.action_space.high)))
        # the last commands, oldest first once full (a ring of numbers, not a deque
        # converted to an array every step)
        self._window = np.zeros(max(round(self.WINDOW / dt), 2))
        self._filled = 0
        self._state = 0.0
        self._rng = np.random.default_rng()

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        # a generator of our own, seeded from the environment's (reproducible per seed)
        self._rng = np.random.default_rng(int(self.env.unwrapped.np_random.integers(2**63)))
        self._state = 0.0
        self._filled = 0
        return observation, info

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
        variance = self._command_variance(command)
        ratio = self.power_ratio
        scale = math.sqrt(ratio / (1.0 - ratio) * variance) / self._unit_std
        noise = scale * self._state
        self._state = self._phi * self._state + self._gamma * float(self._rng.standard_normal())
        observation, reward, terminated, truncated, info = self.env.step(
            np.array([command + noise])
        )
        return (
            observation,
            reward,
            terminated,
            truncated,
            {**info, "command": command, "remnant": noise},
        )


class ObservationNoise(gym.ObservationWrapper, gym.utils.RecordConstructorArgs):
    """Gaussian perception noise of standard deviation ``std`` on every observed value."""

    def __init__(self, env: gym.Env, std: float) -> None:
        gym.utils.RecordConstructorArgs.__init__(self, std=std)
        gym.ObservationWrapper.__init__(self, env)
        self.std = check_positive("std", std, allow_zero=True)
        self._rng = np.random.default_rng()

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._rng = np.random.default_rng(int(self.env.unwrapped.np_random.integers(2**63)))
        return self.observation(observation), info

    def observation(self, observation: FloatArray) -> FloatArray:  # noqa: D102
        return observation + self.std * self._rng.standard_normal(observation.shape)


#: Wrapper names for configurations: ``{"kind": name, **arguments}``.
WRAPPERS: dict[str, type[gym.Wrapper]] = {
    "action_delay": ActionDelay,
    "neuromuscular": NeuromuscularFilter,
    "motor_noise": MotorNoise,
    "observation_noise": ObservationNoise,
}


def apply_wrappers(
    env: gym.Env, wrappers: list[dict[str, Any]] | tuple[dict[str, Any], ...]
) -> gym.Env:
    """Wrap ``env`` with ``[{"kind": "action_delay", "delay": 0.2}, ...]``, innermost first."""
    for spec in wrappers:
        spec = dict(spec)
        kind = check_choice("wrapper kind", spec.pop("kind", None), tuple(WRAPPERS))
        env = WRAPPERS[kind](env, **spec)
    return env
