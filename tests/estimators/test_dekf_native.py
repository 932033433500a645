"""The DEKF's C port against its numba kernels: the same numbers, bit for bit, on every path.

The C port (``_dekf_native.c``) runs wherever it builds and the numba kernels
elsewhere, so a user's numbers must not depend on which ran: every array of an
estimate, the online updates, a block of samples and the batched step are compared
byte for byte (``np.array_equal`` with NaN equal to NaN is not enough for "the same
numbers": signed zeros and NaN payloads aside, equal bytes is what identical means).
The configurations cover the kernel's branches: SI and DI, dropped samples with a
pinned parameter, an empty variance window, the dimensional eq. 49 with jitter, 50 Hz
(two Euler substeps) with a second-order Padé delay and smoother storage, the
gain-delay and preview models, and the two ways a filter stops (non-finite values, a
covariance blow-up).

The build itself: where no compiler is found the numba kernels run and say why; a
failed build leaves nothing in the cache folder; a library is built once per source
and compiler; a C port whose constants differ from the Python modules' is refused.
"""

import ctypes
import math
import os
from pathlib import Path

import numpy as np
import pytest
from scenarios import PREVIEW as TYPICAL_PREVIEW

from manualcontrol.envs import _native
from manualcontrol.estimators import DEKF
from manualcontrol.estimators._pilot_core import SC_SIZE
from manualcontrol.estimators.batch import FilterBatch
from manualcontrol.estimators.members import _dekf_native
from manualcontrol.pilots import Pilot, simulate

needs_compiler = pytest.mark.skipif(
    _native._compiler() is None, reason="no C compiler: the C port cannot be built here"
)

ARRAYS = (
    "mean",
    "std",
    "predictions",
    "innovations",
    "innovation_covariance",
    "finite",
    "covariance_ok",
    "dropped",
    "diverged",
    "pinned",
)


# the thesis's DI preview pilot, with a far-viewpoint anticipation delay
PREVIEW = {**TYPICAL_PREVIEW["DI"], "tau_f": 0.6}
PURSUIT = {name: value for name, value in PREVIEW.items() if name != "tau_f"}


@pytest.fixture(scope="module")
def runs():
    base = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=12.0
    )
    u, e = np.array(base.u), np.array(base.e)
    u[300:340] = np.nan  # 0.4 s of the stick lost, three samples of the display
    e[500:503] = np.nan
    gaps = base.with_signals(u=u, e=e)
    u, e = np.array(base.u), np.array(base.e)
    u[200:800] = np.nan  # 6 s of nothing: the 5-s variance windows run empty
    e[200:800] = np.nan
    blackout = base.with_signals(u=u, e=e)
    spike = np.array(base.u)
    spike[600] = 1e300
    fifty = simulate(
        Pilot("precision"), "popovici2017", "popovici2017", seed=0, measurement_time=12.0, dt=0.02
    )
    preview = Pilot("preview", PREVIEW)
    ahead = simulate(preview, "DI", "vanderel-bw4", seed=1, measurement_time=12.0)
    return {
        "base": base,
        "gaps": gaps,
        "blackout": blackout,
        "spike": base.with_signals(u=spike),
        "fifty": fifty,
        "ahead": ahead,
    }


CASES = {
    "SI": ("base", {}, {}),
    "DI": ("base", {"ce": "DI"}, {}),
    "dropped samples, limits, a pinned parameter": (
        "gaps",
        {"limits": {"K_v": (0.45, 0.55), "zeta_nms": (0.29, 0.30)}, "pinned_time": 1.0},
        {},
    ),
    "an empty variance window": ("blackout", {}, {}),
    "dimensional eq. 49, jitter, causal start, identity noise input": (
        "base",
        {
            "total_derivative": "dimensional",
            "jitter": 1e-12,
            "initial_variance": "causal",
            "noise_input": "identity",
            "estimated": ("K_p", "K_v", "tau_v", "omega_nms"),
            "initial": {"zeta_nms": 0.3},
            "pinned_time": math.inf,
        },
        {},
    ),
    "50 Hz, second-order Pade, smoothed": ("fifty", {"delay_order": 2}, {"smooth": True}),
    "gain-delay model": ("base", {"model": "gain-delay"}, {}),
    "preview model": (
        "ahead",
        {"model": "preview", "ce": "DI", "anticipation_time": 1.5, "initial": PREVIEW},
        {},
    ),
    "preview model, no anticipation delay": (
        "ahead",
        {"model": "preview", "ce": "DI", "anticipation_time": 0.0, "initial": PURSUIT},
        {},
    ),
    "a non-finite stop": ("spike", {}, {}),
    "a covariance stop": ("base", {"max_covariance": 10.0}, {}),
}


def same_bytes(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return a.shape == b.shape and a.dtype == b.dtype and a.tobytes() == b.tobytes()


def assert_same_result(native, numba):
    for name in ARRAYS:
        assert same_bytes(getattr(native, name), getattr(numba, name)), name
    assert native.health == numba.health
    assert native.parameter_names == numba.parameter_names


def numba_only(monkeypatch):
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")


@needs_compiler
@pytest.mark.parametrize("case", list(CASES))
def test_the_c_port_estimates_what_numba_does_bit_for_bit(case, runs, monkeypatch):
    run, settings, options = CASES[case]
    recording = runs[run]
    native = DEKF(**settings).estimate(recording, **options)
    assert _dekf_native.library() is not None
    numba_only(monkeypatch)
    assert _dekf_native.library() is None
    numba = DEKF(**settings).estimate(recording, **options)
    assert_same_result(native, numba)
    if case == "a non-finite stop":
        assert numba.health.diverged
    if options.get("smooth"):
        assert not same_bytes(native.mean, DEKF(**settings).estimate(recording).mean)


def online_samples(recording):
    keys = ("e", "u")
    return [{key: float(recording[key][k]) for key in keys} for k in range(len(recording))]


def online_means(estimator, recording, samples):
    estimator.reset(recording.dt, t0=float(recording.t[0]))
    rows = []
    for sample in samples:
        estimate = estimator.update(sample)
        rows.append([estimate.mean[name] for name in estimator.parameter_names])
    return np.array(rows)


@needs_compiler
def test_online_updates_and_blocks_in_c_equal_numba_and_the_offline_run(runs, monkeypatch):
    recording = runs["gaps"]
    samples = online_samples(recording)
    settings = {"initial_variance": "causal", "initial": {"K_p": 1.5}}
    native = online_means(DEKF(**settings), recording, samples)
    offline = DEKF(**settings).estimate(recording)
    assert same_bytes(native, offline.mean)
    # a block of samples in one call, then the rest one by one
    blocked = DEKF(**settings)
    blocked.reset(recording.dt, t0=float(recording.t[0]))
    values = np.array([[s["e"], s["u"]] for s in samples[:700]])
    blocked.update_block(values)
    assert same_bytes(blocked.latest()[0], native[699])
    for sample in samples[700:]:
        blocked.update(sample)
    assert same_bytes(blocked.latest()[0], native[-1])
    numba_only(monkeypatch)
    assert same_bytes(online_means(DEKF(**settings), recording, samples), native)


@needs_compiler
def test_the_batched_step_in_c_equals_numba_with_restarts_and_idle_copies(runs, monkeypatch):
    recordings = [
        simulate(
            Pilot.typical("precision", "SI"), "SI", "popovici2017", seed=s, measurement_time=4.0
        )
        for s in range(3)
    ]
    estimator = DEKF(initial_variance="causal", initial={"K_p": 1.5})

    def batched():
        batch = FilterBatch(estimator, 3)
        batch.reset(recordings[0].dt)
        means = []
        for k in range(len(recordings[0])):
            signals = {key: np.array([r[key][k] for r in recordings]) for key in ("e", "u")}
            active = np.array([True, k % 7 != 0, True])
            batch.step(signals, active)
            if k == 150:
                batch.reset_copies([2])
            means.append(batch.latest()[0].copy())
        return np.array(means), batch

    native, batch = batched()
    assert batch._native is not None
    numba_only(monkeypatch)
    numba, batch = batched()
    assert batch._native is None
    assert same_bytes(native, numba)
    assert not same_bytes(native[:, 0], native[:, 1])  # the copies do differ


@pytest.fixture
def fresh_build_state(monkeypatch):
    """A process that has built nothing yet (the module's memory of builds emptied)."""
    monkeypatch.setattr(_native, "_LOADED", {})
    monkeypatch.setattr(_native, "_FAILED", {})
    monkeypatch.setattr(_dekf_native, "_CHECKED", {})


def test_without_a_compiler_numba_runs_the_same_numbers_and_says_why(
    runs, monkeypatch, tmp_path, fresh_build_state
):
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("PATH", str(tmp_path))  # and no cc either
    monkeypatch.setenv("NUMBA_CACHE_DIR", os.environ.get("NUMBA_CACHE_DIR", ""))
    assert _dekf_native.library() is None
    assert "no C compiler found" in _native.native_failure(_dekf_native.SOURCE)
    result = DEKF().estimate(runs["base"])
    monkeypatch.setenv("MANUALCONTROL_NATIVE", "0")
    assert same_bytes(result.mean, DEKF().estimate(runs["base"]).mean)
    assert "MANUALCONTROL_NATIVE=0" in _native.native_failure(_dekf_native.SOURCE)


@needs_compiler
def test_a_failed_build_says_so_and_leaves_nothing_behind(tmp_path):
    source = tmp_path / "broken.c"
    source.write_text("int f(void) { return undeclared_name; }\n")
    folder = tmp_path / "cache"
    with pytest.raises(_native.NativeBuildError, match=r"could not build broken\.c"):
        _native.build_library(source, _native._compiler(), folder)
    assert list(folder.iterdir()) == []


@needs_compiler
def test_a_library_is_built_once_per_source_and_anew_for_an_edited_one(tmp_path):
    source = tmp_path / "tiny.c"
    source.write_text("int answer(void) { return 42; }\n")
    folder = tmp_path / "cache"
    compiler = _native._compiler()
    first = _native.build_library(source, compiler, folder)
    stamp = first.stat().st_mtime_ns
    assert _native.build_library(source, compiler, folder) == first
    assert first.stat().st_mtime_ns == stamp
    assert ctypes.CDLL(str(first)).answer() == 42
    source.write_text("int answer(void) { return 43; }\n")
    second = _native.build_library(source, compiler, folder)
    assert second != first
    assert ctypes.CDLL(str(second)).answer() == 43
    assert sorted(p.name for p in folder.iterdir()) == sorted([first.name, second.name])


@needs_compiler
def test_an_edited_shared_header_rebuilds_the_library_that_includes_it(tmp_path):
    header = tmp_path / "shared.h"
    header.write_text("#define ANSWER 42\n")
    source = tmp_path / "tiny.c"
    source.write_text('#include "shared.h"\nint answer(void) { return ANSWER; }\n')
    assert _native.local_headers(source) == [header]
    folder = tmp_path / "cache"
    compiler = _native._compiler()
    first = _native.build_library(source, compiler, folder)
    assert ctypes.CDLL(str(first)).answer() == 42
    header.write_text("#define ANSWER 43\n")  # the source itself unchanged
    second = _native.build_library(source, compiler, folder)
    assert second != first
    assert ctypes.CDLL(str(second)).answer() == 43


def test_every_port_includes_the_shared_header_that_ships_beside_it():
    from manualcontrol.estimators import members

    folder = Path(members.__file__).parent
    for source in sorted(folder.glob("_*_native.c")):
        assert _native.local_headers(source) == [folder / "_native_common.h"], source.name
    assert (folder / "_native_common.h").is_file()


@needs_compiler
def test_a_c_port_whose_constants_differ_from_the_modules_is_refused(
    monkeypatch, fresh_build_state
):
    from manualcontrol.estimators import _pilot_core

    monkeypatch.setattr(_pilot_core, "SC_SIZE", SC_SIZE + 1)
    with pytest.raises(RuntimeError, match=r"constants .* differ .* edit the two together"):
        _dekf_native.library()


@needs_compiler
def test_a_compiler_command_of_several_words_builds_and_names_its_own_library(
    tmp_path, monkeypatch
):
    source = tmp_path / "tiny.c"
    source.write_text("int answer(void) { return ANSWER; }\n")
    folder = tmp_path / "cache"
    monkeypatch.setenv("CC", "cc -DANSWER=42")
    compiler = _native._compiler()
    assert compiler[1:] == ["-DANSWER=42"]
    built = _native.build_library(source, compiler, folder)
    assert ctypes.CDLL(str(built)).answer() == 42
    # the machine is part of the name: another one sharing the folder builds its own
    monkeypatch.setattr(_native.platform, "machine", lambda: "another-machine")
    assert _native.build_library(source, compiler, folder) != built


@needs_compiler
def test_a_library_that_does_not_load_is_built_in_the_next_folder(
    tmp_path, monkeypatch, fresh_build_state
):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "noexec"))
    load = ctypes.CDLL
    refused = []

    def no_exec_in_numba_cache(path, *arguments, **options):
        if str(tmp_path / "noexec") in str(path):
            refused.append(path)
            raise OSError("failed to map segment from shared object")
        return load(path, *arguments, **options)

    monkeypatch.setattr(_native.ctypes, "CDLL", no_exec_in_numba_cache)
    assert _dekf_native.library() is not None
    assert len(refused) == 1
    assert _native.native_failure(_dekf_native.SOURCE) == ""
