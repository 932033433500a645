"""Bicubic (four-sample) interpolation of sampled signals, value and time derivative.

Boer & Kenyon (1998), Appendix: the sinc kernel approximated on [-2, 2] by

    f(x) = 1.5 x^3 - 2.5 x^2 + 1,            x in [0, 1]
    g(x) = -0.5 x^3 + 2.5 x^2 - 4 x + 2,     x in [1, 2]

The value at fractional sample position n + d (d in [0, 1)) is

    h(n + d) = g(1 + d) x[n-1] + f(d) x[n] + f(1 - d) x[n+1] + g(2 - d) x[n+2]

and its derivative (per sample) uses the kernel derivatives with the sign of the
distance, d/dd of each weight. The kernel is the Keys cubic convolution kernel with
a = -0.5: it reproduces quadratics exactly and its weights sum to one.

These functions are compiled with numba because every delay line, previewed target
and fractional-delay estimator calls them once per sample.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray


@numba.njit(cache=True, inline="always")
def bicubic_weights(d: float) -> tuple[float, float, float, float]:
    """Weights of samples n-1, n, n+1, n+2 for the value at n + d, d in [0, 1]."""
    e = 1.0 - d
    # g(1 + d), f(d), f(1 - d), g(2 - d), expanded
    w_m1 = -0.5 * d * e * e
    w_0 = 1.5 * d * d * d - 2.5 * d * d + 1.0
    w_1 = 1.5 * e * e * e - 2.5 * e * e + 1.0
    w_2 = -0.5 * d * d * e
    return w_m1, w_0, w_1, w_2


@numba.njit(cache=True, inline="always")
def bicubic_derivative_weights(d: float) -> tuple[float, float, float, float]:
    """d/dd of :func:`bicubic_weights` (derivative per sample interval)."""
    # d/dd g(1 + d) = g'(1 + d);  d/dd f(d) = f'(d);  d/dd f(1 - d) = -f'(1 - d);
    # d/dd g(2 - d) = -g'(2 - d), with f'(x) = 4.5x^2 - 5x, g'(x) = -1.5x^2 + 5x - 4.
    x = 1.0 + d
    w_m1 = -1.5 * x * x + 5.0 * x - 4.0
    w_0 = 4.5 * d * d - 5.0 * d
    e = 1.0 - d
    w_1 = -(4.5 * e * e - 5.0 * e)
    x = 2.0 - d
    w_2 = -(-1.5 * x * x + 5.0 * x - 4.0)
    return w_m1, w_0, w_1, w_2


@numba.njit(cache=True)
def interpolate_at(values: NDArray[np.float64], position: float) -> tuple[float, float]:
    """Value and derivative (per sample) of ``values`` at fractional index ``position``.

    Samples outside ``[0, len(values) - 1]`` are replaced by the nearest end sample, so
    reads near either end degrade gracefully instead of reaching outside the array.
    Positions outside the array are clamped to its ends (derivative zero there).
    """
    last = values.shape[0] - 1
    if position <= 0.0:
        return values[0], 0.0
    if position >= last:
        return values[last], 0.0
    n = int(np.floor(position))
    d = position - n
    i_m1 = n - 1 if n - 1 >= 0 else 0
    i_1 = n + 1 if n + 1 <= last else last
    i_2 = n + 2 if n + 2 <= last else last
    a, b, c, w = bicubic_weights(d)
    value = a * values[i_m1] + b * values[n] + c * values[i_1] + w * values[i_2]
    a, b, c, w = bicubic_derivative_weights(d)
    slope = a * values[i_m1] + b * values[n] + c * values[i_1] + w * values[i_2]
    return value, slope


@numba.njit(cache=True)
def interpolate_many(
    values: NDArray[np.float64], positions: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`interpolate_at` for every entry of ``positions``."""
    out_value = np.empty(positions.shape[0])
    out_slope = np.empty(positions.shape[0])
    for k in range(positions.shape[0]):
        out_value[k], out_slope[k] = interpolate_at(values, positions[k])
    return out_value, out_slope
