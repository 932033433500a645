"""Gap-postview tracking: the past track, shown down to a gap before the present.

Boer & Kenyon (1998, Sec. V, Fig. 5): a winding track is displayed from ``t - postview``
(1 s, the top of the screen) down to ``t - gap``; between its end and the marker, which
sits at the present, the screen is blank. The marker moves with the stick through the
controlled element (a pure gain in the paper), and the task is to keep it where the
track will cross the present line, ``ft(t)``: the participant has to extrapolate across
the gap. The gap may vary in time (a schedule; the paper's followed a random walk).

==============  ======================================================================
observation     ``[ft(t - gap), ft(t - gap - dt), .., ft(t - gap - (W - 1) dt), gap, y]``
                (float64): the visible track read back from its lower end, ``W =
                round(postview/dt) + 1`` samples, entries beyond the top of the screen
                (lags past ``postview``) held at ``ft(t - postview)``; the gap (s) and
                the marker position ``y``
==============  ======================================================================

With ``include_rates=True`` the backward-difference rates of the track's end and of the
marker are appended, with ``include_previous_action=True`` the previous stick (as in
:mod:`~manualcontrol.envs.tracking`, whose stepping, actions, rewards, termination and
truncation this environment shares; ``e = ft - y`` is scored though ``ft`` is not
shown). ``info`` adds ``gap``; :meth:`PostviewTracking.recording` adds the ``gap``
trace to the parameters.

:func:`postview_samples` and :func:`edge_perceptions` are the display's reading rules,
shared with :func:`~manualcontrol.pilots.simulate` (``task="postview"``) so that a pilot
acting in this environment reproduces that simulation: the track's end value and its
slope by the second-order backward difference over the first three samples.

Rendering: the track runs down the screen from ``t - postview`` at the top to
``t - gap``, above the marker (a box) at the bottom; the time axis is not drawn.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_positive
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.schedules import Schedule, as_schedule
from manualcontrol.envs.signals import ForcingPair
from manualcontrol.envs.tracking import TrackingEnv

__all__ = [
    "DEFAULT_GAP",
    "DEFAULT_POSTVIEW",
    "PostviewTracking",
    "check_gap",
    "edge_perceptions",
    "postview_samples",
]

FloatArray = NDArray[np.float64]

#: Default gap (s): about where Boer & Kenyon's gap signal started (Sec. V-B).
DEFAULT_GAP = 0.4
#: Past track shown (s): the top of the screen is ``t - 1 s`` (Sec. V-A).
DEFAULT_POSTVIEW = 1.0


def check_gap(gap: float | Schedule, times: FloatArray, postview: float) -> FloatArray:
    """The gap at ``times`` as an array, checked to lie in ``[0, postview)``."""
    try:
        schedule = as_schedule(gap)
    except TypeError as error:
        raise TypeError(f"gap: {error}") from None
    values = np.broadcast_to(np.asarray(schedule(times), dtype=np.float64), times.shape).copy()
    bad = (values < 0.0) | (values >= postview)
    if bad.any():
        raise ValueError(
            f"gap must lie in [0, {postview:g}) s (below the postview shown), got "
            f"{float(values[bad][0])!r} at t = {float(times[bad][0]):g} s"
        )
    return values


def postview_samples(
    target: Callable[[FloatArray], Any] | None,
    times: FloatArray,
    gaps: FloatArray,
    dt: float,
    postview: float,
    count: int,
) -> FloatArray:
    """``(len(times), count)``: the track read back from its visible end at each time.

    Column ``j`` is ``ft(t - min(gap + j dt, postview))``: what the display shows
    ``j`` samples above the end of the track (held at the top of the screen).
    """
    lags = np.minimum(gaps[:, None] + dt * np.arange(count), postview)
    if target is None:
        return np.zeros(lags.shape)
    return np.asarray(target(times[:, None] - lags), dtype=np.float64)


def edge_perceptions(samples: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    """Value and slope (per s) of the visible track's end from :func:`postview_samples`.

    The slope is the second-order backward difference ``(3 x0 - 4 x1 + x2) / (2 dt)``
    (exact for quadratics) over the first three samples, which the display shows.
    """
    x0, x1, x2 = samples[..., 0], samples[..., 1], samples[..., 2]
    return x0, (3.0 * x0 - 4.0 * x1 + x2) / (2.0 * dt)


class PostviewTracking(TrackingEnv):
    """Gap-postview tracking (Boer & Kenyon 1998, Sec. V); see the module docstring.

    Parameters
    ----------
    controlled_element
        As for :class:`~manualcontrol.envs.tracking.TrackingEnv`; default ``"gain"``
        (the paper's pure-gain marker).
    forcing, realisation
        Default ``"boer-kenyon1998-postview"``: 0.6-Hz band-limited noise (the target).
    gap
        The blank stretch below the track (s): a number or a schedule, in
        ``[0, postview)`` over the whole episode (default 0.4).
    postview
        Past track shown (s, > 0; default 1).
    **kwargs
        The other keywords of :class:`~manualcontrol.envs.tracking.TrackingEnv`
        (``dt``, ``measurement_time``, ``run_in``, ``action_bound``, ``reward``, ...).

    Example::

        >>> import gymnasium as gym
        >>> import manualcontrol.envs
        >>> env = gym.make("ManualControl/PostviewTracking-v0", gap=0.3, dt=1 / 36)
        >>> observation, info = env.reset(seed=0)
        >>> observation.shape, info["gap"]
        ((39,), 0.3)
    """

    task: ClassVar[str] = "postview"

    def __init__(
        self,
        controlled_element: Any = "gain",
        forcing: str | ForcingPair = "boer-kenyon1998-postview",
        realisation: int | None = 0,
        *,
        gap: float | Schedule = DEFAULT_GAP,
        postview: float = DEFAULT_POSTVIEW,
        **kwargs: Any,
    ) -> None:
        self.postview = check_positive("postview", postview)
        try:
            self.gap = as_schedule(gap)
        except TypeError as error:
            raise TypeError(f"gap: {error}") from None
        if "available_preview" in kwargs and kwargs["available_preview"] not in (None, 0, 0.0):
            raise ValueError(
                f"available_preview must be 0 (or omitted) in a postview task, "
                f"got {kwargs['available_preview']!r}"
            )
        kwargs.pop("available_preview", None)
        self._windows: FloatArray | None = None
        super().__init__(controlled_element, forcing, realisation, **kwargs)
        if self.postview_samples < 3:
            raise ValueError(
                f"postview must show at least 3 samples (>= 2 dt = {2 * self.dt:g} s), "
                f"got {self.postview!r}"
            )
        self._gaps = check_gap(self.gap, self._time, self.postview)

    # ------------------------------------------------------------------ set-up

    @property
    def postview_samples(self) -> int:
        """``W``: track samples in the observation."""
        return round(self.postview / self.dt) + 1

    def _base_size(self) -> int:
        return self.postview_samples + 2

    def _rate_size(self) -> int:
        return 2

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[FloatArray, dict[str, Any]]:
        """Start an episode at rest; ``options={"realisation": i}`` picks the realisation."""
        self._windows = None
        return super().reset(seed=seed, options=options)

    def _window(self) -> FloatArray:
        if self._windows is None:
            self._windows = postview_samples(
                self.forcing.target,
                self._time,
                self._gaps,
                self.dt,
                self.postview,
                self.postview_samples,
            )
        return self._windows

    def _observe(self, k: int) -> FloatArray:
        windows = self._window()
        count = self.postview_samples
        extra = (2 if self.include_rates else 0) + self.include_previous_action
        observation = np.empty(count + 2 + extra)
        observation[:count] = windows[k]
        observation[count] = self._gaps[k]
        observation[count + 1] = self._y[k]
        if self.include_rates:
            dt = self.dt
            observation[count + 2] = 0.0 if k == 0 else (windows[k, 0] - windows[k - 1, 0]) / dt
            observation[count + 3] = 0.0 if k == 0 else (self._y[k] - self._y[k - 1]) / dt
        if self.include_previous_action:
            observation[-1] = self._previous_u
        return observation

    def _info(self, k: int, u: float) -> dict[str, Any]:
        info = super()._info(k, u)
        info["gap"] = float(self._gaps[k])
        return info

    def recording(self, include_run_in: bool = False) -> Recording:
        """The steps so far as a Recording; adds the ``gap`` trace and the display settings."""
        recorded = super().recording(include_run_in)
        start = 0 if include_run_in else min(self.n_run_in, self._k - 1)
        gaps = self._gaps[start : start + len(recorded)]
        metadata: Mapping[str, Any] = {
            "gap": self.gap.to_dict(),
            "postview": self.postview,
            "source": "manualcontrol.envs.postview.PostviewTracking",
        }
        return recorded.with_parameters(gap=gaps).with_metadata(**metadata)

    # -------------------------------------------------------------- rendering

    def _draw(self, canvas: Any, pygame: Any) -> None:
        width, height = canvas.get_size()
        canvas.fill((20, 20, 28))
        scale = 0.4 * width / (3.0 / self._inverse_std)
        centre = width / 2
        k = max(self._k, 0)
        track_colour, marker_colour = (240, 200, 60), (80, 200, 255)
        marker_row = int(0.85 * height)
        top_row = int(0.1 * height)
        per_second = (marker_row - top_row) / self.postview
        gap = float(self._gaps[k])
        lags = gap + self.dt * np.arange(self.postview_samples)
        visible = lags <= self.postview + 1e-12
        values = self._window()[k][visible]
        rows = marker_row - lags[visible] * per_second
        points = [(centre + scale * float(v), float(r)) for v, r in zip(values, rows, strict=True)]
        if len(points) > 1:
            pygame.draw.lines(canvas, track_colour, False, points, 3)
        elif points:
            pygame.draw.circle(canvas, track_colour, (int(points[0][0]), int(points[0][1])), 4)
        x = centre + scale * float(self._y[k])
        pygame.draw.rect(
            canvas, marker_colour, pygame.Rect(int(x) - 12, marker_row - 12, 24, 24), 3
        )
