"""The numba kernels of :mod:`~manualcontrol.estimators.members._schiess_roland_core`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, ``bench/compile_kernels.py``'s numba jobs): the records and
constants stay in the numba-free module, which exports these kernels by name on first
use.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.envs._interpolation import bicubic_derivative_weights, bicubic_weights
from manualcontrol.estimators._pilot_core import (
    SC_DIV_INDEX,
    SC_DIV_PARAM,
    SC_DIV_REASON,
    SC_FROZEN,
    SC_K,
)
from manualcontrol.estimators._pilot_kernels import report_frozen, report_row
from manualcontrol.estimators.filters._kalman_kernels import clamp, joseph_correct
from manualcontrol.estimators.filters._linalg_kernels import symmetrise
from manualcontrol.estimators.filters._monitor_kernels import belief_health
from manualcontrol.estimators.filters._smoother_kernels import store_belief
from manualcontrol.estimators.filters.monitor import (
    REASON_BEYOND_SAMPLE_RATE,
    REASON_NONE,
    REASON_PINNED,
)
from manualcontrol.estimators.members._schiess_roland_core import (
    _FLOW_SPLIT_CAP,
    _PARAM_STATE,
    _SERIES_REACH,
    _SERIES_TERMS,
    _SERIES_TOLERANCE,
    ADAPTIVE_MODIFIED,
    ADAPTIVE_OFF,
    CFG_ADAPTIVE,
    CFG_BICUBIC,
    CFG_DT,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_MAX_DELAY,
    CFG_NOISE_FORM,
    CFG_PLANT_GAIN,
    CFG_PROCESS_NOISE,
    CFG_RAMP,
    COL_E0,
    COL_PARAM,
    COL_PHI,
    COL_RHO,
    COL_W,
    COL_Z,
    I_ALPHA1,
    I_ALPHA2,
    I_C,
    I_C_RATE,
    I_ETA,
    I_ETA_RATE,
    I_K1,
    I_TAU1,
    I_TAU2,
    I_TAU3,
    I_THETA,
    I_U,
    N_COLUMNS,
    N_DYNAMIC,
    N_PARAMETERS,
    N_STATES,
)

# --------------------------------------------------------------------- the model


@numba.njit(cache=True, _nrt=False)
def _apply_a(x, K, v, out):
    """``out = A(p) v`` for the dynamic states (eqs. 7-12), ``p`` read from ``x``."""
    tau1 = x[I_TAU1]
    tau2 = x[I_TAU2]
    out[0] = v[1]
    out[1] = K * (v[2] + v[4])
    out[2] = (v[3] - v[2]) / tau2
    out[3] = -v[3] / tau1
    out[4] = v[5]
    out[5] = -x[I_ALPHA2] * v[4] - x[I_ALPHA1] * v[5]


@numba.njit(cache=True, _nrt=False)
def input_gains(x):
    """``(b_u, b_y4)``: the coefficients of the delayed error in eqs. 9 and 10."""
    k1, tau1, tau2, tau3 = x[I_K1], x[I_TAU1], x[I_TAU2], x[I_TAU3]
    return k1 * tau3 / (tau1 * tau2), k1 / tau1 * (1.0 - tau3 / tau1)


@numba.njit(cache=True, _nrt=False)
def _input_gain_derivatives(x, column):
    """``d(b_u, b_y4)/dp`` for parameter column ``column`` (K_1, tau_1, tau_2, tau_3)."""
    k1, tau1, tau2, tau3 = x[I_K1], x[I_TAU1], x[I_TAU2], x[I_TAU3]
    if column == 0:
        return tau3 / (tau1 * tau2), (1.0 - tau3 / tau1) / tau1
    if column == 1:
        return -k1 * tau3 / (tau1 * tau1 * tau2), -k1 / (tau1 * tau1) + 2.0 * k1 * tau3 / tau1**3
    if column == 2:
        return -k1 * tau3 / (tau1 * tau2 * tau2), 0.0
    if column == 3:
        return k1 / (tau1 * tau2), -k1 / (tau1 * tau1)
    return 0.0, 0.0


@numba.njit(cache=True, _nrt=False)
def _add_a_derivative(x, column, v, out, h):
    """``out += h (dA/dp) v`` for parameter column ``column`` (tau_1, tau_2, alpha_1, alpha_2)."""
    if column == 1:
        tau1 = x[I_TAU1]
        out[3] += h * v[3] / (tau1 * tau1)
    elif column == 2:
        tau2 = x[I_TAU2]
        out[2] += h * (v[2] - v[3]) / (tau2 * tau2)
    elif column == 4:
        out[5] -= h * v[5]
    elif column == 5:
        out[5] -= h * v[4]


@numba.njit(cache=True, _nrt=False)
def _series_norm(x, K, dt):
    """``||A dt||`` (infinity norm) for the Taylor series' reach."""
    tau1 = abs(x[I_TAU1])
    tau2 = abs(x[I_TAU2])
    rows = max(1.0, 2.0 * abs(K), 2.0 / tau2, 1.0 / tau1, abs(x[I_ALPHA1]) + abs(x[I_ALPHA2]))
    return rows * dt


@numba.njit(cache=True, _nrt=False)
def _substep(x, z, xi, rho, h, K, s):
    """Taylor series of the exact flow over ``h`` from ``z`` with input ``xi + rho t``.

    On return ``s.sums[c]`` holds, per column ``c`` (module constants ``COL_*``): the new
    state, ``e^(A h)`` (by columns), the sensitivities to the parameters in ``A`` and
    ``b``, to the input value, to its slope, and ``int_0^h e^(A s) e_6 ds``.
    """
    terms, nxt, sums = s.terms, s.next_terms, s.sums
    b_u, b_y4 = input_gains(x)
    for c in range(N_COLUMNS):
        for i in range(N_DYNAMIC):
            terms[c, i] = 0.0
            sums[c, i] = 0.0
    for i in range(N_DYNAMIC):
        terms[COL_Z, i] = z[i]
        terms[COL_PHI + i, i] = 1.0
    for c in range(N_COLUMNS):
        for i in range(N_DYNAMIC):
            sums[c, i] = terms[c, i]
    # the scalar input's own series: xi_0 = xi, xi_1 = h rho, zero after that; its
    # derivatives by (xi, rho): (1, 0), (0, h), zero after that
    xi_prev = xi
    dxi_e0 = 1.0
    dxi_rho = 0.0
    scale = 1.0
    for i in range(N_DYNAMIC):
        scale = max(scale, abs(z[i]))
    for k in range(1, _SERIES_TERMS + 1):
        hk = h / k
        biggest = 0.0
        # nothing in A reads c, and c' only feeds c: their columns of e^(A h) are
        # e_c and e_c' + h e_c, finished after two terms
        first = 0 if k < 3 else 1
        for c in range(N_COLUMNS):
            if first == 1 and (c == COL_PHI + I_C or c == COL_PHI + I_C_RATE):
                continue
            _apply_a(x, K, terms[c], nxt[c])
            for i in range(N_DYNAMIC):
                nxt[c, i] *= hk
        nxt[COL_Z, 2] += hk * b_u * xi_prev
        nxt[COL_Z, 3] += hk * b_y4 * xi_prev
        for j in range(6):
            c = COL_PARAM + j
            if j < 4:
                db_u, db_y4 = _input_gain_derivatives(x, j)
                nxt[c, 2] += hk * db_u * xi_prev
                nxt[c, 3] += hk * db_y4 * xi_prev
            if j > 0:
                _add_a_derivative(x, j, terms[COL_Z], nxt[c], hk)
        nxt[COL_E0, 2] += hk * b_u * dxi_e0
        nxt[COL_E0, 3] += hk * b_y4 * dxi_e0
        nxt[COL_RHO, 2] += hk * b_u * dxi_rho
        nxt[COL_RHO, 3] += hk * b_y4 * dxi_rho
        if k == 1:
            nxt[COL_W, 5] += hk
        for c in range(N_COLUMNS):
            if first == 1 and (c == COL_PHI + I_C or c == COL_PHI + I_C_RATE):
                continue
            for i in range(N_DYNAMIC):
                v = nxt[c, i]
                terms[c, i] = v
                sums[c, i] += v
                if abs(v) > biggest:
                    biggest = abs(v)
        if k == 1:
            xi_prev = h * rho
            dxi_e0 = 0.0
            dxi_rho = h
        else:
            xi_prev = 0.0
            dxi_rho = 0.0
        # terms fall like ||A h||^k / k! with ||A h|| <= _SERIES_REACH: once past the
        # hump, a term below rounding of the largest entry ends the series
        if k > _SERIES_REACH and biggest <= _SERIES_TOLERANCE * scale:
            break


@numba.njit(cache=True, _nrt=False)
def flow(x, e0, rho, dt, K, s):
    """Exact flow of eqs. 7-12 over ``dt`` with delayed input ``e0 + rho t`` (module doc).

    Writes the new dynamic states into ``x[:6]``, ``e^(A dt)`` into ``s.Z``, the
    sensitivities into ``s.J`` (columns in parameter order; the theta column holds the
    sensitivity to the input value ``e0``) and ``s.Jrho`` (to the slope ``rho``), and
    ``G_w`` into ``s.Gw``. Splits the step when ``||A dt||`` exceeds the series' reach
    (parameters far outside any pilot's), composing the substeps by the chain rule.
    Returns the number of substeps, or -1 where more than ``_FLOW_SPLIT_CAP`` would be
    needed (the belief has left what the samples can show): nothing is written then.
    """
    n_sub = 1
    while _series_norm(x, K, dt) / n_sub > _SERIES_REACH:
        if n_sub >= _FLOW_SPLIT_CAP:
            return -1
        n_sub *= 2
    h = dt / n_sub
    Z, J, Jrho, Gw, sums, z = s.Z, s.J, s.Jrho, s.Gw, s.sums, s.z
    U, T1, v = s.U, s.T1, s.v
    theta = I_THETA - N_DYNAMIC
    for i in range(N_DYNAMIC):
        z[i] = x[i]
    for step in range(n_sub):
        _substep(x, z, e0 + rho * step * h, rho, h, K, s)
        if step == 0:
            for i in range(N_DYNAMIC):
                for j in range(N_DYNAMIC):
                    Z[i, j] = sums[COL_PHI + j, i]
                for j in range(6):
                    J[i, _PARAM_STATE[j] - N_DYNAMIC] = sums[COL_PARAM + j, i]
                J[i, theta] = sums[COL_E0, i]
                Jrho[i] = sums[COL_RHO, i]
                Gw[i] = sums[COL_W, i]
        else:
            # totals <- e^(A h) totals + this substep's own terms (the input at this
            # substep is e0 + rho t_step, so its slope sensitivity gains t_step G_e0)
            for i in range(N_DYNAMIC):
                for j in range(N_DYNAMIC):
                    acc = 0.0
                    for m in range(N_DYNAMIC):
                        acc += sums[COL_PHI + m, i] * Z[m, j]
                    U[i, j] = acc
                for j in range(N_PARAMETERS):
                    acc = 0.0
                    for m in range(N_DYNAMIC):
                        acc += sums[COL_PHI + m, i] * J[m, j]
                    T1[i, j] = acc
                a_rho = 0.0
                a_w = 0.0
                for m in range(N_DYNAMIC):
                    a_rho += sums[COL_PHI + m, i] * Jrho[m]
                    a_w += sums[COL_PHI + m, i] * Gw[m]
                v[i] = a_rho + sums[COL_E0, i] * step * h + sums[COL_RHO, i]
                v[N_DYNAMIC + i] = a_w + sums[COL_W, i]
            for i in range(N_DYNAMIC):
                Jrho[i] = v[i]
                Gw[i] = v[N_DYNAMIC + i]
                for j in range(N_DYNAMIC):
                    Z[i, j] = U[i, j]
                for j in range(N_PARAMETERS):
                    J[i, j] = T1[i, j]
                for j in range(6):
                    J[i, _PARAM_STATE[j] - N_DYNAMIC] += sums[COL_PARAM + j, i]
                J[i, theta] += sums[COL_E0, i]
        for i in range(N_DYNAMIC):
            z[i] = sums[COL_Z, i]
    for i in range(N_DYNAMIC):
        x[i] = z[i]
    return n_sub


@numba.njit(cache=True, _nrt=False)
def predict_covariance_structured(P, Z, J, s):
    """``P <- Phi P Phi^T`` for ``Phi = [[Z, J], [0, I]]`` (the parameters are constant)."""
    n_z = N_DYNAMIC
    n_p = N_PARAMETERS
    T1, U = s.T1, s.U
    # T1 = Z P_zp + J P_pp ; U = Z P_zz + J P_pz
    for i in range(n_z):
        for j in range(n_p):
            acc = 0.0
            for m in range(n_z):
                acc += Z[i, m] * P[m, n_z + j]
            for m in range(n_p):
                acc += J[i, m] * P[n_z + m, n_z + j]
            T1[i, j] = acc
        for j in range(n_z):
            acc = 0.0
            for m in range(n_z):
                acc += Z[i, m] * P[m, j]
            for m in range(n_p):
                acc += J[i, m] * P[n_z + m, j]
            U[i, j] = acc
    # P_zz = U Z^T + T1 J^T ; P_zp = T1
    for i in range(n_z):
        for j in range(i, n_z):
            acc = 0.0
            for m in range(n_z):
                acc += U[i, m] * Z[j, m]
            for m in range(n_p):
                acc += T1[i, m] * J[j, m]
            P[i, j] = acc
            P[j, i] = acc
        for j in range(n_p):
            P[i, n_z + j] = T1[i, j]
            P[n_z + j, i] = T1[i, j]


# ------------------------------------------------------------------ the history


@numba.njit(cache=True, _nrt=False)
def _ring(hist, j, newest):
    """Sample ``j`` of a ring whose newest sample is ``newest`` (clamped to what it holds)."""
    size = hist.shape[0]
    oldest = newest - size + 1
    if oldest < 0:
        oldest = 0
    if j > newest:
        j = newest
    if j < oldest:
        j = oldest
    return hist[j % size]


@numba.njit(cache=True, _nrt=False)
def _error_at(belief, j, newest_c, newest_d, dt):
    """Delayed error ``e_j = D_j - c_j`` and its rate ``dD/dt - c'`` at sample ``j``.

    ``c`` samples beyond the newest filtered one are clamped to it (with ``D`` read at
    the same sample); ``dD/dt`` is the central difference of the forcing where both
    neighbours are known, one-sided at the ends.
    """
    if j > newest_c:
        j = newest_c
    if j < 0:
        j = 0
    d_j = _ring(belief.hist_d, j, newest_d)
    c_j = _ring(belief.hist_c, j, newest_c)
    rate_c = _ring(belief.hist_rate, j, newest_c)
    lo = j - 1 if j >= 1 else j
    hi = j + 1 if j + 1 <= newest_d else j
    if hi > lo:
        rate_d = (_ring(belief.hist_d, hi, newest_d) - _ring(belief.hist_d, lo, newest_d)) / (
            (hi - lo) * dt
        )
    else:
        rate_d = 0.0
    return d_j - c_j, rate_d - rate_c


@numba.njit(cache=True, _nrt=False)
def delayed_error(belief, position, newest_c, newest_d, dt, bicubic):
    """``(e, de/dt)`` at fractional sample ``position`` (eq. 17's delayed error).

    ``bicubic = False``: the sample ``round(position)`` (the paper's integer
    ``q = theta/dt``); True: the four-sample bicubic interpolation of the project's
    delay lines (Boer & Kenyon 1998, Appendix) of the error and of its rate.
    """
    if not bicubic:
        j = int(np.floor(position + 0.5))
        return _error_at(belief, j, newest_c, newest_d, dt)
    n = int(np.floor(position))
    d = position - n
    e_a = _error_at(belief, n - 1, newest_c, newest_d, dt)[0]
    e_b = _error_at(belief, n, newest_c, newest_d, dt)[0]
    e_c = _error_at(belief, n + 1, newest_c, newest_d, dt)[0]
    e_d = _error_at(belief, n + 2, newest_c, newest_d, dt)[0]
    w_m1, w_0, w_1, w_2 = bicubic_weights(d)
    value = w_m1 * e_a + w_0 * e_b + w_1 * e_c + w_2 * e_d
    # the rate of what is read: the derivative of the interpolant (per sample / dt)
    w_m1, w_0, w_1, w_2 = bicubic_derivative_weights(d)
    rate = (w_m1 * e_a + w_0 * e_b + w_1 * e_c + w_2 * e_d) / dt
    return value, rate


# --------------------------------------------------------------- adaptive noise


@numba.njit(cache=True, _nrt=False)
def adaptive_variance(P, gamma, innovations, available, R, mode):
    """Jazwinski's fictitious noise variance from one residual (eqs. A3-A6), >= 0.

    ``mode`` 1 (full): both measurements; 2 (modified): the plant output only. With the
    misprints corrected: the normalised residual is ``(m_j - [H y]_j)/sqrt(R_jj)`` (A4),
    A5 uses ``H_j P H_i^T`` and A6 ``H_j Gamma Gamma^T H_i^T``. The measurement rows are
    ``H_stick = e_u + e_eta`` and ``H_plant = e_c``.
    """
    residual = 0.0
    count = 0
    spread = 0.0
    gain = 0.0
    # rows: 0 stick (u + eta), 1 plant output (c)
    for j in range(2):
        if not available[j] or (mode == ADAPTIVE_MODIFIED and j == 0):
            continue
        count += 1
    if count == 0:
        return 0.0
    for j in range(2):
        if not available[j] or (mode == ADAPTIVE_MODIFIED and j == 0):
            continue
        sj = np.sqrt(R[j, j])
        residual += innovations[j] / sj
        gain += (gamma[I_U] + gamma[I_ETA] if j == 0 else gamma[I_C]) / sj
        for i in range(2):
            if not available[i] or (mode == ADAPTIVE_MODIFIED and i == 0):
                continue
            si = np.sqrt(R[i, i])
            # H_j P H_i^T
            if j == 0 and i == 0:
                hph = P[I_U, I_U] + 2.0 * P[I_U, I_ETA] + P[I_ETA, I_ETA]
            elif j == 1 and i == 1:
                hph = P[I_C, I_C]
            else:
                hph = P[I_C, I_U] + P[I_C, I_ETA]
            spread += hph / (sj * si)
    n = float(count)
    residual /= n
    expected = 1.0 / n + spread / (n * n)  # A5
    d = gain * gain / (n * n)  # A6
    if d <= 0.0:
        return 0.0
    value = (residual * residual - expected) / d  # A3
    return value if value > 0.0 else 0.0


# ----------------------------------------------------------------------- storage


@numba.njit(cache=True, _nrt=False)
def _store_phi(out, row, Z, J, predicted):
    Phi = out.Phi
    if Phi.shape[0] == 0:
        return
    for i in range(N_STATES):
        for j in range(N_STATES):
            Phi[row, i, j] = 1.0 if i == j else 0.0
    if not predicted:
        return
    for i in range(N_DYNAMIC):
        for j in range(N_DYNAMIC):
            Phi[row, i, j] = Z[i, j]
        for j in range(N_PARAMETERS):
            Phi[row, i, N_DYNAMIC + j] = J[i, j]


# -------------------------------------------------------------------------- step


@numba.njit(cache=True, _nrt=False)
def _stopped_row(belief, monitor, s, dropped, row, out):
    """A stopped filter's row: its belief as it stands, no prediction, its last states."""
    x, P = belief.x, belief.P
    store_belief(row, x, P, out.x_prior, out.P_prior)
    store_belief(row, x, P, out.x_post, out.P_post)
    _store_phi(out, row, s.Z, s.J, False)
    for i in range(2):
        out.predictions[row, i] = np.nan
        out.innovations[row, i] = np.nan
        for j in range(2):
            out.S[row, i, j] = np.nan
    if row > 0:  # a stopped filter repeats its last states (update: the row holds them)
        for i in range(out.states.shape[1]):
            out.states[row, i] = out.states[row - 1, i]
    report_frozen(belief.sc, monitor, belief.prev_d, belief.in_d, dropped, row, out)


@numba.njit(cache=True, _nrt=False)
def sr_step(config, belief, monitor, report, scratch, d_k, u_k, y_k, row, out):
    """Advance the belief by one sample; write its estimate into output row ``row``.

    ``d_k`` is the forcing ``D`` (the target), ``u_k`` the stick ``delta = u + eta`` and
    ``y_k`` the plant output ``c`` (NaN: missing). The first sample has no prediction
    (the prior is the initial belief).
    """
    cfg = config.cfg
    x, P, sc = belief.x, belief.P, belief.sc
    s = scratch
    dt = cfg[CFG_DT]
    K = cfg[CFG_PLANT_GAIN]
    k = int(sc[SC_K])
    # the forcing in use: a missing one holds its last value and drops the sample
    dropped_input = np.isnan(d_k)
    belief.in_d[0] = belief.prev_d[0] if dropped_input else d_k
    size = belief.hist_d.shape[0]
    belief.hist_d[k % size] = belief.in_d[0]
    available = (not np.isnan(u_k) and not dropped_input, not np.isnan(y_k) and not dropped_input)
    dropped = not (available[0] or available[1])

    if sc[SC_FROZEN] > 0.0:
        _stopped_row(belief, monitor, s, dropped, row, out)
        return

    predicted = k > 0
    if predicted:
        # ---- delayed error from the history (eq. 17): c up to k - 1, D up to k
        theta = x[I_THETA]
        max_delay = cfg[CFG_MAX_DELAY]
        theta_read = min(max(theta, 0.0), max_delay)
        bicubic = cfg[CFG_BICUBIC] > 0.0
        position = (k - 1) - theta_read / dt  # t_{k-1} - theta
        e0, rate0 = delayed_error(belief, position, k - 1, k, dt, bicubic)
        rho = 0.0
        rate1 = 0.0
        if cfg[CFG_RAMP] > 0.0:
            e1, rate1 = delayed_error(belief, position + 1.0, k - 1, k, dt, bicubic)
            rho = (e1 - e0) / dt
        # ---- prediction, eqs. 18-19, exact over the step
        if flow(x, e0, rho, dt, K, s) < 0:  # beyond the split's cap: nothing predicted
            sc[SC_FROZEN] = 1.0
            if sc[SC_DIV_REASON] == REASON_NONE or sc[SC_DIV_REASON] == REASON_PINNED:
                sc[SC_DIV_REASON] = REASON_BEYOND_SAMPLE_RATE
                sc[SC_DIV_INDEX] = k
                sc[SC_DIV_PARAM] = -1
            _stopped_row(belief, monitor, s, dropped, row, out)
            return
        # theta acts through the delayed input: d e_d / d theta = -de/dt(t - theta)
        for i in range(N_DYNAMIC):
            sens_e0 = s.J[i, I_THETA - N_DYNAMIC]
            if cfg[CFG_RAMP] > 0.0:
                s.J[i, I_THETA - N_DYNAMIC] = -sens_e0 * rate0 - s.Jrho[i] * (rate1 - rate0) / dt
            else:
                s.J[i, I_THETA - N_DYNAMIC] = -sens_e0 * rate0
        predict_covariance_structured(P, s.Z, s.J, s)
        q = cfg[CFG_PROCESS_NOISE]
        if cfg[CFG_NOISE_FORM] > 0.0:
            P[I_ETA_RATE, I_ETA_RATE] += q
        else:
            for i in range(N_DYNAMIC):
                for j in range(N_DYNAMIC):
                    P[i, j] += q * s.Gw[i] * s.Gw[j]
        symmetrise(P)

    # ---- measurement prediction (eq. 16): stick u + eta, plant output c
    prediction_u = x[I_U] + x[I_ETA]
    prediction_y = x[I_C]
    innovation_u = u_k - prediction_u if available[0] else np.nan
    innovation_y = y_k - prediction_y if available[1] else np.nan

    # ---- adaptive fictitious noise (eqs. A1-A6), averaged over the window
    mode = int(cfg[CFG_ADAPTIVE])
    q_bar = 0.0
    if mode != ADAPTIVE_OFF:
        s.r2[0] = innovation_u
        s.r2[1] = innovation_y
        window = belief.q_window
        if not dropped:
            value = adaptive_variance(P, config.gamma, s.r2, available, config.R, mode)
            slot = int(belief.q_sum[2]) % window.shape[0]
            if belief.q_sum[1] >= window.shape[0]:
                belief.q_sum[0] -= window[slot]
            else:
                belief.q_sum[1] += 1.0
            window[slot] = value
            belief.q_sum[0] += value
            belief.q_sum[2] += 1.0
            if slot == window.shape[0] - 1:  # recompute exactly at every wrap
                total = 0.0
                for i in range(window.shape[0]):
                    total += window[i]
                belief.q_sum[0] = total
        if belief.q_sum[1] > 0.0:
            q_bar = max(belief.q_sum[0] / belief.q_sum[1], 0.0)
        if q_bar > 0.0:
            gamma = config.gamma
            for i in range(N_STATES):
                for j in range(N_STATES):
                    P[i, j] += q_bar * gamma[i] * gamma[j]  # A2
    store_belief(row, x, P, out.x_prior, out.P_prior)
    _store_phi(out, row, s.Z, s.J, predicted)

    # innovation covariance of both outputs (reported also for a partial correction)
    S_uu = P[I_U, I_U] + 2.0 * P[I_U, I_ETA] + P[I_ETA, I_ETA] + config.R[0, 0]
    S_yy = P[I_C, I_C] + config.R[1, 1]
    S_uy = P[I_C, I_U] + P[I_C, I_ETA] + config.R[0, 1]

    # ---- correction, eqs. 20-22 (Joseph form; eq. 20's "-R" read "+R")
    correct_ok = True
    if available[0] and available[1]:
        s.r2[0] = innovation_u
        s.r2[1] = innovation_y
        for i in range(N_STATES):
            s.H2[0, i] = 0.0
            s.H2[1, i] = 0.0
        s.H2[0, I_U] = 1.0
        s.H2[0, I_ETA] = 1.0
        s.H2[1, I_C] = 1.0
        correct_ok = joseph_correct(x, P, s.r2, s.H2, config.R, s.work2, cfg[CFG_JITTER])
    elif available[0] or available[1]:
        for i in range(N_STATES):
            s.H1[0, i] = 0.0
        if available[0]:
            s.H1[0, I_U] = 1.0
            s.H1[0, I_ETA] = 1.0
            s.r1[0] = innovation_u
            s.R1[0, 0] = config.R[0, 0]
        else:
            s.H1[0, I_C] = 1.0
            s.r1[0] = innovation_y
            s.R1[0, 0] = config.R[1, 1]
        correct_ok = joseph_correct(x, P, s.r1, s.H1, s.R1, s.work1, cfg[CFG_JITTER])
    clamp(x, config.state_limit, report.lo, report.hi)
    store_belief(row, x, P, out.x_post, out.P_post)

    # ---- history for the delayed terms: the filtered c and c' of this sample
    belief.hist_c[k % size] = x[I_C]
    belief.hist_rate[k % size] = x[I_C_RATE]
    belief.prev_d[0] = belief.in_d[0]

    # ---- health and report
    finite, cov_ok = belief_health(x, P, cfg[CFG_MAX_COV], True)
    if not correct_ok:
        if np.isfinite(S_uu) and np.isfinite(S_yy):
            cov_ok = False
        else:
            finite = False
    p, variance = s.p, s.variance
    for j in range(N_PARAMETERS):
        p[j] = x[N_DYNAMIC + j]
        variance[j] = P[N_DYNAMIC + j, N_DYNAMIC + j]
    s.scalars[0] = prediction_u
    s.scalars[1] = innovation_u
    s.scalars[2] = S_uu
    report_row(
        sc,
        monitor,
        report,
        p,
        variance,
        config.estimated,
        finite,
        cov_ok,
        dropped,
        s.scalars,
        row,
        out,
    )
    out.predictions[row, 0] = prediction_u if finite else np.nan
    out.predictions[row, 1] = prediction_y if finite else np.nan
    out.innovations[row, 0] = innovation_u if finite else np.nan
    out.innovations[row, 1] = innovation_y if finite else np.nan
    out.S[row, 0, 0] = S_uu if finite else np.nan
    out.S[row, 1, 1] = S_yy if finite else np.nan
    out.S[row, 0, 1] = S_uy if finite else np.nan
    out.S[row, 1, 0] = S_uy if finite else np.nan
    if finite:
        for i in range(N_DYNAMIC):
            out.states[row, i] = x[i]
        out.states[row, N_DYNAMIC] = q_bar
    elif row > 0:
        for i in range(out.states.shape[1]):
            out.states[row, i] = out.states[row - 1, i]


@numba.njit(cache=True, _nrt=False)
def sr_run(config, belief, monitor, report, scratch, d, u, y, out):
    """:func:`sr_step` over every sample."""
    for k in range(u.shape[0]):
        sr_step(config, belief, monitor, report, scratch, d[k], u[k], y[k], k, out)
