"""``score_from`` is checked at suite load: one that leaves nothing to score is refused.

Rows are scored over ``t >= score_from``; a value at or past the last measured sample
used to load and then fail every run. The error names the file, the batch and the key,
as the other suite errors do (``tests/bench/test_scenarios.py``).
"""

import importlib.resources
import re
import textwrap

import pytest

from manualcontrol.bench.scenarios import BUILTIN_SUITES, SuiteError, load_suite

SMALL = """
name = "mine"
[[batch]]
name = "one"
task = "compensatory"
element = "SI"
forcing = "vanderel-bw4"
realisations = [0, 1]
measurement_time = 10.0
[batch.pilot]
model = "precision"
parameters = { K_p = 1.3, K_v = 0.0, tau_v = 0.26, omega_nms = 10.5, zeta_nms = 0.35 }
[batch.estimator]
name = "dekf"
model = "precision"
ce = "SI"
"""

OPEN_LOOP = """
name = "open"
[[batch]]
name = "armax"
task = "open-loop"
forcing = "boer-kenyon1998"
realisations = [0]
dt = 0.05
run_in = 2.0
{extra}
[batch.system]
a = [0.5924]
b = [1.5119, -1.1043]
step = 0.05
delay = 0.1
[batch.estimator]
name = "rdi"
n_a = 1
n_b = 1
input = "ft"
output = "u"
"""


def write(tmp_path, text):
    path = tmp_path / "suite.toml"
    path.write_text(textwrap.dedent(text))
    return path


def with_score_from(value, text=SMALL):
    return text.replace("measurement_time = 10.0", f"measurement_time = 10.0\nscore_from = {value}")


@pytest.mark.parametrize("value", ["1000", "1000.0", "10.0", "9.995"])
def test_a_score_from_past_the_measurement_is_refused_at_load(tmp_path, value):
    path = write(tmp_path, with_score_from(value))
    message = (
        f"{path}: batch 1 (one): score_from must lie in [0, 9.99] s, the times of the measured "
        "samples (t = 0 to 9.99 s: measurement_time = 10 s at dt = 0.01 s), "
        f"got {float(value)!r}: it would leave nothing to score"
    )
    with pytest.raises(SuiteError, match=re.escape(message) + "$"):
        load_suite(path)


def test_a_negative_score_from_is_refused_at_load(tmp_path):
    path = write(tmp_path, with_score_from("-1.0"))
    with pytest.raises(
        SuiteError, match=re.escape(f"{path}: batch 1 (one): score_from must be >= 0, got -1.0")
    ):
        load_suite(path)


@pytest.mark.parametrize("value", ["0.0", "5.0", "9.99"])
def test_a_score_from_inside_the_measurement_loads(tmp_path, value):
    suite = load_suite(write(tmp_path, with_score_from(value)))
    assert suite.scenarios()[0].score_from == float(value)


def test_the_default_measurement_time_is_the_forcing_period(tmp_path):
    text = SMALL.replace("measurement_time = 10.0\n", "score_from = 1000\n")
    path = write(tmp_path, text)
    with pytest.raises(
        SuiteError,
        match=re.escape(
            f"{path}: batch 1 (one): score_from must lie in [0, 119.99] s, the times of the "
            "measured samples (t = 0 to 119.99 s: measurement_time = 120 s (the forcing "
            "period) at dt = 0.01 s), got 1000.0: it would leave nothing to score"
        ),
    ):
        load_suite(path)
    # inside the period it loads
    load_suite(write(tmp_path, SMALL.replace("measurement_time = 10.0\n", "score_from = 119.0\n")))


def test_a_suite_default_score_from_names_the_batch_it_fails(tmp_path):
    text = SMALL.replace("[[batch]]", "[defaults]\nscore_from = 15.0\n\n[[batch]]", 1)
    path = write(tmp_path, text)
    with pytest.raises(SuiteError, match=re.escape(f"{path}: batch 1 (one): score_from must lie")):
        load_suite(path)


def test_the_window_runs_from_the_start_time(tmp_path):
    text = SMALL.replace("measurement_time = 10.0", "measurement_time = 10.0\nstart_time = 0.25")
    loaded = load_suite(write(tmp_path, with_score_from("10.24", text)))
    assert loaded.scenarios()[0].score_from == 10.24
    path = write(tmp_path, with_score_from("10.25", text))
    with pytest.raises(
        SuiteError,
        match=re.escape(
            "score_from must lie in [0, 10.24] s, the times of the measured samples "
            "(t = 0.25 to 10.24 s: start_time = 0.25 s, measurement_time = 10 s at dt = 0.01 s), "
            "got 10.25"
        ),
    ):
        load_suite(path)


def test_an_open_loop_batch_is_checked_against_its_measurement_time(tmp_path):
    good = OPEN_LOOP.format(extra="measurement_time = 30.0\nscore_from = 10.0")
    assert load_suite(write(tmp_path, good)).scenarios()[0].score_from == 10.0
    path = write(tmp_path, OPEN_LOOP.format(extra="score_from = 60.0"))
    with pytest.raises(
        SuiteError,
        match=re.escape(
            f"{path}: batch 1 (armax): score_from must lie in [0, 59.95] s, the times of the "
            "measured samples (t = 0 to 59.95 s: measurement_time = 60 s (the default) at "
            "dt = 0.05 s), got 60.0"
        ),
    ):
        load_suite(path)


@pytest.mark.parametrize("name", BUILTIN_SUITES)
def test_every_builtin_suite_still_loads(name):
    assert load_suite(name).scenarios()


def test_a_lane_keeping_score_from_past_its_drive_is_refused_at_load(tmp_path):
    folder = importlib.resources.files("manualcontrol.bench").joinpath("suites")
    text = folder.joinpath("zhao2019.toml").read_text()
    text = text.replace("[[batch]]", "[[batch]]\nscore_from = 10000.0", 1)
    with pytest.raises(SuiteError, match=r"score_from must lie in \[0, .*got 10000\.0"):
        load_suite(write(tmp_path, text))
