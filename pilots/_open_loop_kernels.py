"""The numba kernel of :mod:`~manualcontrol.pilots.open_loop`: the ARMAX recursion.

Imported only where an open-loop run is simulated
(:func:`~manualcontrol.pilots.open_loop.simulate_open_loop`): the bench reads that
module's :class:`~manualcontrol.pilots.open_loop.ARMAXSystem` for every suite it
lists, and a bench whose runs go through the C ports never imports numba.
"""

from __future__ import annotations

import numba


@numba.njit(cache=True)
def armax(a, b, r, offset, shifts, lag, out):
    """``out[k] = sum a_i out[k - i lag] + sum b_m r[offset + k - m lag - shifts[k]]``."""
    for k in range(out.shape[0]):
        acc = 0.0
        for i in range(a.shape[0]):
            j = k - (i + 1) * lag
            if j >= 0:
                acc += a[i] * out[j]
        for m in range(b.shape[0]):
            acc += b[m] * r[offset + k - m * lag - shifts[k]]
        out[k] = acc
