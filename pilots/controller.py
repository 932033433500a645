"""A cybernetic pilot acting through an environment's observations.

The controller is the pilot half of the sampled loop of :func:`simulate`
(``loop="sampled"``): the same discretised pilot, the same delay-line reads, the same
remnant draws. Driven by a :mod:`~manualcontrol.envs.tracking` environment it gives
the recording that simulation gives (to rounding), so one source of discretised
dynamics serves both loops.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs.tasks import task_named
from manualcontrol.pilots._random import as_generator
from manualcontrol.pilots.loop import SimulationSetup, discrete_pilot
from manualcontrol.pilots.simulation import distinct_parameter_sets, matrix_parameters, simulate
from manualcontrol.pilots.spec import PilotSpec
from manualcontrol.pilots.stability import check_stable

__all__ = ["PilotController"]

FloatArray = NDArray[np.float64]


# numba kernels read this module's constants
# what each pilot perception reads from an observation (read by _kernels._act)
_ERROR, _OUTPUT, _FAR, _NEAR_RATE, _EDGE, _EDGE_RATE = 0, 1, 2, 3, 4, 5


def __getattr__(name: str) -> object:
    """The numba kernel ``_act`` (and the kernels it calls), imported on first use (PEP 562).

    It lives in :mod:`~manualcontrol.pilots._kernels`: a process that never lets the
    controller act (an identification, which only builds pilots) never imports numba.
    """
    if name in ("_act", "interpolate_at", "lpv_output_step", "lpv_state_step"):
        from manualcontrol.pilots import _kernels

        value = getattr(_kernels, name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def _check_episode_growth(
    setup: SimulationSetup, on_unstable: str, loss_of_control: float | None
) -> None:
    """Growth check of a time-varying loop: the episode simulated once, remnant-free.

    With the env's loss-of-control limit the episode ends there, as the env's would, and
    only the run up to it is judged (the critical task is meant to be lost).
    """
    pilot = setup.pilot
    display = task_named(setup.task)
    postview = {"gap": setup.gap, "postview": setup.postview} if display.shows_postview else {}
    try:
        simulate(
            PilotSpec(pilot.model, dict(pilot.parameters), None, pilot.delay_order),
            setup.element,
            setup.forcing,
            task=setup.task,
            available_preview=setup.available_preview if display.shows_preview else None,
            dt=setup.dt,
            run_in=setup.run_in,
            measurement_time=setup.measurement_time,
            loop="sampled",
            on_unstable=on_unstable,
            loss_of_control=loss_of_control,
            keep_run_in=True,
            disturbance_at=setup.disturbance_at,
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
        display = task_named(base.task)
        postview = {"gap": base.gap, "postview": base.postview} if display.shows_postview else {}
        setup = SimulationSetup.create(
            pilot,
            base.element,
            base.forcing,
            task=base.task,
            available_preview=base.available_preview if display.shows_preview else None,
            dt=base.dt,
            run_in=base.run_in,
            measurement_time=base.measurement_time,
            disturbance_at=getattr(base, "disturbance_at", "output"),
            **postview,
        )
        rng, _ = as_generator(seed)
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
                    available_preview=setup.available_preview if display.shows_preview else None,
                    dt=base.dt,
                    run_in=base.run_in,
                    measurement_time=base.measurement_time,
                    seed=replay,
                    loop="sampled",
                    disturbance_at=setup.disturbance_at,
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
        n_delay = len(system.delay_inputs)
        if n_delay:
            delays = traces[pilot.model.delay_parameter] / setup.dt
            # one delay for every channel; the last repeated for the final state step
            delay_samples = np.repeat(np.append(delays, delays[-1])[:, None], n_delay, 1)
            pad = int(np.ceil(delay_samples.max())) + 4
        else:
            delay_samples = np.zeros((n + 1, 0))
            pad = 0
        n_x = exact.phi.shape[-1]
        codes = {
            "e": _ERROR,
            "y": _OUTPUT,
            "ft_far": _FAR,
            "ft_near_rate": _NEAR_RATE,
            "ft_edge": _EDGE,
            "ft_edge_rate": _EDGE_RATE,
        }
        preview_positions = np.zeros((n, 2))
        for column, name in enumerate(("tau_f", "tau_n")):
            if name in traces:
                preview_positions[:, column] = traces[name] / setup.dt
        self._x = np.zeros(n_x)
        # everything the compiled step reads, in its argument order (observation, k last)
        self._arguments = (
            exact.phi,
            exact.gamma,
            exact.gamma_ramp,
            system.system.C,
            system.system.D,
            np.zeros(0, dtype=np.int64) if index is None else index,
            self._x,
            np.zeros(len(system.inputs)),
            np.zeros((n_delay, pad + n)),
            np.zeros((n_delay, pad + n)),
            np.zeros(n_delay),
            np.zeros(system.system.C.shape[-2] + n_delay + n_x),
            np.asarray(system.delay_inputs, dtype=np.int64),
            np.asarray(system.delay_outputs, dtype=np.int64),
            delay_samples,
            np.zeros(n_x, dtype=np.bool_),
            pad,
            np.array([codes[name] for name in pilot.model.perceptions], dtype=np.int64),
            setup.preview_window,
            preview_positions,
            setup.dt,
            np.zeros(0) if self.noise is None else self.noise,
        )
        self._n_samples = n
        self._entry = None
        self.setup = setup
        self.k = 0
        self.last_remnant = 0.0

    def act(self, observation: FloatArray) -> FloatArray:
        """The stick for this observation (shape ``(1,)``); advances the pilot one sample."""
        k = self.k
        if k >= self._n_samples:
            raise RuntimeError("the pilot's episode is over; reset the pilot with the environment")
        observation = np.ascontiguousarray(observation, dtype=np.float64)
        entry = self._entry
        if entry is not None and observation.ndim == 1:
            u, self.last_remnant = entry(*self._arguments, k, observation)
        else:
            from manualcontrol.pilots._kernels import _act

            u, self.last_remnant = _act(*self._arguments, k, observation)
            if observation.ndim == 1:
                # numba's dispatcher types all 24 arguments each call (0.7 of 2.5 us); they
                # keep their types until the next reset, so call the compiled overload
                types = tuple(_act.typeof_pyval(a) for a in (*self._arguments, k, observation))
                self._entry = _act.overloads[types].entry_point
        self.k = k + 1
        return np.array([u])
