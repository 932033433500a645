"""The numba kernels of :mod:`~manualcontrol.estimators._pilot_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference): the record layouts and constants they read stay in the
numba-free module, which exports these kernels by name on first use.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators._pilot_core import (
    CFG_FIRST_WINDOW,
    CFG_FIXED_QE,
    CFG_FIXED_R,
    CFG_FLOOR,
    CFG_Q2,
    CFG_R2,
    CFG_R2_PARAMETER,
    CFG_WINDOW,
    SC_DIV_INDEX,
    SC_DIV_PARAM,
    SC_DIV_REASON,
    SC_E,
    SC_FROZEN,
    SC_K,
    SC_U,
    SC_VAR_E0,
    SC_VAR_U0,
)
from manualcontrol.estimators.filters._monitor_kernels import (
    track_pins,
    window_push,
    window_variance,
)
from manualcontrol.estimators.filters.monitor import (
    REASON_COVARIANCE,
    REASON_NONE,
    REASON_NONFINITE,
    REASON_PINNED,
)


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
