"""Compiled pieces every filter on a pilot internal model shares (DEKF, joint and dual UKF).

Each sample of such a filter starts the same way (the windowed signal variances that set
``R = r^2 var(u)`` and the chain-input process noise ``q^2 var(e)``, Popovici eqs.
24-25 and thesis eqs. 29-30; dropped inputs held at their last value) and ends the same
way (every parameter's mean and standard deviation reported in model order, limits and
pins tracked, divergence recorded; a diverged filter stops and repeats its last
estimate). The filters differ only in between: how the belief is predicted and
corrected.

The records are namedtuples of arrays:

* ``cfg``: the ``CFG_*`` configuration vector;
* ``sc``: the ``SC_*`` scalar state (sample counter, first-window variances, window
  sums, frozen flag, divergence record);
* :data:`PilotMonitor`: the variance windows, pin counters and last reported values;
* :data:`PilotReport`: how parameters are reported (limits, the report transform
  ``offset + sign value`` that turns ``tau_f*`` back into ``tau_f``);
* :data:`PilotOutput`: one row per sample of means, standard deviations, the primary
  output's (prediction, innovation, variance), flags and pins.

Sample rates: the papers ran at 100 Hz (:data:`PAPERS_DT`), and two of their choices are
steps of that rate, not of the pilot: the Euler prediction of the canonical states
(Popovici eq. 8, thesis eq. 13), whose error grows with its step ``h`` (it damps the
neuromuscular mode less than the pilot does, and ``zeta_nms`` comes out about
``omega_nms h / 2`` high), and eq. 49 as printed (the DEKF's total derivative, weighted
by 1/dt at 100 Hz). :func:`euler_substeps` keeps the Euler step at most the papers'
0.01 s at every rate (one step a sample at 100 Hz and faster, two at 50 and 60 Hz), and
the DEKF keeps the printed weight at 1/(0.01 s). Everything else the DEKF and the
unscented filters read is in seconds (the 5-s variance window, the pin time) or keeps
its meaning per second by itself: with ``Gamma = I dt`` a random walk's variance a
sample is ``Q dt^2`` and ``R`` is a sample's variance, so a filter's time constant,
about ``dt sqrt(R / (Q dt^2)) = sqrt(R/Q)`` seconds, is the same at every rate. (The RML,
whose remnant state has an exact, continuous noise, takes ``R`` and ``Q`` per second
instead: :mod:`~manualcontrol.estimators.members.rml`, "Sample rates".)
"""

from __future__ import annotations

import math
from collections import namedtuple

import numba
import numpy as np

from manualcontrol.estimators.filters.monitor import (
    REASON_COVARIANCE,
    REASON_NONE,
    REASON_NONFINITE,
    REASON_PINNED,
    track_pins,
    window_push,
    window_variance,
)

# ---- indices into the configuration vector ``cfg``
CFG_DT = 0
CFG_Q2 = 1
CFG_R2 = 2
CFG_WINDOW = 3  # samples N; the window holds N + 1 samples
CFG_FIRST_WINDOW = 4  # 1: use var0 for k < N (papers); 0: causal growing window
CFG_FLOOR = 5
CFG_JITTER = 6
CFG_MAX_COV = 7
CFG_DIMENSIONAL = 8  # DEKF: 1 = eq. 49 with dt on df/dtheta; 0 = as printed
CFG_FIXED_R = 9  # > 0 replaces r^2 var(u)
CFG_FIXED_QE = 10  # > 0 replaces q^2 var(e)
CFG_ERROR_STATE = 11
CFG_GAMMA2 = 12  # Gamma^2: dt^2 (Euler noise input) or 1 (identity)
CFG_R2_PARAMETER = 13  # r^2 of a parameter filter (the same as CFG_R2 unless set)
CFG_SPREAD = 14  # unscented filters: sigma-point spread c
CFG_COUNT = 15  # unscented filters: sigma points to propagate (2N or 2N + 1)
CFG_SUBSTEPS = 16  # Euler substeps a sample (euler_substeps; 0 reads as 1)
CFG_SIZE = 17

#: The papers' sample time (s): Popovici et al. (2017) and the thesis ran at 100 Hz, the
#: step of their Euler prediction and of eq. 49 as printed (module docstring).
PAPERS_DT = 0.01

# ---- indices into the scalar vector ``sc``
SC_K = 0
SC_VAR_U0 = 1
SC_VAR_E0 = 2
SC_U = 3  # shift, sum, sum of squares, count
SC_E = 7
SC_FROZEN = 11
SC_DIV_INDEX = 12
SC_DIV_REASON = 13
SC_DIV_PARAM = 14
SC_SIZE = 15


def euler_substeps(dt: float, per_papers_step: int = 1) -> int:
    """Euler substeps over a sample of ``dt`` s: ``per_papers_step`` per :data:`PAPERS_DT`.

    ``ceil(per_papers_step dt / 0.01 s)``, at least 1: no substep is longer than
    ``0.01 s / per_papers_step``, the step the papers' rate gives (module docstring). With
    the default one a sample at 100 Hz and faster, two at 50 and 60 Hz; a relative
    tolerance of 1e-9 keeps a ``dt`` that rounding put a hair above 0.01 s at one.
    """
    return max(1, math.ceil(per_papers_step * dt / PAPERS_DT * (1.0 - 1e-9)))


PilotMonitor = namedtuple(
    "PilotMonitor", ["buf_u", "buf_e", "pins", "pin_ring", "last_mean", "last_std", "pinned_now"]
)
PilotReport = namedtuple("PilotReport", ["lo", "hi", "offset", "sign"])
PilotOutput = namedtuple("PilotOutput", ["mean", "std", "scalar", "flag", "pinned"])


@numba.njit(cache=True, _nrt=False, inline="always")
def noise_levels(cfg, sc, monitor, u_k, e_k):
    """Push the sample into the variance windows; return ``(R, R_parameter, q_error)``."""
    k = int(sc[SC_K])
    window_push(monitor.buf_u, sc, SC_U, u_k, k)
    window_push(monitor.buf_e, sc, SC_E, e_k, k)
    if cfg[CFG_FIRST_WINDOW] > 0.0 and k < int(cfg[CFG_WINDOW]):
        var_u = sc[SC_VAR_U0]
        var_e = sc[SC_VAR_E0]
    else:
        var_u = window_variance(sc, SC_U)
        var_e = window_variance(sc, SC_E)
    floor = cfg[CFG_FLOOR]
    var_u = max(var_u, floor)
    R = cfg[CFG_FIXED_R] if cfg[CFG_FIXED_R] > 0.0 else cfg[CFG_R2] * var_u
    R_p = cfg[CFG_FIXED_R] if cfg[CFG_FIXED_R] > 0.0 else cfg[CFG_R2_PARAMETER] * var_u
    q_error = cfg[CFG_FIXED_QE] if cfg[CFG_FIXED_QE] > 0.0 else cfg[CFG_Q2] * max(var_e, floor)
    return R, R_p, q_error


@numba.njit(cache=True, _nrt=False, inline="always")
def inputs_in_use(inputs_k, u_k, prev_in, in_use):
    """Inputs used this sample (a dropped one holds its last value); True if dropped."""
    dropped = np.isnan(u_k)
    for i in range(inputs_k.shape[0]):
        if np.isnan(inputs_k[i]):
            dropped = True
            in_use[i] = prev_in[i]
        else:
            in_use[i] = inputs_k[i]
    return dropped


@numba.njit(cache=True, _nrt=False)
def report_frozen(sc, monitor, prev_in, in_use, dropped, row, out):
    """A stopped filter's row: its last estimate, NaN predictions, flagged diverged."""
    for j in range(out.mean.shape[1]):
        out.mean[row, j] = monitor.last_mean[j]
        out.std[row, j] = monitor.last_std[j]
        out.pinned[row, j] = False
    out.scalar[row, 0] = np.nan
    out.scalar[row, 1] = np.nan
    out.scalar[row, 2] = np.nan
    out.flag[row, 0] = False
    out.flag[row, 1] = False
    out.flag[row, 2] = dropped
    out.flag[row, 3] = True
    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]
    sc[SC_K] = sc[SC_K] + 1


@numba.njit(cache=True, _nrt=False, inline="always")
def report_row(
    sc, monitor, report, p, variance, estimated, finite, cov_ok, dropped, scalars, row, out
):
    """Report one sample and record divergence (see the module docstring).

    ``p`` holds every parameter's internal value in model order, ``variance`` the
    variance of each estimated one (``estimated`` marks them; the others report a
    standard deviation of 0). ``scalars`` = (prediction, innovation, variance) of the
    primary output. A row that is not finite repeats the last estimate; a filter that
    is not finite or whose covariance broke stops from the next sample on.
    """
    k = int(sc[SC_K])
    n_p = p.shape[0]
    last_mean, last_std, pinned_now = monitor.last_mean, monitor.last_std, monitor.pinned_now
    for j in range(n_p):
        out.pinned[row, j] = False
        pinned_now[j] = False
    if finite:
        for j in range(n_p):
            out.mean[row, j] = p[j]
            if estimated[j]:
                out.std[row, j] = np.sqrt(max(variance[j], 0.0))
                pinned_now[j] = p[j] <= report.lo[j] or p[j] >= report.hi[j]
            else:
                out.std[row, j] = 0.0
        for j in range(n_p):
            out.pinned[row, j] = pinned_now[j]
        pinned = track_pins(pinned_now, monitor.pins, monitor.pin_ring, k)
        for j in range(n_p):
            out.mean[row, j] = report.offset[j] + report.sign[j] * out.mean[row, j]
            last_mean[j] = out.mean[row, j]
            last_std[j] = out.std[row, j]
        if sc[SC_DIV_REASON] == REASON_NONE and pinned >= 0:
            sc[SC_DIV_REASON] = REASON_PINNED
            sc[SC_DIV_INDEX] = k
            sc[SC_DIV_PARAM] = pinned
    else:
        for j in range(n_p):
            out.mean[row, j] = last_mean[j]
            out.std[row, j] = last_std[j]
    if not finite or not cov_ok:
        sc[SC_FROZEN] = 1.0
        if sc[SC_DIV_REASON] == REASON_NONE or sc[SC_DIV_REASON] == REASON_PINNED:
            sc[SC_DIV_REASON] = REASON_NONFINITE if not finite else REASON_COVARIANCE
            sc[SC_DIV_INDEX] = k
            sc[SC_DIV_PARAM] = -1
    for i in range(3):
        out.scalar[row, i] = scalars[i] if finite else np.nan
    out.flag[row, 0] = finite
    out.flag[row, 1] = cov_ok
    out.flag[row, 2] = dropped
    out.flag[row, 3] = sc[SC_DIV_REASON] != REASON_NONE
    sc[SC_K] = k + 1
