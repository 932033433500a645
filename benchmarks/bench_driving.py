"""Lane keeping and Zhao's filters: environment steps/s beside CartPole, UKF samples/s.

Single environments through gymnasium.make (default wrappers included), actions drawn
in advance, side by side with CartPole-v1 in the same process; the native vector env;
Zhao's UKF (one core, the 220-s zhao2019 drive at 100 Hz: ``estimate()`` end to end,
and its C port's run and its numba kernel's run alone), the multi-UKF, and the
closed-loop simulation. Medians of repeats. Run with one BLAS thread, as the Makefile does:

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_driving.py [--quick]
"""

import argparse
import statistics
import time

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401
from manualcontrol.envs.schedules import Ramp
from manualcontrol.estimators import MultiUKF, ZhaoUKF
from manualcontrol.estimators.members import _zhao_core as core
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving


def single_rate(env_id, actions, **kwargs):
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return len(actions) / (time.perf_counter() - start)


def vector_rate(env_id, num_envs, actions, **kwargs):
    envs = gym.make_vec(env_id, num_envs=num_envs, **kwargs)
    envs.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        envs.step(action)
    return len(actions) * num_envs / (time.perf_counter() - start)


def median(function, repeats):
    return statistics.median(function() for _ in range(repeats))


def timed(function):
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--quick", action="store_true", help="fewer steps and repeats")
    args = parser.parse_args()
    steps = 20_000 if args.quick else 100_000
    repeats = 3 if args.quick else 5
    rng = np.random.default_rng(0)
    torques = list(rng.uniform(-2, 2, (steps, 1)))
    pushes = list(rng.integers(0, 2, steps))
    print(f"single environment, steps/s, median of {repeats} x {steps} steps (interleaved)")
    rates = {"CartPole-v1": [], "LaneKeeping-v0 (torque)": [], "LaneKeeping-v0 (angle)": []}
    for _ in range(repeats):  # interleaved so that load on the machine hits all alike
        rates["CartPole-v1"].append(single_rate("CartPole-v1", pushes))
        rates["LaneKeeping-v0 (torque)"].append(
            single_rate(
                "ManualControl/LaneKeeping-v0", torques, road="random", measurement_time=60.0
            )
        )
        rates["LaneKeeping-v0 (angle)"].append(
            single_rate(
                "ManualControl/LaneKeeping-v0",
                [0.02 * a for a in torques],
                road="random",
                steering="angle",
                measurement_time=60.0,
            )
        )
    cartpole = statistics.median(rates["CartPole-v1"])
    for name, values in rates.items():
        rate = statistics.median(values)
        print(f"  {name:40s} {rate:12,.0f}   {rate / cartpole:.2f}x")

    print(f"batched, env-steps/s, median of {repeats} x 1000 batched steps")
    cart = rng.integers(0, 2, (1000, 16))
    rate = median(lambda: vector_rate("CartPole-v1", 16, cart), repeats)
    print(f"  {'CartPole-v1 vector, N = 16':40s} {rate:14,.0f}")
    actions = rng.uniform(-2, 2, (1000, 1024, 1))
    rate = median(
        lambda: vector_rate("ManualControl/LaneKeeping-v0", 1024, actions, measurement_time=60.0),
        repeats,
    )
    print(f"  {'LaneKeeping-v0 native vector, N = 1024':40s} {rate:14,.0f}")

    driver = Driver({"K_p": Ramp(3.4, 4.42, 40.0, 70.0), "K_c": Ramp(15.0, 19.5, 110.0, 140.0)})
    simulate_driving(driver)
    elapsed = median(lambda: timed(lambda: simulate_driving(driver)), repeats)
    recording = simulate_driving(driver)
    n = len(recording)
    print(
        f"zhao2019 drive: {n} samples; simulate_driving {elapsed * 1e3:.1f} ms "
        f"({n * 0.01 / elapsed:,.0f}x real time)"
    )
    print(f"filters, samples/s, median of {2 * repeats + 1} (one core)")
    for label, estimator in (
        ("ZhaoUKF estimate()", ZhaoUKF()),
        ("MultiUKF estimate()", MultiUKF()),
    ):
        estimator.estimate(recording)  # compile
        elapsed = median(lambda e=estimator: timed(lambda: e.estimate(recording)), 2 * repeats + 1)
        print(f"  {label:40s} {n / elapsed:12,.0f}")
    ukf = ZhaoUKF()
    inputs = np.ascontiguousarray(
        np.column_stack([recording[s] for s in ("theta_far", "theta_near", "delta_d", "Gamma_s")])
    )
    outputs = np.ascontiguousarray(np.column_stack([recording["Gamma_d"], recording["delta_sw"]]))

    def numba_run():
        ukf.reset(0.01, speed=recording.metadata["speed"])
        out = ukf._new_output(n, False)
        return timed(lambda: core.zhao_run(*ukf._records, inputs, outputs, out))

    def c_run():
        ukf.reset(0.01, speed=recording.metadata["speed"])
        native = ukf._native_records(ukf._new_output(n, False))
        return timed(lambda: native.run(inputs, outputs))

    # estimate() runs the C port where it builds, the numba kernel elsewhere: both alone
    elapsed = median(numba_run, 2 * repeats + 1)
    print(f"  {'ZhaoUKF numba kernel alone':40s} {n / elapsed:12,.0f}")
    ukf.reset(0.01, speed=recording.metadata["speed"])
    if ukf._native_records(ukf._new_output(n, False)) is not None:
        elapsed = median(c_run, 2 * repeats + 1)
        print(f"  {'ZhaoUKF C port alone':40s} {n / elapsed:12,.0f}")


if __name__ == "__main__":
    main()
