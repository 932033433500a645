"""An online estimator in every copy of a batched tracking environment, one call a step.

:class:`VectorEstimatorObserver` wraps a native batched tracking environment
(``gymnasium.make_vec("ManualControl/CompensatoryTracking-v0", num_envs=N)``, see
:mod:`manualcontrol.envs.tracking_vector`) and, after each step, feeds every copy's
sample to its own copy of an online estimator. The ``N`` filters are one
:class:`~manualcontrol.estimators.batch.FilterBatch`, stepped by one compiled call per
environment step, so the estimator costs about its own arithmetic per copy and nothing
per copy in Python.

Each copy's estimates are those an :class:`~manualcontrol.estimators.observer.
EstimatorObserver` gives around a single environment with the same arguments and seed
``seed + i`` (the batched environment seeds its copies so), bit for bit: the samples
are the same (the displayed error, output and target ahead of step ``k`` seen before
the action, and the stick applied), and so is the step that reads them. (With a
time-varying element the batched environment's signals agree with the single one's to
about 1e-12, not bit for bit: it sums each copy's matrix product in another order.)

The batched environment resets a copy the step after its episode ended (next-step
autoreset) and ignores that step's action; the observer then restarts that copy's
filter and feeds it nothing on that step.

``info["estimates"]`` (``estimates_in_info="arrays"``, the default) holds ``t`` (``N``:
the time of each copy's last sample, NaN where a copy has had none since its reset),
``mean`` and ``std`` (``N x p``, columns in :attr:`VectorEstimatorObserver.
parameter_names` order; zeros in a row whose ``t`` is NaN: no estimate yet, the initial
values being the estimator's ``resolved.initial``), copies made at every step.
``"none"`` reports nothing: :meth:`VectorEstimatorObserver.latest` gives views of the
arrays and :meth:`VectorEstimatorObserver.last_estimate` one copy's estimate as the
single observer's dicts. Per-copy dicts are not offered at every step: building them
would cost more than the filters.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from gymnasium.vector import VectorWrapper
from gymnasium.vector.utils import batch_space
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_choice, check_int
from manualcontrol.envs.tracking_vector import TrackingVectorEnv
from manualcontrol.estimators.batch import FilterBatch
from manualcontrol.estimators.observer import check_online_estimator

__all__ = ["VECTOR_ESTIMATE_FORMS", "VectorEstimatorObserver"]

#: What ``info["estimates"]`` holds each step (module docstring).
VECTOR_ESTIMATE_FORMS: tuple[str, ...] = ("arrays", "none")

FloatArray = NDArray[np.float64]


class VectorEstimatorObserver(VectorWrapper):
    """Feed a batch of online estimators from a batched tracking environment.

    Parameters
    ----------
    env
        A native batched tracking environment (``gymnasium.make_vec`` of a tracking id).
    estimator
        An online estimator set up for a causal start, of a member with a batched step
        (:class:`~manualcontrol.estimators.batch.FilterBatch`); every copy gets its
        settings.
    append_to_observation
        Append each copy's estimated parameters' means to its observation.
    estimates_in_info
        ``"arrays"`` or ``"none"`` (:data:`VECTOR_ESTIMATE_FORMS`, module docstring).
    """

    def __init__(
        self,
        env: Any,
        estimator: Any,
        append_to_observation: bool = False,
        estimates_in_info: str = "arrays",
    ) -> None:
        if not isinstance(env.unwrapped, TrackingVectorEnv):
            raise TypeError(
                "env must be a batched manualcontrol tracking environment "
                "(gymnasium.make_vec of a tracking id, vectorization_mode=None), got "
                f"{type(env.unwrapped).__name__}; wrap single environments in an "
                "EstimatorObserver each"
            )
        super().__init__(env)
        self.estimates_in_info = check_choice(
            "estimates_in_info", estimates_in_info, VECTOR_ESTIMATE_FORMS
        )
        keys = check_online_estimator(estimator)
        self.batch = FilterBatch(estimator, env.num_envs)
        self.append_to_observation = bool(append_to_observation)
        self._display_keys = tuple(key for key in keys if key in ("e", "y", "ft"))
        settings = getattr(estimator, "settings", None)
        self._anticipation = float(getattr(settings, "anticipation_time", None) or 0.0)
        base = env.unwrapped
        batch = self.batch
        batch.reset(base.dt)
        #: The columns of the estimate arrays: the estimator's parameters.
        self.parameter_names = batch.parameter_names
        #: The estimated parameters: what ``append_to_observation`` appends, in order.
        self.estimated = batch.estimated_names()
        self._estimated_columns = np.array(
            [self.parameter_names.index(name) for name in self.estimated], dtype=np.int64
        )
        initial = batch.estimator.resolved.initial
        self._initial_means = np.array([initial[name] for name in self.estimated])
        if self.append_to_observation:
            box = env.single_observation_space
            low = np.full(len(self.estimated), -np.inf)
            self.single_observation_space = spaces.Box(
                np.concatenate([box.low, low]), np.concatenate([box.high, -low]), dtype=np.float64
            )
            self.observation_space = batch_space(self.single_observation_space, env.num_envs)
        self._ahead = self._targets_ahead() if "ft_ahead" in keys else None
        n = env.num_envs
        self._t = np.full(n, np.nan)
        self._index = np.zeros(n, dtype=np.int64)
        self._restarting = np.zeros(n, dtype=np.bool_)
        self._pending: dict[str, FloatArray] = {}

    # ------------------------------------------------------------------ samples

    def _targets_ahead(self) -> FloatArray:
        """``ft(t_k + tau_a)`` at every step time, one row per forcing realisation.

        Evaluated once, elementwise at the same times as the single observer's.
        """
        base = self.env.unwrapped
        times = base.times + self._anticipation
        rows = []
        for realisation in range(base.realisation_count):
            target = base.forcing_of(realisation).target
            rows.append(np.zeros_like(times) if target is None else np.asarray(target(times)))
        return np.stack(rows)

    def _display(self, info: dict[str, Any]) -> dict[str, FloatArray]:
        """What each copy's next sample takes from the display (before the action)."""
        pending = {"t": np.array(info["t"], dtype=np.float64)}
        for key in self._display_keys:
            pending[key] = np.array(info[key], dtype=np.float64)
        if self._ahead is not None:
            pending["ft_ahead"] = self._ahead[self.env.unwrapped.realisations, self._index]
        return pending

    def _observe(self, observations: FloatArray) -> FloatArray:
        if not self.append_to_observation:
            return observations
        means = self.batch.latest()[0][:, self._estimated_columns]
        fresh = np.isnan(self._t)
        if fresh.any():  # no sample since the copy's reset: the initial values
            means = means.copy()
            means[fresh] = self._initial_means
        return np.concatenate([observations, means], axis=1)

    # ---------------------------------------------------------------------- API

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Reset every copy and its filter."""
        observations, info = self.env.reset(seed=seed, options=options)
        self.batch.reset(self.env.unwrapped.dt)
        self._t[:] = np.nan
        self._index[:] = 0
        self._restarting[:] = False
        self._pending = self._display(info)
        return self._observe(observations), info

    def step(
        self, actions: Any
    ) -> tuple[FloatArray, FloatArray, NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:
        """Step every copy; feed each copy's filter its sample of this step."""
        observations, rewards, terminated, truncated, info = self.env.step(actions)
        pending = self._pending
        pending["u"] = np.asarray(info["u"], dtype=np.float64)
        restarting = self._restarting
        fed = ~restarting
        self.batch.step(pending, fed)
        self._t[fed] = pending["t"][fed]
        self._index += 1
        if restarting.any():  # the environment reset these copies on this step
            self.batch.reset_copies(restarting)
            self._t[restarting] = np.nan
            self._index[restarting] = 0
        self._restarting = terminated | truncated
        self._pending = self._display(info)
        if self.estimates_in_info == "arrays":
            mean, std = self.batch.latest()
            info["estimates"] = {"t": self._t.copy(), "mean": mean.copy(), "std": std.copy()}
        return self._observe(observations), rewards, terminated, truncated, info

    def latest(self) -> tuple[FloatArray, FloatArray]:
        """Views of every copy's means and standard deviations after the last step."""
        return self.batch.latest()

    @property
    def times(self) -> FloatArray:
        """Time of each copy's last sample (NaN where none since its reset; a copy)."""
        return self._t.copy()

    def last_estimate(self, i: int) -> dict[str, Any] | None:
        """Copy ``i``'s last estimate as the single observer's dicts; None before one."""
        i = check_int("i", i, minimum=0, maximum=self.num_envs - 1)
        if np.isnan(self._t[i]):
            return None
        return self.batch.latest_plain(i, float(self._t[i]))
