"""The numba kernels of :mod:`~manualcontrol.pilots.driver`: eq. 2 and the driver's loop.

:func:`driver_matrices` writes Zhao eq. 2 (corrected, the driver model's module
docstring); :func:`exact_delay_step` and :func:`pade_step` are one sample of the driver,
:func:`driver_sample` and :func:`driver_action` one sample of it in an episode,
:func:`drive` the closed loop with the lane-keeping car
(:mod:`~manualcontrol.envs._driving_kernels`), and :func:`resimulate` the driver alone
on recorded perceptions. Imported only where a numba kernel runs or compiles (a driving
simulation or resimulation, the driver acting in the environment, the Zhao filters'
numba kernels, ``bench/compile_kernels.py``): the driver model's module keeps
the parameters, the records and eq. 2's definition, and exports these kernels by
name on first use, so that an identification of the driver, which runs in C, never
imports numba.
"""

from __future__ import annotations

import math

import numba

from manualcontrol.envs._driving_kernels import lane_step, perceive
from manualcontrol.envs._dynamics_kernels import read_held, read_smooth
from manualcontrol.pilots.driver import _eq2_matrices

#: Zhao eq. 2 (corrected) into ``A`` .. ``D``: the driver model's one definition of it,
#: compiled (its docstring says why the two give the same bytes).
driver_matrices = numba.njit(cache=True, _nrt=False)(_eq2_matrices)


@numba.njit(cache=True, _nrt=False)
def exact_delay_step(p, tau_next, v_x, dt, inputs, noise, inject, state, smooth, held, newest, out):
    """One sample of the driver with the exact delay (:mod:`~manualcontrol.pilots.driver`).

    ``p`` the parameters at this sample, ``tau_next`` the delay at the next one,
    ``inputs`` (4,) the perceptions held over the sample, ``noise`` the remnant sample,
    ``inject`` its :data:`~manualcontrol.pilots.driver.INJECT_OUTPUT`/``INJECT_INPUT``
    code. ``state`` = ``(x_1, Gamma_d, smooth part of delta_sw now)``;
    ``smooth``/``held`` the delay-line histories, ``newest`` this sample's index in
    them. ``out`` = (Gamma_d with any output remnant, delta_sw) at this sample; the
    state is advanced to the next.
    """
    K_p, K_c, T_I, T_L, tau_p, K_r, K_t, T_N = p[0], p[1], p[2], p[3], p[4], p[5], p[6], p[7]
    c = K_c / v_x
    lead = T_L / T_I
    x1 = state[0]
    smooth[newest] = c * (1.0 - lead) * x1
    visual = K_p * inputs[0] + c * lead * inputs[1]
    if inject == 2:
        visual += noise
    held[newest] = visual
    held_mean = read_held(held, newest, newest - tau_p / dt)
    smooth_now = state[2]
    delta_sw = smooth_now + held_mean
    out[0] = state[1] + (noise if inject == 1 else 0.0)
    out[1] = delta_sw
    smooth_next = read_smooth(smooth, newest, newest + 1.0 - tau_next / dt)
    a = math.exp(-dt / T_N)
    b = 1.0 - a
    ramp = 1.0 - (T_N / dt) * b
    G = K_r * v_x + K_t
    state[1] = (
        a * state[1]
        + b * (G * delta_sw - K_t * inputs[2] - inputs[3])
        + ramp * G * (smooth_next - smooth_now)
    )
    a1 = math.exp(-dt / T_I)
    state[0] = a1 * x1 + (1.0 - a1) * inputs[1]
    state[2] = smooth_next


@numba.njit(cache=True, _nrt=False)
def pade_step(phi, gamma, C, D, inputs, noise, inject, state, work, out):
    """One sample of eq. 2 discretised (``phi`` (3, 3), ``gamma`` (3, 5), ``C``, ``D`` (2, 5)).

    Input 5 is the remnant at the visual signal (``inject`` =
    :data:`~manualcontrol.pilots.driver.INJECT_INPUT`).
    """
    for i in range(5):
        work[i] = inputs[i] if i < 4 else (noise if inject == 2 else 0.0)
    for r in range(2):
        acc = 0.0
        for j in range(3):
            acc += C[r, j] * state[j]
        for j in range(5):
            acc += D[r, j] * work[j]
        out[r] = acc
    if inject == 1:
        out[0] += noise
    for i in range(3):
        acc = 0.0
        for j in range(3):
            acc += phi[i, j] * state[j]
        for j in range(5):
            acc += gamma[i, j] * work[j]
        work[5 + i] = acc
    for i in range(3):
        state[i] = work[5 + i]


@numba.njit(cache=True, _nrt=False)
def driver_sample(d, k, inputs):
    """The driver's outputs at sample ``k`` into ``d.out``; its state advanced."""
    if d.pade:
        i = d.index[k]
        pade_step(
            d.phi[i],
            d.gamma[i],
            d.C[i],
            d.D[i],
            inputs,
            d.noise[k],
            d.inject,
            d.state,
            d.work,
            d.out,
        )
    else:
        exact_delay_step(
            d.p[k],
            d.p[k + 1, 4],
            d.v_x,
            d.dt,
            inputs,
            d.noise[k],
            d.inject,
            d.state,
            d.smooth,
            d.held,
            d.pad + k,
            d.out,
        )


@numba.njit(cache=True, _nrt=False)
def driver_action(d, k, angle, bound):
    """The action of sample ``k`` from ``d.out``: torque, or intended angle (+ remnant)."""
    if angle > 0.0:
        action = d.out[1] + (d.noise[k] if d.inject == 1 else 0.0)
    else:
        action = d.out[0]
    if action > bound:
        action = bound
    elif action < -bound:
        action = -bound
    return action


@numba.njit(cache=True, _nrt=False)
def drive(car, d, out):
    """The closed loop over ``out.action.shape[0]`` samples (the driver model's module)."""
    perceive(car.packed, car.far_gain, car.state, car.kappa[0], car.kappa_far[0], out.perceived, 0)
    for k in range(out.action.shape[0]):
        driver_sample(d, k, out.perceived[k])
        out.Gamma_d[k] = d.out[0]
        out.delta_sw[k] = d.out[1]
        action = driver_action(d, k, car.angle, car.bound)
        out.action[k] = action
        lane_step(
            car.packed,
            car.far_gain,
            car.state,
            action,
            car.kappa[k],
            car.kappa[k + 1],
            car.kappa_far[k + 1],
            out.perceived,
            k + 1,
        )


@numba.njit(cache=True, _nrt=False)
def resimulate(d, inputs, out):
    """The driver alone on recorded perceptions ``inputs`` (n, 4): ``(Gamma_d, delta_sw)``.

    :func:`~manualcontrol.pilots.driving.resimulate_driver`'s loop, one
    :func:`driver_sample` a sample, into ``out`` (n, 2).
    """
    for k in range(inputs.shape[0]):
        driver_sample(d, k, inputs[k])
        out[k, 0] = d.out[0]
        out[k, 1] = d.out[1]
