"""An identification through the C ports never imports numba, and numba's is the same.

Where the C ports build, ``manualcontrol identify <recording> --estimator <member>
--no-plot`` (the DEKF, the RML, the joint and dual UKFs, the RDI, Schiess-Roland's filter,
Zhao's UKF and multi-UKF on a lane-keeping run, and the smoothed twins, whose RTS pass
has its own port) simulates, discretises, filters and smooths in C: the numba kernels
live in modules that only the fallback imports, so numba (a quarter of the command's
CPU time) is never loaded. With ``MANUALCONTROL_NATIVE=0`` the same command runs the
numba kernels and writes the same estimation, byte for byte.
"""

import json
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

#: Identifications through the command's main, one after the other in one process (the
#: jobs a JSON list of [recording, estimator, out]): after each, the numba modules and
#: the C ports loaded so far, or the error it raised. One process a path, not one a
#: member: each fresh process paid the interpreter, the imports and (on numba's path)
#: numba's own import and kernel loading again, most of this file's time.
SCRIPT = """
import json, sys, traceback
from manualcontrol.bench.cli import main
from manualcontrol.envs import _native
report = {}
for recording, estimator, out in json.loads(sys.argv[1]):
    try:
        code = main(["identify", recording, "--estimator", estimator, "--out", out, "--no-plot"])
        assert code == 0, code
    except BaseException:
        report[estimator] = {"error": traceback.format_exc()}
        continue
    loaded = sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite"))
    report[estimator] = {"loaded": loaded, "ports": sorted(_native._LOADED)}
print(json.dumps(report))
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


def simulated(source, options, path, seconds=30.0):
    """The recording a member of :data:`MEMBERS` reads, simulated into ``path``."""
    if source == DRIVING:  # a few seconds of lane keeping keep it fast
        simulate_driving(Driver(), measurement_time=4.0, **options).save(path)
    else:
        pilot, plant, task = source
        simulate(Pilot(pilot), plant, task, measurement_time=seconds, **options).save(path)
    return path


def first_to_load(report, order, estimator, what="loaded"):
    """The first member, up to ``estimator`` in ``order``, after which ``what`` was loaded.

    ``what``: ``"loaded"``, numba's modules; ``"ports"``, C ports. The members run in one
    process: one that loads either leaves it loaded for those after it, which can then
    no longer be told apart (its own test names it).
    """
    for name in order[: order.index(estimator) + 1]:
        if report[name].get(what):
            return name
    return None


def assert_each_path_ran_alone(reports, order, estimator):
    """``estimator`` ran without error on both paths, C without numba, numba without C."""
    through_c, through_numba = reports[True][estimator], reports[False][estimator]
    assert "error" not in through_c, through_c.get("error")
    assert "error" not in through_numba, through_numba.get("error")
    loader = first_to_load(reports[True], order, estimator)
    assert loader is None, f"the C path imported numba (first after {loader})"
    assert "numba" in through_numba["loaded"]
    # numba's path ran no C port (numba itself is loaded by the first member alone)
    porter = first_to_load(reports[False], order, estimator, "ports")
    assert porter is None, f"numba's path loaded a C port (first after {porter})"


def c_path_missing(estimator, whole_identify=True):
    """Why ``estimator``'s C path cannot run here, or None where it can.

    A whole identify needs the LPV toolkit's port too (and the smoother's, smoothed);
    the online updates only the member's.
    """
    port = MEMBERS[estimator][0]
    if _native._compiler() is None:
        return "no C compiler: the C ports cannot be built here"
    if port.library() is None:
        return f"the {estimator}'s C port did not build here"
    if not whole_identify:
        return None
    if _dynamics_native.library() is None:
        return "the LPV toolkit's C port did not build here"
    if estimator.endswith("-smoothed") and _smoother_native.library() is None:
        return "the RTS smoother's C port did not build here"
    return None


def both_paths(tmp_path_factory, script, members, seconds, whole_identify):
    """``script`` on every member's recording, through C in one process and numba in another.

    Returns the folder, the members run (in order) and each path's report: the last line
    the script prints, JSON keyed by member.
    """
    folder = tmp_path_factory.mktemp("paths")
    with pytest.MonkeyPatch.context() as patch:  # whether each port builds, C ports on
        patch.delenv("MANUALCONTROL_NATIVE", raising=False)
        order = [name for name in members if c_path_missing(name, whole_identify) is None]
    if not order:  # every member's test skips, saying why
        return folder, order, {True: {}, False: {}}
    recordings = {}  # members reading the same run share its file
    jobs = {True: [], False: []}
    for estimator in order:
        _, source, options = MEMBERS[estimator]
        key = repr((source, sorted(options.items())))
        if key not in recordings:
            path = folder / f"run{len(recordings)}.npz"
            recordings[key] = simulated(source, options, path, seconds)
        for native in jobs:
            place = folder / ("c" if native else "numba") / estimator
            job = [str(recordings[key]), estimator, str(place)]
            jobs[native].append(job if whole_identify else job[:2])
    reports = {
        native: json.loads(run_script(script, json.dumps(batch), native=native)[-1])
        for native, batch in jobs.items()
    }
    return folder, order, reports


@pytest.fixture(scope="module")
def identified(tmp_path_factory):
    """Every member's identify through C in one process, through numba in another."""
    return both_paths(tmp_path_factory, SCRIPT, sorted(MEMBERS), 30.0, whole_identify=True)


@pytest.mark.parametrize("estimator", sorted(MEMBERS))
def test_a_warm_identify_imports_no_numba_and_numba_writes_the_same(
    estimator, identified, monkeypatch
):
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    reason = c_path_missing(estimator)
    if reason is not None:
        pytest.skip(reason)
    folder, order, reports = identified
    assert_each_path_ran_alone(reports, order, estimator)
    c_bytes = (folder / "c" / estimator / "estimation.npz").read_bytes()
    assert c_bytes == (folder / "numba" / estimator / "estimation.npz").read_bytes()


#: A preview pilot's simulation: the target ahead read in numpy, the loop in C.
PREVIEW = """
import sys
from manualcontrol.pilots import Pilot, simulate
recording = simulate(Pilot.typical("preview", "SI"), "SI", measurement_time=5.0)
print(float(abs(recording.u).sum()))
print(sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite")))
"""


#: Each member's online path, one after the other in one process (the jobs a JSON list
#: of [recording, estimator]): reset as ``estimate`` resets it, then ``update`` a sample
#: at a time (the default observer's step); the means it gave (hex of their bytes), the
#: numba modules and the C ports loaded so far, or the error it raised.
UPDATES = """
import json, sys, traceback
import numpy as np
from manualcontrol.envs import _native
from manualcontrol.envs.recording import Recording
from manualcontrol.estimators import make_estimator

def updates(path, name):
    recording = Recording.load(path)
    estimator = make_estimator({"name": name})
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
    return np.asarray(means).tobytes().hex()

report = {}
for path, name in json.loads(sys.argv[1]):
    try:
        means = updates(path, name)
    except BaseException:
        report[name] = {"error": traceback.format_exc()}
        continue
    loaded = sorted(name for name in sys.modules if name.split(".")[0] in ("numba", "llvmlite"))
    report[name] = {"means": means, "loaded": loaded, "ports": sorted(_native._LOADED)}
print(json.dumps(report))
"""

#: The members whose online step has a C port, and the recording each reads.
ONLINE_MEMBERS = [name for name in MEMBERS if not name.endswith("-smoothed")]


@pytest.fixture(scope="module")
def updated(tmp_path_factory):
    """Every member's online updates through C in one process, through numba in another."""
    return both_paths(tmp_path_factory, UPDATES, ONLINE_MEMBERS, 5.0, whole_identify=False)


@pytest.mark.parametrize("estimator", ONLINE_MEMBERS)
def test_an_online_update_imports_no_numba_and_numba_gives_the_same(
    estimator, updated, monkeypatch
):
    # the step kernel is read by name only where numba takes the step
    monkeypatch.delenv("MANUALCONTROL_NATIVE", raising=False)
    reason = c_path_missing(estimator, whole_identify=False)
    if reason is not None:
        pytest.skip(reason)
    _, order, reports = updated
    assert_each_path_ran_alone(reports, order, estimator)
    assert reports[True][estimator]["means"] == reports[False][estimator]["means"]


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
