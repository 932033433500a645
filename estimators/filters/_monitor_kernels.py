"""The numba kernels of :mod:`~manualcontrol.estimators.filters.monitor`.

Imported only where a numba kernel runs or compiles (no C port, ``MANUALCONTROL_NATIVE=0``,
the tests' reference): the constants they read stay in the numba-free module, which
exports these kernels by name on first use.
"""

from __future__ import annotations

import numba
import numpy as np

from manualcontrol.estimators.filters.monitor import (
    NEGATIVE_TOLERANCE,
    PIN_FRACTION,
)


@numba.njit(cache=True, _nrt=False, inline="always")
def belief_health(x, P, max_cov, zero_ok):
    """``(finite, covariance_ok)`` of a belief (module docstring).

    ``zero_ok``: a zero diagonal is acceptable (a state whose variance the data have
    pinned to rounding); otherwise a diagonal must be positive when all are zero.
    """
    n = x.shape[0]
    finite = True
    largest = 0.0
    for i in range(n):
        if not np.isfinite(x[i]) or not np.isfinite(P[i, i]):
            finite = False
        elif P[i, i] > largest:
            largest = P[i, i]
    ok = True
    for i in range(n):
        v = P[i, i]
        below = v < -NEGATIVE_TOLERANCE * largest if zero_ok else v <= -NEGATIVE_TOLERANCE * largest
        if below or v > max_cov:
            ok = False
    return finite, ok


@numba.njit(cache=True, _nrt=False)
def track_pins(pinned_now, pins, ring, k):
    """Count samples at a limit over the last ``ring.shape[1]`` samples.

    ``pinned_now`` (p,) bool this sample, ``pins`` (p,) running counts, ``ring`` (p, n).
    Returns the index of the first parameter pinned for :data:`PIN_FRACTION` of a
    full ring, or -1.
    """
    n_pin = ring.shape[1]
    if n_pin == 0:
        return -1
    pos = k % n_pin
    for j in range(pins.shape[0]):
        now = 1 if pinned_now[j] else 0
        pins[j] += now - ring[j, pos]
        ring[j, pos] = now
    if k + 1 >= n_pin:
        for j in range(pins.shape[0]):
            if pins[j] >= PIN_FRACTION * n_pin:
                return j
    return -1


@numba.njit(cache=True, _nrt=False)
def window_push(buf, sc, base, value, k):
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
def window_variance(sc, base):
    """Population variance of the finite values in the ring (0 when empty)."""
    c = sc[base + 3]
    if c < 1.0:
        return 0.0
    mean = sc[base + 1] / c
    var = sc[base + 2] / c - mean * mean
    return var if var > 0.0 else 0.0
