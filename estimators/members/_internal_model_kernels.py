"""The numba kernels of :mod:`~manualcontrol.estimators.members.internal_model`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference, :meth:`InternalModel.evaluate
<manualcontrol.estimators.members.internal_model.InternalModel.evaluate>`): the model's
builder and its records stay in the numba-free module, which exports these kernels by
name on first use.
"""

from __future__ import annotations

import numba


@numba.njit(cache=True, _nrt=False)
def _pade_jet(tau, order, sign, value, slope, row):
    """Padé polynomial (thesis eq. 4) in descending powers, constant term 1, and d/dtau.

    Written to ``value[row]`` and ``slope[row]``; ``sign`` -1 for the numerator
    (``-tau s``), +1 for the denominator.
    """
    # c_k = (2m - k)! / (k! (m - k)!) / c_0, built by the ratio c_k/c_{k-1}
    c = 1.0
    power = 1.0  # (sign tau)^k, built up step by step
    previous = 1.0
    for k in range(order + 1):
        if k > 0:
            c = c * (order - k + 1) / (k * (2 * order - k + 1))
            previous = power
            power = power * sign * tau
        value[row, order - k] = c * power
        slope[row, order - k] = 0.0 if k == 0 else c * k * sign * previous


@numba.njit(cache=True, _nrt=False)
def _chain_polynomial(
    p,
    raw,
    raw_grad,
    start,
    length,
    total,
    k,
    sign,
    active,
    c,
    which,
    pade_value,
    pade_slope,
    out,
    out_grad,
):
    """``out[c] = raw[start:start+length]`` times the Padé polynomial of ``p[k]`` (if k >= 0).

    Gradients only in the parameters ``active[c, which]`` (-1 ends the list); other
    entries stay 0. Whole arrays and indices are passed, not views (cheaper in numba).
    """
    n_p = p.shape[0]
    for i in range(total):
        out[c, i] = 0.0
        for jj in range(n_p):
            j = active[c, which, jj]
            if j < 0:
                break
            out_grad[c, i, j] = 0.0
    if k < 0:
        for i in range(length):
            out[c, i] = raw[start + i]
            for jj in range(n_p):
                j = active[c, which, jj]
                if j < 0:
                    break
                out_grad[c, i, j] = raw_grad[start + i, j]
        return
    order = pade_value.shape[1] - 1
    _pade_jet(p[k], order, sign, pade_value, pade_slope, which)
    for i in range(length):
        r = raw[start + i]
        for m in range(order + 1):
            w = pade_value[which, m]
            out[c, i + m] += r * w
            for jj in range(n_p):
                j = active[c, which, jj]
                if j < 0:
                    break
                out_grad[c, i + m, j] += raw_grad[start + i, j] * w
            out_grad[c, i + m, k] += r * pade_slope[which, m]


@numba.njit(cache=True, _nrt=False)
def evaluate_coefficients(p, kernel):
    """Canonical-form coefficients of every chain and their gradients in ``p``.

    Writes ``negA`` (last row of each chain's companion matrix, ``-a_i``), ``C`` (the
    chain output row) and ``d`` (feedthrough per chain), each with its gradient in
    the parameters listed in ``active`` (shape ``(n_chain, 3, n_p)``: per chain the
    parameters of its numerator, of its denominator and of both, each list ended by
    -1); gradient entries of other parameters are left untouched (zero).
    """
    term_coef, term_var, term_exp, term_slot = (
        kernel.term_coef,
        kernel.term_var,
        kernel.term_exp,
        kernel.term_slot,
    )
    chain_num, chain_den, chain_pade = kernel.chain_num, kernel.chain_den, kernel.chain_pade
    chain_offset, chain_size = kernel.chain_offset, kernel.chain_size
    chain_num_length, chain_den_length = kernel.chain_num_length, kernel.chain_den_length
    active, raw, raw_grad = kernel.active, kernel.raw, kernel.raw_grad
    num, num_grad, den, den_grad = kernel.num, kernel.num_grad, kernel.den, kernel.den_grad
    pade_value, pade_slope = kernel.pade_value, kernel.pade_slope
    negA, negA_grad, C, C_grad = kernel.negA, kernel.negA_grad, kernel.C, kernel.C_grad
    d, d_grad = kernel.d, kernel.d_grad
    n_p = p.shape[0]
    gradients = kernel.gradients
    for t in range(term_coef.shape[0]):
        raw[term_slot[t]] = 0.0
        if not gradients:
            continue
        for i in range(n_p):
            j = term_var[t, i]
            if j < 0:
                break
            raw_grad[term_slot[t], j] = 0.0
    for t in range(term_coef.shape[0]):
        # integer powers by multiplication (exponents are small)
        value = term_coef[t]
        n_var = 0
        for i in range(n_p):
            j = term_var[t, i]
            if j < 0:
                break
            n_var += 1
            for _ in range(term_exp[t, i]):
                value *= p[j]
        slot = term_slot[t]
        raw[slot] += value
        if not gradients:
            continue
        for i in range(n_var):
            j = term_var[t, i]
            derivative = term_coef[t] * term_exp[t, i]
            for _ in range(term_exp[t, i] - 1):
                derivative *= p[j]
            for other in range(n_var):
                if other != i:
                    jj = term_var[t, other]
                    for _ in range(term_exp[t, other]):
                        derivative *= p[jj]
            raw_grad[slot, j] += derivative
    n_chain = chain_num.shape[0]
    for c in range(n_chain):
        # numerator and denominator of the chain, with the Padé factor when it has one
        _chain_polynomial(
            p,
            raw,
            raw_grad,
            chain_num[c, 0],
            chain_num[c, 1],
            chain_num_length[c],
            chain_pade[c],
            -1.0,
            active,
            c,
            0,
            pade_value,
            pade_slope,
            num,
            num_grad,
        )
        _chain_polynomial(
            p,
            raw,
            raw_grad,
            chain_den[c, 0],
            chain_den[c, 1],
            chain_den_length[c],
            chain_pade[c],
            1.0,
            active,
            c,
            1,
            pade_value,
            pade_slope,
            den,
            den_grad,
        )
        # monic normalisation and canonical form (thesis eq. 4.7)
        n = chain_size[c]
        off = chain_offset[c]
        inv_lead = 1.0 / den[c, 0]
        pad = chain_den_length[c] - chain_num_length[c]  # numerator padding
        # feedthrough d = b_0 / lead (zero for strictly proper chains)
        if pad == 0:
            d[c] = num[c, 0] * inv_lead
            for jj in range(n_p):
                j = active[c, 2, jj]
                if j < 0:
                    break
                d_grad[c, j] = (num_grad[c, 0, j] - d[c] * den_grad[c, 0, j]) * inv_lead
        else:
            d[c] = 0.0
        dc = d[c]
        for i in range(n):
            # ascending state index i <-> descending coefficient index n - i
            q = n - i
            a = den[c, q] * inv_lead
            negA[off + i] = -a
            for jj in range(n_p):
                j = active[c, 1, jj]
                if j < 0:
                    break
                negA_grad[off + i, j] = -(den_grad[c, q, j] - a * den_grad[c, 0, j]) * inv_lead
            has_b = q - pad >= 0
            b = num[c, q - pad] * inv_lead if has_b else 0.0
            C[off + i] = b - dc * a
            for jj in range(n_p):
                j = active[c, 2, jj]
                if j < 0:
                    break
                b_grad = 0.0
                if has_b:
                    b_grad = (num_grad[c, q - pad, j] - b * den_grad[c, 0, j]) * inv_lead
                C_grad[off + i, j] = b_grad - d_grad[c, j] * a + dc * negA_grad[off + i, j]


@numba.njit(cache=True, _nrt=False, inline="always")
def model_f(x, inputs, kernel, f, F, dfdp, jacobians):
    """``f``; with ``jacobians`` also ``df/dx`` (shift rows are set too) and ``df/dp``.

    Reads the coefficients that :func:`evaluate_coefficients` left in ``kernel``.
    """
    chain_offset, chain_size = kernel.chain_offset, kernel.chain_size
    branch_chain, branch_input = kernel.branch_chain, kernel.branch_input
    negA, negA_grad, C, C_grad = kernel.negA, kernel.negA_grad, kernel.C, kernel.C_grad
    d, d_grad = kernel.d, kernel.d_grad
    n_p = dfdp.shape[1] if jacobians else 0
    n_chain = chain_size.shape[0]
    for c in range(n_chain):
        n = chain_size[c]
        off = chain_offset[c]
        for i in range(n - 1):
            f[off + i] = x[off + i + 1]
            F[off + i, off + i + 1] = 1.0
            for j in range(n_p):
                dfdp[off + i, j] = 0.0
        if n == 0:
            continue
        last = off + n - 1
        acc = 0.0
        for j in range(n_p):
            dfdp[last, j] = 0.0
        for i in range(n):
            acc += negA[off + i] * x[off + i]
            F[last, off + i] = negA[off + i]
            for j in range(n_p):
                dfdp[last, j] += negA_grad[off + i, j] * x[off + i]
        if c == 0:
            # main chain input v = sum over branches of (C_b x_b + d_b in_b)
            for b in range(branch_chain.shape[0]):
                cb = branch_chain[b]
                ob = chain_offset[cb]
                for i in range(chain_size[cb]):
                    acc += C[ob + i] * x[ob + i]
                    F[last, ob + i] = C[ob + i]
                    for j in range(n_p):
                        dfdp[last, j] += C_grad[ob + i, j] * x[ob + i]
                u_b = inputs[branch_input[b]]
                acc += d[cb] * u_b
                for j in range(n_p):
                    dfdp[last, j] += d_grad[cb, j] * u_b
        else:
            # a branch chain is driven by its own input
            for b in range(branch_chain.shape[0]):
                if branch_chain[b] == c:
                    acc += inputs[branch_input[b]]
        f[last] = acc


@numba.njit(cache=True, _nrt=False, inline="always")
def model_g(x, inputs, kernel, dgdx, dgdp, jacobians):
    """``g`` (returned); with ``jacobians`` also ``dg/dx`` and ``dg/dp`` (written)."""
    chain_offset, chain_size = kernel.chain_offset, kernel.chain_size
    branch_chain, branch_input = kernel.branch_chain, kernel.branch_input
    C, C_grad, d, d_grad = kernel.C, kernel.C_grad, kernel.d, kernel.d_grad
    n_p = dgdp.shape[0] if jacobians else 0
    n0 = chain_size[0]
    g = 0.0
    for j in range(n_p):
        dgdp[j] = 0.0
    for i in range(n0):
        g += C[i] * x[i]
        dgdx[i] = C[i]
        for j in range(n_p):
            dgdp[j] += C_grad[i, j] * x[i]
    # feedthrough of the main chain: d_0 v
    v = 0.0
    for j in range(dgdx.shape[0] - n0):
        dgdx[n0 + j] = 0.0
    for b in range(branch_chain.shape[0]):
        cb = branch_chain[b]
        ob = chain_offset[cb]
        for i in range(chain_size[cb]):
            v += C[ob + i] * x[ob + i]
            dgdx[ob + i] = d[0] * C[ob + i]
            for j in range(n_p):
                dgdp[j] += d[0] * C_grad[ob + i, j] * x[ob + i]
        u_b = inputs[branch_input[b]]
        v += d[cb] * u_b
        for j in range(n_p):
            dgdp[j] += d[0] * d_grad[cb, j] * u_b
    g += d[0] * v
    for j in range(n_p):
        dgdp[j] += d_grad[0, j] * v
    return g
