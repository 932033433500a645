"""Closed-loop driving: the cybernetic driver steering the lane-keeping car.

:func:`simulate_driving` is the sampled loop of
:class:`~manualcontrol.envs.driving.LaneKeeping` with a
:class:`~manualcontrol.pilots.driver.Driver` acting: the same car model, road samples and
action clipping (the environment is built and reset to obtain them, so there is one
set-up), the same compiled driver step. A driver acting through
:meth:`Driver.act <manualcontrol.pilots.driver.Driver.act>` in the environment gives the
same recording to rounding (tests/pilots/test_driving.py).

Every sample ``k``: the driver reads the perceptions of observation ``k`` (held over the
sample), outputs its torque (or, with angle steering, its intended wheel angle), the
action is clipped to the environment's bound and the car is advanced one sample.
Remnant noise is one standard normal sample per step through the remnant filter
(exact zero-order hold), scaled by its gain; a requested power ratio ``P_r``
(``var(u_n)/var(u)`` of the action, thesis eq. 6) is met by linearity: the loop is run
once with the road and no noise and once with the noise and a straight road, and the
gain solved from the two (as :func:`~manualcontrol.pilots.simulate` does).
"""

from __future__ import annotations

from collections import namedtuple
from collections.abc import Mapping
from typing import Any

import numba
import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_positive, check_vector
from manualcontrol.envs.driving import LaneKeeping, Road, lane_step, perceive, road_preset
from manualcontrol.envs.dynamics import discretize
from manualcontrol.envs.recording import Recording
from manualcontrol.pilots.driver import (
    INJECT_INPUT,
    INJECT_NONE,
    INJECT_OUTPUT,
    Driver,
    driver_matrices,
    exact_delay_step,
    pade_step,
)
from manualcontrol.pilots.remnant import Remnant
from manualcontrol.pilots.simulation import _as_generator, _gain_for_ratio, remnant_power_ratio

__all__ = ["DriverController", "resimulate_driver", "simulate_driving"]

FloatArray = NDArray[np.float64]

#: The car of one episode: ``packed``/``far_gain`` of the environment's model, the
#: curvature samples, the action bound, 1.0 for angle steering, and the car state (2n,).
CarRecord = namedtuple(
    "CarRecord", ["packed", "far_gain", "kappa", "kappa_far", "bound", "angle", "state"]
)
#: The driver of one episode: parameters per sample ``p`` (n + 1, 8), speed, dt, remnant
#: ``noise`` (n,) and its injection code, state (3,), delay-line histories and their
#: padding, the Padé matrices per distinct parameter set and the set of each sample
#: (empty with the exact delay), scratch and the last output (Gamma_d, delta_sw).
DriverRecord = namedtuple(
    "DriverRecord",
    [
        "p",
        "v_x",
        "dt",
        "noise",
        "inject",
        "state",
        "smooth",
        "held",
        "pad",
        "pade",
        "phi",
        "gamma",
        "C",
        "D",
        "index",
        "work",
        "out",
    ],
)
LoopOutput = namedtuple("LoopOutput", ["perceived", "action", "Gamma_d", "delta_sw"])

_INJECT_CODES = {None: INJECT_NONE, "output": INJECT_OUTPUT, "input": INJECT_INPUT}


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
    """The closed loop over ``out.action.shape[0]`` samples (module docstring)."""
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


def _remnant_noise(remnant: Remnant, white: FloatArray, dt: float) -> FloatArray:
    """The remnant filter's shape driven by held white noise (exact zero-order hold)."""
    import scipy.signal  # here: importing it costs 1.3 s, which every suite listing paid

    num, den = remnant.shape()
    numd, dend, _ = scipy.signal.cont2discrete((num, den), dt, method="zoh")
    return scipy.signal.lfilter(np.ravel(numd), dend, white)


def _driver_record(
    driver: Driver,
    traces: Mapping[str, FloatArray],
    v_x: float,
    dt: float,
    noise: FloatArray,
    inject: int,
) -> Any:
    names = driver.model.parameter_names
    p = np.ascontiguousarray(np.column_stack([traces[name] for name in names]))
    n = noise.shape[0]
    pade = driver.delay_order == 1
    if pade:
        unique, index = np.unique(p[:n], axis=0, return_inverse=True)
        A = np.zeros((len(unique), 3, 3))
        B = np.zeros((len(unique), 3, 5))
        C = np.zeros((len(unique), 2, 3))
        D = np.zeros((len(unique), 2, 5))
        for i, row in enumerate(unique):
            driver_matrices(row, v_x, A[i], B[i], C[i], D[i])
        exact = discretize(A, B, dt)
        phi, gamma = exact.phi, exact.gamma
        index = np.asarray(index, dtype=np.int64).ravel()
        pad = 0
    else:
        phi = gamma = np.zeros((0, 3, 3))
        C = D = np.zeros((0, 2, 3))
        index = np.zeros(0, dtype=np.int64)
        pad = int(np.ceil(p[:, 4].max() / dt)) + 4
    return DriverRecord(
        p=p,
        v_x=float(v_x),
        dt=float(dt),
        noise=np.ascontiguousarray(noise, dtype=np.float64),
        inject=inject,
        state=np.zeros(3),
        smooth=np.zeros(pad + n + 1),
        held=np.zeros(pad + n + 1),
        pad=pad,
        pade=pade,
        phi=np.ascontiguousarray(phi),
        gamma=np.ascontiguousarray(gamma),
        C=np.ascontiguousarray(C),
        D=np.ascontiguousarray(D),
        index=index,
        work=np.zeros(8),
        out=np.zeros(2),
    )


def _car_record(env: LaneKeeping, kappa: FloatArray, kappa_far: FloatArray) -> Any:
    model = env.model
    return CarRecord(
        packed=model.packed,
        far_gain=model.far_gain,
        kappa=np.ascontiguousarray(kappa),
        kappa_far=np.ascontiguousarray(kappa_far),
        bound=float(env.action_bound),
        angle=1.0 if env.steering == "angle" else 0.0,
        state=np.zeros(2 * model.phi.shape[0]),
    )


def _run(env, driver, traces, kappa, kappa_far, noise, inject) -> Any:
    n = env.episode_steps
    d = _driver_record(driver, traces, env.speed, env.dt, noise, inject)
    car = _car_record(env, kappa, kappa_far)
    out = LoopOutput(np.zeros((n + 1, 7)), np.zeros(n), np.zeros(n), np.zeros(n))
    drive(car, d, out)
    return out


def _environment(road: Any, environment: Mapping[str, Any]) -> LaneKeeping:
    if isinstance(road, str) and road == "random":
        raise ValueError(
            "simulate_driving needs a fixed road: pass Road.random(seed) for a random one"
        )
    env = LaneKeeping(road_preset(road), **dict(environment))
    env.reset(seed=0)
    return env


def _calibrated_gain(
    env: LaneKeeping,
    driver: Driver,
    traces: Mapping[str, FloatArray],
    kappa: FloatArray,
    kappa_far: FloatArray,
    unit: FloatArray,
    inject: int,
    ratio: float,
) -> float:
    n = env.episode_steps
    measured = slice(env.n_run_in, n)
    forced = _run(env, driver, traces, kappa, kappa_far, np.zeros(n), inject).action
    zero = np.zeros_like(kappa)
    alone = _run(env, driver, traces, zero, zero, unit, inject).action
    return _gain_for_ratio(forced[measured], alone[measured], ratio)


def simulate_driving(
    driver: Driver,
    road: str | Road | Mapping[str, Any] = "zhao2019",
    *,
    seed: int | np.random.Generator | None = None,
    remnant_signal: Any = None,
    output_noise: Mapping[str, float] | None = None,
    keep_run_in: bool = False,
    **environment: Any,
) -> Recording:
    """Simulate the driver on a road and return the :class:`Recording`.

    Parameters
    ----------
    driver
        The synthetic driver (schedules, remnant, delay mode).
    road
        A road preset, :class:`~manualcontrol.envs.driving.Road` or its dict.
    seed
        Seed or generator of the remnant noise (the only random input).
    remnant_signal
        Instead of the driver's remnant filter, inject these samples (one per step) at
        the remnant's injection point (``"output"`` when the driver has none).
    output_noise
        Sensor noise on the recorded driver outputs: standard deviations of white noise
        added to ``Gamma_d`` and/or ``delta_sw`` (``{"Gamma_d": 0.12}``), drawn after
        the remnant from the same generator. It is measurement noise only: the loop is
        driven by the noise-free signals, which stay in the recording as
        ``Gamma_d_true`` and ``delta_sw_true``.
    keep_run_in
        Keep the run-in samples (times from ``-run_in``).
    environment
        Keywords of :class:`~manualcontrol.envs.driving.LaneKeeping`: ``vehicle``,
        ``speed``, ``steering``, ``dt``, ``run_in``, ``measurement_time``,
        ``near_distance``, ``far_gain``, ``far_preview``, ``lane_width``,
        ``action_bound``.

    The recording holds ``t``, the perceptions ``theta_far, theta_near, delta_d,
    Gamma_s``, the driver's ``Gamma_d`` (torque steering; with the output remnant) and
    ``delta_sw``, the action ``u`` (the torque, or the wheel angle with angle
    steering), ``kappa``, ``y_L``, ``psi_L``, ``a_y``, the remnant ``n`` as injected and
    ``u_n``, the part of ``u`` it caused, when there is one; the driver's parameter
    traces; metadata with the set-up, the calibrated remnant and the largest lateral
    offset (``lane_departure`` when it exceeds the lane).
    """
    if not isinstance(driver, Driver):
        raise TypeError(f"driver must be a Driver, got {driver!r}")
    noise_levels = _output_noise(output_noise)
    for key in ("reward", "reward_scale", "effort_weight", "include_rates", "render_mode"):
        if key in environment:
            raise TypeError(f"simulate_driving got an environment keyword it does not use: {key!r}")
    env = _environment(road, environment)
    n = env.episode_steps
    times = env.times
    traces = driver.parameter_traces(times)
    kappa, kappa_far = env.episode_curvature()
    rng, seed_used = _as_generator(seed)
    remnant = driver.remnant
    inject = _INJECT_CODES[None if remnant is None else remnant.injection]
    gain = 0.0
    if remnant_signal is not None:
        unit = check_vector("remnant_signal", remnant_signal, length=n)
        gain = 1.0
        if remnant is None:
            inject = INJECT_OUTPUT
    elif remnant is not None:
        unit = _remnant_noise(remnant, rng.standard_normal(n), env.dt)
        gain = remnant.K_r
        if remnant.P_r is not None:
            gain = _calibrated_gain(
                env, driver, traces, kappa, kappa_far, unit, inject, remnant.P_r
            )
    else:
        unit = np.zeros(n)
    out = _run(env, driver, traces, kappa, kappa_far, gain * unit, inject)
    measured = slice(env.n_run_in, n)
    part = slice(0, n) if keep_run_in else measured
    perceived = out.perceived[:n]
    signals = {
        "t": times[part],
        "theta_far": perceived[part, 0],
        "theta_near": perceived[part, 1],
        "delta_d": perceived[part, 2],
        "Gamma_s": perceived[part, 3],
    }
    if env.steering == "torque":
        signals["Gamma_d"] = out.Gamma_d[part]
    signals.update(
        delta_sw=out.delta_sw[part],
        u=out.action[part],
        kappa=kappa[:n][part],
        y_L=perceived[part, 5],
        psi_L=perceived[part, 6],
        a_y=perceived[part, 4],
    )
    metadata = env.describe()
    metadata.update(
        driver=driver.to_dict(),
        seed=seed_used,
        delay_order=driver.delay_order,
        source="manualcontrol.pilots.driving.simulate_driving",
    )
    offset = float(np.max(np.abs(perceived[measured, 5])))
    metadata.update(
        max_lateral_offset=offset,
        lane_departure=offset > env.lane_limit,
        max_lateral_acceleration=float(np.max(np.abs(perceived[measured, 4]))),
    )
    if noise_levels:
        for name, level in noise_levels.items():
            if name not in signals:
                raise ValueError(
                    f"output_noise names {name!r}, which angle steering does not record"
                )
            clean = signals[name]
            signals[f"{name}_true"] = clean
            signals[name] = clean + level * rng.standard_normal(n)[part]
        metadata["output_noise"] = dict(noise_levels)
    if inject != INJECT_NONE:
        signals["n"] = gain * unit[part]
        zero = np.zeros_like(kappa)
        alone = _run(env, driver, traces, zero, zero, gain * unit, inject).action
        signals["u_n"] = alone[part]
        metadata.update(
            remnant="signal" if remnant_signal is not None else remnant.with_gain(gain).to_dict(),
            remnant_power_ratio=remnant_power_ratio(out.action[measured], alone[measured]),
        )
    return Recording(
        signals=signals,
        dt=env.dt,
        parameters={name: trace[:n][part] for name, trace in traces.items()},
        metadata=metadata,
    )


def _output_noise(spec: Mapping[str, float] | None) -> dict[str, float]:
    if spec is None:
        return {}
    if not isinstance(spec, Mapping):
        raise TypeError(
            f"output_noise must map Gamma_d/delta_sw to a standard deviation, got {spec!r}"
        )
    levels = {}
    for name, value in spec.items():
        if name not in ("Gamma_d", "delta_sw"):
            raise ValueError(f"output_noise keys must be 'Gamma_d' or 'delta_sw', got {name!r}")
        levels[name] = check_positive(f"output_noise[{name!r}]", value, allow_zero=True)
    return levels


def resimulate_driver(
    parameters: Any, inputs: Any, speed: float, dt: float
) -> tuple[FloatArray, FloatArray]:
    """The driver model alone, driven by recorded perceptions: its ``(Gamma_d, delta_sw)``.

    ``parameters`` (n, 8) holds every parameter at every sample (model order, e.g. an
    estimator's traces), ``inputs`` (n, 4) the perceptions ``theta_far, theta_near,
    delta_d, Gamma_s``. The same compiled step as :func:`simulate_driving` (exact delay,
    perceptions held over each sample), started at rest, no remnant. NaN perceptions
    (dropped samples) hold the last value.
    """
    p = np.asarray(parameters, dtype=np.float64)
    u = np.array(inputs, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 8:
        raise ValueError(f"parameters must have shape (n, 8), got {p.shape}")
    if u.ndim != 2 or u.shape != (p.shape[0], 4):
        raise ValueError(f"inputs must have shape ({p.shape[0]}, 4), got {u.shape}")
    for column in u.T:
        bad = ~np.isfinite(column)
        if bad.any():
            index = np.where(~bad, np.arange(column.shape[0]), 0)
            np.maximum.accumulate(index, out=index)
            column[:] = np.where(np.isfinite(column[index]), column[index], 0.0)
    n = p.shape[0]
    traces = {
        name: np.append(p[:, j], p[-1, j]) for j, name in enumerate(Driver.model.parameter_names)
    }
    d = _driver_record(
        Driver(),
        traces,
        check_positive("speed", speed),
        check_positive("dt", dt),
        np.zeros(n),
        INJECT_NONE,
    )
    out = np.zeros((n, 2))
    _resimulate(d, np.ascontiguousarray(u), out)
    return out[:, 0], out[:, 1]


@numba.njit(cache=True, _nrt=False)
def _resimulate(d, inputs, out):
    for k in range(inputs.shape[0]):
        driver_sample(d, k, inputs[k])
        out[k, 0] = d.out[0]
        out[k, 1] = d.out[1]


class DriverController:
    """A driver's runtime state in one episode of :class:`~manualcontrol.envs.driving.LaneKeeping`.

    Create it after ``env.reset(...)`` (it reads the episode's road); a remnant with a
    requested power ratio is calibrated on the simulated loop of the same episode, so
    both give the same gain.
    """

    def __init__(
        self, driver: Driver, env: Any, seed: int | np.random.Generator | None = None
    ) -> None:
        base = getattr(env, "unwrapped", env)
        if not isinstance(base, LaneKeeping):
            raise TypeError(f"env must be a LaneKeeping environment, got {type(base).__name__}")
        if base._k < 0:
            raise RuntimeError("reset the environment before the driver")
        n = base.episode_steps
        traces = driver.parameter_traces(base.times)
        rng, _ = _as_generator(seed)
        remnant = driver.remnant
        inject = _INJECT_CODES[None if remnant is None else remnant.injection]
        noise = np.zeros(n)
        if remnant is not None:
            unit = _remnant_noise(remnant, rng.standard_normal(n), base.dt)
            gain = remnant.K_r
            if remnant.P_r is not None:
                kappa, kappa_far = base.episode_curvature()
                gain = _calibrated_gain(
                    base, driver, traces, kappa, kappa_far, unit, inject, remnant.P_r
                )
            noise = gain * unit
        self._record = _driver_record(driver, traces, base.speed, base.dt, noise, inject)
        self._angle = 1.0 if base.steering == "angle" else 0.0
        self._bound = float(base.action_bound)
        self._n = n
        self.k = 0

    def act(self, observation: Any) -> FloatArray:
        """The action for this observation (shape ``(1,)``); advances the driver one sample."""
        k = self.k
        if k >= self._n:
            raise RuntimeError("the driver's episode is over; reset it with the environment")
        inputs = np.ascontiguousarray(np.asarray(observation, dtype=np.float64)[:4])
        driver_sample(self._record, k, inputs)
        self.k = k + 1
        self.last_output = (float(self._record.out[0]), float(self._record.out[1]))
        return np.array([driver_action(self._record, k, self._angle, self._bound)])
