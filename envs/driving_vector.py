"""Native batched lane keeping: numpy over ``num_envs`` cars at once.

Registered as the ``vector_entry_point`` of ``ManualControl/LaneKeeping-v0``, so
``gymnasium.make_vec("ManualControl/LaneKeeping-v0", num_envs=1024)`` steps every car
in a few array operations. Each copy behaves exactly like the single environment of
:mod:`manualcontrol.envs.driving` with the same arguments, seeded ``seed + i`` (as
:class:`gymnasium.vector.SyncVectorEnv` seeds its copies; with ``road="random"`` each
copy draws its own road), with next-step autoreset: the step after an episode ends
resets that copy, ignores its action and returns its first observation with zero
reward.

``info`` holds arrays over the copies: ``t, s, kappa, y_L, psi_L, a_y, action`` after
the step and ``clipped`` (whether the action was clipped). Rendering is not offered.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_action, check_int, check_options
from manualcontrol.envs.driving import LaneKeeping, Road

__all__ = ["LaneKeepingVector"]

FloatArray = NDArray[np.float64]


class _RoadTable:
    """Curvature of one road per copy at increasing path lengths, by segment pointers."""

    def __init__(self, count: int) -> None:
        self.starts = np.full((count, 2), np.inf)
        self.kappa_from = np.zeros((count, 1))
        self.kappa_to = np.zeros((count, 1))
        self.index = np.zeros(count, dtype=np.int64)

    def set(self, i: int, road: Road) -> None:
        size = len(road.segments)
        if size + 1 > self.starts.shape[1]:
            grow = size + 1 - self.starts.shape[1]
            self.starts = np.pad(self.starts, ((0, 0), (0, grow)), constant_values=np.inf)
            self.kappa_from = np.pad(self.kappa_from, ((0, 0), (0, grow)))
            self.kappa_to = np.pad(self.kappa_to, ((0, 0), (0, grow)))
        self.starts[i] = np.inf
        self.starts[i, : size + 1] = np.concatenate(
            ([0.0], np.cumsum([s.length for s in road.segments]))
        )
        self.kappa_from[i] = 0.0
        self.kappa_to[i] = 0.0
        self.kappa_from[i, :size] = [s.start for s in road.segments]
        self.kappa_to[i, :size] = [s.end for s in road.segments]
        self.index[i] = 0

    def at(self, s: FloatArray) -> FloatArray:
        """Curvature at ``s`` (non-decreasing per copy between resets), as Road.curvature."""
        rows = np.arange(s.shape[0])
        last = self.starts.shape[1] - 2
        while True:
            ahead = (s >= self.starts[rows, self.index + 1]) & (self.index < last)
            if not ahead.any():
                break
            self.index[ahead] += 1
        i = self.index
        start = self.starts[rows, i]
        end = self.starts[rows, i + 1]
        with np.errstate(invalid="ignore"):
            fraction = np.clip((s - start) / (end - start), 0.0, 1.0)
        kappa = self.kappa_from[rows, i] + (self.kappa_to[rows, i] - self.kappa_from[rows, i]) * (
            fraction
        )
        return np.where(np.isfinite(end) & (s >= start) & (s < end), kappa, 0.0)


class LaneKeepingVector(VectorEnv[FloatArray, FloatArray, FloatArray]):
    """``num_envs`` lane-keeping cars stepped together; arguments as the single environment."""

    metadata: ClassVar[dict[str, Any]] = {
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": [],
    }

    def __init__(self, num_envs: int = 1, render_mode: str | None = None, **kwargs: Any) -> None:
        if render_mode is not None:
            raise ValueError(
                f"render_mode must be None for the batched environment, got {render_mode!r}; "
                "render single environments instead"
            )
        self.num_envs = check_int("num_envs", num_envs, minimum=1)
        template = LaneKeeping(**kwargs)
        self.template = template
        self.single_observation_space = template.observation_space
        self.single_action_space = template.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.render_mode = None
        self.dt = template.dt
        self.episode_steps = template.episode_steps
        model = template.model
        self._phi_t = model.phi.T.copy()
        self._gamma = model.gamma
        self._H_t = model.H.T.copy()
        self._h_kappa = model.h_kappa
        if template.road is not None:
            self._kappa = template.road.curvature(template._s)
            self._kappa_far = template.road.curvature(template._s + template.far_preview)
            self._tables: tuple[_RoadTable, _RoadTable] | None = None
        else:
            self._tables = (_RoadTable(self.num_envs), _RoadTable(self.num_envs))
        self._generators: list[np.random.Generator] = []
        self._k = np.zeros(self.num_envs, dtype=np.int64)

    def _curvatures(self, k: NDArray[np.int64]) -> tuple[FloatArray, FloatArray]:
        if self._tables is None:
            return self._kappa[k], self._kappa_far[k]
        s = self.template.speed * self.dt * k
        near, far = self._tables
        return near.at(s), far.at(s + self.template.far_preview)

    def _new_road(self, i: int, road_seed: int | None) -> None:
        if self._tables is None:
            return
        template = self.template
        if road_seed is None:
            road_seed = int(self._generators[i].integers(2**31))
        length = template.speed * self.dt * self.episode_steps + template.far_preview + 1.0
        road = Road.random(check_int("road_seed", road_seed, minimum=0), length)
        for table in self._tables:
            table.set(i, road)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Reset every copy; copy ``i`` is seeded ``seed + i``."""
        options = check_options(options, ("road_seed",), example={"road_seed": 0})
        if "road_seed" in options and self._tables is None:
            raise ValueError("reset option road_seed applies to road='random' only")
        if seed is not None or not self._generators:
            self._generators = [
                seeding.np_random(None if seed is None else seed + i)[0]
                for i in range(self.num_envs)
            ]
        n = self.num_envs
        for i in range(n):
            self._new_road(i, options.get("road_seed"))
        self._x = np.zeros((n, self._phi_t.shape[0]))
        self._k = np.zeros(n, dtype=np.int64)
        self._u = np.zeros(n)
        self._done = np.zeros(n, dtype=bool)
        self._clipped = np.zeros(n, dtype=bool)
        self._kappa_now, far = self._curvatures(self._k)
        self._percept = self._perceive(self._x, self._kappa_now, far)
        self._previous = self._percept[:, :4].copy()
        return self._observe(), self._infos()

    def _perceive(self, x: FloatArray, kappa: FloatArray, far: FloatArray) -> FloatArray:
        percept = np.empty((x.shape[0], 7))
        percept[:, 0] = self.template.far_gain * far
        percept[:, 1:] = x @ self._H_t + kappa[:, None] * self._h_kappa
        return percept

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
            # (num_envs,) is accepted too: one steering action per copy either way
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
        x = (
            self._x @ self._phi_t
            + u[:, None] * self._gamma[:, 0]
            + (self._kappa_now[:, None] * self._gamma[:, 1])
        )
        k = np.minimum(self._k + 1, self.episode_steps)
        kappa, far = self._curvatures(k)
        previous = self._percept[:, :4]
        percept = self._perceive(x, kappa, far)
        y_L, a_y = percept[:, 5], percept[:, 4]
        offset = y_L / template.reward_scale
        kind = template.reward_kind
        if kind == "bounded":
            reward = 1.0 / (1.0 + offset * offset)
        elif kind == "squared_offset":
            reward = -offset * offset
        else:
            effort = u / bound
            reward = -offset * offset - template.effort_weight * effort * effort
        if template.loss_of_control:
            terminated = (np.abs(y_L) > template.lane_limit) | (np.abs(a_y) > template.skid_limit)
        else:
            terminated = np.zeros(self.num_envs, dtype=bool)
        truncated = k >= self.episode_steps
        done = self._done
        if done.any():
            rows = np.flatnonzero(done)
            for i in rows:
                self._new_road(int(i), None)
            x[done] = 0.0
            k[done] = 0
            u[done] = 0.0
            kappa_reset, far_reset = self._curvatures(k)
            kappa[done] = kappa_reset[done]
            far[done] = far_reset[done]
            percept[done] = self._perceive(x[done], kappa[done], far[done])
            previous = previous.copy()
            previous[done] = percept[done, :4]
            reward[done] = 0.0
            terminated[done] = False
            truncated[done] = False
        self._x, self._k, self._u = x, k, u
        self._kappa_now = kappa
        self._previous = previous
        self._percept = percept
        self._done = terminated | truncated
        return self._observe(), reward, terminated, truncated, self._infos()

    def _observe(self) -> FloatArray:
        template = self.template
        columns = [self._percept[:, :4]]
        if template.include_rates:
            first = (self._k == 0)[:, None]
            columns.append(np.where(first, 0.0, (self._percept[:, :4] - self._previous) / self.dt))
        if template.include_previous_action:
            columns.append(self._u[:, None])
        return np.concatenate(columns, axis=1) if len(columns) > 1 else columns[0].copy()

    def _infos(self) -> dict[str, Any]:
        template = self.template
        return {
            "t": template.time_origin + self._k * self.dt,
            "s": template.speed * self.dt * self._k,
            "kappa": self._kappa_now.copy(),
            "y_L": self._percept[:, 5].copy(),
            "psi_L": self._percept[:, 6].copy(),
            "a_y": self._percept[:, 4].copy(),
            "action": self._u.copy(),
            "clipped": self._clipped.copy(),
        }

    def close_extras(self, **kwargs: Any) -> None:  # noqa: D102
        self.template.close()
