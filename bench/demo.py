"""``make demo``: a closed-loop tracking run built from the task-world core.

A crossover-model operator (McRuer & Jex 1967: the open loop ``omega_c e^{-tau s}/s``
near crossover, i.e. a pure gain with an exact delay on a single integrator) tracks
the 4 rad/s-bandwidth target of the thesis preset while a disturbance acts on the
controlled-element output. The run is simulated with an exact (delay-line) delay,
written as a :class:`~manualcontrol.envs.recording.Recording` and plotted.

This stands in for the main job until the pilot models and estimators exist.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from manualcontrol.envs._files import atomic_path
from manualcontrol.envs.dynamics import (
    Block,
    DelayChannel,
    StateSpace,
    discretize,
    interconnect,
    simulate_lpv,
)
from manualcontrol.envs.elements import make_element
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.signals import forcing_preset

CROSSOVER_FREQUENCY = 2.5  # rad/s
OPERATOR_DELAY = 0.25  # s


def crossover_run(
    dt: float = 0.01, run_in: float = 20.0, measurement_time: float = 120.0
) -> Recording:
    """Simulate the crossover-model loop on the SI preset and cut the run-in."""
    element = make_element("SI")
    forcing = forcing_preset("vanderel-bw4", realisation=0)
    n = round((run_in + measurement_time) / dt)
    t = np.arange(n) * dt
    ft, fd = forcing.sample(n * dt, dt)
    gain = CROSSOVER_FREQUENCY / float(element.K(0.0))
    operator = StateSpace(np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), [[gain]])
    loop = interconnect(
        [
            Block(operator, ("e_seen",), ("u",)),
            Block(element.state_space(), ("u",), ("x",)),
        ],
        inputs=("ft", "fd"),
        outputs=("u", "y", "e"),
        sums={"y": {"x": 1.0, "fd": 1.0}, "e": {"ft": 1.0, "y": -1.0}},
        delays=(DelayChannel("e", "e_seen"),),
    )
    exact = discretize(loop.system.A, loop.system.B, dt)
    _, outputs = simulate_lpv(
        exact,
        loop.system.C,
        loop.system.D,
        np.column_stack([ft, fd, np.zeros(n)]),
        dt,
        delay_inputs=loop.delay_inputs,
        delay_outputs=loop.delay_outputs,
        delays=OPERATOR_DELAY,
    )
    recording = Recording(
        signals={
            "t": t,
            "ft": ft,
            "fd": fd,
            "u": outputs[:, 0],
            "y": outputs[:, 1],
            "e": outputs[:, 2],
        },
        dt=dt,
        metadata={
            "task": "compensatory",
            "controlled_element": element.to_dict(),
            "forcing": forcing.name,
            "realisation": forcing.realisation,
            "operator": "crossover model, pure gain and exact delay",
            "crossover_frequency": CROSSOVER_FREQUENCY,
            "delay": OPERATOR_DELAY,
            "run_in": run_in,
        },
    )
    return recording.slice_time(run_in)


def plot(recording: Recording, path: Path) -> None:
    """Draw target, output, error and stick of a recording to a PNG file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(10, 7), sharex=True)
    t = recording.t
    axes[0].plot(t, recording.ft, label="target $f_t$", lw=1.0)
    axes[0].plot(t, recording.y, label="output $y$", lw=1.0)
    axes[0].legend(loc="upper right")
    axes[1].plot(t, recording.e, color="tab:red", lw=0.8, label="error $e$")
    axes[1].plot(t, recording.fd, color="tab:gray", lw=0.8, label="disturbance $f_d$")
    axes[1].legend(loc="upper right")
    axes[2].plot(t, recording.u, color="tab:green", lw=0.8, label="control $u$")
    axes[2].legend(loc="upper right")
    axes[2].set_xlabel("time [s]")
    rms = float(np.sqrt(np.mean(recording.e**2)))
    axes[0].set_title(
        f"Crossover-model operator on 1.5/s, omega_c = {CROSSOVER_FREQUENCY} rad/s, "
        f"tau = {OPERATOR_DELAY} s (RMS error {rms:.3f})"
    )
    fig.tight_layout()
    with atomic_path(path) as temporary:
        fig.savefig(temporary, dpi=110, format="png")
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    """Run the demo and print where its results are."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/demo"), help="output folder")
    args = parser.parse_args(argv)
    recording = crossover_run()
    recording_path = recording.save(args.out / "crossover_run.npz")
    figure_path = args.out / "crossover_run.png"
    plot(recording, figure_path)
    rms = float(np.sqrt(np.mean(recording.e**2)))
    print(f"simulated {recording.duration:.0f} s, RMS error {rms:.3f}")
    print(f"recording: {recording_path}")
    print(f"figure:    {figure_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
