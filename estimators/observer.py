"""Running an online estimator inside a tracking environment.

:class:`EstimatorObserver` wraps any :mod:`~manualcontrol.envs.tracking` environment
(possibly wrapped itself, e.g. with an agent's human limitations) and feeds each
step's signals to an online estimator, whoever acts: a cybernetic pilot, an RL policy
or a person. After every step ``info["estimates"]`` holds the current estimate:

``mean``, ``std``
    every parameter of the estimator's pilot model (held ones with std 0);
``innovation``, ``innovation_variance``, ``prediction``
    the filter's one-step figures for the sample just taken;
``health``
    ``finite``, ``covariance_ok``, ``pinned`` (parameter names), ``dropped``,
    ``diverged``.

All are plain dicts, lists and floats, new at every step, so ``info`` pickles (a
vector env in subprocesses) and a vector env stacks them per key.

Where the C ports build, a pilot filter (DEKF, RML, joint and dual UKF; not the RML's
causal remnant choice, which steps two passes and decides between them in Python) reads
the sample, steps and builds these dicts in one C call
(:mod:`~manualcontrol.estimators._online_native`); elsewhere building them in Python
costs about as much as the filter's own step. ``estimates_in_info`` chooses what a
step reports: ``"dicts"`` (the default, as above), ``"arrays"`` (``t``
and copies of ``mean`` and ``std`` as arrays, columns in :attr:`EstimatorObserver.
parameter_names` order), or ``"none"`` (nothing; :meth:`EstimatorObserver.
last_estimate` builds the dicts of the last step on request). The estimates are the
same in every form, bit for bit.

With ``"none"`` (and nothing appended to the observation), nobody reads an estimate
between steps unless they ask, so the observer keeps the samples (their floats in a
list) and steps the filter through them in one compiled call when an estimate is read
(:meth:`EstimatorObserver.last_estimate`, :attr:`EstimatorObserver.estimator`), at the
end of an episode, or every :data:`BLOCK_SAMPLES` samples
(:meth:`~manualcontrol.estimators.members.pilot_filter.PilotFilter.update_block`, for
members with a batched step). What is read is what stepping every sample would have
given, bit for bit; the loop pays for the filter's arithmetic and not for entering
compiled code each step.

A sample the filter refuses (an infinite value; NaN marks a dropped sample) raises
``ValueError`` and is left out, in every form, and the steps after it go on: at the
step that completes it, or with ``"none"`` when its block is stepped (once a block,
naming the first such sample's time), the samples around it stepped first. The step
that raises returns nothing, so where it is an episode's last the caller resets.

With ``append_to_observation=True`` the means of the estimated parameters are
appended to the observation (in the estimator's order; the initial values before the
first sample), the observation space extended accordingly.

The sample of step ``k`` is the displayed error ``e[k]`` (and output ``y[k]``, target
ahead ``ft(t_k + tau_a)`` for a preview model) seen before the action, and the stick
``u[k]`` applied: the same samples an offline :meth:`estimate` reads from the episode's
:class:`~manualcontrol.envs.recording.Recording`, so both give the same numbers. The
estimator must start causally (``initial_variance="causal"`` for the DEKF: online,
the first window of data is not known at reset).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from manualcontrol.envs._lazy import has_kernel
from manualcontrol.envs._validation import check_choice
from manualcontrol.envs.tracking import TrackingEnv
from manualcontrol.estimators.protocol import ParameterValues

__all__ = [
    "BLOCK_SAMPLES",
    "ESTIMATE_FORMS",
    "ONLINE_SAMPLE_KEYS",
    "EstimatorObserver",
    "check_online_estimator",
]

#: The samples a tracking environment gives an online estimator (module docstring).
ONLINE_SAMPLE_KEYS: tuple[str, ...] = ("e", "u", "y", "ft", "ft_ahead")

#: What ``info["estimates"]`` holds each step (module docstring).
ESTIMATE_FORMS: tuple[str, ...] = ("dicts", "arrays", "none")

#: Samples the ``"none"`` form keeps at most before stepping the filter through them
#: (module docstring): enough that entering compiled code costs little a sample, few
#: enough that the kept block stays small and in cache.
BLOCK_SAMPLES = 256

FloatArray = NDArray[np.float64]


def _plain(values: Mapping[str, float]) -> dict[str, float]:
    """A plain dict of an estimate's values (at once for the filters' row snapshots)."""
    return values.as_dict() if isinstance(values, ParameterValues) else dict(values)


def check_online_estimator(estimator: Any) -> tuple[str, ...]:
    """The sample keys of an estimator an environment can feed online, or raise.

    Online, nothing of the run is known at reset: the estimator must start causally
    (``initial_variance="causal"``) and make no restarts (a second pass over the whole
    recording), and read only what a tracking display and stick give.
    """
    settings = getattr(estimator, "settings", None)
    # only the filters on pilot models (their noise group) can start on a first window
    noise = getattr(settings, "noise", None)
    if getattr(noise, "initial_variance", "causal") != "causal":
        raise ValueError(
            "estimator must start causally online: configure it with "
            "initial_variance='causal' (and initial K_p), got "
            f"initial_variance={noise.initial_variance!r}"
        )
    if getattr(settings, "restarts", 0):
        raise ValueError(
            "restarts pass a whole recording again (estimate, offline); an observer "
            f"runs the filter online: configure it with restarts=0, got "
            f"restarts={settings.restarts!r}"
        )
    keys = tuple(estimator.sample_keys)
    unknown = sorted(set(keys) - set(ONLINE_SAMPLE_KEYS))
    if unknown:
        raise ValueError(f"the environment cannot supply the estimator's samples {unknown}")
    return keys


class EstimatorObserver(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Feed an online estimator from an environment; report its estimates in ``info``.

    Parameters
    ----------
    env
        A tracking environment, possibly wrapped.
    estimator
        An online estimator (e.g. :class:`~manualcontrol.estimators.DEKF`) set up for a
        causal start.
    append_to_observation
        Append the estimated parameters' means to the observation.
    estimates_in_info
        What each step's ``info["estimates"]`` holds: ``"dicts"``, ``"arrays"`` or
        ``"none"`` (:data:`ESTIMATE_FORMS`, module docstring).
    """

    def __init__(
        self,
        env: gym.Env,
        estimator: Any,
        append_to_observation: bool = False,
        estimates_in_info: str = "dicts",
    ) -> None:
        gym.utils.RecordConstructorArgs.__init__(
            self,
            estimator=estimator,
            append_to_observation=append_to_observation,
            estimates_in_info=estimates_in_info,
        )
        self.estimates_in_info = check_choice(
            "estimates_in_info", estimates_in_info, ESTIMATE_FORMS
        )
        gym.Wrapper.__init__(self, env)
        if not isinstance(env.unwrapped, TrackingEnv):
            raise TypeError(
                "env must be a manualcontrol tracking environment, "
                f"got {type(env.unwrapped).__name__}"
            )
        keys = check_online_estimator(estimator)
        self._estimator = estimator
        self._kept = 0
        self.append_to_observation = bool(append_to_observation)
        settings = getattr(estimator, "settings", None)
        self._keys = keys
        self._display_keys = tuple(key for key in keys if key in ("e", "y", "ft"))
        self._anticipation = float(getattr(settings, "anticipation_time", None) or 0.0)
        self._estimated = self._estimated_names()
        # the family's members build these dicts from their output row directly, or
        # leave the estimate in the row until asked (update_quiet, latest)
        self._update_plain = getattr(estimator, "update_plain", None)
        self._update_quiet = getattr(estimator, "update_quiet", None)
        #: The columns of the ``"arrays"`` form: the estimator's parameters.
        self.parameter_names = tuple(estimator.parameter_names)
        self._columns = {name: j for j, name in enumerate(self.parameter_names)}
        self._t = None
        if self.append_to_observation:
            low = np.full(len(self._estimated), -np.inf)
            box = env.observation_space
            self.observation_space = spaces.Box(
                np.concatenate([box.low, low]), np.concatenate([box.high, -low]), dtype=np.float64
            )
        self._last: dict[str, Any] | None = None
        self._pending: dict[str, float] = {}
        self._ahead: list[float] | None = None
        self._step_index = 0
        # the "none" form's kept samples (module docstring), flat in the estimator's
        # sample_keys order, u last: a float appended per value is the cheapest keeping
        order = tuple(getattr(estimator, "sample_keys", ()))
        self._keeps = (
            self.estimates_in_info == "none"
            and not self.append_to_observation
            and hasattr(estimator, "update_block")
            and has_kernel(type(estimator), "_step_many_kernel")
            and not (estimator.batchable() if hasattr(estimator, "batchable") else "")
            and order[-1:] == ("u",)
        )
        self._kept_keys = order[:-1]  # what the display gives, read before the action
        self._kept_values: list[float] = []
        self._kept_t = 0.0
        self._consumed_t: float | None = None

    @property
    def estimator(self) -> Any:
        """The online estimator, stepped through every sample so far."""
        self._step_kept()
        return self._estimator

    def _step_kept(self) -> None:
        """Step the filter through the kept samples (the ``"none"`` form's block).

        A sample the filter refuses (an infinite value; NaN is a dropped sample) is
        left out, as the other forms leave it out at its own step, and the rest are
        stepped before the refusal is raised: nothing kept is lost.
        """
        if self._kept:
            kept, self._kept = self._kept, 0
            width = len(self._kept_keys) + 1
            values = self._kept_values
            # after the last whole sample: the next sample's display, kept already
            self._kept_values = values[kept * width :]
            block = np.array(values[: kept * width], dtype=np.float64).reshape(kept, width)
            refused = np.isinf(block).any(axis=1)
            if not refused.any():
                self._estimator.update_block(block, t=self._t)
                self._consumed_t = self._t
                return
            first = int(np.flatnonzero(refused)[0])
            # the block's samples are the steps just before this one, at the env's times
            times = self.env.unwrapped.times[self._step_index - kept : self._step_index]
            for part in np.split(np.arange(kept), np.flatnonzero(refused)):
                part = part[~refused[part]]
                if len(part):
                    self._consumed_t = float(times[part[-1]])
                    self._estimator.update_block(block[part], t=self._consumed_t)
            self._t = self._consumed_t  # the estimate's time: its last sample's
            column = int(np.flatnonzero(np.isinf(block[first]))[0])
            key = (*self._kept_keys, "u")[column]
            raise ValueError(
                f"the sample at t = {times[first]:.6g} s has {key} infinite; it was left out "
                "of the estimate (NaN marks a dropped sample)"
            )

    @staticmethod
    def _as_plain(estimate: Any) -> dict[str, Any]:
        return {
            "t": estimate.t,
            "mean": _plain(estimate.mean),
            "std": _plain(estimate.std),
            "innovation": estimate.innovation,
            "innovation_variance": estimate.innovation_variance,
            "prediction": estimate.prediction,
            "health": estimate.health.as_dict(),
        }

    def _estimated_names(self) -> tuple[str, ...]:
        # what is estimated is resolved at reset (e.g. the SI rule holds K_v); the env's
        # forcing, which some estimators read at reset, is drawn at the env's own reset
        dt = self.env.unwrapped.dt
        names = getattr(self.estimator, "estimated_names", None)
        if names is not None:
            return tuple(names(dt))
        self.estimator.reset(dt)
        return tuple(self.estimator.resolved.estimated)

    def _reset_estimator(self, t0: float) -> None:
        """Reset the estimator for an episode from ``t0``, with the forcing where it reads it."""
        base = self.env.unwrapped
        if getattr(self.estimator, "reads_forcing", False):
            self.estimator.reset(base.dt, t0=t0, forcing=base.forcing)
        else:
            self.estimator.reset(base.dt, t0=t0)

    def _observe(self, observation: FloatArray) -> FloatArray:
        if not self.append_to_observation:
            return observation
        if self._t is None:  # before the first sample: the initial values
            initial = self.estimator.resolved.initial
            means = [initial[name] for name in self._estimated]
        elif self._last is None:  # the estimate left in the filter's row
            row = self._latest()[0]
            means = [float(row[self._columns[name]]) for name in self._estimated]
        else:
            means = [self._last["mean"][name] for name in self._estimated]
        return np.concatenate([observation, np.asarray(means, dtype=np.float64)])

    def _display(self, info: dict[str, Any]) -> dict[str, float]:
        """What the sample of this step takes from the display (before the action).

        Only the keys the estimator reads (and ``t``); ``u`` is added after the step.
        """
        sample = {"t": float(info["t"])}
        for key in self._display_keys:
            sample[key] = float(info[key])
        if self._ahead is not None:
            sample["ft_ahead"] = self._ahead[self._step_index]
        return sample

    def _target_ahead(self) -> FloatArray | None:
        """``ft(t + tau_a)`` at every step time of the episode, in one evaluation.

        Per step this was a scalar call of the forcing (35 us in preview). The env's
        own preview window is not read instead: ``tau_a`` may lie beyond the shown
        preview, and its samples at ``t0 + (k + j) dt`` differ from ``ft(t_k + tau_a)``
        by rounding, which the offline :meth:`estimate` on the episode's recording
        would not reproduce. The same elementwise evaluation at the same times does.
        """
        if "ft_ahead" not in self._keys:
            return None
        base = self.env.unwrapped
        times = base.times + self._anticipation
        target = base.forcing.target
        if target is None:
            return np.zeros_like(times)
        return np.asarray(target(times), dtype=np.float64)

    def reset(self, **kwargs: Any) -> tuple[FloatArray, dict[str, Any]]:  # noqa: D102
        observation, info = self.env.reset(**kwargs)
        self._kept, self._kept_values = 0, []  # an episode left unfinished: its samples go
        self._consumed_t = None  # the last sample the filter took (its time)
        self._reset_estimator(float(info["t"]))
        ahead = self._target_ahead()
        self._ahead = None if ahead is None else ahead.tolist()  # floats, read per step
        self._step_index = 0
        self._pending = self._display(info)
        self._last = None
        self._t = None
        if self._keeps:
            self._keep_display(info)
        return self._observe(observation), info

    def _keep_display(self, info: dict[str, Any]) -> None:
        """Keep what ``info`` displays: the next sample, but for its stick ``u``."""
        values = self._kept_values
        for key in self._kept_keys:
            values.append(self._ahead[self._step_index] if key == "ft_ahead" else float(info[key]))
        self._kept_t = float(info["t"])

    def last_estimate(self) -> dict[str, Any] | None:
        """The last step's estimate as the ``"dicts"`` form reports it; None before one."""
        if self._t is None:
            return None
        if self._last is None:
            self._last = self.estimator.latest_plain(self._t)
        return self._last

    def _latest(self) -> tuple[FloatArray, FloatArray]:
        """Means and standard deviations after the last step (views where the filter has them)."""
        if self._last is not None:
            mean, std = self._last["mean"], self._last["std"]
            return (
                np.array([mean[n] for n in self.parameter_names]),
                np.array([std[n] for n in self.parameter_names]),
            )
        return self.estimator.latest()

    def step(self, action: Any) -> tuple[FloatArray, float, bool, bool, dict[str, Any]]:  # noqa: D102
        observation, reward, terminated, truncated, info = self.env.step(action)
        if self._keeps:  # keep the sample; the filter steps when read
            self._kept_values.append(float(info["u"]))
            self._t = self._kept_t
            self._last = None
            self._kept += 1
            self._step_index += 1
            if not (terminated or truncated):  # first: a refusal below leaves it kept
                self._keep_display(info)
            if self._kept == BLOCK_SAMPLES or terminated or truncated:
                self._step_kept()
            return observation, reward, terminated, truncated, info
        sample = self._pending
        sample["u"] = float(info["u"])
        quiet = self._update_quiet
        try:
            if self.estimates_in_info == "dicts" or quiet is None:
                plain = self._update_plain
                if plain is None:
                    self._last = self._as_plain(self.estimator.update(sample))
                else:
                    self._last = plain(sample)
                self._t = self._last["t"]
            else:  # the thin path: the estimate stays in the filter's row until asked
                self._t = quiet(sample)
                self._last = None
        finally:  # a sample the filter refuses is left out, and the next one comes
            self._step_index += 1
            self._pending = self._display(info)
        # the env's info is a new dict every step
        if self.estimates_in_info == "dicts":
            info["estimates"] = self._last
        elif self.estimates_in_info == "arrays":
            # the filter's row after this sample where it stayed there (this form keeps
            # no samples back: no stepping through the estimator property)
            mean, std = self._latest() if self._last is not None else self._estimator.latest()
            info["estimates"] = {"t": self._t, "mean": mean.copy(), "std": std.copy()}
        return self._observe(observation), reward, terminated, truncated, info
