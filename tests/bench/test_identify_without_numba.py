"""An identification through the C ports never imports numba, and numba's is the same.

Where the C ports build, ``manualcontrol identify <recording> --estimator <member>
--no-plot`` (the DEKF, the RML, the joint and dual UKFs, the RDI, Schiess-Roland's filter,
Zhao's UKF and multi-UKF on a lane-keeping run, and the smoothed twins, whose RTS pass
has its own port) simulates, discretises, filters and smooths in C: the numba kernels
live in modules that only the fallback imports, so numba (a quarter of the command's
CPU time) is never loaded. With ``MANUALCONTROL_NATIVE=0`` the same command runs the
numba kernels and writes the same estimation, byte for byte.
"""

import os
import subprocess
import sys

import pytest

from manualcontrol.envs import _dynamics_native, _native
from manualcontrol.estimators.filters import _smoother_native
from manualcontrol.estimators.members import (
    _dekf_native,
    _rdi_native,
    _rml_native,
    _schiess_roland_native,
    _ukf_native,
    _zhao_native,
)
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.driver import Driver
from manualcontrol.pilots.driving import simulate_driving

#: One identification through the command's main, then the numba modules it loaded.
SCRIPT = """
import sys
from manualcontrol.bench.cli import main
code = main(
    ["identify", sys.argv[1], "--estimator", sys.argv[3], "--out", sys.argv[2], "--no-plot"]
)
assert code == 0, code
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""

#: Each member whose whole identify runs in C: its C port, and the pilot, element and
#: forcing of its recording (with simulate's other arguments), or ``DRIVING`` for a
#: lane-keeping run.
DRIVING = "lane-keeping"
MEMBERS = {
    "dekf": (_dekf_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "rml": (_rml_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "rdi": (_rdi_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "joint-ukf": (_ukf_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "dual-ukf": (_ukf_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "schiess-roland": (
        _schiess_roland_native,
        ("schiess-roland", "schiess-roland1975", "schiess-roland1975"),
        {"seed": 0},
    ),
    # the smoothed twins: the filter's C port, then the RTS smoother's
    "dekf-smoothed": (_dekf_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "rml-smoothed": (_rml_native, ("precision", "popovici2017", "popovici2017"), {"run_in": 0.0}),
    "joint-ukf-smoothed": (
        _ukf_native,
        ("precision", "popovici2017", "popovici2017"),
        {"run_in": 0.0},
    ),
    "zhao-ukf": (_zhao_native, DRIVING, {}),
    "zhao-multi-ukf": (_zhao_native, DRIVING, {}),
}


def run_script(script, *arguments, native=True):
    """The lines ``script`` prints in a fresh process (C ports on, or numba's alone)."""
    environment = {k: v for k, v in os.environ.items() if k != "MANUALCONTROL_NATIVE"}
    if not native:
        environment["MANUALCONTROL_NATIVE"] = "0"
    done = subprocess.run(
        [sys.executable, "-c", script, *map(str, arguments)],
        capture_output=True,
        text=True,
        env=environment,
        timeout=600,
        check=False,
    )
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()


def identify(recording, out, native, estimator="dekf"):
    return run_script(SCRIPT, recording, out, estimator, native=native)[-1]


@pytest.mark.skipif(
    _native._compiler() is None, reason="no C compiler: the C ports cannot be built here"
)
@pytest.mark.parametrize("estimator", sorted(MEMBERS))
def test_a_warm_identify_imports_no_numba_and_numba_writes_the_same(
    estimator, tmp_path, monkeypatch
):
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    port, source, options = MEMBERS[estimator]
    if port.library() is None or _dynamics_native.library() is None:
        pytest.skip(f"the {estimator}'s or the LPV toolkit's C port did not build here")
    if estimator.endswith("-smoothed") and _smoother_native.library() is None:
        pytest.skip("the RTS smoother's C port did not build here")
    recording = tmp_path / "run.npz"
    if source == DRIVING:  # a few seconds of lane keeping keep it fast
        simulate_driving(Driver(), measurement_time=4.0, **options).save(recording)
    else:
        pilot, plant, task = source
        simulate(Pilot(pilot), plant, task, measurement_time=30.0, **options).save(recording)
    loaded = identify(recording, tmp_path / "c", native=True, estimator=estimator)
    assert loaded == "[]", f"the C path imported {loaded}"
    loaded = identify(recording, tmp_path / "numba", native=False, estimator=estimator)
    assert "'numba'" in loaded
    c_bytes = (tmp_path / "c" / "estimation.npz").read_bytes()
    assert c_bytes == (tmp_path / "numba" / "estimation.npz").read_bytes()


#: A preview pilot's simulation: the target ahead read in numpy, the loop in C.
PREVIEW = """
import sys
from manualcontrol.pilots import Pilot, simulate
recording = simulate(Pilot.typical("preview", "SI"), "SI", measurement_time=5.0)
print(float(abs(recording.u).sum()))
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""


#: A member's online path: reset as ``estimate`` resets it, then ``update`` a sample at
#: a time (the default observer's step), the same numbers through C and numba.
UPDATES = """
import sys
import numpy as np
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import make_estimator
recording = Recording.load(sys.argv[1])
estimator = make_estimator({"name": sys.argv[2]})
keys = tuple(estimator.sample_keys)
signals = estimator.signals(recording)
if not isinstance(signals, dict):
    signals = dict(zip(keys, signals))
settings = estimator.settings
options = {}
if hasattr(getattr(settings, "noise", None), "initial_variance"):
    first = slice(0, round(settings.noise.window / recording.dt) + 1)
    options = {"var_u0": float(np.nanvar(signals["u"][first])),
               "var_e0": float(np.nanvar(signals["e"][first]))}
elif hasattr(estimator, "initial_states_of"):
    options = {"initial_states": estimator.initial_states_of(recording)}
elif "speed" in recording.metadata and hasattr(settings, "speed"):
    options = {"speed": recording.metadata["speed"]}
estimator.reset(recording.dt, t0=float(recording.t[0]), **options)
means = []
for k in range(200):
    estimate = estimator.update({key: float(signals[key][k]) for key in keys})
    means.append([float(value) for value in estimate.mean.values()])
print(np.asarray(means).tobytes().hex())
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""

#: The members whose online step has a C port, and the recording each reads.
ONLINE_MEMBERS = [name for name in MEMBERS if not name.endswith("-smoothed")]


@pytest.mark.skipif(
    _native._compiler() is None, reason="no C compiler: the C ports cannot be built here"
)
@pytest.mark.parametrize("estimator", ONLINE_MEMBERS)
def test_an_online_update_imports_no_numba_and_numba_gives_the_same(
    estimator, tmp_path, monkeypatch
):
    # the step kernel is read by name only where numba takes the step
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    port, source, options = MEMBERS[estimator]
    if port.library() is None:
        pytest.skip(f"the {estimator}'s C port did not build here")
    recording = tmp_path / "run.npz"
    if source == DRIVING:
        simulate_driving(Driver(), measurement_time=4.0, **options).save(recording)
    else:
        pilot, plant, task = source
        simulate(Pilot(pilot), plant, task, measurement_time=5.0, **options).save(recording)
    outputs = {
        native: run_script(UPDATES, recording, estimator, native=native)[-2:]
        for native in (True, False)
    }
    assert outputs[True][1] == "[]", f"the C path imported {outputs[True][1]}"
    assert "'numba'" in outputs[False][1]
    assert outputs[True][0] == outputs[False][0]


#: The online observer's thin form: built, stepped through a block and read.
ONLINE = """
import sys
import gymnasium as gym
import manualcontrol.envs
from manualcontrol.estimators import DEKF
from manualcontrol.estimators.observer import EstimatorObserver
env = EstimatorObserver(
    gym.make("ManualControl/CompensatoryTracking-v0", controlled_element="DI", run_in=0.0,
             measurement_time=5.0),
    DEKF(ce="DI", initial_variance="causal", initial={"K_p": 0.24}),
    estimates_in_info="none",
)
assert env._keeps  # the samples kept and stepped as a block (update_block)
env.reset(seed=0)
for _ in range(450):
    env.step([0.1])
print(env.last_estimate()["mean"]["K_p"])
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""


#: What an identification of the driver imports besides the filters: the driver model,
#: the car and the Zhao filters' records, and the driver model's eq. 2 run as Python;
#: and what every bench reads its suites with (the driving simulation's module).
DRIVER_MODULES = """
import sys
import numpy as np
import manualcontrol.envs.driving, manualcontrol.pilots.driver, manualcontrol.pilots.driving
import manualcontrol.bench.scenarios
import manualcontrol.estimators.members._zhao_core
from manualcontrol.pilots.driver import CyberneticDriverModel
system = CyberneticDriverModel().state_space({}, 18.0)
print(float(np.abs(system.A).sum()))
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""


#: Paths that print one number they computed, then the numba modules they loaded: the
#: script and the C port it runs through (None: none; it holds without a compiler too).
NUMBA_FREE_PATHS = {
    # the target ahead read in numpy, the loop in C
    "a preview simulation": (PREVIEW, _dynamics_native),
    # asking whether the member has a batched step must not import its kernel
    "the online observer's block path": (ONLINE, _dekf_native),
    "the driver model, the car and the suites' modules": (DRIVER_MODULES, None),
}


@pytest.mark.parametrize("path", sorted(NUMBA_FREE_PATHS))
def test_a_path_imports_no_numba(path, monkeypatch):
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    script, port = NUMBA_FREE_PATHS[path]
    if port is not None and port.library() is None:
        pytest.skip(f"{port.SOURCE.name} did not build here")
    number, loaded = run_script(script)[-2:]
    assert float(number) > 0.0
    assert loaded == "[]", f"{path} imported {loaded}"


#: Each numba-free module and the kernel module that took its numba kernels.
HOMES = {
    "manualcontrol.envs.signals": "manualcontrol.envs._interpolation",
    "manualcontrol.pilots.loop": "manualcontrol.pilots._kernels",
    "manualcontrol.pilots.controller": "manualcontrol.pilots._kernels",
    "manualcontrol.estimators._pilot_core": "manualcontrol.estimators._pilot_kernels",
    "manualcontrol.estimators.filters.kalman": "manualcontrol.estimators.filters._kalman_kernels",
    "manualcontrol.estimators.filters.linalg": "manualcontrol.estimators.filters._linalg_kernels",
    "manualcontrol.estimators.filters.monitor": (
        "manualcontrol.estimators.filters._monitor_kernels"
    ),
    "manualcontrol.estimators.filters.smoothers": (
        "manualcontrol.estimators.filters._smoother_kernels"
    ),
    "manualcontrol.estimators.members.internal_model": (
        "manualcontrol.estimators.members._internal_model_kernels"
    ),
    "manualcontrol.estimators.members._dekf_core": (
        "manualcontrol.estimators.members._dekf_kernels"
    ),
    "manualcontrol.estimators.members._rml_core": "manualcontrol.estimators.members._rml_kernels",
    "manualcontrol.estimators.filters.unscented": (
        "manualcontrol.estimators.filters._unscented_kernels"
    ),
    "manualcontrol.estimators.members._ukf_core": "manualcontrol.estimators.members._ukf_kernels",
    "manualcontrol.estimators.members._rdi_core": "manualcontrol.estimators.members._rdi_kernels",
    "manualcontrol.estimators.members._schiess_roland_core": (
        "manualcontrol.estimators.members._schiess_roland_kernels"
    ),
    "manualcontrol.estimators.members._zhao_core": "manualcontrol.estimators.members._zhao_kernels",
    "manualcontrol.pilots.driver": "manualcontrol.pilots._driver_kernels",
    "manualcontrol.envs.driving": "manualcontrol.envs._driving_kernels",
}
#: The kernels a numba-free module exported before they moved (the rest it still defines).
MOVED = {
    "manualcontrol.envs.signals": ("interpolate_many",),
    "manualcontrol.pilots.loop": ("interpolate_at",),
    "manualcontrol.pilots.controller": ("_act", "interpolate_at"),
    # the driver's kernels; the resimulation's (moved from pilots/driving.py) has no
    # other user, and eq. 2's is compiled from the driver module itself
    "manualcontrol.pilots.driver": (
        "driver_matrices",
        "exact_delay_step",
        "pade_step",
        "driver_sample",
        "driver_action",
        "drive",
    ),
}


@pytest.mark.parametrize("home", sorted(HOMES))
def test_the_kernels_stay_importable_from_their_old_homes(home):
    """Each kernel is the kernel module's very dispatcher, read from where it was."""
    import importlib

    kernels = importlib.import_module(HOMES[home])
    names = MOVED.get(home) or [
        name
        for name, value in vars(kernels).items()
        if getattr(getattr(value, "py_func", None), "__module__", None) == kernels.__name__
    ]
    assert names
    module = importlib.import_module(home)
    for name in names:
        assert getattr(module, name) is getattr(kernels, name), name


def test_the_dekf_names_its_kernels_lazily():
    from manualcontrol.estimators.members import _dekf_kernels
    from manualcontrol.estimators.members.dekf import DEKF

    assert DEKF._step_kernel is _dekf_kernels.dekf_step
    assert DEKF()._step_many_kernel is _dekf_kernels.dekf_step_many


@pytest.mark.parametrize(
    ("member", "kernels", "prefix"),
    [
        ("rml.RML", "_rml_kernels", "bank"),
        ("ukf.JointUKF", "_ukf_kernels", "joint"),
        ("ukf.DualUKF", "_ukf_kernels", "dual"),
    ],
)
def test_the_pilot_filters_name_their_kernels_lazily(member, kernels, prefix):
    import importlib

    module, name = member.split(".")
    cls = getattr(importlib.import_module(f"manualcontrol.estimators.members.{module}"), name)
    kernels = importlib.import_module(f"manualcontrol.estimators.members.{kernels}")
    assert cls._step_kernel is getattr(kernels, f"{prefix}_step")
    assert cls._step_many_kernel is getattr(kernels, f"{prefix}_step_many")


def test_zhaos_filters_name_their_kernels_lazily():
    from manualcontrol.estimators.members import _zhao_kernels
    from manualcontrol.estimators.members.zhao_ukf import MultiUKF, ZhaoUKF

    assert ZhaoUKF._step_kernel is _zhao_kernels.zhao_step
    assert ZhaoUKF()._run_kernel is _zhao_kernels.zhao_run
    assert MultiUKF._step_kernel is _zhao_kernels.multi_step
    assert MultiUKF()._run_kernel is _zhao_kernels.multi_run


def test_the_lane_keeping_car_and_the_driver_name_their_kernels_lazily():
    from manualcontrol.envs import _driving_kernels
    from manualcontrol.envs.driving import LaneKeeping
    from manualcontrol.pilots import _driver_kernels
    from manualcontrol.pilots.driver import DriverController

    assert LaneKeeping._perceive is _driving_kernels.perceive
    assert LaneKeeping._lane_step is _driving_kernels.lane_step
    assert DriverController._sample is _driver_kernels.driver_sample
    assert DriverController._action is _driver_kernels.driver_action
