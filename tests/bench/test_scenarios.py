"""Suite files: the built-in suites load, bad files fail with messages that point at the fix."""

import re
import textwrap

import pytest

from manualcontrol.bench.scenarios import BUILTIN_SUITES, SuiteError, load_suite

MINIMAL = """
name = "mine"
[[batch]]
name = "one"
task = "compensatory"
element = "DI"
forcing = "vanderel-bw4"
realisations = [0, 1]
remnant_seeds = [0, 1, 2]
[batch.pilot]
model = "precision"
remnant = "popovici2017"
[batch.pilot.parameters]
K_p = 0.24
K_v = 0.36
tau_v = { kind = "sine", mean = 0.3, amplitude = 0.02, period = 60.0, phase = 0.0 }
[batch.estimator]
name = "dekf"
model = "precision"
ce = "DI"
"""


def write(tmp_path, text):
    path = tmp_path / "suite.toml"
    path.write_text(textwrap.dedent(text))
    return path


def test_builtin_suites_have_the_papers_batch_sizes():
    assert set(BUILTIN_SUITES) >= {
        "popovici2017",
        "vertregt2020-feasibility",
        "vertregt2020-performance",
    }
    feasibility = load_suite("vertregt2020-feasibility")
    assert [b.name for b in feasibility.batches] == [
        "compensatory-SI",
        "compensatory-DI",
        "preview-SI",
        "preview-DI",
    ]
    assert len(feasibility.scenarios()) == 40  # 4 batches x 10 realisations (Table II)
    performance = load_suite("vertregt2020-performance")
    assert len(performance.batches) == 8 and len(performance.scenarios()) == 800  # 5 x 20 each
    assert performance.batch("all-SI-full").reference["parameters"]["tau_f"] == {
        "rel_bias": -0.125,
        "nrmse": 0.214,
    }
    assert performance.batch("constant-physical-DI-full").reference["vaf_resimulated_ideal"] == 76.4
    assert len(performance.scenarios(quick=True)) == 8


def test_a_user_suite_crosses_realisations_and_seeds(tmp_path):
    suite = load_suite(write(tmp_path, MINIMAL))
    scenarios = suite.scenarios()
    assert [(s.realisation, s.remnant_seed) for s in scenarios] == [
        (r, s) for r in (0, 1) for s in (0, 1, 2)
    ]
    assert len({s.key for s in scenarios}) == 6
    pilot = scenarios[0].build_pilot()
    assert pilot.remnant.P_r == 0.30 and pilot.parameters["tau_v"](15.0) == pytest.approx(0.32)


def test_scenario_key_changes_with_any_setting(tmp_path):
    first = load_suite(write(tmp_path, MINIMAL)).scenarios()[0]
    changed = load_suite(write(tmp_path, MINIMAL.replace("K_p = 0.24", "K_p = 0.25"))).scenarios()[
        0
    ]
    assert first.key != changed.key
    assert first.key.startswith("one-r0-s0-")


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            ('task = "compensatory"', 'task = "gap"'),
            "batch 1 (one): task must be one of 'compensatory', 'pursuit', 'preview', got 'gap'",
        ),
        (('element = "DI"', 'element = "TI"'), "batch 1 (one): controlled element must be one of"),
        (
            ("realisations = [0, 1]", "realisations = [0, 12]"),
            "realisations must lie in [0, 9] for forcing 'vanderel-bw4', got 12",
        ),
        (
            ("realisations = [0, 1]", "realisations = []"),
            "realisations must be a non-empty list of integers, got []",
        ),
        (
            ('model = "precision"\nremnant', 'model = "crossover"\nremnant'),
            "pilot: pilot model must be one of",
        ),
        (("K_p = 0.24", "K_q = 0.24"), "pilot: PrecisionModel has no parameter(s) 'K_q'"),
        (
            ('name = "dekf"', 'name = "ukf"'),
            "estimator: estimator name must be one of 'dekf', 'zhao-ukf', 'zhao-multi-ukf', "
            "got 'ukf'",
        ),
        (('ce = "DI"', 'ce = "DI"\nq2 = -1.0'), "estimator: q2 must be > 0, got -1.0"),
        (
            ('forcing = "vanderel-bw4"', 'forcing = "vanderel-bw4"\nrun_time = 3'),
            "unknown key(s) ['run_time']",
        ),
    ],
)
def test_bad_suite_files_name_the_problem(tmp_path, change, message):
    old, new = change
    assert old in MINIMAL
    with pytest.raises(SuiteError, match=re.escape(message)):
        load_suite(write(tmp_path, MINIMAL.replace(old, new, 1)))


def test_not_a_suite(tmp_path):
    with pytest.raises(SuiteError, match=re.escape("suite must be a built-in name")):
        load_suite("nonexistent")
    path = write(tmp_path, "name = [")
    with pytest.raises(SuiteError, match="not valid TOML"):
        load_suite(path)
    with pytest.raises(SuiteError, match=re.escape("a suite needs at least one [[batch]]")):
        load_suite(write(tmp_path, 'name = "empty"'))
