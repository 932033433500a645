"""A cybernetic pilot acting through an environment's observations.

The controller is the pilot half of the sampled loop of :func:`simulate`
(``loop="sampled"``): the same discretised pilot, the same delay-line reads, the same
remnant draws. Driven by a :mod:`~manualcontrol.envs.tracking` environment it gives
the recording that simulation gives (to rounding), so one source of discretised
dynamics serves both loops.
"""

from __future__ import annotations

from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._interpolation import interpolate_at
from manualcontrol.envs.dynamics import read_held, read_smooth
from manualcontrol.envs.postview import edge_perceptions
from manualcontrol.pilots.simulation import (
    SimulationSetup,
    _as_generator,
    discrete_pilot,
    distinct_parameter_sets,
    matrix_parameters,
    simulate,
)
from manualcontrol.pilots.stability import check_stable

__all__ = ["PilotController"]

FloatArray = NDArray[np.float64]


@numba.njit(cache=True)
def _step(
    phi: FloatArray,
    gamma: FloatArray,
    ramp: FloatArray,
    c: FloatArray,
    d: FloatArray,
    x: FloatArray,
    inputs: FloatArray,
    smooth: FloatArray,
    held: FloatArray,
    newest: int,
    delay_inputs: NDArray[np.int64],
    delay_outputs: NDArray[np.int64],
    position_now: FloatArray,
    position_next: FloatArray,
    smooth_now: FloatArray,
) -> FloatArray:
    """One sample of the pilot: outputs now, state and delay line advanced (as simulate_lpv)."""
    n_x = x.shape[0]
    n_u = inputs.shape[0]
    for i in range(delay_inputs.shape[0]):
        r = delay_outputs[i]
        acc = 0.0
        for j in range(n_x):
            acc += c[r, j] * x[j]
        smooth[i, newest] = acc
        held_value = 0.0
        for j in range(n_u):
            if j != delay_inputs[i]:
                held_value += d[r, j] * inputs[j]
        held[i, newest] = held_value
        inputs[delay_inputs[i]] = smooth_now[i] + read_held(held[i], newest, position_now[i])
    outputs = np.empty(c.shape[0])
    for r in range(c.shape[0]):
        acc = 0.0
        for j in range(n_x):
            acc += c[r, j] * x[j]
        for j in range(n_u):
            acc += d[r, j] * inputs[j]
        outputs[r] = acc
    smooth_next = np.empty(delay_inputs.shape[0])
    for i in range(delay_inputs.shape[0]):
        smooth_next[i] = read_smooth(smooth[i], newest, position_next[i])
    x_next = np.empty(n_x)
    for r in range(n_x):
        acc = 0.0
        for j in range(n_x):
            acc += phi[r, j] * x[j]
        for j in range(n_u):
            acc += gamma[r, j] * inputs[j]
        for i in range(delay_inputs.shape[0]):
            acc += ramp[r, delay_inputs[i]] * (smooth_next[i] - smooth_now[i])
        x_next[r] = acc
    for r in range(n_x):
        x[r] = x_next[r]
    for i in range(delay_inputs.shape[0]):
        smooth_now[i] = smooth_next[i]
    return outputs


def _check_episode_growth(
    setup: SimulationSetup, on_unstable: str, loss_of_control: float | None
) -> None:
    """Growth check of a time-varying loop: the episode simulated once, remnant-free.

    With the env's loss-of-control limit the episode ends there, as the env's would, and
    only the run up to it is judged (the critical task is meant to be lost).
    """
    from manualcontrol.pilots.pilot import Pilot

    pilot = setup.pilot
    postview = {"gap": setup.gap, "postview": setup.postview} if setup.task == "postview" else {}
    try:
        simulate(
            Pilot(pilot.model, dict(pilot.parameters), None, pilot.delay_order),
            setup.element,
            setup.forcing,
            task=setup.task,
            available_preview=setup.available_preview if setup.task == "preview" else None,
            dt=setup.dt,
            run_in=setup.run_in,
            measurement_time=setup.measurement_time,
            loop="sampled",
            on_unstable=on_unstable,
            loss_of_control=loss_of_control,
            keep_run_in=True,
            **postview,
        )
    except ValueError as error:
        if not str(error).startswith("control was lost"):
            raise  # (lost during the run-in: nothing left to judge)


class PilotController:
    """Runtime state of a pilot in one episode of a tracking environment.

    Create it after ``env.reset(...)`` (it reads the episode's forcing realisation):
    ``PilotController(pilot, env, seed)``; then call :meth:`act` with each observation.
    A remnant with a requested power ratio is calibrated first on the simulated
    sampled loop of the same episode (so both loops use the same gain).
    """

    def __init__(
        self,
        pilot: Any,
        env: Any,
        seed: int | np.random.Generator | None = None,
        on_unstable: str = "raise",
    ) -> None:
        base = getattr(env, "unwrapped", env)
        for attribute in ("task", "element", "forcing", "dt", "run_in", "measurement_time"):
            if not hasattr(base, attribute):
                raise TypeError(
                    f"env must be a manualcontrol tracking environment after reset(), "
                    f"it has no {attribute!r}"
                )
        postview = {"gap": base.gap, "postview": base.postview} if base.task == "postview" else {}
        setup = SimulationSetup.create(
            pilot,
            base.element,
            base.forcing,
            task=base.task,
            available_preview=base.available_preview if base.task == "preview" else None,
            dt=base.dt,
            run_in=base.run_in,
            measurement_time=base.measurement_time,
            **postview,
        )
        rng, _ = _as_generator(seed)
        traces = setup.parameter_traces()
        if check_stable(setup, on_unstable=on_unstable) is None:
            _check_episode_growth(setup, on_unstable, getattr(base, "loss_of_control", None))
        n = setup.n_samples
        remnant = pilot.remnant
        if remnant is not None:
            # simulate() draws the same noise from a generator in the same state
            replay = np.random.Generator(type(rng.bit_generator)())
            replay.bit_generator.state = rng.bit_generator.state
            noise = rng.standard_normal(n)
            if remnant.P_r is not None:
                calibration = simulate(
                    pilot,
                    base.element,
                    base.forcing,
                    task=base.task,
                    available_preview=setup.available_preview if base.task == "preview" else None,
                    dt=base.dt,
                    run_in=base.run_in,
                    measurement_time=base.measurement_time,
                    seed=replay,
                    loop="sampled",
                    **postview,
                )
                remnant = remnant.with_gain(calibration.metadata["remnant"]["K_r"])
            self.noise = noise * remnant.K_r
        else:
            self.noise = None
        self.remnant = remnant
        first, index = distinct_parameter_sets(
            [traces[name] for name in matrix_parameters(setup, traces)], n
        )
        values = {name: trace[first] for name, trace in traces.items()}
        system, exact, _ = discrete_pilot(setup, values, remnant)
        self._phi, self._gamma, self._ramp = exact.phi, exact.gamma, exact.gamma_ramp
        self._c, self._d = system.system.C, system.system.D
        self._index = index
        self._delay_inputs = np.asarray(system.delay_inputs, dtype=np.int64)
        self._delay_outputs = np.asarray(system.delay_outputs, dtype=np.int64)
        n_delay = len(system.delay_inputs)
        if n_delay:
            delays = traces[pilot.model.delay_parameter] / setup.dt
            self._delay_samples = np.append(delays, delays[-1])
            self._pad = int(np.ceil(self._delay_samples.max())) + 4
        else:
            self._delay_samples = np.zeros(n + 1)
            self._pad = 0
        self._smooth = np.zeros((n_delay, self._pad + n))
        self._held = np.zeros((n_delay, self._pad + n))
        self._smooth_now = np.zeros(n_delay)
        self._x = np.zeros(self._phi.shape[-1])
        self._inputs = np.zeros(len(system.inputs))
        self._perceptions = pilot.model.perceptions
        self._task = base.task
        self._window = setup.preview_window
        self._preview_positions = {
            name: traces[name] / setup.dt for name in ("tau_f", "tau_n") if name in traces
        }
        self.setup = setup
        self.k = 0

    def _perceive(self, observation: FloatArray) -> None:
        inputs = self._inputs
        k = self.k
        if self._task == "compensatory":
            inputs[0] = observation[0]
            return
        if self._task == "postview":
            # the visible end of the track and its slope, as simulate() reads them
            edge, slope = edge_perceptions(observation[:3], self.setup.dt)
            inputs[self._perceptions.index("ft_edge")] = edge
            inputs[self._perceptions.index("ft_edge_rate")] = slope
            return
        window = self._window
        target = np.ascontiguousarray(observation[:window], dtype=np.float64)
        y = float(observation[window])
        for i, name in enumerate(self._perceptions):
            if name == "y":
                inputs[i] = y
            elif name == "ft_far":
                inputs[i] = interpolate_at(target, self._preview_positions["tau_f"][k])[0]
            elif name == "ft_near_rate":
                slope = interpolate_at(target, self._preview_positions["tau_n"][k])[1]
                inputs[i] = slope / self.setup.dt

    def act(self, observation: FloatArray) -> FloatArray:
        """The stick for this observation (shape ``(1,)``); advances the pilot one sample."""
        k = self.k
        if k >= self.setup.n_samples:
            raise RuntimeError("the pilot's episode is over; reset the pilot with the environment")
        self._perceive(np.asarray(observation, dtype=np.float64))
        if self.noise is not None:
            self._inputs[len(self._perceptions)] = self.noise[k]
        i = 0 if self._index is None else self._index[k]
        newest = self._pad + k
        position_now = np.full(len(self._delay_inputs), newest - self._delay_samples[k])
        position_next = np.full(len(self._delay_inputs), newest + 1.0 - self._delay_samples[k + 1])
        outputs = _step(
            self._phi[i],
            self._gamma[i],
            self._ramp[i],
            self._c[i],
            self._d[i],
            self._x,
            self._inputs,
            self._smooth,
            self._held,
            newest,
            self._delay_inputs,
            self._delay_outputs,
            position_now,
            position_next,
            self._smooth_now,
        )
        self.k = k + 1
        self.last_remnant = float(outputs[1])
        return np.array([outputs[0]])
