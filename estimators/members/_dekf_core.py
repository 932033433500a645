"""Compiled core of the Dual Extended Kalman Filter: one step, and a whole run.

Pure numerics on small records (namedtuples of arrays):
:func:`dekf_step` advances a :data:`DEKFBelief` by one sample and writes that
sample's estimate into row ``row`` of a :data:`DEKFOutput`; :func:`dekf_run` loops it
over a recording, and :func:`dekf_step_many` steps a stack of filters on one sample
each. The online ``DEKF.update``, the batch ``DEKF.estimate`` and the batched online
path all call :func:`dekf_step`, so they give identical numbers. The covariance algebra (Joseph
correction, symmetrisation, health checks, windowed variances, pin tracking) is the
family's shared code in :mod:`manualcontrol.estimators.filters`.

The six steps (thesis Part I eqs. 11-25, Popovici et al. 2017 eqs. 6-15):

1. parameter prediction ``theta^- = theta^+``, ``P_p^- = P_p^+ + Gamma Q_p Gamma^T``
   (eqs. 11-12, ``Phi_p = I``: the parameters are random walks, eq. 9);
2. state prediction by one Euler step ``x^- = x^+ + f(x^+, in_{k-1}, theta^-) dt``
   (eq. 13, Popovici eq. 8) and ``P_s^- = Phi_s P_s^+ Phi_s^T + Gamma Q_s Gamma^T``
   (eq. 14) with ``Phi_s = I + F dt``, the Jacobian of that Euler step, and
   ``Gamma = I dt`` (or ``I``, ``cfg[CFG_GAMMA2]`` holds its square); a sample longer
   than the papers' 0.01 s is predicted in ``m = cfg[CFG_SUBSTEPS]`` Euler substeps of
   ``h = dt/m`` (:func:`~manualcontrol.estimators._pilot_core.euler_substeps`: two at
   50 and 60 Hz), ``Phi_s`` their product and eq. 49's recursion run through each;
3. state correction with innovation ``r = u - g(x^-, theta^-)`` (eqs. 15-19, Joseph form);
4. state limitation by estimate projection (eq. 20);
5. parameter correction with the total derivative ``G_p^tot`` (eqs. 21-24, 47-50);
6. parameter limitation by estimate projection (eq. 25).

The first sample has no prediction (the prior is the initial belief). ``Phi_s`` is
applied through the structure of ``F`` (shift rows ``x_i' = x_{i+1}`` and one dense
row per canonical chain) in O(n^2) rather than as a dense product.

With smoother storage in the output record (arrays of one row per sample, see
:func:`manualcontrol.estimators.members.dekf.DEKF.estimate`), each step also stores the
state filter's prior, posterior and ``Phi_s`` and the parameter filter's prior and
posterior, from which :mod:`~manualcontrol.estimators.filters.smoothers` smooths the
state filter as an EKF and the parameter filter as random walks.

The kernels are compiled with ``_nrt=False`` (numba's array reference counting off):
they allocate nothing, and the atomic reference counts of the arrays passed around
each step otherwise cost more than the arithmetic.
"""

from __future__ import annotations

from collections import namedtuple

import numba
import numpy as np

from manualcontrol.estimators._pilot_core import (
    CFG_DIMENSIONAL,
    CFG_DT,
    CFG_ERROR_STATE,
    CFG_GAMMA2,
    CFG_JITTER,
    CFG_MAX_COV,
    CFG_SUBSTEPS,
    PAPERS_DT,
    SC_FROZEN,
    SC_K,
    inputs_in_use,
    noise_levels,
    report_frozen,
    report_row,
)
from manualcontrol.estimators.filters.batch import take
from manualcontrol.estimators.filters.kalman import clamp, joseph_correct
from manualcontrol.estimators.filters.linalg import symmetrise
from manualcontrol.estimators.filters.monitor import belief_health
from manualcontrol.estimators.filters.smoothers import store_belief
from manualcontrol.estimators.members.internal_model import evaluate_coefficients, model_f, model_g

#: Settings as arrays: ``cfg`` (``CFG_*`` of :mod:`~manualcontrol.estimators._pilot_core`),
#: which canonical rows of ``F`` are dense, where the gains and parameters sit in the
#: model's parameter vector, their process noises, and the limit entry of each
#: state-filter and parameter-filter state (-1: none).
DEKFConfig = namedtuple(
    "DEKFConfig",
    [
        "cfg",
        "is_dense",
        "gain_index",
        "theta_index",
        "q_state",
        "q_theta",
        "state_limit",
        "theta_limit",
        "estimated",
    ],
)
#: The belief: state filter ``x, P`` (canonical states then gains), parameter filter
#: ``th, Pp``, the total derivative ``dx = dx^+/dtheta``, the previous inputs, the
#: parameter vector ``p`` in model order and the scalars ``sc`` (``SC_*``).
DEKFBelief = namedtuple("DEKFBelief", ["x", "P", "th", "Pp", "dx", "prev_in", "p", "sc"])
DEKFScratch = namedtuple(
    "DEKFScratch",
    [
        "F",
        "f",
        "dfdp",
        "dgdx",
        "dgdp",
        "M",
        "H_state",
        "H_theta",
        "R_state",
        "R_theta",
        "r",
        "state_work",
        "theta_work",
        "dxm",
        "in_use",
        "variance",
        "scalars",
    ],
)
#: Per-row outputs; the smoother storage has one row per sample or none.
DEKFOutput = namedtuple(
    "DEKFOutput",
    [
        "mean",
        "std",
        "scalar",
        "flag",
        "pinned",
        "x_prior",
        "P_prior",
        "x_post",
        "P_post",
        "Phi",
        "th_prior",
        "Pp_prior",
        "th_post",
        "Pp_post",
    ],
)


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
def _store_phi(out, row, F, is_dense, n_c, dt, k):
    """``Phi_s`` of this sample's prediction (identity on the gains; identity at k = 0)."""
    Phi = out.Phi
    if Phi.shape[0] == 0:
        return
    n_s = Phi.shape[1]
    for i in range(n_s):
        for j in range(n_s):
            Phi[row, i, j] = 1.0 if i == j else 0.0
    if k == 0:
        return
    for i in range(n_c):
        if is_dense[i]:
            for j in range(n_c):
                Phi[row, i, j] += dt * F[i, j]
        else:
            Phi[row, i, i + 1] += dt


@numba.njit(cache=True, _nrt=False)
def dekf_step(model, config, belief, monitor, report, scratch, inputs_k, u_k, e_k, row, out):
    """Advance the belief by one sample; write its estimate into output row ``row``.

    ``out.scalar[row]`` = (prediction, innovation, innovation variance);
    ``out.flag[row]`` = (finite, covariance ok, dropped, diverged).
    """
    cfg = config.cfg
    x, P, th, Pp, dx, prev_in, p, sc = belief
    F, f, dfdp, dgdx, dgdp = scratch.F, scratch.f, scratch.dfdp, scratch.dgdx, scratch.dgdp
    H, Ht, dxm, in_use = scratch.H_state, scratch.H_theta, scratch.dxm, scratch.in_use
    gain_index, theta_index = config.gain_index, config.theta_index

    n_c = f.shape[0]
    n_s = x.shape[0]
    n_g = gain_index.shape[0]
    n_t = th.shape[0]
    dt = cfg[CFG_DT]
    gamma2 = cfg[CFG_GAMMA2]
    k = int(sc[SC_K])

    # retrospective variances (Popovici eqs. 24-25, thesis eqs. 29-30)
    R, R_p, q_error = noise_levels(cfg, sc, monitor, u_k, e_k)
    dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use)

    if sc[SC_FROZEN] > 0.0:
        store_belief(row, x, P, out.x_prior, out.P_prior)
        store_belief(row, x, P, out.x_post, out.P_post)
        store_belief(row, th, Pp, out.th_prior, out.Pp_prior)
        store_belief(row, th, Pp, out.th_post, out.Pp_post)
        _store_phi(out, row, F, config.is_dense, n_c, dt, 0)
        report_frozen(sc, monitor, prev_in, in_use, dropped, row, out)
        return

    # current parameter vector: gains from the state filter, theta^- = theta^+ (eq. 11)
    for g in range(n_g):
        p[gain_index[g]] = x[n_c + g]
    for t in range(n_t):
        p[theta_index[t]] = th[t]
    evaluate_coefficients(p, model)

    if k > 0:
        # ---- 1. parameter prediction (eq. 12)
        for t in range(n_t):
            Pp[t, t] += config.q_theta[t] * gamma2
        # ---- 2. state prediction (eqs. 13-14) at x^+_{k-1}, in_{k-1}, theta^-_k: Euler
        # substeps of h = dt / m (one at 100 Hz), Phi_s their product
        m = max(1, int(cfg[CFG_SUBSTEPS]))
        h = dt / m
        # eq. 49's weight of df/dtheta per substep: h (dimensional), h / 0.01 s (printed:
        # 1 a sample at the papers' 100 Hz, the same weight per second at every rate)
        scale = h if cfg[CFG_DIMENSIONAL] > 0.0 else h / PAPERS_DT
        store_phi = out.Phi.shape[0] > 0
        if store_phi:
            _store_phi(out, row, F, config.is_dense, n_c, h, 0)
        for j in range(m):
            model_f(x, prev_in, model, f, F, dfdp, True)
            # total-derivative recursion, eq. 49: dx^-_k = df/dtheta (dt) + Phi dx^+_{k-1}
            if j > 0:
                for i in range(n_s):
                    for t in range(n_t):
                        dx[i, t] = dxm[i, t]
            _apply_phi(F, config.is_dense, n_c, h, dx, dxm)
            for i in range(n_c):
                for t in range(n_t):
                    dxm[i, t] += dfdp[i, theta_index[t]] * scale
            for i in range(n_c):
                x[i] += f[i] * h
            _apply_phi(F, config.is_dense, n_c, h, P, scratch.M)
            _apply_phi_transpose(F, config.is_dense, n_c, h, scratch.M, P)
            if store_phi:
                _apply_phi(F, config.is_dense, n_c, h, out.Phi[row], scratch.M)
                for a in range(n_s):
                    for b in range(n_s):
                        out.Phi[row, a, b] = scratch.M[a, b]
        for i in range(n_s):
            P[i, i] += config.q_state[i] * gamma2
        P[int(cfg[CFG_ERROR_STATE]), int(cfg[CFG_ERROR_STATE])] += q_error * gamma2
        symmetrise(P)
    else:
        for i in range(n_s):
            for t in range(n_t):
                dxm[i, t] = dx[i, t]
        _store_phi(out, row, F, config.is_dense, n_c, dt, k)
    store_belief(row, x, P, out.x_prior, out.P_prior)
    store_belief(row, th, Pp, out.th_prior, out.Pp_prior)

    # ---- output equation at x^-_k, theta^-_k
    prediction = model_g(x, in_use, model, dgdx, dgdp, True)
    for i in range(n_c):
        H[0, i] = dgdx[i]
    for g in range(n_g):
        H[0, n_c + g] = dgdp[gain_index[g]]
    # G_p^tot = dg/dtheta + dg/dx dx^-/dtheta (eq. 48)
    for t in range(n_t):
        acc = dgdp[theta_index[t]]
        for i in range(n_s):
            acc += H[0, i] * dxm[i, t]
        Ht[0, t] = acc

    correct_ok = True
    if dropped:
        innovation = np.nan
        S = R
        for i in range(n_s):
            acc = 0.0
            for j in range(n_s):
                acc += P[i, j] * H[0, j]
            S += H[0, i] * acc
        # no correction: K_s = 0, so dx^+ = dx^- (eq. 50)
        for i in range(n_s):
            for t in range(n_t):
                dx[i, t] = dxm[i, t]
    else:
        innovation = u_k - prediction  # eq. 16
        scratch.r[0] = innovation
        # ---- 3. state correction (eqs. 15-19)
        scratch.R_state[0, 0] = R
        correct_ok = joseph_correct(
            x, P, scratch.r, H, scratch.R_state, scratch.state_work, cfg[CFG_JITTER]
        )
        S = scratch.state_work.S[0, 0]
        K = scratch.state_work.K
        # ---- 4. state limitation (eq. 20): with unit-row D, the projection clamps
        clamp(x, config.state_limit, report.lo, report.hi)
        # ---- 5. parameter correction (eqs. 21-24)
        if n_t > 0 and correct_ok:
            scratch.R_theta[0, 0] = R_p
            correct_ok = joseph_correct(
                th, Pp, scratch.r, Ht, scratch.R_theta, scratch.theta_work, cfg[CFG_JITTER]
            )
            # ---- 6. parameter limitation (eq. 25)
            clamp(th, config.theta_limit, report.lo, report.hi)
        # eq. 50 for the next step: dx^+_k = dx^-_k - K_s,k G_p,k^tot
        for i in range(n_s):
            for t in range(n_t):
                dx[i, t] = dxm[i, t] - K[i, 0] * Ht[0, t]
    store_belief(row, x, P, out.x_post, out.P_post)
    store_belief(row, th, Pp, out.th_post, out.Pp_post)

    for i in range(prev_in.shape[0]):
        prev_in[i] = in_use[i]

    # ---- health and report
    max_cov = cfg[CFG_MAX_COV]
    finite_s, cov_ok_s = belief_health(x, P, max_cov, True)
    finite_t, cov_ok_t = belief_health(th, Pp, max_cov, False)
    finite = np.isfinite(prediction) and finite_s and finite_t
    cov_ok = cov_ok_s and cov_ok_t
    if not dropped and not np.isfinite(innovation):
        finite = False
    if not correct_ok:
        # an innovation variance that is not positive: non-finite, or the covariance broke
        if np.isfinite(S):
            cov_ok = False
        else:
            finite = False
    variance = scratch.variance
    for g in range(n_g):
        p[gain_index[g]] = x[n_c + g]
        variance[gain_index[g]] = P[n_c + g, n_c + g]
    for t in range(n_t):
        p[theta_index[t]] = th[t]
        variance[theta_index[t]] = Pp[t, t]
    scalars = scratch.scalars
    scalars[0] = prediction
    scalars[1] = innovation
    scalars[2] = S
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
        scalars,
        row,
        out,
    )


@numba.njit(cache=True, _nrt=False)
def dekf_run(model, config, belief, monitor, report, scratch, inputs, u, e, out):
    """:func:`dekf_step` over every sample; ``inputs`` has shape ``(n, n_inputs)``."""
    for k in range(u.shape[0]):
        dekf_step(model, config, belief, monitor, report, scratch, inputs[k], u[k], e[k], k, out)


@numba.njit(cache=True, _nrt=False)
def dekf_step_many(
    model, config, belief, monitor, report, scratch, inputs, u, e, active, rows, out
):
    """:func:`dekf_step` on sample ``i`` wherever ``active[i]`` is set, in order.

    The records are stacked (:func:`~manualcontrol.estimators.filters.batch.stack_records`):
    sample ``i`` (``inputs[i], u[i], e[i]``) steps the filter in row ``rows[i]`` of
    each, whose estimate goes to row 0 of its one-row output. Many filters on one
    sample each: ``rows = arange(n)``. One filter on a block of samples, in time order:
    ``rows`` all zero on a stack of one
    (:func:`~manualcontrol.estimators.filters.batch.stack_of_one`).
    """
    records = (model, config, belief, monitor, report, scratch, out)
    last = 0
    views = take(records, 0)
    for i in range(u.shape[0]):
        if active[i]:
            r = rows[i]
            if r != last:  # a block of one filter's samples takes its views once
                views = take(records, r)
                last = r
            dekf_step(*views[:6], inputs[i], u[i], e[i], 0, views[6])
