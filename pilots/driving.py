"""Closed-loop driving: the cybernetic driver steering the lane-keeping car.

:func:`simulate_driving` is the sampled loop of
:class:`~manualcontrol.envs.driving.LaneKeeping` with a
:class:`~manualcontrol.pilots.driver.Driver` acting: the same car model, road samples and
action clipping (the environment is built and reset to obtain them, so there is one
set-up), the same compiled driver step. A driver acting through
:meth:`Driver.act <manualcontrol.pilots.driver.Driver.act>` in the environment gives the
same recording to rounding (tests/pilots/test_driving.py): both run the compiled loop
of :func:`~manualcontrol.pilots.driver.drive_episode`.

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

from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from manualcontrol.envs._validation import check_positive, check_vector
from manualcontrol.envs.driving import LaneKeeping, Road, road_preset
from manualcontrol.envs.recording import Recording
from manualcontrol.pilots._random import as_generator
from manualcontrol.pilots.driver import (
    INJECT_CODES,
    INJECT_NONE,
    INJECT_OUTPUT,
    Driver,
    DriverController,
    calibrated_gain,
    drive_episode,
    driver_record,
    remnant_noise,
)
from manualcontrol.pilots.simulation import remnant_power_ratio

__all__ = [
    "DriverController",
    "output_noise_levels",
    "resimulate_driver",
    "simulate_driving",
]

FloatArray = NDArray[np.float64]


def _environment(road: Any, environment: Mapping[str, Any]) -> LaneKeeping:
    if isinstance(road, str) and road == "random":
        raise ValueError(
            "simulate_driving needs a fixed road: pass Road.random(seed) for a random one"
        )
    env = LaneKeeping(road_preset(road), **dict(environment))
    env.reset(seed=0)
    return env


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
    noise_levels = output_noise_levels(output_noise)
    for key in ("reward", "reward_scale", "effort_weight", "include_rates", "render_mode"):
        if key in environment:
            raise TypeError(f"simulate_driving got an environment keyword it does not use: {key!r}")
    env = _environment(road, environment)
    n = env.episode_steps
    times = env.times
    traces = driver.parameter_traces(times)
    kappa, kappa_far = env.episode_curvature()
    rng, seed_used = as_generator(seed)
    remnant = driver.remnant
    inject = INJECT_CODES[None if remnant is None else remnant.injection]
    gain = 0.0
    if remnant_signal is not None:
        unit = check_vector("remnant_signal", remnant_signal, length=n)
        gain = 1.0
        if remnant is None:
            inject = INJECT_OUTPUT
    elif remnant is not None:
        unit = remnant_noise(remnant, rng.standard_normal(n), env.dt)
        gain = remnant.K_r
        if remnant.P_r is not None:
            gain = calibrated_gain(env, driver, traces, kappa, kappa_far, unit, inject, remnant.P_r)
    else:
        unit = np.zeros(n)
    out = drive_episode(env, driver, traces, kappa, kappa_far, gain * unit, inject)
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
        alone = drive_episode(env, driver, traces, zero, zero, gain * unit, inject).action
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


def output_noise_levels(spec: Mapping[str, float] | None) -> dict[str, float]:
    """Validated sensor-noise levels ``{"Gamma_d" or "delta_sw": standard deviation}``.

    :func:`simulate_driving`'s ``output_noise``; the bench checks a lane-keeping batch's
    noise table with it when the suite is read.
    """
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
    d = driver_record(
        Driver(),
        traces,
        check_positive("speed", speed),
        check_positive("dt", dt),
        np.zeros(n),
        INJECT_NONE,
    )
    out = np.zeros((n, 2))
    # imported here: the bench reads this module for its suites, and needs numba only
    # where a driver is simulated
    from manualcontrol.pilots._driver_kernels import resimulate

    resimulate(d, np.ascontiguousarray(u), out)
    return out[:, 0], out[:, 1]
