"""Native batched tracking environments: numpy over ``num_envs`` copies at once.

Registered as the ``vector_entry_point`` of the tracking ids, so
``gymnasium.make_vec("ManualControl/CompensatoryTracking-v0", num_envs=1024)`` (with
the default ``vectorization_mode=None``) steps all copies in a handful of array
operations. Each copy behaves exactly like the single environment of
:mod:`manualcontrol.envs.tracking` with the same arguments, seeded ``seed + i``
(as :class:`gymnasium.vector.SyncVectorEnv` seeds its copies), with next-step
autoreset: the step after an episode ends resets that copy, ignores its action and
returns its first observation with zero reward.

``info`` holds arrays over the copies: ``t, ft, fd, y, e, u`` after the step and
``clipped`` (whether the action was clipped). The disturbance enters where the single
environment's ``disturbance_at`` says (the element's output or its input).
Rendering is not offered (render single environments).
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_action, check_int, check_options
from manualcontrol.envs.signals import forcing_preset
from manualcontrol.envs.tracking import (
    CompensatoryTracking,
    PreviewTracking,
    PursuitTracking,
    TrackingEnv,
)

__all__ = [
    "CompensatoryTrackingVector",
    "PreviewTrackingVector",
    "PursuitTrackingVector",
    "TrackingVectorEnv",
]

FloatArray = NDArray[np.float64]


class TrackingVectorEnv(VectorEnv[FloatArray, FloatArray, FloatArray]):
    """``num_envs`` tracking tasks stepped together; arguments as the single environment."""

    metadata: ClassVar[dict[str, Any]] = {
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": [],
    }
    single_env: ClassVar[type[TrackingEnv]]

    def __init__(
        self,
        num_envs: int = 1,
        render_mode: str | None = None,
        max_episode_steps: int | None = None,
        **kwargs: Any,
    ) -> None:
        if render_mode is not None:
            raise ValueError(
                f"render_mode must be None for the batched environment, got {render_mode!r}; "
                "render single environments instead"
            )
        self.num_envs = check_int("num_envs", num_envs, minimum=1)
        template = self.single_env(**kwargs)
        self.template = template
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self.dt = template.dt
        self.episode_steps = template.episode_steps
        # gym.make_vec passes max_episode_steps (TimeLimit's job for single envs): a copy
        # is truncated after that many steps, or at the end of its run when that is sooner
        self.max_episode_steps = (
            self.episode_steps
            if max_episode_steps is None
            else min(
                self.episode_steps, check_int("max_episode_steps", max_episode_steps, minimum=1)
            )
        )
        self.window = template.preview_window
        # every realisation's forcing, sampled once: rows are realisations
        realisations = template._realisations
        tables = [
            (forcing_preset(template._preset, r) if template._preset else template._forcing).sample(
                (self.episode_steps + self.window) * self.dt, self.dt, template.time_origin
            )
            for r in range(realisations)
        ]
        self._ft = np.stack([ft for ft, _ in tables])
        self._fd = np.stack([fd for _, fd in tables])
        variances = [
            template._forcing_variance(
                forcing_preset(template._preset, r) if template._preset else template._forcing
            )
            for r in range(realisations)
        ]
        self._inverse_variance = 1.0 / np.asarray(variances)
        self._time = template._time
        self._time_varying = template.element.is_time_varying
        self._disturbance_at_input = template.disturbance_at == "input"
        self._phi = template._phi
        self._gamma = template._gamma
        self._c = template._c
        self._d = template._d
        self._generators: list[np.random.Generator] = []
        self._k = np.zeros(self.num_envs, dtype=np.int64)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Reset every copy; copy ``i`` is seeded ``seed + i``."""
        options = check_options(options, ("realisation",))
        if seed is not None or not self._generators:
            self._generators = [
                seeding.np_random(None if seed is None else seed + i)[0]
                for i in range(self.num_envs)
            ]
        n = self.num_envs
        self._realisation = np.empty(n, dtype=np.int64)
        for i in range(n):
            self._realisation[i] = self._pick_realisation(i, options.get("realisation"))
        order = self._c.shape[-1]
        self._x = np.zeros((n, order))
        self._k = np.zeros(n, dtype=np.int64)
        self._y = self._start_output(self._realisation)
        self._e = self._ft[self._realisation, 0] - self._y
        self._previous = {
            "e": self._e.copy(),
            "ft": self._ft[self._realisation, 0].copy(),
            "y": self._y.copy(),
        }
        self._u = np.zeros(n)
        self._done = np.zeros(n, dtype=bool)
        self._clipped = np.zeros(n, dtype=bool)
        return self._observe(), self._infos()

    @property
    def times(self) -> FloatArray:
        """Time of every observation of an episode, as the single environment's ``times``."""
        return self.template.times

    @property
    def realisations(self) -> NDArray[np.int64]:
        """The forcing realisation each copy flies now (a copy; after :meth:`reset`)."""
        return self._realisation.copy()

    @property
    def realisation_count(self) -> int:
        """How many forcing realisations the copies draw from."""
        return int(self._ft.shape[0])

    def forcing_of(self, realisation: int) -> Any:
        """The :class:`~manualcontrol.envs.signals.ForcingPair` of one realisation."""
        template = self.template
        realisation = template.check_realisation(realisation)
        return (
            forcing_preset(template._preset, realisation) if template._preset else template._forcing
        )

    def _start_output(self, rows: NDArray[np.int64]) -> FloatArray:
        """``y`` at rest for copies on these forcing rows (as the single environment)."""
        if self._disturbance_at_input:
            return np.zeros(len(rows))
        return self._fd[rows, 0].copy()

    def _pick_realisation(self, i: int, requested: int | None) -> int:
        template = self.template
        realisation = requested if requested is not None else template.realisation
        if realisation is None:
            return int(self._generators[i].integers(template._realisations))
        return template.check_realisation(realisation)

    def step(
        self, actions: FloatArray
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Step every copy; copies whose episode ended last step are reset instead."""
        template = self.template
        if not (
            type(actions) is np.ndarray
            and actions.dtype.kind == "f"
            and actions.shape == (self.num_envs, 1)
        ):
            # (num_envs,) is accepted too: one stick per copy either way
            shape = (
                (self.num_envs,) if np.shape(actions) == (self.num_envs,) else (self.num_envs, 1)
            )
            actions = check_action("actions", actions, shape)
        u = actions.astype(np.float64, copy=False).reshape(self.num_envs)
        if not np.all(np.isfinite(u)):
            bad = np.flatnonzero(~np.isfinite(u)).tolist()
            raise ValueError(f"actions must be finite, got non-finite values for copies {bad}")
        bound = template.action_bound
        self._clipped = np.abs(u) > bound
        u = np.clip(u, -bound, bound)
        # copies that ended last step are stepped harmlessly (clamped), then reset below
        k = np.minimum(self._k, self.episode_steps - 1)
        rows = self._realisation
        # what drives the element: the stick, plus the disturbance where it enters there
        drive = u + self._fd[rows, k] if self._disturbance_at_input else u
        if self._time_varying:
            phi = self._phi[k]
            x = np.einsum("nij,nj->ni", phi, self._x) + self._gamma[k] * drive[:, None]
            y_next = np.einsum("ni,ni->n", self._c[k + 1], x) + self._d[k + 1] * drive
        else:
            x, y_next = self._advance_constant(drive)
        k = k + 1
        self._previous = {"e": self._e, "ft": self._ft[self._realisation, k - 1], "y": self._y}
        y = y_next if self._disturbance_at_input else y_next + self._fd[rows, k]
        e = self._ft[rows, k] - y
        variance = self._inverse_variance[rows]
        kind = template.reward_kind
        if kind == "squared_error":
            reward = -e * e * variance
        elif kind == "absolute_error":
            reward = -np.abs(e) * np.sqrt(variance)
        elif kind == "bounded":
            reward = 1.0 / (1.0 + e * e * variance)
        else:
            reward = -(e * e + template.effort_weight * u * u) * variance
        limit = template.loss_of_control
        terminated = np.abs(e) > limit if limit is not None else np.zeros(self.num_envs, dtype=bool)
        truncated = k >= self.max_episode_steps
        self._x, self._k, self._y, self._e, self._u = x, k, y, e, u

        done = self._done
        if done.any():
            for i in np.flatnonzero(done):
                self._realisation[i] = self._pick_realisation(i, None)
            row = self._realisation[done]
            self._x[done] = 0.0
            self._k[done] = 0
            self._y[done] = self._start_output(row)
            self._e[done] = self._ft[row, 0] - self._y[done]
            self._u[done] = 0.0
            for name in self._previous:
                self._previous[name] = self._previous[name].copy()
            self._previous["e"][done] = self._e[done]
            self._previous["ft"][done] = self._ft[row, 0]
            self._previous["y"][done] = self._y[done]
            reward[done] = 0.0
            terminated[done] = False
            truncated[done] = False
        self._done = terminated | truncated
        return self._observe(), reward, terminated, truncated, self._infos()

    def _advance_constant(self, drive: FloatArray) -> tuple[FloatArray, FloatArray]:
        """The states and output after one step of a constant element, every copy at once.

        The single environment's sums, term by term in the same order (a matrix product
        would sum in another and differ in the last bits), so each copy's signals equal
        its single environment's bit for bit.
        """
        x = self._x
        phi, gamma, c = self._phi, self._gamma, self._c
        advanced = np.empty_like(x)
        for i in range(x.shape[1]):
            acc = 0.0
            for j in range(x.shape[1]):
                acc = acc + phi[i, j] * x[:, j]
            advanced[:, i] = acc + gamma[i] * drive
        acc = 0.0
        for j in range(x.shape[1]):
            acc = acc + c[j] * advanced[:, j]
        return advanced, acc + self._d * drive

    def _observe(self) -> FloatArray:
        template = self.template
        rows, k = self._realisation, self._k
        dt = self.dt
        first = self._k == 0
        display = template._display
        if display.shows_error_only:
            columns = [self._e]
            if template.include_rates:
                columns.append(np.where(first, 0.0, (self._e - self._previous["e"]) / dt))
        elif not display.shows_preview:  # the target and the output
            ft = self._ft[rows, k]
            columns = [ft, self._y]
            if template.include_rates:
                columns += [
                    np.where(first, 0.0, (ft - self._previous["ft"]) / dt),
                    np.where(first, 0.0, (self._y - self._previous["y"]) / dt),
                ]
        else:
            window = self._ft[rows[:, None], k[:, None] + np.arange(self.window)]
            columns = [window, self._y[:, None]]
            if template.include_rates:
                ft = self._ft[rows, k]
                columns += [
                    np.where(first, 0.0, (ft - self._previous["ft"]) / dt)[:, None],
                    np.where(first, 0.0, (self._y - self._previous["y"]) / dt)[:, None],
                ]
            if template.include_previous_action:
                columns.append(self._u[:, None])
            return np.concatenate(columns, axis=1)
        if template.include_previous_action:
            columns.append(self._u)
        return np.stack(columns, axis=1)

    def _infos(self) -> dict[str, Any]:
        rows, k = self._realisation, self._k
        return {
            "t": self._time[k],
            "ft": self._ft[rows, k],
            "fd": self._fd[rows, k],
            "y": self._y.copy(),
            "e": self._e.copy(),
            "u": self._u.copy(),
            "clipped": self._clipped.copy(),
        }

    def close_extras(self, **kwargs: Any) -> None:  # noqa: D102
        self.template.close()


class CompensatoryTrackingVector(TrackingVectorEnv):
    """Batched :class:`~manualcontrol.envs.tracking.CompensatoryTracking`."""

    single_env = CompensatoryTracking


class PursuitTrackingVector(TrackingVectorEnv):
    """Batched :class:`~manualcontrol.envs.tracking.PursuitTracking`."""

    single_env = PursuitTracking


class PreviewTrackingVector(TrackingVectorEnv):
    """Batched :class:`~manualcontrol.envs.tracking.PreviewTracking`."""

    single_env = PreviewTracking
