"""What every filter of the family watches besides its belief, compiled.

* Health: a belief is *finite* when its mean and covariance diagonal are, and its
  covariance is *ok* when no diagonal entry lies below zero beyond rounding and none
  exceeds the divergence threshold (:func:`belief_health`). A filter stops at the
  first sample that fails either (the divergence is reported, never silent NaN output).
* Parameters pinned at a limit: a ring of the last ``n`` samples per parameter counts
  how long each sat at a limit (:func:`track_pins`); 90 % of the ring counts as
  divergence, reported while the filter goes on.
* Retrospective variances over a sliding window (Popovici eqs. 24-25, thesis eqs.
  29-30: ``R = r^2 var(u)``, ``Q = q^2 var(e)``), NaN samples left out
  (:func:`window_push`, :func:`window_variance`).

Divergence reasons are small integer codes (``REASON_*``), turned into words by the
estimator.

The kernels live in :mod:`~manualcontrol.estimators.filters._monitor_kernels`, imported
on first use (a process whose filters run in C never imports numba); the constants they
read stay here.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from manualcontrol.envs._lazy import kernels_on_first_use

if TYPE_CHECKING:  # what tools read; at run time each kernel is imported on first use
    from manualcontrol.estimators.filters._monitor_kernels import (
        belief_health,
        track_pins,
        window_push,
        window_variance,
    )

__all__ = [
    "NEGATIVE_TOLERANCE",
    "PIN_FRACTION",
    "REASON_BEYOND_SAMPLE_RATE",
    "REASON_COVARIANCE",
    "REASON_NONE",
    "REASON_NONFINITE",
    "REASON_PINNED",
    "belief_health",
    "track_pins",
    "window_push",
    "window_variance",
]

# numba kernels read this module's constants
#: Fraction of the samples of the pin window at a limit that counts as pinned.
PIN_FRACTION = 0.9
#: Relative tolerance for a covariance diagonal below zero (rounding of a variance ~0).
NEGATIVE_TOLERANCE = 1e-10

REASON_NONE = 0
REASON_NONFINITE = 1
REASON_COVARIANCE = 2
REASON_PINNED = 3
#: The belief's dynamics left what the samples can show (a member's own bound, e.g.
#: Schiess & Roland's exact flow split past its cap).
REASON_BEYOND_SAMPLE_RATE = 4


#: The numba kernels (and what they import), imported from their module on first use.
_KERNELS = (
    "belief_health",
    "track_pins",
    "window_push",
    "window_variance",
)
__getattr__ = kernels_on_first_use(
    globals(), "manualcontrol.estimators.filters._monitor_kernels", _KERNELS
)
