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


@pytest.mark.parametrize("name", BUILTIN_SUITES)
def test_the_listing_counts_the_runs_the_validated_suite_expands(name):
    from collections import Counter

    from manualcontrol.bench.listing import outline, read_builtin_suite

    suite, listed = load_suite(name), outline(read_builtin_suite(name))
    assert (listed.name, listed.description) == (suite.name, suite.description)
    for quick, counts in ((False, listed.runs), (True, listed.quick_runs)):
        expanded = Counter(scenario.batch for scenario in suite.scenarios(quick=quick))
        assert counts == dict(expanded)
        assert list(counts) == [batch.name for batch in suite.batches]


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
    # 4 batches x 10 realisations (Table II), each identified by three estimators
    assert len({s.simulation_key for s in feasibility.scenarios()}) == 40
    assert len(feasibility.scenarios()) == 120
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
            "batch 1 (one): task must be one of 'compensatory', 'pursuit', 'preview', 'postview', "
            "'open-loop', got 'gap'",
        ),
        (
            ('element = "DI"', 'element = "TI"'),
            "batch 1 (one): element: controlled element must be one of",
        ),
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
            "estimator (ukf): estimator name must be one of 'dekf', ",
        ),
        (('ce = "DI"', 'ce = "DI"\nq2 = -1.0'), "estimator (dekf): q2 must be > 0, got -1.0"),
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


SMALL = """
name = "mine"
[[batch]]
name = "one"
task = "compensatory"
element = "SI"
forcing = "vanderel-bw4"
realisations = [0, 1]
[batch.pilot]
model = "precision"
parameters = { K_p = 1.3, K_v = 0.0, tau_v = 0.26, omega_nms = 10.5, zeta_nms = 0.35 }
[batch.estimator]
name = "dekf"
model = "precision"
ce = "SI"
"""


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (SMALL.replace('name = "mine"', 'name = "mine"\nquick = 5'), "unknown top-level key(s)"),
        (
            SMALL.replace("realisations = [0, 1]", "realisations = [0, 1]\nquick = 5"),
            "batch 1 (one): quick must be a table ({...} or [quick]), got 5",
        ),
        (
            SMALL.replace('name = "mine"', 'name = "mine"\ndefaults = 5'),
            "suite.toml: defaults must be a table ({...} or [defaults]), got 5",
        ),
        (
            'name = "mine"\nbatch = [1]\n',
            "batch 1: each [[batch]] must be a table ({...} or [each [[batch]]]), got 1",
        ),
        (
            'name = "mine"\nbatch = 3\n',
            "a suite needs at least one [[batch]] table, got batch = 3",
        ),
        (
            SMALL.replace(
                '[batch.pilot]\nmodel = "precision"\nparameters = { K_p = 1.3, K_v = 0.0, tau_v = '
                "0.26, omega_nms = 10.5, zeta_nms = 0.35 }",
                'pilot = "precision"',
            ),
            "batch 1 (one): pilot must be a table ({...} or [pilot]), got 'precision'",
        ),
        (
            SMALL.replace("parameters = {", "parameters = 3\nx = {"),
            "pilot has unknown key(s) ['x']",
        ),
        (
            SMALL.replace("K_p = 1.3,", 'K_p = "fast",'),
            "batch 1 (one): pilot: pilot parameter K_p: schedule must be a number or a dict",
        ),
        (
            SMALL.replace("realisations = [0, 1]", "realisations = [0, 1, 1]"),
            "batch 1 (one): realisations must not repeat a value, repeated: [1]",
        ),
        (
            SMALL.replace("realisations = [0, 1]", "realisations = [0, 1]\nremnant_seeds = [2, 2]"),
            "remnant_seeds must not repeat a value, repeated: [2]",
        ),
        (
            SMALL.replace(
                "realisations = [0, 1]", "realisations = [0, 1]\nquick = { realisations = [5] }"
            ),
            "quick.realisations must be taken from realisations [0, 1], got [5]",
        ),
        (
            SMALL.replace('task = "compensatory"', 'task = "preview"'),
            "batch 1 (one): task 'preview' does not fit the 'precision' pilot model",
        ),
        (
            SMALL.replace("K_v = 0.0", "K_v = 0.5").replace("K_p = 1.3", "K_p = 1.5"),
            "batch 1 (one): the precision pilot (K_p=1.5, K_v=0.5, tau_v=0.26, omega_nms=10.5, "
            "zeta_nms=0.35) and the controlled element integrator (K=1.5) close an unstable loop",
        ),
        (
            SMALL.replace('name = "dekf"', 'name = "dekf"\nr2 = "big"'),
            "batch 1 (one): estimator (dekf): r2 must be a real number, got 'big'",
        ),
        (
            SMALL.replace("realisations = [0, 1]", "realisations = [0, 1]\nreference = 3"),
            "batch 1 (one): reference must be a table ({...} or [reference]), got 3",
        ),
        (
            SMALL.replace('name = "mine"', "name = 5"),
            "suite.toml: name must be a non-empty string, got 5",
        ),
        (
            SMALL.replace('name = "mine"', 'name = "mine"\ndescription = 5'),
            "suite.toml: description must be a string, got 5",
        ),
        (
            SMALL.replace(
                "realisations = [0, 1]", "realisations = [0, 1]\nmeasurement_time = 0.001"
            ),
            "batch 1 (one): measurement_time must hold at least one sample",
        ),
    ],
)
def test_whole_suite_is_validated_at_load_with_the_key_path(tmp_path, text, message):
    with pytest.raises(SuiteError, match=re.escape(message)):
        load_suite(write(tmp_path, text))


def test_the_small_suite_itself_loads(tmp_path):
    suite = load_suite(write(tmp_path, SMALL))
    assert len(suite.scenarios()) == 2
    assert suite.scenarios()[0].build_pilot().parameters["K_p"](0.0) == 1.3


def test_a_written_element_and_the_disturbance_point(tmp_path):
    plain = load_suite(write(tmp_path, SMALL)).scenarios()[0]
    lab = SMALL.replace('element = "SI"', 'element = "1.5/s"\ndisturbance_at = "input"')
    scenario = load_suite(write(tmp_path, lab)).scenarios()[0]
    assert scenario.element == "1.5/s" and scenario.disturbance_at == "input"
    assert scenario.to_dict()["disturbance_at"] == "input" and scenario.key != plain.key
    # the default is left out of the description, so existing scenarios keep their keys
    assert plain.disturbance_at == "output" and "disturbance_at" not in plain.to_dict()
    output = SMALL.replace('element = "SI"', 'element = "SI"\ndisturbance_at = "output"')
    assert load_suite(write(tmp_path, output)).scenarios()[0].key == plain.key


def test_the_disturbance_point_as_a_suite_default(tmp_path):
    # a lab's whole experiment puts the disturbance at the input: said once
    text = SMALL.replace("[[batch]]", '[defaults]\ndisturbance_at = "input"\n\n[[batch]]', 1)
    assert load_suite(write(tmp_path, text)).scenarios()[0].disturbance_at == "input"


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            'disturbance_at = "inlet"',
            "batch 1 (one): disturbance_at must be one of 'output', 'input', got 'inlet'",
        ),
        ("disturbance_at = 1", "batch 1 (one): disturbance_at must be one of 'output', 'input'"),
    ],
)
def test_a_bad_disturbance_point_names_the_batch_and_key(tmp_path, change, message):
    text = SMALL.replace('element = "SI"', f'element = "SI"\n{change}')
    with pytest.raises(SuiteError, match=re.escape(message)):
        load_suite(write(tmp_path, text))


def test_suite_pilots_are_built_by_pilot_from_dict(monkeypatch):
    from manualcontrol.bench import scenarios
    from manualcontrol.pilots import Pilot

    calls = []
    original = Pilot.from_dict.__func__
    monkeypatch.setattr(
        Pilot, "from_dict", classmethod(lambda cls, data: calls.append(data) or original(cls, data))
    )
    pilot = scenarios._pilot_from({"model": "preview", "near_view": True, "parameters": {}})
    assert calls and calls[0]["model_options"] == {"near_view": True}
    assert pilot.model.near_view
