"""Laboratories' own trial files: what Recording.load accepts, and what it refuses and how.

Each file is written here the way lab software writes them (a commented header, a trailing
separator, float32 or clock time stamps, milliseconds), so every accepted form is pinned
by the values it loads and every refusal by its message. The command-line wording of the
same refusals (``manualcontrol identify``) is tested at the end.
"""

import re

import numpy as np
import pytest
import scipy.io

from manualcontrol.bench.cli import EXIT_USAGE, UsageError, _load_trial, build_parser, main
from manualcontrol.envs.recording import (
    MissingColumnError,
    MissingSignalError,
    NonUniformTimeError,
    Recording,
    load_recording,
)


def row(*values):
    """One CSV row, each number in its shortest exact form."""
    return ",".join(repr(float(value)) for value in values)


def write_lines(path, lines):
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def trial_columns(n=200, dt=0.01):
    t = np.arange(n) * dt
    return t, np.sin(t), 0.5 * np.cos(3 * t), np.cos(t), 0.1 * t


def clock_stamps(n=3600, seed=0, jitter=4e-4, hiccup=0.058):
    """Stamps of a 60 Hz logger on the wall clock: uneven intervals, one late frame."""
    rng = np.random.default_rng(seed)
    steps = 1 / 60 + rng.uniform(-jitter, jitter, n - 1)
    if hiccup:
        steps[n // 3] += hiccup
    return 1.7e9 + np.concatenate(([0.0], np.cumsum(steps)))


def jitter_of(t):
    """Largest deviation from the grid through the first and last stamps, and where."""
    dt = (t[-1] - t[0]) / (t.shape[0] - 1)
    deviation = np.abs(t - (t[0] + np.arange(t.shape[0]) * dt))
    index = int(np.argmax(deviation))
    return float(deviation[index]), index


# ------------------------------------------------------------------ a commented header


@pytest.mark.parametrize(
    "header",
    [
        "# t,target,disturbance,stick,output",
        "#t,target,disturbance,stick,output",
        "## t, target, disturbance, stick, output",
    ],
)
def test_header_written_as_a_comment_names_the_columns(tmp_path, header):
    t, ft, fd, y, u = trial_columns()
    rows = [f"{a:.3e},{row(b, c, d, e)}" for a, b, c, d, e in zip(t, ft, fd, u, y, strict=True)]
    path = write_lines(tmp_path / "trial.csv", ["# subject 3, run 2", header, *rows])
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "ft", "fd", "y", "u")
    assert len(rec) == 200 and rec.dt == 0.01
    np.testing.assert_array_equal(rec.t, [float(f"{a:.3e}") for a in t])  # as written
    np.testing.assert_array_equal(rec.ft, ft)
    np.testing.assert_array_equal(rec.fd, fd)
    np.testing.assert_array_equal(rec.u, u)  # the "stick" column
    np.testing.assert_array_equal(rec.y, y)  # the "output" column
    assert "ignored_columns" not in rec.metadata


def test_commented_header_with_other_separator_and_a_dropped_first_sample(tmp_path):
    path = write_lines(
        tmp_path / "trial.csv",
        ["# dt: 0.02", "# time;error;stick", "0;;1.5", "0.02;0.25;2", "0.04;0.5;2.5"],
    )
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "e", "u") and rec.dt == 0.02
    np.testing.assert_array_equal(rec.e, [np.nan, 0.25, 0.5])
    np.testing.assert_array_equal(rec.u, [1.5, 2.0, 2.5])


def test_a_comment_that_does_not_fit_the_rows_is_not_a_header(tmp_path):
    path = write_lines(tmp_path / "trial.csv", ["# t,u", "0,1,2", "0.01,1,2"])
    message = f"{path} has no header row naming its columns (line 2 holds numbers)"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)


def test_a_comment_after_the_header_row_is_skipped(tmp_path):
    path = write_lines(tmp_path / "trial.csv", ["t,u", "# t,u,junk", "0,1", "0.01,2"])
    np.testing.assert_array_equal(Recording.load(path).u, [1.0, 2.0])


def test_byte_order_mark_does_not_rename_the_first_column(tmp_path):
    path = tmp_path / "excel.csv"
    path.write_text("\ufefft,u\n0,1\n0.01,2\n", encoding="utf-8")
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "u") and rec.dt == 0.01


# ------------------------------------------------------------ an empty trailing column


@pytest.mark.parametrize(
    ("header", "ending"),
    [("t,u,stick_raw,", ","), ("t,u,stick_raw", ","), ("t,u,stick_raw,", "")],
)
def test_empty_trailing_column_is_dropped(tmp_path, header, ending):
    rows = [f"{i / 100!r},{i},{2 * i}{ending}" for i in range(5)]
    rec = Recording.load(write_lines(tmp_path / "trial.csv", [header, *rows]))
    assert rec.signal_names == ("t", "u") and rec.dt == 0.01
    np.testing.assert_array_equal(rec.u, np.arange(5.0))
    assert rec.metadata["ignored_columns"] == ("stick_raw",)


def test_unnamed_trailing_column_holding_values_is_refused(tmp_path):
    path = write_lines(tmp_path / "trial.csv", ["t,u,", "0,1,", "0.01,2,7"])
    message = (
        f"{path} line 3: the last column has no name in the header but holds '7' here; name "
        "it in the header row (only an unnamed column that is empty in every row is dropped)"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)


def test_empty_column_name_elsewhere_is_still_refused(tmp_path):
    path = write_lines(tmp_path / "trial.csv", ["t,,u", "0,1,2"])
    message = f"{path} line 1: the header row has an empty column name"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)


# ---------------------------------------------------------------------- ignored columns


def test_unmapped_columns_are_listed_once_in_the_metadata(tmp_path):
    path = write_lines(
        tmp_path / "trial.csv",
        ["time,Stick,frame,param:K_p,comment_code"]
        + [f"{i / 100},{i},{i + 7},2.5,3" for i in range(4)],
    )
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "u") and rec.parameter_names == ("K_p",)
    assert rec.metadata["ignored_columns"] == ("frame", "comment_code")
    # mapping a column takes it off the list
    mapped = Recording.load(path, columns={"frame_number": "frame"})
    np.testing.assert_array_equal(mapped["frame_number"], np.arange(4.0) + 7)
    assert mapped.metadata["ignored_columns"] == ("comment_code",)


def test_ignored_mat_columns_count_struct_fields_and_matrix_columns_once(tmp_path):
    t = np.arange(30) / 60
    path = tmp_path / "lab.mat"
    scipy.io.savemat(
        path,
        {
            "trial": {"t": t, "u": 2 * t, "subject": "S01"},
            "data": np.column_stack([t, np.sin(t), 3 * t]),
        },
    )
    rec = Recording.load(path)
    assert rec.signal_names == ("t", "u")
    assert rec.metadata["ignored_columns"] == ("trial.subject", "data:1", "data:2", "data:3")
    rec = Recording.load(path, columns={"e": "data:2"})
    np.testing.assert_allclose(rec.e, np.sin(t))
    assert rec.metadata["ignored_columns"] == ("trial.subject", "data:1", "data:3")


def test_own_files_have_no_ignored_columns(tmp_path):
    t, *_, u = trial_columns(20)
    rec = Recording({"t": t, "u": u, "u_model": 2 * u}, 0.01)
    for suffix in ("csv", "npz", "mat"):
        assert Recording.load(rec.save(tmp_path / f"own.{suffix}")) == rec


# ------------------------------------------------------------------ a missing signal


def test_required_signal_missing_lists_the_columns_and_the_mapping(tmp_path):
    path = write_lines(
        tmp_path / "trial.csv", ["time,target,joystick"] + [f"{i / 100},0,{i}" for i in range(4)]
    )
    message = (
        f"{path} has no column for signal 'u' (pilot control output): looked for u, stick, "
        "control, delta, in any case; columns in the file: time, target, joystick (read as "
        "no signal: joystick); map one with columns={'u': 'COLUMN'}"
    )
    with pytest.raises(MissingColumnError, match=re.escape(message)) as caught:
        Recording.load(path, require=("u",))
    # callers catching a bad file (ValueError) or a missing signal (KeyError) still do
    assert isinstance(caught.value, ValueError) and isinstance(caught.value, MissingSignalError)
    assert isinstance(caught.value, KeyError) and str(caught.value) == message
    assert caught.value.columns == ("time", "target", "joystick")
    # the mapping the message names fixes it
    rec = Recording.load(path, columns={"u": "joystick"}, require=("u",))
    np.testing.assert_array_equal(rec.u, np.arange(4.0))


def test_require_is_checked(tmp_path):
    path = write_lines(tmp_path / "trial.csv", ["t,u", "0,1", "0.01,2"])
    with pytest.raises(TypeError, match=re.escape("require must be a list or tuple of signal")):
        Recording.load(path, require="u")
    with pytest.raises(ValueError, match=re.escape("each name in require must be one of 't'")):
        Recording.load(path, require=("stick",))
    with pytest.raises(TypeError, match=re.escape("resample must be True or False, got 'yes'")):
        Recording.load(path, resample="yes")
    with pytest.raises(
        ValueError, match=re.escape("time_unit must be one of 's', 'ms', got 'min'")
    ):
        Recording.load(path, time_unit="min")


# -------------------------------------------------------------------- time stamps


def test_float32_time_stamps_are_read_as_the_uniform_grid(tmp_path):
    n = 36_000  # ten minutes at 60 Hz
    t32 = np.arange(n, dtype=np.float32) * np.float32(1 / 60)
    u = np.sin(np.arange(n) / 100)
    path = write_lines(
        tmp_path / "float32.csv",
        ["t,u"] + [f"{a},{float(b)!r}" for a, b in zip(t32, u, strict=True)],
    )
    deviation, _ = jitter_of(t32.astype(np.float64))
    assert 1e-7 < deviation < 1e-2 / 60  # off the grid by rounding only
    rec = Recording.load(path)
    assert rec.dt == pytest.approx(1 / 60, rel=1e-6)
    np.testing.assert_array_equal(rec.t, rec.t[0] + np.arange(n) * rec.dt)  # the grid
    np.testing.assert_allclose(rec.t, t32, rtol=0, atol=1e-2 / 60)
    np.testing.assert_array_equal(rec.u, u)
    assert "resampled" not in rec.metadata
    # with the lab's nominal dt given, the stamps are read as that grid
    given = Recording.load(path, dt=1 / 60)
    assert given.dt == 1 / 60
    np.testing.assert_array_equal(given.t, np.arange(n) * (1 / 60))


@pytest.mark.parametrize(("jitter", "hiccup"), [(4e-4, 0.058), (4e-4, 0.0)])
def test_clock_time_stamps_with_jitter_are_refused_with_the_jitter(tmp_path, jitter, hiccup):
    t = clock_stamps(jitter=jitter, hiccup=hiccup)
    u = np.sin(t - t[0])
    path = write_lines(
        tmp_path / "clock.csv", ["t,u"] + [row(a, b) for a, b in zip(t, u, strict=True)]
    )
    deviation, index = jitter_of(t)
    assert deviation > 1e-2 / 60  # more than rounding of the stamps
    with pytest.raises(NonUniformTimeError) as caught:
        Recording.load(path)
    text = str(caught.value)
    assert text.startswith(f"{path}: t is not uniformly sampled at dt=")
    assert (
        f"the time stamps of column 't' deviate from the uniform grid t[0] + i*dt by up to "
        f"{1e3 * deviation:.3g} ms (sample {index}, t={float(t[index])!r}), more than the "
        "0.167 ms (1 % of dt) that rounding of the stamps explains"
    ) in text
    median = float(np.median(np.diff(t)))
    assert text.endswith(
        "pass resample=True to interpolate every signal linearly onto a uniform grid at the "
        f"median sample interval ({median:.6g} s) from the first time stamp"
    )
    error = caught.value
    assert error.max_deviation == pytest.approx(deviation) and error.max_index == index
    # the same stamps given directly are refused too: the tolerance is relative to dt
    with pytest.raises(ValueError, match="t is not uniformly sampled"):
        Recording({"t": t}, (t[-1] - t[0]) / (t.shape[0] - 1))


def test_resample_interpolates_onto_a_uniform_grid_at_the_median_interval(tmp_path):
    t = clock_stamps()
    u = np.sin(t - t[0])
    u[1000] = np.nan  # a dropped sample
    ft = np.cos(t - t[0])
    path = write_lines(
        tmp_path / "clock.csv",
        ["time,target,stick,param:K_p"]
        + [row(a, b, c, 2 + (a - t[0])) for a, b, c in zip(t, ft, u, strict=True)],
    )
    rec = Recording.load(path, resample=True)
    median = float(np.median(np.diff(t)))
    assert rec.dt == median
    count = int(np.floor((t[-1] - t[0]) / median)) + 1
    grid = t[0] + np.arange(count) * median
    np.testing.assert_array_equal(rec.t, grid)  # from the first stamp: nothing subtracted
    np.testing.assert_array_equal(rec.ft, np.interp(grid, t, ft))
    np.testing.assert_array_equal(rec.parameters["K_p"], np.interp(grid, t, 2 + (t - t[0])))
    np.testing.assert_allclose(rec.ft, np.cos(grid - t[0]), atol=1e-3)  # linear is close
    near = np.flatnonzero(np.abs(grid - t[1000]) < median)
    assert np.isnan(rec.u[near]).all() and np.isnan(rec.u).sum() == near.size
    deviation, _ = jitter_of(t)
    assert dict(rec.metadata["resampled"]) == {
        "from_jitter_ms": 1e3 * deviation,
        "dt": median,
        "samples_in_file": t.shape[0],
        "method": "linear interpolation",
    }
    # a given dt is the grid's spacing
    given = Recording.load(path, dt=1 / 60, resample=True)
    assert given.dt == 1 / 60 and given.metadata["resampled"]["dt"] == 1 / 60
    np.testing.assert_array_equal(given.t, t[0] + np.arange(given.t.shape[0]) * (1 / 60))


def test_resample_leaves_uniform_files_alone(tmp_path):
    t, *_, u = trial_columns()
    path = write_lines(
        tmp_path / "trial.csv", ["t,u"] + [row(a, b) for a, b in zip(t, u, strict=True)]
    )
    assert Recording.load(path, resample=True) == Recording.load(path)
    assert "resampled" not in Recording.load(path, resample=True).metadata
    assert load_recording(path, resample=True, require=["u"]) == Recording.load(path)


def test_time_stamps_that_go_back_or_repeat_are_refused_as_such(tmp_path):
    # rows out of order are not a clock's jitter: resampling would not mend them
    path = write_lines(tmp_path / "back.csv", ["t,u", "0,0", "0.02,1", "0.01,2", "0.05,3"])
    message = (
        f"{path}: the time column 't' must increase, but t[2]=0.01 follows t[1]=0.02 (1 such "
        "step(s)): rows out of order or repeated; sort or mend them"
    )
    for resample in (False, True):
        with pytest.raises(ValueError, match=re.escape(message)):
            Recording.load(path, resample=resample)
    repeated = write_lines(tmp_path / "dup.csv", ["t,u", "0,0", "0.01,1", "0.01,2", "0.02,3"])
    with pytest.raises(ValueError, match=re.escape("t[2]=0.01 follows t[1]=0.01")):
        Recording.load(repeated)


def test_a_dt_that_contradicts_the_time_column_is_named(tmp_path):
    path = write_lines(tmp_path / "tagged.csv", ["# dt: 0.02", "t,u", "0,0", "0.01,1", "0.02,2"])
    message = f"{path}: the file's dt entry 0.02 s contradicts the time column 't'"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)
    empty = write_lines(tmp_path / "empty.csv", ["t,u"])
    with pytest.raises(ValueError, match=re.escape(f"{empty} has no samples: its columns")):
        Recording.load(empty)


def test_time_column_must_be_finite_with_a_given_dt(tmp_path):
    path = write_lines(tmp_path / "nan.csv", ["t,u", "0,0", ",1", "0.02,2"])
    message = f"{path}: the time column 't' must be finite, found nan at index 1"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path, dt=0.01)


# ----------------------------------------------------------------------- milliseconds


def ms_file(tmp_path, step_ms=10.0, n=50):
    rows = [f"{i * step_ms:g},{i},{-i}" for i in range(n)]
    return write_lines(tmp_path / "ms.csv", ["time_ms,stick,error", *rows])


def test_time_step_that_looks_like_milliseconds_is_refused_with_the_hint(tmp_path):
    path = ms_file(tmp_path)
    message = (
        f"{path}: the time column 'time_ms' steps by 10 per sample; in seconds that is 0.1 Hz, "
        "far slower than manual-control data are sampled, and in milliseconds 100 Hz: it "
        "looks like milliseconds: pass time_unit='ms' (or time_unit='s' if the file really "
        "is in seconds)"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path, columns={"t": "time_ms"})


def test_time_unit_ms_reads_milliseconds_and_s_keeps_seconds(tmp_path):
    path = ms_file(tmp_path)
    rec = Recording.load(path, columns={"t": "time_ms"}, time_unit="ms")
    assert rec.dt == 0.01
    np.testing.assert_array_equal(rec.t, np.arange(50) * 10.0 / 1000)  # 350 ms is 0.35 s
    np.testing.assert_array_equal(rec.u, np.arange(50.0))
    slow = Recording.load(path, columns={"t": "time_ms"}, time_unit="s")
    assert slow.dt == 10.0
    # outside 1-100 nothing is guessed
    assert Recording.load(ms_file(tmp_path, step_ms=0.5), columns={"t": "time_ms"}).dt == 0.5


def test_time_unit_ms_scales_a_dt_entry_and_not_our_own_files(tmp_path):
    path = tmp_path / "lab.npz"
    np.savez(path, time=np.arange(5) * 20.0, stick=np.zeros(5), dt=20.0)
    assert Recording.load(path, time_unit="ms").dt == 0.02
    own = Recording({"t": np.arange(5) * 0.01, "u": np.zeros(5)}, 0.01).save(tmp_path / "r.npz")
    message = (
        f"{own} was written by Recording.save, which stores time in seconds; a time unit of "
        "'ms' is for files from elsewhere"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(own, time_unit="ms")


# ------------------------------------------------------------------- the command line


def load_trial(*argv):
    return _load_trial(build_parser().parse_args(["identify", *map(str, argv)]))


def test_cli_lists_ignored_columns_once(tmp_path, capsys):
    t, ft, _, y, u = trial_columns()
    path = write_lines(
        tmp_path / "trial.csv",
        ["# t,target,output,stick,frame,"]
        + [
            f"{row(a, b, c, d)},{i},"
            for i, (a, b, c, d) in enumerate(zip(t, ft, y, u, strict=True))
        ],
    )
    rec = load_trial(path)
    assert capsys.readouterr().out == "ignored columns: frame\n"
    np.testing.assert_array_equal(rec.e, ft - y)  # formed from ft and y
    np.testing.assert_array_equal(rec.u, u)


def test_cli_missing_signal_speaks_command_line_words(tmp_path, capsys):
    path = write_lines(tmp_path / "trial.csv", ["time,error,joystick", "0,0,1", "0.01,1,2"])
    with pytest.raises(UsageError) as caught:
        load_trial(path)
    assert str(caught.value) == (
        f"{path} has no column for signal 'u' (pilot control output): looked for u, stick, "
        "control, delta, in any case; columns in the file: time, error, joystick (read as no "
        "signal: joystick); map one with --column u=COLUMN"
    )
    code = main(["identify", str(path), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == EXIT_USAGE and "map one with --column u=COLUMN" in err
    assert "columns=" not in err and "Traceback" not in err
    assert load_trial(path, "--column", "u=joystick").u[1] == 2.0


def test_cli_jitter_refusal_names_resample_and_resample_reads_it(tmp_path, capsys):
    t = clock_stamps(600)
    u = np.sin(t - t[0])
    path = write_lines(
        tmp_path / "clock.csv",
        ["t,e,u"] + [row(a, b, b) for a, b in zip(t, u, strict=True)],
    )
    with pytest.raises(UsageError) as caught:
        load_trial(path)
    text = str(caught.value)
    deviation, index = jitter_of(t)
    assert f"by up to {1e3 * deviation:.3g} ms (sample {index}, " in text
    assert "; pass --resample to interpolate every signal linearly" in text
    assert "resample=True" not in text
    rec = load_trial(path, "--resample")
    out = capsys.readouterr().out
    assert out == (
        f"resampled: 600 time stamps, off a uniform grid by up to {1e3 * deviation:.3g} ms, "
        f"interpolated linearly onto {len(rec)} samples at dt = {rec.dt:.6g} s\n"
    )
    assert rec.metadata["resampled"]["samples_in_file"] == 600


def test_cli_time_in_milliseconds_hint_and_option(tmp_path):
    path = ms_file(tmp_path)
    with pytest.raises(UsageError) as caught:
        load_trial(path, "--column", "t=time_ms")
    assert str(caught.value) == (
        f"{path}: the sample time is 10 s; manual-control data are sampled at tens of Hz or "
        "faster: the time column looks like milliseconds: pass --time-unit ms; if there is "
        "no time column, pass --dt SECONDS"
    )
    rec = load_trial(path, "--column", "t=time_ms", "--time-unit", "ms")
    assert rec.dt == 0.01 and rec.signal_names == ("t", "e", "u")
    # --dt is in seconds whatever the unit of a time column
    np.savez(tmp_path / "no_time.npz", e=np.zeros(5), u=np.arange(5.0))  # a stick that moved
    assert load_trial(tmp_path / "no_time.npz", "--dt", "0.01", "--time-unit", "ms").dt == 0.01
    with pytest.raises(UsageError, match=re.escape("--dt is in seconds")):
        load_trial(tmp_path / "no_time.npz", "--dt", "10", "--time-unit", "ms")


def test_two_structs_offering_one_signal_are_not_guessed_between(tmp_path):
    # a lab's file with two trials side by side: which u is meant only the user can say
    path = tmp_path / "two.mat"
    t = np.arange(100) * 0.01
    scipy.io.savemat(path, {"a": {"t": t, "u": np.sin(t)}, "b": {"t": t, "u": np.cos(t)}})
    message = f"{path}: signal 't' ('t') is in more than one variable (a.t, b.t): say which"
    with pytest.raises(ValueError, match=re.escape(message)):
        Recording.load(path)
    chosen = Recording.load(path, columns={"t": "b.t", "u": "b.u"})
    np.testing.assert_array_equal(chosen.u, np.cos(t))
