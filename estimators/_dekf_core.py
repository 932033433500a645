"""Compiled core of the Dual Extended Kalman Filter: one step, and a whole run.

Pure numerics: :func:`dekf_step` advances a belief (arrays it updates in place) by one
sample and writes that sample's estimate into row ``row`` of the output arrays;
:func:`dekf_run` loops it over a recording. The online ``DEKF.update`` and the batch
``DEKF.estimate`` both call :func:`dekf_step`, so they give identical numbers.

The six steps (thesis Part I eqs. 11-25, Popovici et al. 2017 eqs. 6-15):

1. parameter prediction ``theta^- = theta^+``, ``P_p^- = P_p^+ + Gamma Q_p Gamma^T``
   (eqs. 11-12, ``Phi_p = I``: the parameters are random walks, eq. 9);
2. state prediction by one Euler step ``x^- = x^+ + f(x^+, in_{k-1}, theta^-) dt``
   (eq. 13, Popovici eq. 8) and ``P_s^- = Phi_s P_s^+ Phi_s^T + Gamma Q_s Gamma^T``
   (eq. 14) with ``Phi_s = I + F dt``, the Jacobian of that Euler step, and
   ``Gamma = I dt`` (or ``I``, ``cfg[CFG_GAMMA2]`` holds its square);
3. state correction with innovation ``r = u - g(x^-, theta^-)`` (eqs. 15-19, Joseph form);
4. state limitation by estimate projection (eq. 20);
5. parameter correction with the total derivative ``G_p^tot`` (eqs. 21-24, 47-50);
6. parameter limitation by estimate projection (eq. 25).

The first sample has no prediction (the prior is the initial belief). Matrix
products exploit the structure of ``F`` (shift rows ``x_i' = x_{i+1}`` and one dense
row per canonical chain) and the rank-one structure of ``I - K G``; the Joseph form
``(I - K G) P (I - K G)^T + K R K^T`` is evaluated as that product, in O(n^2).

The kernels are compiled with ``_nrt=False`` (numba's array reference counting off):
they allocate nothing, and the atomic reference counts of the ~60 arrays passed
around each step otherwise cost more than the arithmetic (about 3.5 us against 1.5 us
per compensatory step).
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators.internal_model import evaluate_coefficients, model_f, model_g

# ---- indices into the configuration vector ``cfg``
CFG_DT = 0
CFG_Q2 = 1
CFG_R2 = 2
CFG_WINDOW = 3  # samples N; the window holds N + 1 samples
CFG_FIRST_WINDOW = 4  # 1: use var0 for k < N (papers); 0: causal growing window
CFG_FLOOR = 5
CFG_JITTER = 6
CFG_MAX_COV = 7
CFG_DIMENSIONAL = 8  # 1: eq. 49 with dt on df/dtheta; 0: as printed
CFG_FIXED_R = 9  # > 0 replaces r^2 var(u)
CFG_FIXED_QE = 10  # > 0 replaces q^2 var(e)
CFG_ERROR_STATE = 11
CFG_GAMMA2 = 12  # Gamma^2: dt^2 (Euler noise input) or 1 (identity)
CFG_R2_PARAMETER = 13  # r^2 of the parameter filter (the same as CFG_R2 unless set)
CFG_SIZE = 14

# ---- indices into the belief's scalar vector ``sc``
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

#: Magnitude below which covariance entries are flushed to zero (subnormal range).
TINY = 1e-290
#: Fraction of the samples of the last ``pinned_time`` at a limit that counts as pinned.
PIN_FRACTION = 0.9
#: Relative tolerance for a covariance diagonal below zero (rounding of a variance ~0).
NEGATIVE_TOLERANCE = 1e-10

REASON_NONE = 0
REASON_NONFINITE = 1
REASON_COVARIANCE = 2
REASON_PINNED = 3


@numba.njit(cache=True, _nrt=False)
def _window_push(buf, sc, base, value, k):
    """Append ``value`` to the ring ``buf`` (NaN = missing), updating running sums in ``sc``.

    ``sc[base:base + 4]`` = (shift, sum, sum of squares, count) of the finite values
    in the ring, taken about ``shift`` (the first value of a filling) against
    cancellation; the sums are recomputed exactly at every wrap of the ring, so
    rounding cannot accumulate over a long run.
    """
    size = buf.shape[0]
    pos = k % size
    old = buf[pos]
    if not np.isnan(old):
        dv = old - sc[base]
        sc[base + 1] -= dv
        sc[base + 2] -= dv * dv
        sc[base + 3] -= 1.0
        if sc[base + 3] <= 0.0:
            sc[base + 1] = 0.0
            sc[base + 2] = 0.0
            sc[base + 3] = 0.0
    buf[pos] = value
    if not np.isnan(value):
        if sc[base + 3] == 0.0:
            sc[base] = value
        dv = value - sc[base]
        sc[base + 1] += dv
        sc[base + 2] += dv * dv
        sc[base + 3] += 1.0
    if pos == size - 1:
        s = 0.0
        ss = 0.0
        c = 0.0
        for i in range(size):
            v = buf[i]
            if not np.isnan(v):
                dv = v - sc[base]
                s += dv
                ss += dv * dv
                c += 1.0
        sc[base + 1] = s
        sc[base + 2] = ss
        sc[base + 3] = c


@numba.njit(cache=True, _nrt=False)
def _window_variance(sc, base):
    c = sc[base + 3]
    if c < 1.0:
        return 0.0
    mean = sc[base + 1] / c
    var = sc[base + 2] / c - mean * mean
    return var if var > 0.0 else 0.0


@numba.njit(cache=True, _nrt=False)
def _apply_phi(F, is_dense, n_c, dt, src, dst):
    """``dst = (I + dt F) src`` for a square or tall ``src``, F acting on canonical rows."""
    n_cols = src.shape[1]
    for i in range(src.shape[0]):
        if i < n_c and is_dense[i]:
            for c in range(n_cols):
                acc = 0.0
                for j in range(n_c):
                    acc += F[i, j] * src[j, c]
                dst[i, c] = src[i, c] + dt * acc
        elif i < n_c:
            for c in range(n_cols):
                dst[i, c] = src[i, c] + dt * src[i + 1, c]
        else:
            for c in range(n_cols):
                dst[i, c] = src[i, c]


@numba.njit(cache=True, _nrt=False)
def _apply_phi_transpose(F, is_dense, n_c, dt, src, dst):
    """``dst = src (I + dt F)^T``."""
    n = src.shape[0]
    for i in range(src.shape[1]):
        if i < n_c and is_dense[i]:
            for r in range(n):
                acc = 0.0
                for j in range(n_c):
                    acc += src[r, j] * F[i, j]
                dst[r, i] = src[r, i] + dt * acc
        elif i < n_c:
            for r in range(n):
                dst[r, i] = src[r, i] + dt * src[r, i + 1]
        else:
            for r in range(n):
                dst[r, i] = src[r, i]


@numba.njit(cache=True, _nrt=False)
def _symmetrise(P):
    """``P <- (P + P^T)/2``, flushing subnormal entries to zero.

    A state without process noise that the measurements pin down (the far-view chain)
    has a variance that decays towards zero; left alone it would reach subnormal
    numbers, whose arithmetic is a hundred times slower, and flicker around zero by
    rounding. Entries below :data:`TINY` in magnitude are set to 0 (flush to zero).
    """
    n = P.shape[0]
    for i in range(n):
        if abs(P[i, i]) < TINY:
            P[i, i] = 0.0
        for j in range(i + 1, n):
            v = 0.5 * (P[i, j] + P[j, i])
            if abs(v) < TINY:
                v = 0.0
            P[i, j] = v
            P[j, i] = v


@numba.njit(cache=True, _nrt=False)
def _joseph(P, G, R, K, PG, m, jitter):
    """Scalar-measurement Kalman update of ``P`` in Joseph form; returns ``S``.

    ``K = P G^T / S`` with ``S = G P G^T + R`` (a scalar: the solve is a division),
    ``P <- (I - K G) P (I - K G)^T + K R K^T``, symmetrised, plus ``jitter I``.
    """
    n = P.shape[0]
    S = R
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * G[j]
        PG[i] = acc
        S += G[i] * acc
    for i in range(n):
        K[i] = PG[i] / S
    # M = (I - K G) P = P - K (G P);  G P = PG^T for symmetric P
    for i in range(n):
        for j in range(n):
            P[i, j] -= K[i] * PG[j]
    # M (I - K G)^T = M - (M G^T) K^T
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += P[i, j] * G[j]
        m[i] = acc
    for i in range(n):
        for j in range(n):
            P[i, j] += -m[i] * K[j] + R * K[i] * K[j]
    _symmetrise(P)
    for i in range(n):
        P[i, i] += jitter
    return S


@numba.njit(cache=True, _nrt=False)
def dekf_step(
    tables,
    work,
    coef,
    cfg,
    is_dense,
    gain_index,
    theta_index,
    p,
    lo,
    hi,
    q_state,
    q_theta,
    report_offset,
    report_sign,
    x,
    P,
    th,
    Pp,
    dx,
    prev_in,
    buf_u,
    buf_e,
    sc,
    pins,
    pin_ring,
    last_mean,
    last_std,
    scratch,
    inputs_k,
    u_k,
    e_k,
    row,
    out_mean,
    out_std,
    out_scalar,
    out_flag,
    out_pinned,
):
    """Advance the belief by one sample; write its estimate into output row ``row``.

    ``out_scalar[row]`` = (prediction, innovation, innovation variance);
    ``out_flag[row]`` = (finite, covariance ok, dropped, diverged).
    """
    (
        term_coef,
        term_var,
        term_exp,
        term_slot,
        chain_num,
        chain_den,
        chain_pade,
        chain_offset,
        chain_size,
        chain_num_length,
        chain_den_length,
        branch_chain,
        branch_input,
        active,
    ) = tables
    raw, raw_grad, num, num_grad, den, den_grad, pade_value, pade_slope = work
    negA, negA_grad, C, C_grad, d, d_grad = coef
    (F, f, dfdp, dgdx, dgdp, M, Gs, PG, K, m, Gt, PGp, Kp, mp, dxm, in_use) = scratch

    n_c = f.shape[0]
    n_s = x.shape[0]
    n_g = gain_index.shape[0]
    n_t = th.shape[0]
    n_p = p.shape[0]
    dt = cfg[CFG_DT]
    gamma2 = cfg[CFG_GAMMA2]
    k = int(sc[SC_K])
    n_window = int(cfg[CFG_WINDOW])

    # ---- retrospective variances (Popovici eqs. 24-25, thesis eqs. 29-30)
    _window_push(buf_u, sc, SC_U, u_k, k)
    _window_push(buf_e, sc, SC_E, e_k, k)
    if cfg[CFG_FIRST_WINDOW] > 0.0 and k < n_window:
        var_u = sc[SC_VAR_U0]
        var_e = sc[SC_VAR_E0]
    else:
        var_u = _window_variance(sc, SC_U)
        var_e = _window_variance(sc, SC_E)
    floor = cfg[CFG_FLOOR]
    var_u = max(var_u, floor)
    R = cfg[CFG_FIXED_R] if cfg[CFG_FIXED_R] > 0.0 else cfg[CFG_R2] * var_u
    R_p = cfg[CFG_FIXED_R] if cfg[CFG_FIXED_R] > 0.0 else cfg[CFG_R2_PARAMETER] * var_u
    q_error = cfg[CFG_FIXED_QE] if cfg[CFG_FIXED_QE] > 0.0 else cfg[CFG_Q2] * max(var_e, floor)

    # inputs used this sample: a dropped input holds its last value
    dropped = np.isnan(u_k)
    for i in range(inputs_k.shape[0]):
        if np.isnan(inputs_k[i]):
            dropped = True
            in_use[i] = prev_in[i]
        else:
            in_use[i] = inputs_k[i]

    if sc[SC_FROZEN] > 0.0:
        for j in range(n_p):
            out_mean[row, j] = last_mean[j]
            out_std[row, j] = last_std[j]
            out_pinned[row, j] = False
        out_scalar[row, 0] = np.nan
        out_scalar[row, 1] = np.nan
        out_scalar[row, 2] = np.nan
        out_flag[row, 0] = False
        out_flag[row, 1] = False
        out_flag[row, 2] = dropped
        out_flag[row, 3] = True
        for i in range(prev_in.shape[0]):
            prev_in[i] = in_use[i]
        sc[SC_K] = k + 1
        return

    # current parameter vector: gains from the state filter, theta^- = theta^+ (eq. 11)
    for g in range(n_g):
        p[gain_index[g]] = x[n_c + g]
    for t in range(n_t):
        p[theta_index[t]] = th[t]
    evaluate_coefficients(
        p,
        term_coef,
        term_var,
        term_exp,
        term_slot,
        chain_num,
        chain_den,
        chain_pade,
        chain_offset,
        chain_size,
        chain_num_length,
        chain_den_length,
        branch_chain,
        branch_input,
        active,
        raw,
        raw_grad,
        num,
        num_grad,
        den,
        den_grad,
        pade_value,
        pade_slope,
        negA,
        negA_grad,
        C,
        C_grad,
        d,
        d_grad,
    )

    if k > 0:
        # ---- 1. parameter prediction (eq. 12)
        for t in range(n_t):
            Pp[t, t] += q_theta[t] * gamma2
        # ---- 2. state prediction (eqs. 13-14) at x^+_{k-1}, in_{k-1}, theta^-_k
        model_f(
            x,
            prev_in,
            chain_num,
            chain_den,
            chain_pade,
            chain_offset,
            chain_size,
            chain_num_length,
            chain_den_length,
            branch_chain,
            branch_input,
            negA,
            negA_grad,
            C,
            C_grad,
            d,
            d_grad,
            f,
            F,
            dfdp,
        )
        # total-derivative recursion, eq. 49: dx^-_k = df/dtheta (dt) + Phi dx^+_{k-1}
        _apply_phi(F, is_dense, n_c, dt, dx, dxm)
        scale = dt if cfg[CFG_DIMENSIONAL] > 0.0 else 1.0
        for i in range(n_c):
            for t in range(n_t):
                dxm[i, t] += dfdp[i, theta_index[t]] * scale
        for i in range(n_c):
            x[i] += f[i] * dt
        _apply_phi(F, is_dense, n_c, dt, P, M)
        _apply_phi_transpose(F, is_dense, n_c, dt, M, P)
        for i in range(n_s):
            P[i, i] += q_state[i] * gamma2
        P[int(cfg[CFG_ERROR_STATE]), int(cfg[CFG_ERROR_STATE])] += q_error * gamma2
        _symmetrise(P)
    else:
        for i in range(n_s):
            for t in range(n_t):
                dxm[i, t] = dx[i, t]

    # ---- output equation at x^-_k, theta^-_k
    prediction = model_g(
        x,
        in_use,
        chain_num,
        chain_den,
        chain_pade,
        chain_offset,
        chain_size,
        chain_num_length,
        chain_den_length,
        branch_chain,
        branch_input,
        negA,
        negA_grad,
        C,
        C_grad,
        d,
        d_grad,
        dgdx,
        dgdp,
    )
    for i in range(n_c):
        Gs[i] = dgdx[i]
    for g in range(n_g):
        Gs[n_c + g] = dgdp[gain_index[g]]
    # G_p^tot = dg/dtheta + dg/dx dx^-/dtheta (eq. 48)
    for t in range(n_t):
        acc = dgdp[theta_index[t]]
        for i in range(n_s):
            acc += Gs[i] * dxm[i, t]
        Gt[t] = acc

    if dropped:
        innovation = np.nan
        S = R
        for i in range(n_s):
            acc = 0.0
            for j in range(n_s):
                acc += P[i, j] * Gs[j]
            S += Gs[i] * acc
        # no correction: K_s = 0, so dx^+ = dx^- (eq. 50)
        for i in range(n_s):
            for t in range(n_t):
                dx[i, t] = dxm[i, t]
    else:
        innovation = u_k - prediction  # eq. 16
        # ---- 3. state correction (eqs. 15-19)
        S = _joseph(P, Gs, R, K, PG, m, cfg[CFG_JITTER])
        for i in range(n_s):
            x[i] += K[i] * innovation
        # ---- 4. state limitation (eq. 20): with unit-row D, the projection clamps
        for g in range(n_g):
            j = gain_index[g]
            if x[n_c + g] < lo[j]:
                x[n_c + g] = lo[j]
            elif x[n_c + g] > hi[j]:
                x[n_c + g] = hi[j]
        # ---- 5. parameter correction (eqs. 21-24)
        if n_t > 0:
            _joseph(Pp, Gt, R_p, Kp, PGp, mp, cfg[CFG_JITTER])
            for t in range(n_t):
                th[t] += Kp[t] * innovation
            # ---- 6. parameter limitation (eq. 25)
            for t in range(n_t):
                j = theta_index[t]
                if th[t] < lo[j]:
                    th[t] = lo[j]
                elif th[t] > hi[j]:
                    th[t] = hi[j]
        # eq. 50 for the next step: dx^+_k = dx^-_k - K_s,k G_p,k^tot
        for i in range(n_s):
            for t in range(n_t):
                dx[i, t] = dxm[i, t] - K[i] * Gt[t]

    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]

    # ---- report and health
    # covariances: finite, no diagonal below zero beyond rounding, none above max_cov
    finite = np.isfinite(prediction)
    cov_ok = True
    max_cov = cfg[CFG_MAX_COV]
    largest = 0.0
    for i in range(n_s):
        if not np.isfinite(x[i]) or not np.isfinite(P[i, i]):
            finite = False
        elif P[i, i] > largest:
            largest = P[i, i]
    for i in range(n_s):
        if P[i, i] < -NEGATIVE_TOLERANCE * largest or P[i, i] > max_cov:
            cov_ok = False
    largest = 0.0
    for t in range(n_t):
        if not np.isfinite(th[t]) or not np.isfinite(Pp[t, t]):
            finite = False
        elif Pp[t, t] > largest:
            largest = Pp[t, t]
    for t in range(n_t):
        if Pp[t, t] <= -NEGATIVE_TOLERANCE * largest or Pp[t, t] > max_cov:
            cov_ok = False
    if not dropped and not np.isfinite(innovation):
        finite = False

    for j in range(n_p):
        out_pinned[row, j] = False
    if finite:
        # means and standard deviations in internal units, then as reported
        for j in range(n_p):
            out_mean[row, j] = p[j]
            out_std[row, j] = 0.0
        for g in range(n_g):
            j = gain_index[g]
            out_mean[row, j] = x[n_c + g]
            out_std[row, j] = np.sqrt(max(P[n_c + g, n_c + g], 0.0))
        for t in range(n_t):
            j = theta_index[t]
            out_mean[row, j] = th[t]
            out_std[row, j] = np.sqrt(max(Pp[t, t], 0.0))
        for g in range(n_g):
            j = gain_index[g]
            v = x[n_c + g]
            out_pinned[row, j] = v <= lo[j] or v >= hi[j]
        for t in range(n_t):
            j = theta_index[t]
            out_pinned[row, j] = th[t] <= lo[j] or th[t] >= hi[j]
        # samples at a limit within the last pin_ring.shape[1] samples
        n_pin = pin_ring.shape[1]
        if n_pin > 0:
            pos = k % n_pin
            for j in range(n_p):
                now = 1 if out_pinned[row, j] else 0
                pins[j] += now - pin_ring[j, pos]
                pin_ring[j, pos] = now
        for j in range(n_p):
            out_mean[row, j] = report_offset[j] + report_sign[j] * out_mean[row, j]
            last_mean[j] = out_mean[row, j]
            last_std[j] = out_std[row, j]
        if sc[SC_DIV_REASON] == REASON_NONE and n_pin > 0 and k + 1 >= n_pin:
            for j in range(n_p):
                if pins[j] >= PIN_FRACTION * n_pin:
                    sc[SC_DIV_REASON] = REASON_PINNED
                    sc[SC_DIV_INDEX] = k
                    sc[SC_DIV_PARAM] = j
                    break
    else:
        for j in range(n_p):
            out_mean[row, j] = last_mean[j]
            out_std[row, j] = last_std[j]
    if not finite or not cov_ok:
        sc[SC_FROZEN] = 1.0
        if sc[SC_DIV_REASON] == REASON_NONE or sc[SC_DIV_REASON] == REASON_PINNED:
            sc[SC_DIV_REASON] = REASON_NONFINITE if not finite else REASON_COVARIANCE
            sc[SC_DIV_INDEX] = k
            sc[SC_DIV_PARAM] = -1

    out_scalar[row, 0] = prediction if finite else np.nan
    out_scalar[row, 1] = innovation if finite else np.nan
    out_scalar[row, 2] = S if finite else np.nan
    out_flag[row, 0] = finite
    out_flag[row, 1] = cov_ok
    out_flag[row, 2] = dropped
    out_flag[row, 3] = sc[SC_DIV_REASON] != REASON_NONE
    sc[SC_K] = k + 1


@numba.njit(cache=True, _nrt=False)
def dekf_run(
    tables,
    work,
    coef,
    cfg,
    is_dense,
    gain_index,
    theta_index,
    p,
    lo,
    hi,
    q_state,
    q_theta,
    report_offset,
    report_sign,
    x,
    P,
    th,
    Pp,
    dx,
    prev_in,
    buf_u,
    buf_e,
    sc,
    pins,
    pin_ring,
    last_mean,
    last_std,
    scratch,
    inputs,
    u,
    e,
    out_mean,
    out_std,
    out_scalar,
    out_flag,
    out_pinned,
):
    """:func:`dekf_step` over every sample; ``inputs`` has shape ``(n, n_inputs)``."""
    for k in range(u.shape[0]):
        dekf_step(
            tables,
            work,
            coef,
            cfg,
            is_dense,
            gain_index,
            theta_index,
            p,
            lo,
            hi,
            q_state,
            q_theta,
            report_offset,
            report_sign,
            x,
            P,
            th,
            Pp,
            dx,
            prev_in,
            buf_u,
            buf_e,
            sc,
            pins,
            pin_ring,
            last_mean,
            last_std,
            scratch,
            inputs[k],
            u[k],
            e[k],
            k,
            out_mean,
            out_std,
            out_scalar,
            out_flag,
            out_pinned,
        )
