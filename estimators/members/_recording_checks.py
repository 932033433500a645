"""Checks of a recording before an estimator runs on it (shared by every estimator).

An estimator given a recording it cannot work on should say what is wrong with the
recording, not fail later with a message about its own initial values.
"""

from __future__ import annotations

import numpy as np

from manualcontrol.envs.recording import Recording

__all__ = ["check_estimable"]


def check_estimable(recording: Recording, *, window: float, signal: str = "u") -> None:
    """Refuse a recording shorter than 1 s (or ``window``) or whose ``signal`` is all NaN.

    The initial noise levels come from the variances over the first ``window``; a
    recording of a few samples gives them no meaning, and the filter's own message
    (about its initial values) would send the user to the wrong place.
    """
    if not isinstance(recording, Recording):
        raise TypeError(f"recording must be a Recording, got {recording!r}")
    span = min(window, 1.0)
    needed = round(span / recording.dt) + 1
    if len(recording) < needed:
        raise ValueError(
            f"the recording has {len(recording)} samples; the estimator needs at least "
            f"{needed} ({span:g} s at dt = {recording.dt:g} s)"
        )
    if signal in recording and not np.any(np.isfinite(recording[signal])):
        raise ValueError(
            f"the recording's {signal} has no finite sample (all {len(recording)} are NaN): "
            "nothing to estimate from"
        )
