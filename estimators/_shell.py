"""Python-side pieces the estimator shells share: reading a sample, summarising health.

The compiled kernels record per-sample flags and, in the scalar state ``sc`` (``SC_*``
of :mod:`~manualcontrol.estimators._pilot_core`), the divergence; these turn that into
what the protocol returns, on top of :func:`~manualcontrol.estimators.protocol.sample_values`
and :func:`~manualcontrol.estimators.protocol.summarise_health` (which estimators with
other scalar layouts, such as the RDI, call directly).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.estimators import _pilot_core as core
from manualcontrol.estimators.filters import monitor
from manualcontrol.estimators.protocol import HealthSummary, sample_values, summarise_health

__all__ = ["REASONS", "health_summary", "read_sample"]

#: Words for the divergence codes of :mod:`~manualcontrol.estimators.filters.monitor`.
REASONS = {
    monitor.REASON_NONFINITE: "non-finite values",
    monitor.REASON_COVARIANCE: "covariance blow-up",
}


def read_sample(sample: Any, keys: Sequence[str], where: str) -> dict[str, float]:
    """The values of ``keys`` in ``sample`` (``t`` may be present too), checked."""
    keys = tuple(keys)
    return sample_values(where, sample, keys, (*keys, "t"))


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
    if reason_code == monitor.REASON_PINNED:
        reason = f"{names[int(sc[core.SC_DIV_PARAM])]} pinned at a limit for {pinned_time:g} s"
    else:
        reason = REASONS.get(reason_code, "")
    return summarise_health(
        t,
        dt,
        flag[:, 2],
        pinned,
        tuple(names),
        reason=reason,
        divergence_index=int(sc[core.SC_DIV_INDEX]),
        stopped=bool(sc[core.SC_FROZEN] > 0.0),
    )
