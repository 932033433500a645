"""How well this machine keeps the play loop's 100-Hz schedule.

A 30-s compensatory run (SI, vanderel-bw4) flown by manualcontrol.human.realtime.fly
with the real clock, a scripted stick (a slow sum of sines, as a hand might move) and
the env's "human" window drawn every step through SDL's dummy video driver (no screen
needed; a real screen adds the compositor's and the driver's time to each flip). Prints
the steps' lateness (median, 99th percentile, maximum), the late steps (more than half
a step late), the jitter and frame time, and whether the timing would pass for
identification. The figures depend on what else the machine is doing: run it on a quiet
machine, and note the load average it prints.

Run: .venv/bin/python benchmarks/play_timing.py [seconds]
"""

import os
import sys

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import gymnasium as gym
import numpy as np

import manualcontrol.envs  # noqa: F401 - registers the environments
from manualcontrol.human import RealClock, ScriptedInput, fly

SECONDS = float(sys.argv[1]) if len(sys.argv) > 1 else 30.0
DT = 0.01


def main():
    env = gym.make(
        "ManualControl/CompensatoryTracking-v0", measurement_time=SECONDS, render_mode="human"
    )
    t = np.arange(round(SECONDS / DT)) * DT
    stick = 0.4 * np.sin(2 * np.pi * 0.3 * t) + 0.2 * np.sin(2 * np.pi * 1.1 * t + 1.0)
    load_before = os.getloadavg()[0]
    flight = fly(env, ScriptedInput(stick), clock=RealClock(), seed=0)
    load_after = os.getloadavg()[0]
    env.close()
    timing = flight.timing
    lateness_ms = 1e3 * flight.lateness
    print(f"{SECONDS:g}-s compensatory run, {timing.steps} steps at {1 / DT:g} Hz, window drawn")
    print(
        f"load average (1 min) before {load_before:.2f}, after {load_after:.2f}; "
        f"{os.cpu_count()} cores"
    )
    print(
        f"lateness  median {np.median(lateness_ms):.3f} ms  p99 "
        f"{np.percentile(lateness_ms, 99):.3f} ms  max {lateness_ms.max():.3f} ms"
    )
    print(
        f"late steps (> {1e3 * timing.late_threshold:g} ms): {timing.late_steps} "
        f"({100 * timing.late_fraction:.2f} %)"
    )
    print(
        f"jitter    median {1e3 * timing.median_jitter:.3f} ms  p99 "
        f"{1e3 * timing.p99_jitter:.3f} ms"
    )
    print(
        f"frame     median {1e3 * timing.median_frame_time:.3f} ms  p99 "
        f"{1e3 * timing.p99_frame_time:.3f} ms  max {1e3 * timing.max_frame_time:.3f} ms"
    )
    print(
        f"wall time {timing.wall_time:.3f} s for {timing.steps * DT:g} s of task; good enough "
        f"for identification: {timing.good_enough_for_identification}"
    )
    if flight.warning:
        print(f"warning: {flight.warning}")


if __name__ == "__main__":
    main()
