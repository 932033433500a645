"""envs.recording: validation, access, derived copies, and file round trips.

Files "from other sources" are made here with plain numpy, csv and scipy.io, so the
reading tests do not depend on our own writer.
"""

import copy
import csv
import dataclasses
import pickle
import re

import numpy as np
import pytest
import scipy.io

import manualcontrol.envs.recording as recording_module
from manualcontrol.envs.recording import (
    FILE_ALIASES,
    FORMAT_TAG,
    MEASURED_SIGNALS,
    SIGNAL_NAMES,
    MissingSignalError,
    Recording,
    load_recording,
    save_recording,
)

FORMATS = ("npz", "csv", "mat")


def simulated(n=400, dt=0.01, seed=0):
    """A recording with every kind of content: all signals, extras, NaN, parameters."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    ft = np.sin(2 * np.pi * 0.3 * t) + 0.1 * rng.standard_normal(n)
    fd = 0.5 * np.cos(2 * np.pi * 0.7 * t)
    y = rng.standard_normal(n) * 1e-3 + ft
    u = rng.standard_normal(n)
    n_remnant = 0.05 * rng.standard_normal(n)
    u[[5, 6, 7, n - 1]] = np.nan  # dropped samples, one stretch at the end
    y[[5, 6]] = np.nan
    u_model = rng.standard_normal(n) * 1e300  # huge and tiny magnitudes
    u_model[3] = -0.0
    u_model[4] = 5e-324
    u_model[10] = np.nan
    e = ft - y
    signals = {"t": t, "ft": ft, "fd": fd, "y": y, "e": e, "u": u, "n": n_remnant}
    signals["u_model"] = u_model
    parameters = {
        "K_p": 2.0 + 0.5 * np.tanh(t - t[n // 2]),
        "tau_v": np.full(n, 0.2 + 1 / 3),
    }
    metadata = {
        "seed": seed,
        "pilot": {"model": "McRuer", "gains": [1.5, 2.5e-7], "nominal": True},
        "note": "Zaal et al. — ÿ 日本",
        "missing": None,
    }
    return Recording(signals, dt, parameters, metadata)


def bits(array):
    return np.ascontiguousarray(array).view(np.uint64).tobytes()


def tiny(dt=0.01):
    t = np.arange(10) * dt
    return {"t": t, "u": np.linspace(0.0, 1.0, 10)}


# ------------------------------------------------------------------------- constants


def test_signal_name_constants():
    assert SIGNAL_NAMES == ("t", "ft", "fd", "y", "e", "u", "n")
    assert MEASURED_SIGNALS == ("y", "e", "u")
    assert set(FILE_ALIASES) == set(SIGNAL_NAMES)
    assert all(FILE_ALIASES[name][0] == name for name in SIGNAL_NAMES)


# ---------------------------------------------------------------------------- access


def test_access_by_attribute_item_and_names():
    t = np.arange(5) * 0.1
    rec = Recording({"u": np.ones(5), "extra": np.zeros(5), "t": t, "ft": t}, dt=0.1)
    assert rec.signal_names == ("t", "ft", "u", "extra")  # standard first, in order
    np.testing.assert_array_equal(rec.t, t)
    np.testing.assert_array_equal(rec["extra"], np.zeros(5))
    assert rec.u.dtype == np.float64
    assert len(rec) == 5
    assert rec.duration == pytest.approx(0.5)
    assert "u" in rec and "n" not in rec
    assert rec.parameter_names == ()
    assert dict(rec.metadata) == {}


def test_absent_signal_error_works_for_hasattr_and_getitem():
    rec = Recording({"t": np.arange(3) * 0.01, "ft": np.zeros(3), "u": np.zeros(3)}, 0.01)
    message = "Recording has no signal 'n'; it has: t, ft, u"
    assert not hasattr(rec, "n")
    with pytest.raises(AttributeError, match=re.escape(message)):
        _ = rec.n
    with pytest.raises(KeyError, match=re.escape(message)) as caught:
        _ = rec["n"]
    assert isinstance(caught.value, MissingSignalError)
    assert str(caught.value) == message


def test_recording_is_not_iterable():
    rec = Recording(tiny(), 0.01)
    with pytest.raises(TypeError):
        iter(rec)


def test_dropped_samples_and_stretches():
    u = np.array([np.nan, 1, 2, np.nan, np.nan, 5, 6, np.nan])
    rec = Recording({"t": np.arange(8) * 0.01, "u": u, "y": np.zeros(8)}, 0.01)
    np.testing.assert_array_equal(rec.dropped_samples(), np.isnan(u))
    assert rec.dropped_stretches("u") == [(0, 1), (3, 2), (7, 1)]
    assert rec.dropped_stretches("y") == []
    assert not rec.dropped_samples("y").any()


def test_repr_is_short_and_informative():
    text = repr(simulated())
    assert text.startswith("Recording(400 samples, dt=0.01, t=0.0..3.99")
    assert "parameters=(K_p, tau_v)" in text


# -------------------------------------------------------------------- immutability


def test_arrays_and_mappings_are_read_only_copies():
    source = np.arange(10) * 0.01
    u = np.ones(10)
    rec = Recording({"t": source, "u": u}, 0.01, {"K_p": np.ones(10)}, {"a": {"b": [1]}})
    u[0] = 99.0  # the caller's array stays theirs
    assert rec.u[0] == 1.0
    with pytest.raises(ValueError, match="read-only"):
        rec.u[0] = 2.0
    with pytest.raises(ValueError, match="read-only"):
        rec.parameters["K_p"][0] = 2.0
    with pytest.raises(TypeError):
        rec.signals["u"] = np.zeros(10)  # type: ignore[index]
    with pytest.raises(TypeError):
        rec.metadata["a"] = 1  # type: ignore[index]
    with pytest.raises(TypeError):
        rec.metadata["a"]["b"] = 2  # nested mappings are read-only too
    assert rec.metadata["a"]["b"] == (1,)  # lists are stored as tuples
    with pytest.raises(dataclasses.FrozenInstanceError):
        rec.dt = 0.02  # type: ignore[misc]


def test_pickle_copy_and_replace():
    rec = simulated(n=50)
    assert pickle.loads(pickle.dumps(rec)).equals(rec)
    assert copy.deepcopy(rec) == rec
    other = dataclasses.replace(rec, metadata={"seed": 1})
    assert other.metadata["seed"] == 1 and other.equals(rec.with_metadata()) is False


def test_metadata_accepts_numpy_values_and_gives_json():
    rec = Recording(tiny(), 0.01, metadata={"seed": np.int64(3), "w": np.array([1.0, 2.0])})
    assert rec.metadata_json() == '{"seed": 3, "w": [1.0, 2.0]}'
    assert type(rec.metadata["seed"]) is int


# ------------------------------------------------------------------------ validation


@pytest.mark.parametrize(
    ("signals", "dt", "error", "message"),
    [
        (tiny(), 0.0, ValueError, "dt must be > 0, got 0.0"),
        (tiny(), -0.01, ValueError, "dt must be > 0, got -0.01"),
        (tiny(), float("nan"), ValueError, "dt must be finite, got nan"),
        (tiny(), "0.01", TypeError, "dt must be a real number, got '0.01'"),
        ({"u": np.zeros(3)}, 0.01, ValueError, "signals must contain 't' (time in s); got: u"),
        ({"t": np.zeros(0)}, 0.01, ValueError, "signal 't' must hold at least one sample, got 0"),
        (
            {"t": np.arange(10) * 0.01, "u": np.zeros(9)},
            0.01,
            ValueError,
            "signal 'u' has length 9 but t has length 10",
        ),
        (
            {"t": np.arange(10) * 0.01, "u": np.zeros((10, 1))},
            0.01,
            ValueError,
            "signal 'u' must be 1-D, got shape (10, 1)",
        ),
        (
            {"t": np.arange(3) * 0.01, "u": ["a", "b", "c"]},
            0.01,
            TypeError,
            "signal 'u' must be a 1-D array of real numbers, got ['a', 'b', 'c']",
        ),
        (
            {"t": np.arange(3) * 0.01, "u": np.ones(3) * 1j},
            0.01,
            TypeError,
            "signal 'u' must be a 1-D array of real numbers",
        ),
        (
            tiny(),
            0.02,
            ValueError,
            "t is not uniformly sampled at dt=0.02, first deviation at index 1 "
            "(t[1]=0.01, expected 0.02)",
        ),
        (
            {"t": [0.0, 0.01, np.nan]},
            0.01,
            ValueError,
            "signal 't' must be finite, found 1 NaN value(s), the first at index 2; "
            "only y, e, u and extra signals may mark dropped samples with NaN",
        ),
        (
            {"t": np.arange(3) * 0.01, "fd": [0.0, 0.0, np.nan]},
            0.01,
            ValueError,
            "signal 'fd' must be finite, found 1 NaN value(s), the first at index 2",
        ),
        (
            {"t": np.arange(3) * 0.01, "n": [np.nan, 0.0, np.nan]},
            0.01,
            ValueError,
            "signal 'n' must be finite, found 2 NaN value(s), the first at index 0",
        ),
        (
            {"t": np.arange(3) * 0.01, "u": [0.0, np.nan, np.inf]},
            0.01,
            ValueError,
            "signal 'u' must not hold infinite values, found 1, the first at index 2 (inf)",
        ),
        (
            {"t": np.arange(3) * 0.01, "u_model": [-np.inf, 0.0, 0.0]},
            0.01,
            ValueError,
            "signal 'u_model' must not hold infinite values, found 1, the first at index 0 (-inf)",
        ),
        (
            {"t": np.arange(3) * 0.01, "u model": np.zeros(3)},
            0.01,
            ValueError,
            "signal name 'u model' is not allowed: names start with a letter and contain only "
            "ASCII letters, digits and underscores",
        ),
        (
            {"t": np.arange(3) * 0.01, "dt": np.zeros(3)},
            0.01,
            ValueError,
            "signal name 'dt' is reserved for the file formats "
            "(dt, metadata, recording_format and the prefix 'param__')",
        ),
        (
            {"t": np.arange(3) * 0.01, "param__K_p": np.zeros(3)},
            0.01,
            ValueError,
            "signal name 'param__K_p' is reserved",
        ),
        ({"t": np.arange(3) * 0.01, 3: np.zeros(3)}, 0.01, TypeError, "signal names must be"),
        ([np.arange(3)], 0.01, TypeError, "signals must be a mapping from signal name"),
    ],
)
def test_invalid_signals_are_rejected(signals, dt, error, message):
    with pytest.raises(error, match=re.escape(message)):
        Recording(signals, dt)


def test_non_uniform_time_names_first_deviation():
    t = np.arange(10) * 0.01
    t[4:] += 0.001
    message = (
        f"t is not uniformly sampled at dt=0.01, first deviation at index 4 "
        f"(t[4]={float(t[4])!r}, expected 0.04)"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording({"t": t}, 0.01)


def test_time_tolerance_is_relative_1e_9():
    t = 1000.0 + np.arange(10) * 0.01
    Recording({"t": t + 5e-7 * np.sin(np.arange(10))}, 0.01)  # within 1e-9 * 1000
    with pytest.raises(ValueError, match="first deviation at index 3"):
        Recording({"t": t + np.r_[0, 0, 0, 2e-6, np.zeros(6)]}, 0.01)


def test_measured_and_extra_signals_may_hold_nan():
    t = np.arange(3) * 0.01
    nan = [np.nan, 0.0, 0.0]
    rec = Recording({"t": t, "y": nan, "e": nan, "u": nan, "u_model": nan}, 0.01)
    assert all(rec.dropped_samples(name)[0] for name in ("y", "e", "u", "u_model"))


@pytest.mark.parametrize(
    ("parameters", "error", "message"),
    [
        ({"K_p": np.ones(9)}, ValueError, "parameter 'K_p' has length 9 but t has length 10"),
        (
            {"K_p": np.r_[np.ones(9), np.nan]},
            ValueError,
            "parameter 'K_p' must be finite, found 1 NaN value(s), the first at index 9",
        ),
        (
            {"tau_v": np.r_[np.inf, np.ones(9)]},
            ValueError,
            "parameter 'tau_v' must not hold infinite values, found 1, the first at index 0 (inf)",
        ),
        ({"1K": np.ones(10)}, ValueError, "parameter name '1K' is not allowed"),
        ([1.0], TypeError, "parameters must be a mapping from parameter name to 1-D array"),
    ],
)
def test_invalid_parameters_are_rejected(parameters, error, message):
    with pytest.raises(error, match=re.escape(message)):
        Recording(tiny(), 0.01, parameters)


@pytest.mark.parametrize(
    ("metadata", "error", "message"),
    [
        ({"seed": {1, 2}}, TypeError, "metadata['seed'] is not JSON-serialisable: got {1, 2}"),
        (
            {"pilot": {"gains": [1.0, object()]}},
            TypeError,
            "metadata['pilot']['gains'][1] is not JSON-serialisable: got <object object",
        ),
        (
            {"K": float("nan")},
            ValueError,
            "metadata['K'] must be finite to be stored as JSON, got nan",
        ),
        ({"a": {2: "b"}}, TypeError, "metadata['a'] has key 2; JSON object keys must be strings"),
        ({1: "a"}, TypeError, "metadata keys must be strings, got 1"),
        ("seed=1", TypeError, "metadata must be a mapping with string keys, got 'seed=1'"),
    ],
)
def test_invalid_metadata_is_rejected(metadata, error, message):
    with pytest.raises(error, match=re.escape(message)):
        Recording(tiny(), 0.01, metadata=metadata)


# -------------------------------------------------------------------- comparison


def test_equals_is_exact_and_treats_nan_as_equal():
    a = simulated(n=60)
    b = simulated(n=60)
    assert a.equals(b) and a == b
    assert a != a.with_signals(u=np.nan_to_num(a.u))
    assert a != a.with_metadata(seed=1)
    assert a != a.with_parameters(K_p=None)
    assert not a.equals("not a recording")
    assert a != 3
    with pytest.raises(TypeError):
        hash(a)


def test_allclose_tolerates_small_differences_only():
    a = simulated(n=60)
    b = a.with_signals(ft=a.ft * (1 + 1e-12))
    assert not a.equals(b)
    assert a.allclose(b)
    assert not a.allclose(b, rtol=0.0, atol=0.0)
    assert not a.allclose(a.with_signals(ft=a.ft + 1e-3))
    assert not a.allclose(a.with_signals(u_model=None))


# ------------------------------------------------------------------------- slicing


def test_slice_time_cuts_run_in_and_keeps_everything_aligned():
    rec = simulated(n=1000)
    cut = rec.slice_time(2.0)
    assert len(cut) == 800
    assert cut.dt == rec.dt
    assert cut.t[0] == 2.0 and cut.t[-1] == rec.t[-1]  # times keep their values
    for name in rec.signal_names:
        np.testing.assert_array_equal(cut[name], rec[name][200:])
    for name in rec.parameter_names:
        np.testing.assert_array_equal(cut.parameters[name], rec.parameters[name][200:])
    assert cut.metadata == rec.metadata
    with pytest.raises(ValueError, match="read-only"):
        cut.u[0] = 0.0


def test_slice_time_is_start_inclusive_stop_exclusive_with_float_slack():
    rec = simulated(n=1000)
    window = rec.slice_time(1.0, 2.0)
    assert len(window) == 100 and window.t[0] == 1.0 and window.t[-1] == pytest.approx(1.99)
    # 0.1 + 0.2 = 0.30000000000000004 > t[30] = 0.3; the sample at 0.3 is still kept.
    assert rec.slice_time(0.1 + 0.2).t[0] == rec.t[30]
    assert len(rec.slice_time(-5.0, 100.0)) == 1000


def test_slice_errors():
    rec = Recording(tiny(), 0.01)
    with pytest.raises(
        ValueError, match=re.escape("stop must be > start, got start=0.05, stop=0.05")
    ):
        rec.slice_time(0.05, 0.05)
    with pytest.raises(
        ValueError,
        match=re.escape(
            "slice_time(start=1.0, stop=None) selects no samples; the recording has t from 0.0 "
            "to 0.09"
        ),
    ):
        rec.slice_time(1.0)
    with pytest.raises(
        ValueError, match=re.escape("slice_samples needs 0 <= i0 < i1 <= 10, got i0=4, i1=4")
    ):
        rec.slice_samples(4, 4)
    with pytest.raises(ValueError, match=re.escape("got i0=-1, i1=10")):
        rec.slice_samples(-1)
    with pytest.raises(TypeError, match=re.escape("i1 must be an integer, got 2.5")):
        rec.slice_samples(0, 2.5)


def test_slice_samples():
    rec = simulated(n=100)
    part = rec.slice_samples(10, 20)
    assert len(part) == 10 and part.t[0] == rec.t[10]
    np.testing.assert_array_equal(part.u, rec.u[10:20])
    assert len(rec.slice_samples(90)) == 10


# ------------------------------------------------------------------- derived copies


def test_with_signals_adds_replaces_and_removes():
    rec = simulated(n=30)
    changed = rec.with_signals(u_hat=np.zeros(30), u=np.ones(30), n=None)
    assert "u_hat" in changed and "n" not in changed and changed.u[0] == 1.0
    assert "n" in rec and rec is not changed  # the original is untouched
    with pytest.raises(ValueError, match=re.escape("signal 't' cannot be removed")):
        rec.with_signals(t=None)
    with pytest.raises(MissingSignalError, match="Recording has no signal 'zz'"):
        rec.with_signals(zz=None)
    with pytest.raises(ValueError, match=re.escape("signal 'u' has length 3 but t has length 30")):
        rec.with_signals(u=np.zeros(3))


def test_with_parameters_and_metadata():
    rec = simulated(n=30)
    more = rec.with_parameters(omega_nms=np.full(30, 10.0), tau_v=None)
    assert more.parameter_names == ("K_p", "omega_nms")
    with pytest.raises(KeyError, match="Recording has no parameter 'zeta_nms'; it has: K_p, tau_v"):
        rec.with_parameters(zeta_nms=None)
    tagged = rec.with_metadata(seed=7, scenario="SI")
    assert tagged.metadata["seed"] == 7 and tagged.metadata["scenario"] == "SI"
    assert tagged.metadata["pilot"] == rec.metadata["pilot"]
    with pytest.raises(TypeError, match=re.escape("metadata['bad'] is not JSON-serialisable")):
        rec.with_metadata(bad={1})


def test_with_error_signal_computes_ft_minus_y_and_keeps_dropped_samples():
    t = np.arange(6) * 0.01
    ft = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 5.0])
    y = np.array([0.5, 0.5, np.nan, 2.0, 2.0, 2.0])
    rec = Recording({"t": t, "ft": ft, "y": y}, 0.01).with_error_signal()
    np.testing.assert_array_equal(rec.e, ft - y)
    assert rec.dropped_stretches("e") == [(2, 1)]
    with pytest.raises(
        ValueError,
        match=re.escape(
            "Recording already has signal 'e'; pass overwrite=True to recompute it as ft - y"
        ),
    ):
        rec.with_error_signal()
    assert rec.with_signals(e=np.zeros(6)).with_error_signal(overwrite=True).equals(rec)
    with pytest.raises(
        ValueError,
        match=re.escape(
            "with_error_signal needs signals 'ft' and 'y' to compute e = ft - y; the recording "
            "lacks 'ft' (it has: t, y)"
        ),
    ):
        Recording({"t": t, "y": y}, 0.01).with_error_signal()


# ----------------------------------------------------------------- own round trips


def assert_bit_identical(loaded, original):
    assert loaded.signal_names == original.signal_names
    assert loaded.parameter_names == original.parameter_names
    assert loaded.dt == original.dt
    for name in original.signal_names:
        assert loaded[name].dtype == np.float64
        assert bits(loaded[name]) == bits(original[name]), name
    for name in original.parameter_names:
        assert bits(loaded.parameters[name]) == bits(original.parameters[name]), name
    assert loaded.metadata_json() == original.metadata_json()
    assert loaded.metadata == original.metadata
    assert loaded.equals(original)


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("dt", [0.01, 1 / 60])
def test_round_trip_is_bit_exact(tmp_path, fmt, dt):
    original = simulated(n=300, dt=dt)
    path = original.save(tmp_path / f"run.{fmt}")
    assert path == tmp_path / f"run.{fmt}"
    assert_bit_identical(Recording.load(path), original)
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"run.{fmt}"]


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_keeps_alias_names_and_awkward_names_literally(tmp_path, fmt):
    # Extra signals named like file aliases ("x", "target", "time") or like numpy.savez
    # keywords ("file", "allow_pickle") come back under their own names.
    t = np.arange(4) * 0.5
    signals = {"t": t, "x": t + 1, "target": t + 2, "time": t + 3, "file": t, "allow_pickle": t}
    original = Recording(signals, 0.5)
    loaded = load_recording(save_recording(original, tmp_path / f"odd.{fmt}"))
    assert_bit_identical(loaded, original)
    assert "ft" not in loaded and "y" not in loaded


@pytest.mark.parametrize("fmt", FORMATS)
def test_round_trip_of_a_single_sample(tmp_path, fmt):
    original = Recording({"t": [3.0], "u": [np.nan]}, 0.25, {"K_p": [1.0]}, {"k": [1]})
    assert_bit_identical(Recording.load(original.save(tmp_path / f"one.{fmt}")), original)


def test_format_argument_overrides_the_suffix(tmp_path):
    original = simulated(n=20)
    path = original.save(tmp_path / "run.dat", format="csv")
    assert path.read_text().startswith(f"# recording_format: {FORMAT_TAG}\n# dt: 0.01\n")
    assert_bit_identical(Recording.load(path, format="csv"), original)
    upper = original.save(tmp_path / "RUN.MAT")
    assert_bit_identical(Recording.load(upper), original)


def test_csv_layout_marks_dropped_samples_and_prefixes_parameters(tmp_path):
    rec = Recording({"t": [0.0, 0.1], "u": [np.nan, 1.0]}, 0.1, {"K_p": [2.0, 2.0]})
    lines = rec.save(tmp_path / "r.csv").read_text().splitlines()
    assert lines[2] == "# metadata: {}"
    assert lines[3:] == ["t,u,param:K_p", "0.0,nan,2.0", "0.1,1.0,2.0"]


def test_npz_layout_loads_without_pickle(tmp_path):
    rec = simulated(n=20)
    with np.load(rec.save(tmp_path / "r.npz"), allow_pickle=False) as archive:
        assert set(archive.files) == {
            *rec.signal_names,
            "param__K_p",
            "param__tau_v",
            "dt",
            "metadata",
            "recording_format",
        }
        assert archive["dt"].item() == 0.01
        assert str(archive["recording_format"]) == FORMAT_TAG


def test_mat_layout_is_column_vectors(tmp_path):
    rec = simulated(n=20)
    contents = scipy.io.loadmat(rec.save(tmp_path / "r.mat"))
    assert contents["u"].shape == (20, 1)
    assert contents["param__K_p"].shape == (20, 1)
    assert contents["dt"].shape == (1, 1)
    assert str(contents["recording_format"][0]) == FORMAT_TAG


# ------------------------------------------------------------- files from elsewhere


def write_csv(path, header, rows, comments=(), delimiter=","):
    with open(path, "w", newline="") as handle:
        for comment in comments:
            handle.write(comment + "\n")
        writer = csv.writer(handle, delimiter=delimiter)
        writer.writerow(header)
        writer.writerows(rows)
    return path


def test_csv_from_an_experiment_with_aliases(tmp_path):
    n = 50
    t = np.arange(n) / 100
    target = np.sin(t)
    output = np.cos(t)
    rows = [
        [
            f"{t[i]:.2f}",
            repr(float(target[i])),
            "0.25",
            repr(float(output[i])),
            "" if i == 7 else str(i),
            "0",
        ]
        for i in range(n)
    ]
    path = write_csv(
        tmp_path / "trial.csv",
        ["time", "target", "disturbance", "output", "stick", "remnant"],
        rows,
        comments=["# subject 3, run 2"],
    )
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "ft", "fd", "y", "u", "n")
    assert rec.dt == 0.01  # inferred from decimal times, not a few ulps off
    np.testing.assert_array_equal(rec.ft, target)
    np.testing.assert_array_equal(rec.y, output)
    assert rec.dropped_stretches("u") == [(7, 1)]  # an empty field is a dropped sample
    assert "e" not in rec  # not invented
    np.testing.assert_array_equal(rec.with_error_signal().e, target - output)


def test_csv_aliases_ignore_case_and_other_delimiters(tmp_path):
    rows = [[f"{i * 0.02:.2f}", str(i), "nan"] for i in range(5)]
    path = write_csv(tmp_path / "t.csv", ["Time", "Stick", "Error"], rows, delimiter=";")
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "e", "u") and rec.dt == 0.02
    assert rec.dropped_samples("e").all()


@pytest.mark.parametrize("name", ["time_s", "Time_s", "time [s]", "Time (s)"])
def test_a_time_column_named_with_its_unit_in_seconds_is_the_time(tmp_path, name):
    rows = [[f"{i / 60:.6f}", str(i)] for i in range(6)]
    path = write_csv(tmp_path / "trial.csv", [name, "stick"], rows)
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "u") and rec.dt == pytest.approx(1 / 60, rel=1e-4)
    assert rec.metadata.get("ignored_columns", []) == []


def test_a_sample_period_named_t_s_is_not_taken_for_the_time(tmp_path):
    path = tmp_path / "trial.npz"
    np.savez(path, e=np.arange(4.0), u=np.ones(4), T_s=0.01)
    rec = Recording.load(path, dt=0.01)
    assert rec.signal_names == ("t", "e", "u") and rec.dt == 0.01
    assert "T_s" in rec.metadata["ignored_columns"]


def test_mat_from_matlab_with_column_and_row_vectors(tmp_path):
    n = 40
    t = np.arange(n) * 0.01
    scipy.io.savemat(
        tmp_path / "trial.mat",
        {
            "T": t.reshape(-1, 1),
            "f_t": np.sin(t).reshape(-1, 1),
            "x": np.cos(t).reshape(1, -1),
            "delta": np.arange(n, dtype=np.int16).reshape(-1, 1),
            "fs": 100.0,
            "subject": "S03",
            "info": {"date": "2019-01-01"},
            "freqs": np.arange(10.0),
        },
    )
    rec = Recording.load(tmp_path / "trial.mat")
    assert rec.signal_names == ("t", "ft", "y", "u")
    assert rec.dt == 0.01
    np.testing.assert_array_equal(rec.y, np.cos(t))
    np.testing.assert_array_equal(rec.u, np.arange(n, dtype=float))
    # fs, subject, the struct's field and freqs are not read, and are listed once each
    assert rec.parameter_names == ()
    assert dict(rec.metadata) == {"ignored_columns": ("fs", "subject", "info.date", "freqs")}


def test_mat_structs_and_matrices_from_a_lab(tmp_path):
    """A scalar struct's fields read as columns; a matrix's columns as name:1, name:2, ..."""
    n = 50
    t = np.arange(n) / 60.0
    scipy.io.savemat(
        tmp_path / "struct.mat",
        {"trial": {"t": t, "ft": np.sin(t), "y": np.cos(t), "u": 2 * t, "subject": "S01"}},
    )
    rec = Recording.load(tmp_path / "struct.mat")
    assert rec.signal_names == ("t", "ft", "y", "u")
    np.testing.assert_allclose(rec.u, 2 * t)
    assert rec.dt == pytest.approx(1 / 60)
    # the same struct through its qualified names
    by_name = Recording.load(
        tmp_path / "struct.mat", columns={"t": "trial.t", "u": "trial.y", "e": "trial.ft"}
    )
    np.testing.assert_allclose(by_name.u, np.cos(t))
    # a matrix of columns [t e u], as many labs save a trial
    scipy.io.savemat(tmp_path / "matrix.mat", {"data": np.column_stack([t, np.sin(t), 3 * t])})
    rec = Recording.load(
        tmp_path / "matrix.mat", columns={"t": "data:1", "e": "data:2", "u": "data:3"}
    )
    np.testing.assert_allclose(rec.e, np.sin(t))
    np.testing.assert_allclose(rec.u, 3 * t)
    # stored as rows (3 x n) it reads the same
    scipy.io.savemat(tmp_path / "rows.mat", {"data": np.vstack([t, np.sin(t), 3 * t])})
    same = Recording.load(
        tmp_path / "rows.mat", columns={"t": "data:1", "e": "data:2", "u": "data:3"}
    )
    np.testing.assert_allclose(same.u, rec.u)
    with pytest.raises(ValueError, match="data:4"):
        Recording.load(tmp_path / "matrix.mat", columns={"t": "data:1", "u": "data:4"})


def test_npz_from_elsewhere_with_parameters_and_dt_entry(tmp_path):
    n = 30
    t = 5.0 + np.arange(n) * 0.02
    np.savez(
        tmp_path / "trial.npz",
        t=t,
        fofu_t=np.ones(n),
        f_d=np.zeros(n),
        ce_output=np.arange(n),
        control=np.full(n, 0.5),
        param__K_p=np.full(n, 3.0),
        dt=0.02,
        junk=np.array([{"a": 1}], dtype=object),  # never read: needs pickle
    )
    rec = Recording.load(tmp_path / "trial.npz")
    assert rec.signal_names == ("t", "ft", "fd", "y", "u")
    assert rec.parameter_names == ("K_p",)
    assert rec.dt == 0.02 and rec.t[0] == 5.0
    with pytest.raises(ValueError, match=re.escape("entry 'junk' cannot be read")):
        Recording.load(tmp_path / "trial.npz", columns={"u_junk": "junk"})


def test_columns_mapping_overrides_and_extends_aliases(tmp_path):
    n = 20
    t = np.arange(n) * 0.05
    scipy.io.savemat(
        tmp_path / "proef.mat",
        {
            "tijd": t,
            "doel": np.sin(t),
            "stick": np.ones(n),
            "stick_filtered": np.full(n, 2.0),
            "model": np.full(n, 3.0),
            "kp": np.full(n, 4.0),
        },
    )
    rec = Recording.load(
        tmp_path / "proef.mat",
        columns={"ft": "doel", "u": "stick_filtered", "u_model": "model", "param:K_p": "kp"},
        time_column="tijd",
    )
    assert rec.signal_names == ("t", "ft", "u", "u_model")  # "stick" is not used twice
    assert rec.u[0] == 2.0 and rec["u_model"][0] == 3.0 and rec.parameters["K_p"][0] == 4.0
    assert rec.dt == 0.05
    same = Recording.load(tmp_path / "proef.mat", columns={"t": "tijd"})
    assert same.signal_names == ("t", "u") and same.u[0] == 1.0


def test_file_without_time_column_needs_dt(tmp_path):
    path = tmp_path / "no_time.npz"
    np.savez(path, e=np.arange(4.0), u=np.ones(4))
    message = (
        f"{path} has no time column (looked for t, time, T, time_s, time [s], time (s)) and "
        "no dt; pass dt= to build the "
        "time axis, or name the time column with time_column="
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)
    rec = Recording.load(path, dt=0.1)
    np.testing.assert_array_equal(rec.t, np.arange(4) * 0.1)


def test_explicit_dt_overrides_the_file_and_is_checked(tmp_path):
    path = tmp_path / "r.npz"
    np.savez(path, t=np.arange(5) * 0.01, dt=0.01)
    with pytest.raises(
        ValueError,
        match=re.escape(
            f"{path}: dt=0.02 contradicts the time column 't', which steps uniformly by 0.01 s"
        ),
    ):
        Recording.load(path, dt=0.02)
    with pytest.raises(ValueError, match=re.escape("dt must be > 0, got -1.0")):
        Recording.load(path, dt=-1.0)


# ------------------------------------------------------------------- loading errors


def test_missing_mapped_column_is_named(tmp_path):
    path = tmp_path / "file.mat"
    scipy.io.savemat(path, {"t": np.arange(3.0), "x": np.zeros(3), "e": np.zeros(3)})
    message = f"{path} has no column 'stick' for signal 'u'; columns present: t, x, e"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path, columns={"u": "stick"})


def test_columns_of_different_lengths(tmp_path):
    path = tmp_path / "file.mat"
    scipy.io.savemat(path, {"time": np.arange(100) * 0.01, "stick": np.zeros(99)})
    message = f"{path}: column 'stick' has length 99 but the time column 'time' has length 100"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)


def test_non_uniform_time_in_file(tmp_path):
    path = tmp_path / "jitter.npz"
    t = np.arange(100) * 0.01
    t[50] += 0.003
    np.savez(path, t=t, u=np.zeros(100))
    message = f"{path}: t is not uniformly sampled at dt=0.01, first deviation at index 50"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)


def test_infinite_values_in_file(tmp_path):
    path = write_csv(tmp_path / "inf.csv", ["t", "u"], [[0.0, 1.0], [0.1, "inf"], [0.2, 0.0]])
    message = f"{path}: signal 'u' must not hold infinite values, found 1, the first at index 1"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)


def test_unknown_suffix_on_load_and_save(tmp_path):
    path = tmp_path / "run.xlsx"
    path.write_text("t\n0\n")
    message = (
        f"{path}: cannot tell the file format from the suffix '.xlsx' (a spreadsheet workbook: "
        "save it as CSV); allowed suffixes: .npz, .csv, .mat, or text as .tsv, .txt, .dat (or "
        "pass format='npz', 'csv' or 'mat')"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)
    # text suffixes are read, not written: a saved recording says what it is by its suffix
    message = (
        f"{tmp_path / 'run.txt'}: cannot tell the file format from the suffix '.txt'; allowed "
        "suffixes: .npz, .csv, .mat (or pass format='npz', 'csv' or 'mat')"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording(tiny(), 0.01).save(tmp_path / "run.txt")
    with pytest.raises(ValueError, match=re.escape("suffix ''")):
        Recording(tiny(), 0.01).save(tmp_path / "run")


def test_text_of_other_separators_and_suffixes_reads_as_the_csv_does(tmp_path):
    columns = {
        "time": np.arange(6) / 60,
        "stick": np.array([0.25, -1.5, 0.0, np.nan, 2.0e-3, 1.0]),
        "x": np.array([1.0, 0.5, -0.25, 0.125, -1.0e-3, 3.0]),
    }
    rows = [[repr(float(value)) for value in row] for row in zip(*columns.values(), strict=True)]
    reference = Recording.load(write_csv(tmp_path / "run.csv", list(columns), rows))

    def text(separator, comma=False, lost=""):
        def cell(value):
            value = lost if value == "nan" else value
            return value.replace(".", ",") if comma else value

        lines = [separator.join(columns)] + [separator.join(map(cell, row)) for row in rows]
        return "\n".join(lines) + "\n"

    files = {
        "semicolon.csv": text(";", comma=True),  # a European spreadsheet's export
        "tab.tsv": text("\t"),
        "tab-comma.txt": text("\t", comma=True),
        "aligned.dat": text("   ", lost="nan"),  # a logger's aligned columns
    }
    for name, contents in files.items():
        (tmp_path / name).write_text(contents)
        read = Recording.load(tmp_path / name)
        assert read.dt == reference.dt, name
        for signal in ("t", "u", "y"):
            assert np.array_equal(read[signal], reference[signal], equal_nan=True), (name, signal)


def test_a_commented_header_over_decimal_commas_and_a_one_column_name_with_a_space(tmp_path):
    # "# t;u;y" above "0,00;1,5;2": the row read in the comment's separator, as numbers
    for separator in (";", "\t", " "):
        path = tmp_path / "commented.txt"
        path.write_text(
            f"# dt: 0,01\n# t{separator}u{separator}y\n"
            + "".join(f"0,0{k}{separator}1,5{separator}-2\n" for k in range(3))
        )
        read = Recording.load(path)
        assert read.dt == 0.01 and list(read.t) == [0.0, 0.01, 0.02], separator
        assert list(read.u) == [1.5] * 3 and list(read.y) == [-2.0] * 3, separator
    # a header of one name with a space is that name, not two space-separated columns
    path = tmp_path / "one.csv"
    path.write_text("# dt: 0.01\nstick pos\n0.5\n0.6\n")
    assert list(Recording.load(path, columns={"u": "stick pos"}).u) == [0.5, 0.6]


def test_a_decimal_comma_is_refused_where_the_separator_is_a_comma_and_a_grouped_number_anywhere(
    tmp_path,
):
    path = tmp_path / "comma.csv"
    path.write_text('t,u\n0,"0,5"\n0.1,1\n')
    with pytest.raises(ValueError, match=re.escape("line 2, column 'u': cannot read '0,5'")):
        Recording.load(path)
    path = tmp_path / "grouped.csv"
    path.write_text("t;u\n0;1.234,5\n0,1;1\n")
    with pytest.raises(ValueError, match=re.escape("line 2, column 'u': cannot read '1.234,5'")):
        Recording.load(path)
    # beside decimal points, a comma groups thousands: refused, not read as 1.234
    path = tmp_path / "thousands.tsv"
    path.write_text("t\tu\n0.0\t0.5\n0.1\t1,234\n")
    with pytest.raises(ValueError, match=re.escape("line 3, column 'u': cannot read '1,234'")):
        Recording.load(path)


def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such recording file"):
        Recording.load(tmp_path / "absent.npz")


def test_time_column_needs_two_samples_to_infer_dt(tmp_path):
    path = write_csv(tmp_path / "one.csv", ["t", "u"], [[0.0, 1.0]])
    message = f"{path}: cannot infer dt from the time column 't' with 1 sample(s); pass dt="
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)
    assert len(Recording.load(path, dt=0.01)) == 1


def test_decreasing_time_column(tmp_path):
    path = write_csv(tmp_path / "back.csv", ["t"], [[0.2], [0.1], [0.0]])
    with pytest.raises(
        ValueError, match=re.escape(f"{path}: cannot infer dt from the time column")
    ):
        Recording.load(path)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("t,u\n0,1\n0.1,2,3\n", "line 3 has 3 fields but the header names 2 columns"),
        ("t,u\n0,1\n0.1,abc\n", "line 3, column 'u': cannot read 'abc' as a number"),
        ("0,1\n0.1,2\n", "has no header row naming its columns (line 1 holds numbers)"),
        ("t,u,u\n0,1,1\n", "line 1: the header row names column 'u' twice"),
        ("# only a comment\n", "has no header row naming its columns"),
        ("# dt: fast\nt\n0\n", "cannot read the '# dt:' header 'fast' as a number"),
        ("# metadata: {oops\nt\n0\n", "metadata is not valid JSON"),
        ("# metadata: [1]\nt\n0\n", "metadata must be a JSON object, got [1]"),
        ("# recording_format: manualcontrol.recording/9\nt\n0\n", "is tagged recording_format="),
        ("t,e\n0,1\n0.1,\n0.2,nan\n", None),  # empty and "nan" fields are dropped samples
    ],
)
def test_csv_problems_are_named(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    if message is None:
        assert Recording.load(path).dropped_stretches("e") == [(1, 2)]
        return
    with pytest.raises(ValueError, match=re.escape(f"{path}")) as caught:
        Recording.load(path)
    assert message in str(caught.value)


def test_unreadable_binary_files(tmp_path):
    garbage = tmp_path / "garbage.npz"
    garbage.write_bytes(b"\x00\x01 not a zip archive" * 10)
    with pytest.raises(ValueError, match=re.escape(f"{garbage} is not a readable .npz file")):
        Recording.load(garbage)
    single = tmp_path / "single.npz"
    with open(single, "wb") as handle:
        np.save(handle, np.arange(3.0))
    with pytest.raises(ValueError, match=re.escape(f"{single} holds a single array")):
        Recording.load(single)
    not_mat = tmp_path / "garbage.mat"
    not_mat.write_bytes(b"\x01" * 200)
    with pytest.raises(ValueError, match=re.escape(f"{not_mat} is not a readable .mat file")):
        Recording.load(not_mat)


def test_matlab_v73_file_gets_a_clear_message(tmp_path):
    path = tmp_path / "hdf5.mat"
    header = b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116, b" ") + b"\x00" * 8
    path.write_bytes(header + b"\x00\x02IM" + b"\x00" * 512)
    with pytest.raises(ValueError, match=re.escape(f"{path} is a MATLAB v7.3 (HDF5) file")):
        Recording.load(path)


def test_non_numeric_or_matrix_columns(tmp_path):
    path = tmp_path / "odd.mat"
    scipy.io.savemat(path, {"t": np.arange(4) * 0.01, "u": np.zeros((4, 2)), "who": "S03"})
    with pytest.raises(
        ValueError,
        match=re.escape(
            f"{path}: column 'u' for signal 'u' must be a vector, got shape (4, 2) (pick one "
            "of its columns: 'u:1' .. 'u:2')"
        ),
    ):
        Recording.load(path)
    np.testing.assert_array_equal(Recording.load(path, columns={"u": "u:2"}).u, 0.0)
    with pytest.raises(ValueError, match=re.escape("column 'who' for signal 'e' is not numeric")):
        Recording.load(path, columns={"e": "who", "u": "t"})


def test_invalid_load_arguments(tmp_path):
    path = tmp_path / "r.npz"
    Recording(tiny(), 0.01).save(path)
    with pytest.raises(
        ValueError, match=re.escape("time_column='a' conflicts with columns['t']='b'")
    ):
        Recording.load(path, columns={"t": "b"}, time_column="a")
    with pytest.raises(ValueError, match=re.escape("signal name 'u-2' is not allowed")):
        Recording.load(path, columns={"u-2": "u"})
    with pytest.raises(TypeError, match=re.escape("columns['u'] must be a column name (str)")):
        Recording.load(path, columns={"u": 3})


def test_mat_names_longer_than_matlab_allows(tmp_path):
    rec = Recording({**tiny(), "s" + "x" * 63: np.zeros(10)}, 0.01)
    with pytest.raises(ValueError, match=re.escape("MATLAB allows at most 63")):
        rec.save(tmp_path / "long.mat")
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------- atomic write


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("existing", [True, False])
def test_failed_save_leaves_old_file_and_no_debris(tmp_path, monkeypatch, fmt, existing):
    target = tmp_path / f"run.{fmt}"
    old = simulated(n=20)
    if existing:
        old.save(target)
        before = target.read_bytes()

    def broken_writer(recording, path):
        path.write_bytes(b"half a file")
        raise OSError("disk full")

    monkeypatch.setattr(recording_module, f"_write_{fmt}", broken_writer)
    with pytest.raises(OSError, match="disk full"):
        simulated(n=30, seed=1).save(target)
    if existing:
        assert target.read_bytes() == before
        assert Recording.load(target).equals(old)
        assert [p.name for p in tmp_path.iterdir()] == [target.name]
    else:
        assert list(tmp_path.iterdir()) == []


def test_save_replaces_an_existing_file(tmp_path):
    target = tmp_path / "run.npz"
    simulated(n=20).save(target)
    newer = simulated(n=30, seed=2)
    newer.save(target)
    assert Recording.load(target).equals(newer)
    assert [p.name for p in tmp_path.iterdir()] == ["run.npz"]
