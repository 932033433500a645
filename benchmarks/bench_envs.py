"""Environment steps per second, side by side with gymnasium's CartPole-v1.

Single environments through gymnasium.make (its default wrappers included), actions
drawn in advance; batched environments through gymnasium.make_vec with the native
vector entry points. Median of 5 repeats in one process.

Run: .venv/bin/python benchmarks/bench_envs.py
"""

import statistics
import time

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401

STEPS = 100_000
VECTOR_STEPS = 1_000
REPEATS = 5


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


def median(function):
    return statistics.median(function() for _ in range(REPEATS))


def main():
    rng = np.random.default_rng(0)
    box_actions = list(rng.uniform(-1, 1, (STEPS, 1)))
    cart_actions = list(rng.integers(0, 2, STEPS))
    print(f"single environment, steps/s, median of {REPEATS} x {STEPS} steps")
    cartpole = median(lambda: single_rate("CartPole-v1", cart_actions))
    print(f"  {'CartPole-v1':40s} {cartpole:12,.0f}   1.00x")
    for task in ("Compensatory", "Pursuit", "Preview"):
        rate = median(
            lambda task=task: single_rate(f"ManualControl/{task}Tracking-v0", box_actions)
        )
        print(f"  {task + 'Tracking-v0 (SI)':40s} {rate:12,.0f}   {rate / cartpole:.2f}x")
    rate = median(
        lambda: single_rate(
            "ManualControl/CompensatoryTracking-v0",
            box_actions,
            controlled_element="popovici2017-tv",
        )
    )
    print(
        f"  {'CompensatoryTracking-v0 (time-varying)':40s} {rate:12,.0f}   {rate / cartpole:.2f}x"
    )

    print(f"batched, env-steps/s, median of {REPEATS} x {VECTOR_STEPS} batched steps")
    cart_vector = rng.integers(0, 2, (VECTOR_STEPS, 16))
    rate16 = median(lambda: vector_rate("CartPole-v1", 16, cart_vector))
    print(f"  {'CartPole-v1 vector, N = 16':40s} {rate16:14,.0f}")
    for task in ("Compensatory", "Pursuit", "Preview"):
        actions = rng.uniform(-1, 1, (VECTOR_STEPS, 1024, 1))
        rate = median(
            lambda task=task, actions=actions: vector_rate(
                f"ManualControl/{task}Tracking-v0", 1024, actions
            )
        )
        print(f"  {task + 'Tracking-v0, N = 1024':40s} {rate:14,.0f}")


if __name__ == "__main__":
    main()
