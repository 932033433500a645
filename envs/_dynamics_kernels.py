"""The numba kernels of the LPV toolkit: matrix exponentials and the LPV sample step.

:func:`expm_batch_kernel` is the compiled Al-Mohy & Higham (2009) scaling and squaring
of :func:`~manualcontrol.envs._expm.expm_batch` (the algorithm, and why it works on
transposes, in that module's docstring); :func:`simulate_lpv_kernel` the whole-run loop
of :func:`~manualcontrol.envs.dynamics.simulate_lpv`, built from the two halves of a
sample, :func:`lpv_output_step` and :func:`lpv_state_step` (which the pilot acting in an
environment, :mod:`~manualcontrol.pilots.controller`, calls from its own kernel) and the
delay-line reads :func:`read_smooth` and :func:`read_held`.

They live apart from :mod:`~manualcontrol.envs.dynamics` and
:mod:`~manualcontrol.envs._expm` because those run the C port of these kernels
(``_dynamics_native.c``, the same numbers bit for bit) wherever it builds: a process
that only discretises and simulates then never imports numba (importing it and loading
its cache is about half a CPU-second of a short command). This module is imported
where the C port is unavailable (``MANUALCONTROL_NATIVE=0``, no compiler), and by the
kernels that call these from their own compiled code.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._interpolation import bicubic_weights

__all__ = [
    "expm_batch_kernel",
    "lpv_output_step",
    "lpv_state_step",
    "read_held",
    "read_smooth",
    "simulate_lpv_kernel",
]

FloatArray = NDArray[np.float64]


# ------------------------------------------------------------ matrix exponential


@numba.njit(cache=True)
def _matmul(a: FloatArray, b: FloatArray, out: FloatArray) -> None:
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            out[i, j] = 0.0
        for k in range(n):
            aik = a[i, k]
            if aik != 0.0:
                for j in range(n):
                    out[i, j] += aik * b[k, j]


@numba.njit(cache=True)
def _norm1(a: FloatArray) -> float:
    """Maximum absolute column sum."""
    n = a.shape[0]
    best = 0.0
    for j in range(n):
        total = 0.0
        for i in range(n):
            total += abs(a[i, j])
        best = max(best, total)
    return best


@numba.njit(cache=True)
def _ell(
    a: FloatArray,
    scale: float,
    norm_a: float,
    power: int,
    recip: float,
    unit_roundoff: float,
    v: FloatArray,
    w: FloatArray,
) -> int:
    """Al-Mohy & Higham's ell(scale A, m) with ``power = 2m + 1``.

    ``|| |A|^p ||_1`` of a non-negative matrix is the largest entry of ``1^T |A|^p``,
    computed exactly by ``p`` vector-matrix products.
    """
    n = a.shape[0]
    for j in range(n):
        v[j] = 1.0
    for _ in range(power):
        for j in range(n):
            total = 0.0
            for i in range(n):
                total += v[i] * abs(a[i, j])
            w[j] = scale * total
        for j in range(n):
            v[j] = w[j]
    abs_norm = 0.0
    for j in range(n):
        abs_norm = max(abs_norm, v[j])
    if abs_norm == 0.0:
        return 0
    alpha = abs_norm / (scale * norm_a * recip)
    value = math.ceil(math.log2(alpha / unit_roundoff) / (power - 1))
    return max(int(value), 0)


@numba.njit(cache=True)
def _polynomial(out: FloatArray, add: bool, coefficients: FloatArray, powers: FloatArray) -> None:
    """``out (+)= sum_p c_p A^(2p)`` over ``p = 0 .. 4`` (``A^0 = I``), highest power last.

    Powers above the highest non-zero coefficient are skipped, not multiplied by
    zero: a power not computed holds whatever was there.
    """
    n = out.shape[0]
    top = 1
    for p in range(2, 5):
        if coefficients[p] != 0.0:
            top = p
    for i in range(n):
        for j in range(n):
            total = coefficients[0] if i == j else 0.0
            for p in range(1, top + 1):
                total = coefficients[p] * powers[p, i, j] + total
            out[i, j] = out[i, j] + total if add else total


@numba.njit(cache=True)
def _solve_in_place(p: FloatArray, q: FloatArray) -> None:
    """``q <- p^{-1} q`` by Gaussian elimination with partial pivoting (``p`` destroyed)."""
    n = p.shape[0]
    for col in range(n):
        pivot = col
        biggest = abs(p[col, col])
        for r in range(col + 1, n):
            if abs(p[r, col]) > biggest:
                biggest = abs(p[r, col])
                pivot = r
        if pivot != col:
            for j in range(n):
                p[col, j], p[pivot, j] = p[pivot, j], p[col, j]
                q[col, j], q[pivot, j] = q[pivot, j], q[col, j]
        inverse = 1.0 / p[col, col]
        for r in range(col + 1, n):
            factor = p[r, col] * inverse
            if factor != 0.0:
                for j in range(col + 1, n):
                    p[r, j] -= factor * p[col, j]
                for j in range(n):
                    q[r, j] -= factor * q[col, j]
    for col in range(n - 1, -1, -1):
        inverse = 1.0 / p[col, col]
        for j in range(n):
            total = q[col, j]
            for k in range(col + 1, n):
                total -= p[col, k] * q[k, j]
            q[col, j] = total * inverse


@numba.njit(cache=True)
def expm_batch_kernel(
    matrices: FloatArray,
    coefficients: FloatArray,
    theta: FloatArray,
    orders: NDArray[np.int64],
    ell_reciprocal: FloatArray,
    unit_roundoff: float,
) -> FloatArray:
    """Algorithm 3.1 on every matrix (runs of equal ones once), in one compiled body.

    The tables are :mod:`~manualcontrol.envs._expm`'s (Padé coefficients, the
    ``theta_m``, the orders ``m``, the ``1/|c_{2m+1}|`` of the bound and the unit
    roundoff), passed in: numba will not cache a kernel that reads a 2-D global, and
    the C port reads the very same arrays.

    exp(A) = exp(A^T)^T: each matrix is transposed in and out and the algorithm run
    on the transpose, as scipy does (see the module docstring). One body with its
    helpers called from few places: LLVM inlines every call site, and a copy per
    call site had made this the slowest kernel of the package to compile.
    """
    count, n = matrices.shape[0], matrices.shape[1]
    result = np.empty_like(matrices)
    # powers[0..4] = A, A^2, A^4, A^6, A^8 (order 13: the scaled B, B^2, B^4, B^6, 2^-s A)
    powers = np.empty((5, n, n))
    work = np.empty((3, n, n))  # U, V and a scratch matrix
    out = np.empty((n, n))
    v = np.empty(n)
    w = np.empty(n)
    for k in range(count):
        if k > 0:
            same = True
            for i in range(n):
                for j in range(n):
                    if matrices[k, i, j] != matrices[k - 1, i, j]:
                        same = False
                        break
                if not same:
                    break
            if same:
                # element by element: a slice assignment would compile numba's shape
                # error message (about 4 CPU-s in every process that compiles this)
                for i in range(n):
                    for j in range(n):
                        result[k, i, j] = result[k - 1, i, j]
                continue
        a = powers[0]
        for i in range(n):
            for j in range(n):
                a[i, j] = matrices[k, j, i]
        for step in range(3):  # A^2 = A A, A^4 = A^2 A^2, A^6 = A^2 A^4
            _matmul(powers[1 if step else 0], powers[step], powers[step + 1])
        norm_a = _norm1(a)
        if norm_a == 0.0:
            for i in range(n):
                for j in range(n):
                    result[k, i, j] = 1.0 if i == j else 0.0
            continue
        d6 = _norm1(powers[3]) ** (1.0 / 6.0)
        eta = max(_norm1(powers[2]) ** 0.25, d6)
        choice = -1
        s = 0
        d8 = 0.0
        for option in range(4):
            if option == 2:  # orders 7 and 9 judge by eta_3 = max(d6, d8)
                _matmul(powers[2], powers[2], powers[4])
                d8 = _norm1(powers[4]) ** 0.125
                eta = max(d6, d8)
            if eta < theta[option] and (
                _ell(
                    a,
                    1.0,
                    norm_a,
                    2 * orders[option] + 1,
                    ell_reciprocal[option],
                    unit_roundoff,
                    v,
                    w,
                )
                == 0
            ):
                choice = option
                break
        if choice < 0:
            choice = 4
            _matmul(powers[2], powers[3], work[2])
            eta5 = min(eta, max(d8, _norm1(work[2]) ** 0.1))
            if eta5 > 0.0:
                s = max(math.ceil(math.log2(eta5 / theta[4])), 0)
            s += _ell(a, 2.0**-s, norm_a, 27, ell_reciprocal[4], unit_roundoff, v, w)
            for i in range(n):
                for j in range(n):
                    powers[1, i, j] *= 2.0 ** (-2 * s)
                    powers[2, i, j] *= 2.0 ** (-4 * s)
                    powers[3, i, j] *= 2.0 ** (-6 * s)
                    powers[4, i, j] = 2.0**-s * a[i, j]
            # U = B [B6 (b13 B6 + b11 B4 + b9 B2) + b7 B6 + ... + b1 I], V likewise
            for part in range(2):
                _polynomial(out, False, coefficients[8 + 2 * part], powers)
                _matmul(powers[3], out, work[part])
                _polynomial(work[part], True, coefficients[9 + 2 * part], powers)
        else:
            # U without its leading A into work[0], V into work[1]
            for part in range(2):
                _polynomial(work[part], False, coefficients[2 * choice + part], powers)
        # U = A (odd part); r_m = (V - U)^{-1} (V + U)
        _matmul(powers[4] if choice == 4 else a, work[0], work[2])
        u, vv, scratch = work[2], work[1], work[0]
        for i in range(n):
            for j in range(n):
                scratch[i, j] = vv[i, j] - u[i, j]
                out[i, j] = vv[i, j] + u[i, j]
        _solve_in_place(scratch, out)
        for _ in range(s):
            _matmul(out, out, scratch)
            for i in range(n):
                for j in range(n):
                    out[i, j] = scratch[i, j]
        for i in range(n):
            for j in range(n):
                result[k, i, j] = out[j, i]
    return result


# ------------------------------------------------------------------ LPV stepping


@numba.njit(cache=True)
def read_smooth(history: FloatArray, newest: int, position: float) -> float:
    """Bicubic read of ``history[0..newest]`` at fractional index ``position``.

    For the part of a delayed signal that is a smooth function of time. Samples
    beyond ``newest`` are not yet known and are replaced by the newest one, so delays
    shorter than about three samples lose interpolation order instead of reading the
    future.
    """
    if position <= 0.0:
        return history[0]
    n = int(np.floor(position))
    if n >= newest:
        return history[newest]
    d = position - n
    i_m1 = n - 1 if n >= 1 else 0
    i_1 = n + 1 if n + 1 <= newest else newest
    i_2 = n + 2 if n + 2 <= newest else newest
    a, b, c, w = bicubic_weights(d)
    return a * history[i_m1] + b * history[n] + c * history[i_1] + w * history[i_2]


@numba.njit(cache=True)
def read_held(history: FloatArray, newest: int, position: float) -> float:
    """Mean of a delayed staircase over one sample, starting at fractional ``position``.

    ``history[j]`` is held over ``[j, j + 1)``; its mean over ``[p, p + 1]`` is the
    linear interpolation at ``p``: exact for held signals, so delaying a zero-order-
    hold input by a whole number of samples is exact.
    """
    if position <= 0.0:
        return history[0]
    n = int(np.floor(position))
    if n >= newest:
        return history[newest]
    d = position - n
    return (1.0 - d) * history[n] + d * history[n + 1]


@numba.njit(cache=True)
def lpv_output_step(
    c: FloatArray,
    d: FloatArray,
    x: FloatArray,
    u: FloatArray,
    smooth: FloatArray,
    held: FloatArray,
    newest: int,
    delay_inputs: NDArray[np.int64],
    delay_outputs: NDArray[np.int64],
    delay_now: FloatArray,
    smooth_now: FloatArray,
    held_state: NDArray[np.bool_],
    outputs: FloatArray,
    fill_past: bool = False,
) -> None:
    """First half of one :func:`simulate_lpv` sample: delayed inputs, then outputs.

    Writes the delay sources of this sample into the histories ``smooth`` and ``held``
    at column ``newest``, the delayed inputs into ``u`` (the smooth part was read one
    step ago, ``smooth_now``; the held part now, ``delay_now`` samples back) and
    ``y = C x + D u`` into ``outputs``. Shared by the whole-run loop and the pilot
    acting in an environment (:class:`~manualcontrol.pilots.controller.PilotController`),
    so both give the same numbers. ``fill_past`` (the first sample of a run started from
    a state that had a past, ``history="initial"``): the histories before ``newest``
    take this sample's values.
    """
    n_x = x.shape[0]
    n_u = u.shape[0]
    for i in range(delay_inputs.shape[0]):
        r = delay_outputs[i]
        acc = 0.0
        held_value = 0.0
        for j in range(n_x):
            if held_state[j]:
                held_value += c[r, j] * x[j]
            else:
                acc += c[r, j] * x[j]
        smooth[i, newest] = acc
        for j in range(n_u):
            if j != delay_inputs[i]:
                held_value += d[r, j] * u[j]
        held[i, newest] = held_value
        if fill_past:
            for j in range(newest):
                smooth[i, j] = acc
                held[i, j] = held_value
            smooth_now[i] = acc
        position = newest - delay_now[i]
        u[delay_inputs[i]] = smooth_now[i] + read_held(held[i], newest, position)
    for r in range(c.shape[0]):
        acc = 0.0
        for j in range(n_x):
            acc += c[r, j] * x[j]
        for j in range(n_u):
            acc += d[r, j] * u[j]
        outputs[r] = acc


@numba.njit(cache=True)
def lpv_state_step(
    phi: FloatArray,
    gamma: FloatArray,
    gamma_ramp: FloatArray,
    x: FloatArray,
    u: FloatArray,
    smooth: FloatArray,
    newest: int,
    delay_inputs: NDArray[np.int64],
    delay_next: FloatArray,
    smooth_now: FloatArray,
    smooth_next: FloatArray,
    x_next: FloatArray,
) -> None:
    """Second half of one :func:`simulate_lpv` sample: the state (and delay reads) advanced.

    ``x <- phi x + gamma u + gamma_ramp (s_next - s_now)`` with the smooth delayed
    parts read ``delay_next`` samples before the next sample; ``smooth_next`` and
    ``x_next`` are work arrays.
    """
    n_x = x.shape[0]
    n_u = u.shape[0]
    n_delay = delay_inputs.shape[0]
    for i in range(n_delay):
        position = newest + 1.0 - delay_next[i]
        smooth_next[i] = read_smooth(smooth[i], newest, position)
    for r in range(n_x):
        acc = 0.0
        for j in range(n_x):
            acc += phi[r, j] * x[j]
        for j in range(n_u):
            acc += gamma[r, j] * u[j]
        for i in range(n_delay):
            acc += gamma_ramp[r, delay_inputs[i]] * (smooth_next[i] - smooth_now[i])
        x_next[r] = acc
    for r in range(n_x):
        x[r] = x_next[r]
    for i in range(n_delay):
        smooth_now[i] = smooth_next[i]


@numba.njit(cache=True)
def simulate_lpv_kernel(
    phi: FloatArray,
    gamma: FloatArray,
    gamma_ramp: FloatArray,
    c: FloatArray,
    d: FloatArray,
    inputs: FloatArray,
    x0: FloatArray,
    delay_inputs: NDArray[np.int64],
    delay_outputs: NDArray[np.int64],
    delay_samples: FloatArray,
    history_pad: int,
    held_state: NDArray[np.bool_],
    history_initial: bool = False,
) -> tuple[FloatArray, FloatArray]:
    """The whole-run loop of :func:`~manualcontrol.envs.dynamics.simulate_lpv` (arrays checked).

    One :func:`lpv_output_step` and one :func:`lpv_state_step` per sample; the
    histories of the delayed sources are ``history_pad`` samples longer than the run.
    """
    n_samples = inputs.shape[0]
    n_x = phi.shape[1]
    n_u = gamma.shape[2]
    n_y = c.shape[1]
    n_delay = delay_inputs.shape[0]
    states = np.empty((n_samples, n_x))
    outputs = np.empty((n_samples, n_y))
    # Each delayed source y_r = C_r x + D_r u has a smooth part C_r x and a part D_r u
    # held over the sample; both histories start at rest (zeros before t = 0).
    smooth = np.zeros((n_delay, history_pad + n_samples))
    held = np.zeros((n_delay, history_pad + n_samples))
    u = np.empty(n_u)
    x = x0.copy()
    x_next = np.empty(n_x)
    smooth_now = np.zeros(n_delay)
    smooth_next = np.zeros(n_delay)
    for k in range(n_samples):
        kp = k if phi.shape[0] > 1 else 0
        kg = k if gamma.shape[0] > 1 else 0
        kc = k if c.shape[0] > 1 else 0
        kd = k if d.shape[0] > 1 else 0
        for j in range(n_u):
            u[j] = inputs[k, j]
        newest = history_pad + k
        for r in range(n_x):
            states[k, r] = x[r]
        lpv_output_step(
            c[kc],
            d[kd],
            x,
            u,
            smooth,
            held,
            newest,
            delay_inputs,
            delay_outputs,
            delay_samples[k],
            smooth_now,
            held_state,
            outputs[k],
            k == 0 and history_initial,
        )
        if k == n_samples - 1:
            break
        lpv_state_step(
            phi[kp],
            gamma[kg],
            gamma_ramp[kg],
            x,
            u,
            smooth,
            newest,
            delay_inputs,
            delay_samples[k + 1],
            smooth_now,
            smooth_next,
            x_next,
        )
    return states, outputs
