"""The numba kernel of the pilots' controller, imported only where it runs.

:func:`_act` is one sample of the controller acting in an environment
(:mod:`~manualcontrol.pilots.controller`). It lives apart from the module that uses it
so that a process that only builds pilots and simulates through the C ports (an
identification, a bench) never imports numba.
"""

from __future__ import annotations

import numba
import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._dynamics_kernels import lpv_output_step, lpv_state_step
from manualcontrol.envs._interpolation import interpolate_at
from manualcontrol.pilots.controller import _EDGE, _ERROR, _FAR, _NEAR_RATE, _OUTPUT

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def _act(
    phi: FloatArray,
    gamma: FloatArray,
    ramp: FloatArray,
    c: FloatArray,
    d: FloatArray,
    index: NDArray[np.int64],
    x: FloatArray,
    inputs: FloatArray,
    smooth: FloatArray,
    held: FloatArray,
    smooth_now: FloatArray,
    work: FloatArray,
    delay_inputs: NDArray[np.int64],
    delay_outputs: NDArray[np.int64],
    delay_samples: FloatArray,
    held_state: NDArray[np.bool_],
    pad: int,
    perceptions: NDArray[np.int64],
    window: int,
    preview_positions: FloatArray,
    dt: float,
    noise: FloatArray,
    k: int,
    observation: FloatArray,
) -> tuple[float, float]:
    """One sample of the pilot: perceive, output ``(u, n)``, advance (as simulate_lpv)."""
    for i in range(perceptions.shape[0]):
        kind = perceptions[i]
        if kind == _ERROR:
            inputs[i] = observation[0]
        elif kind == _OUTPUT:
            inputs[i] = observation[window]
        elif kind == _FAR:
            inputs[i] = interpolate_at(observation[:window], preview_positions[k, 0])[0]
        elif kind == _NEAR_RATE:
            slope = interpolate_at(observation[:window], preview_positions[k, 1])[1]
            inputs[i] = slope / dt
        elif kind == _EDGE:  # postview: the visible end of the track, as simulate() reads it
            inputs[i] = observation[0]
        else:  # its slope, envs.postview.edge_perceptions's backward difference
            inputs[i] = (3.0 * observation[0] - 4.0 * observation[1] + observation[2]) / (2.0 * dt)
    if noise.shape[0]:
        inputs[perceptions.shape[0]] = noise[k]
    i = 0 if index.shape[0] == 0 else index[k]
    n_delay = delay_inputs.shape[0]
    n_x = x.shape[0]
    outputs = work[: c.shape[1]]
    smooth_next = work[c.shape[1] : c.shape[1] + n_delay]
    x_next = work[c.shape[1] + n_delay : c.shape[1] + n_delay + n_x]
    newest = pad + k
    lpv_output_step(
        c[i],
        d[i],
        x,
        inputs,
        smooth,
        held,
        newest,
        delay_inputs,
        delay_outputs,
        delay_samples[k],
        smooth_now,
        held_state,
        outputs,
    )
    lpv_state_step(
        phi[i],
        gamma[i],
        ramp[i],
        x,
        inputs,
        smooth,
        newest,
        delay_inputs,
        delay_samples[k + 1],
        smooth_now,
        smooth_next,
        x_next,
    )
    return outputs[0], outputs[1]
