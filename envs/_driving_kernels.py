"""The numba kernels of :mod:`~manualcontrol.envs.driving`: the car's sample step.

:func:`lane_step` advances the sampled car one sample and :func:`perceive` reads the
driver's perceptions off its state; the environment's step calls them from Python, the
driver's closed loop (:mod:`~manualcontrol.pilots._driver_kernels`) from its own
compiled code. They live apart from the environment so that a process that only
imports it (an identification of the driver, whose records the driver model's module
names) never imports numba: the environment imports this module when an episode
starts, and the old module exports these kernels by name on first use.
"""

from __future__ import annotations

import numba


@numba.njit(cache=True, _nrt=False)
def perceive(packed, far_gain, state, kappa, kappa_far, out, row):
    """``out[row]`` = (theta_far, theta_near, delta_d, Gamma_s, a_y, y_L, psi_L) of the state.

    ``packed`` is :attr:`~manualcontrol.envs.driving.LaneKeepingModel.packed`; ``state``
    holds ``x`` in its first ``n`` entries.
    """
    n = packed.shape[1] - 2
    out[row, 0] = far_gain * kappa_far
    for i in range(6):
        acc = packed[n + i, n] * kappa
        for j in range(n):
            acc += packed[n + i, j] * state[j]
        out[row, i + 1] = acc


@numba.njit(cache=True, _nrt=False)
def lane_step(packed, far_gain, state, action, kappa, kappa_next, far_next, out, row):
    """Advance the state one sample with ``action`` and ``kappa`` held; perceive it.

    ``state`` (2n,) holds ``x`` and n entries of scratch; :func:`perceive` of the new
    state goes to ``out[row]``. Few arguments on purpose: each array argument costs a
    conversion on every call, and the environment calls this once a step.
    """
    n = packed.shape[1] - 2
    for i in range(n):
        acc = packed[i, n] * action + packed[i, n + 1] * kappa
        for j in range(n):
            acc += packed[i, j] * state[j]
        state[n + i] = acc
    for i in range(n):
        state[i] = state[n + i]
    perceive(packed, far_gain, state, kappa_next, far_next, out, row)
