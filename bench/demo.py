"""``make demo``: a simulated preview-tracking run with a time-varying pilot.

Van der El's preview pilot (thesis Table 6.1 values) tracks the 4 rad/s-bandwidth
target of the thesis preset on single-integrator dynamics while its preview time
drops from 0.6 to 0.3 s (a sigmoid at t = 60 s), with Levison remnant at the
output feedback calibrated to 35 % of the control power (thesis Sec. IV-D). The run is
written as a :class:`~manualcontrol.envs.recording.Recording` and plotted.

This stands in for the main job until the estimators exist.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from manualcontrol.envs._files import atomic_path
from manualcontrol.envs.recording import Recording
from manualcontrol.envs.schedules import Sigmoid
from manualcontrol.pilots import Pilot, simulate


def preview_run(seed: int = 1) -> Recording:
    """Simulate the demo run: 60 s run-in (cut) and 120 s measurement at 100 Hz."""
    pilot = Pilot("preview", {"tau_f": Sigmoid(0.6, 0.3, 60.0, 20.0)}, remnant="vertregt2020-SI")
    return simulate(pilot, "SI", "vanderel-bw4", realisation=0, seed=seed)


def plot(recording: Recording, path: Path) -> None:
    """Draw target, output, stick and preview time of a recording to a PNG file."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(4, 1, figsize=(10, 8), sharex=True)
    t = recording.t
    axes[0].plot(t, recording.ft, label="target $f_t$", lw=1.0)
    axes[0].plot(t, recording.y, label="output $y$", lw=1.0)
    axes[0].legend(loc="upper right")
    axes[1].plot(t, recording.e, color="tab:red", lw=0.8, label="error $e$")
    axes[1].legend(loc="upper right")
    axes[2].plot(t, recording.u, color="tab:green", lw=0.8, label="control $u$")
    axes[2].plot(t, recording.n, color="tab:gray", lw=0.6, label="remnant $n$")
    axes[2].legend(loc="upper right")
    axes[3].plot(t, recording.parameters["tau_f"], color="k", label=r"preview time $\tau_f$ [s]")
    axes[3].legend(loc="upper right")
    axes[3].set_xlabel("time [s]")
    ratio = recording.metadata["remnant_power_ratio"]
    rms = float(np.sqrt(np.mean(recording.e**2)))
    axes[0].set_title(
        f"Preview pilot on 1.5/s: RMS error {rms:.3f}, remnant power ratio {ratio:.2f}"
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
    recording = preview_run()
    recording_path = recording.save(args.out / "preview_run.npz")
    figure_path = args.out / "preview_run.png"
    plot(recording, figure_path)
    rms = float(np.sqrt(np.mean(recording.e**2)))
    print(f"simulated {recording.duration:.0f} s, RMS error {rms:.3f}")
    print(f"recording: {recording_path}")
    print(f"figure:    {figure_path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
