"""Python-side pieces every estimator shell shares: reading a sample, summarising health.

The compiled kernels record per-sample flags and, in the scalar state ``sc`` (``SC_*``
of :mod:`~manualcontrol.estimators._pilot_core`), the divergence; these turn that into
what the protocol returns, written once for the family.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import reject_unknown
from manualcontrol.estimators import _pilot_core as core
from manualcontrol.estimators.filters import monitor
from manualcontrol.estimators.protocol import HealthSummary

__all__ = ["REASONS", "health_summary", "read_sample"]

#: Words for the divergence codes of :mod:`~manualcontrol.estimators.filters.monitor`.
REASONS = {
    monitor.REASON_NONFINITE: "non-finite values",
    monitor.REASON_COVARIANCE: "covariance blow-up",
}


def read_sample(sample: Any, keys: Sequence[str], where: str) -> dict[str, float]:
    """The values of ``keys`` in ``sample`` (``t`` may be present too), checked.

    NaN is allowed (a dropped sample), infinity and non-numbers are not; missing and
    unknown keys raise naming ``where``.
    """
    if not isinstance(sample, Mapping):
        raise TypeError(f"sample must be a mapping of signal values, got {sample!r}")
    reject_unknown(where, sample, (*keys, "t"))
    missing = [key for key in keys if key not in sample]
    if missing:
        raise ValueError(
            f"{where} lacks {', '.join(map(repr, missing))}; it needs {', '.join(map(repr, keys))}"
        )
    values = {}
    for key in keys:
        value = sample[key]
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
            raise TypeError(f"sample[{key!r}] must be a number, got {value!r}")
        value = float(value)
        if math.isinf(value):
            raise ValueError(f"sample[{key!r}] must be finite or NaN (dropped), got {value!r}")
        values[key] = value
    return values


def health_summary(
    sc: NDArray[np.float64],
    t: NDArray[np.float64],
    dt: float,
    flag: NDArray[np.bool_],
    pinned: NDArray[np.bool_],
    names: Sequence[str],
    pinned_time: float,
) -> HealthSummary:
    """A run's :class:`HealthSummary` from the kernel's scalar state and per-sample flags.

    ``flag[:, 2]`` marks dropped samples; ``pinned`` (n, p) the parameters at a limit.
    """
    reason_code = int(sc[core.SC_DIV_REASON])
    diverged = reason_code != monitor.REASON_NONE
    if reason_code == monitor.REASON_PINNED:
        name = names[int(sc[core.SC_DIV_PARAM])]
        reason = f"{name} pinned at a limit for {pinned_time:g} s"
    else:
        reason = REASONS.get(reason_code, "")
    index = int(sc[core.SC_DIV_INDEX])
    dropped = flag[:, 2]
    edges = np.diff(np.concatenate(([0], dropped.astype(np.int8), [0])))
    starts = np.flatnonzero(edges == 1)
    stops = np.flatnonzero(edges == -1)
    stretches = tuple(
        (float(t[a]), float((b - a) * dt)) for a, b in zip(starts, stops, strict=True)
    )
    return HealthSummary(
        diverged=diverged,
        divergence_time=float(t[index]) if diverged and 0 <= index < len(t) else math.nan,
        divergence_reason=reason,
        stopped=bool(sc[core.SC_FROZEN] > 0.0),
        dropped_samples=int(dropped.sum()),
        dropped_stretches=stretches,
        pinned_fraction={
            n: float(pinned[:, j].mean()) if len(t) else 0.0 for j, n in enumerate(names)
        },
    )
