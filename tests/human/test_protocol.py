"""Experiment protocols: the file read and checked, the plan and its orders, and every
kind of mistake refused naming the file, the table, the key and the value."""

import itertools
import textwrap

import pytest

from manualcontrol.human.devices import JoystickInput, KeyboardInput
from manualcontrol.human.protocol import (
    Practice,
    ProtocolError,
    balanced_latin_square,
    load_protocol,
    parse_protocol,
    participant_number,
)

FORCING = """
[condition.forcing]
name = "fast"

[condition.forcing.target]
frequencies = [1.5707963267948966, 3.141592653589793, 4.71238898038469]
amplitudes = [1.0, 0.5, 0.25]
phases = [0.0, 1.0, 2.0]
measurement_time = 4.0
"""

BASE = f"""
name = "two-elements"
practice = 2
measurement_runs = 4

[breaks]
between_runs = 5
between_conditions = "key"

[input]
device = "joystick"
dead_zone = 0.1

[[condition]]
name = "SI"
task = "compensatory"
element = "SI"
measurement_time = 4.0
scale = 8.0
{FORCING}
[[condition]]
name = "DI"
task = "compensatory"
element = "DI"
forcing = "vanderel-bw4"
realisations = [0, 1, 2]
practice_realisations = [9]
measurement_time = 2.0
"""


def write(tmp_path, text, name="protocol.toml"):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def test_a_protocol_is_read_with_its_defaults(tmp_path):
    protocol = load_protocol(write(tmp_path, BASE))
    assert protocol.name == "two-elements"
    assert protocol.order == "as-listed" and protocol.seed is None
    assert protocol.breaks.between_runs == 5.0 and protocol.breaks.between_conditions == "key"
    assert protocol.input.device == "joystick" and protocol.input.dead_zone == 0.1
    assert isinstance(protocol.input.make(), JoystickInput)
    si, di = protocol.conditions
    assert si.practice == Practice(2) and si.measurement_runs == 4 and si.scale == 8.0
    assert si.realisations == (0,) and si.options["forcing"]["name"] == "fast"
    assert di.realisations == (0, 1, 2) and di.practice_realisations == (9,)
    assert di.env_id == "ManualControl/CompensatoryTracking-v0"
    assert protocol.text == textwrap.dedent(BASE)
    assert protocol.show_score is True


def test_to_dict_reads_back_into_the_same_protocol(tmp_path):
    protocol = load_protocol(write(tmp_path, BASE))
    again = parse_protocol(protocol.to_dict(), "again")
    assert again == protocol
    assert again.digest == protocol.digest
    changed = parse_protocol({**protocol.to_dict(), "show_score": False})
    assert changed.digest != protocol.digest
    assert protocol.differences(changed) == ["show_score: True -> False"]


def test_the_plan_in_order_with_realisations_files_and_seeds(tmp_path):
    protocol = load_protocol(write(tmp_path, BASE))
    plan = protocol.runs("P01")
    assert len(plan) == 12
    assert [(r.condition, r.kind, r.index) for r in plan[:6]] == [
        ("SI", "practice", 1),
        ("SI", "practice", 2),
        ("SI", "measurement", 1),
        ("SI", "measurement", 2),
        ("SI", "measurement", 3),
        ("SI", "measurement", 4),
    ]
    assert [r.number for r in plan] == list(range(1, 13))
    di = [r for r in plan if r.condition == "DI"]
    assert [r.realisation for r in di] == [9, 9, 0, 1, 2, 0]
    assert plan[0].file_name == "01-SI-practice-1.npz"
    assert plan[11].file_name == "12-DI-measurement-4.npz"
    assert plan == protocol.runs("P01")  # deterministic
    assert [r.seed for r in plan] != [r.seed for r in protocol.runs("P02")]


def test_the_balanced_latin_square():
    assert balanced_latin_square(1) == [[0]]
    assert balanced_latin_square(2) == [[0, 1], [1, 0]]
    for n in (3, 4, 5, 6):
        rows = balanced_latin_square(n)
        assert len(rows) == (n if n % 2 == 0 else 2 * n)
        for row in rows:
            assert sorted(row) == list(range(n))
        firsts = [row[0] for row in rows]
        assert all(firsts.count(c) == len(rows) // n for c in range(n))
        pairs = [pair for row in rows for pair in itertools.pairwise(row)]
        counts = {pair: pairs.count(pair) for pair in itertools.permutations(range(n), 2)}
        assert len(set(counts.values())) == 1  # each condition follows each other equally


def test_counterbalanced_orders_follow_the_participant_number(tmp_path):
    protocol = load_protocol(write(tmp_path, 'order = "counterbalanced"\n' + BASE))
    assert protocol.condition_order("P01")[0] == ("SI", "DI")
    assert protocol.condition_order("P02")[0] == ("DI", "SI")
    assert protocol.condition_order("P03")[0] == ("SI", "DI")
    assert protocol.condition_order("anna", 2)[0] == ("DI", "SI")
    assert "participant number 2, row 2 of the 2" in protocol.condition_order("P02")[1]
    assert [r.condition for r in protocol.runs("P02")][:6] == ["DI"] * 6
    with pytest.raises(ValueError, match="the id 'anna' has no digits"):
        protocol.runs("anna")
    assert (participant_number("P07"), participant_number("s12b"), participant_number("x")) == (
        7,
        12,
        None,
    )


def test_random_orders_are_the_participants_own_and_repeatable(tmp_path):
    text = 'order = "random"\nseed = 3\n' + BASE
    three = text + '\n[[condition]]\nname = "gain"\ntask = "compensatory"\nelement = "gain"\n'
    three += 'forcing = "vanderel-bw4"\nmeasurement_time = 1.0\n'
    protocol = load_protocol(write(tmp_path, three))
    orders = {protocol.condition_order(f"P{i}")[0] for i in range(12)}
    assert len(orders) > 1
    assert protocol.condition_order("P5") == protocol.condition_order("P5")
    assert "random (seed 3, participant P5)" == protocol.condition_order("P5")[1]


def test_practice_to_a_criterion():
    practice = Practice(4, 0.5, 2)
    assert not practice.met(1, 0.1)  # at least two runs
    assert practice.met(2, 0.4) and not practice.met(2, 0.6)
    assert practice.met(4, 9.0)  # the cap
    assert Practice(2).met(2, 9.0) and not Practice(2).met(1, 0.0)
    assert practice.to_dict() == {"until_rms_below": 0.5, "max_runs": 4, "min_runs": 2}


def test_input_flags_override_the_file(tmp_path):
    protocol = load_protocol(write(tmp_path, BASE))
    keyboard = protocol.with_input(device="keyboard")
    assert isinstance(keyboard.input.make(), KeyboardInput)
    assert keyboard.input.dead_zone is None  # the new device's own default
    assert keyboard.digest != protocol.digest
    assert protocol.with_input(dead_zone=0.2).input.dead_zone == 0.2
    with pytest.raises(ProtocolError, match="range applies to the mouse and the joystick"):
        protocol.with_input(device="keyboard", range=2.0)


def swap(old, new):
    return lambda text: text.replace(old, new, 1)


def si(key_value):
    """Add a key to the SI condition."""
    return swap('name = "SI"\n', f'name = "SI"\n{key_value}\n')


@pytest.mark.parametrize(
    ("edit", "where", "message"),
    [
        (swap("practice = 2", "pratice = 2"), "", "unknown top-level key(s) ['pratice']"),
        (si("colour = 3"), "condition 1 (SI)", "unknown key(s) ['colour']"),
        (
            swap('task = "compensatory"', 'task = "tracking"'),
            "condition 1 (SI)",
            "task must be one of compensatory, pursuit, preview, postview, lane-keeping, "
            "got 'tracking'",
        ),
        (
            swap('element = "SI"', 'element = "1/(s"'),
            "condition 1 (SI)",
            "element '1/(s': controlled element must be one of",
        ),
        (
            swap('forcing = "vanderel-bw4"', 'forcing = "vanderel"'),
            "condition 2 (DI)",
            "forcing must be one of 'vanderel-bw4',",
        ),
        (
            swap("practice = 2", "practice = -1"),
            "",
            "practice must be a whole number >= 0, got -1",
        ),
        (
            swap("measurement_runs = 4", "measurement_runs = 0"),
            "",
            "measurement_runs must be a whole number >= 1, got 0",
        ),
        (
            swap('name = "two-elements"', 'order = "alphabetical"'),
            "",
            "order must be one of 'as-listed', 'counterbalanced', 'random', got 'alphabetical'",
        ),
        (
            swap('name = "two-elements"', 'order = "random"'),
            "",
            "order = 'random' needs a seed",
        ),
        (
            swap('name = "two-elements"', "seed = 4"),
            "",
            "seed applies to order = 'random' only, not 'as-listed'; got seed = 4",
        ),
        (
            lambda text: text[: text.index("[[condition]]")],
            "",
            "a protocol needs at least one [[condition]] table, got condition = None",
        ),
        (
            swap('name = "DI"', 'name = "SI"'),
            "condition 2 (SI)",
            "name 'SI' is used by an earlier condition; names must be unique",
        ),
        (
            swap('device = "joystick"', 'device = "trackball"'),
            "",
            "input.device must be one of mouse, keyboard, joystick, got 'trackball'",
        ),
        (
            swap("measurement_time = 4.0\nscale", "measurement_time = 0\nscale"),
            "condition 1 (SI)",
            "measurement_time must be a number > 0, got 0.0",
        ),
        (
            swap("measurement_time = 2.0", "measurement_time = -3"),
            "condition 2 (DI)",
            "measurement_time must be a number > 0, got -3.0",
        ),
        (
            swap("realisations = [0, 1, 2]", "realisations = [0, 12]"),
            "condition 2 (DI)",
            "realisations: realisation must lie in [0, 9] for this forcing, got 12",
        ),
        (
            swap("practice_realisations = [9]", "practice_realisations = [-1]"),
            "condition 2 (DI)",
            "practice_realisations must be a whole number >= 0, got -1",
        ),
        (
            si("available_preview = 1.0"),
            "condition 1 (SI)",
            "available_preview must be 0 (or omitted) in a compensatory task, got 1.0",
        ),
        (
            si("road = 'zhao2019'"),
            "condition 1 (SI)",
            "road applies to lane keeping, not task 'compensatory'",
        ),
        (
            swap("between_runs = 5", "between_runs = -5"),
            "",
            'breaks.between_runs must be a number of seconds >= 0 or "key", got -5.0',
        ),
        (
            swap("between_runs = 5", 'between_runs = "space"'),
            "",
            "breaks.between_runs must be a number of seconds >= 0 or \"key\", got 'space'",
        ),
        (
            swap("dead_zone = 0.1", "dead_zone = 1.5"),
            "",
            "input.dead_zone must be a number in [0, 1), got 1.5",
        ),
        (
            swap("practice = 2", "practice = {until_rms_below = 0.5}"),
            "",
            "practice as a table needs until_rms_below (the RMS error that ends practice) and "
            "max_runs",
        ),
        (
            swap("practice = 2", "practice = {until_rms_below = 0.5, max_runs = 2, min_runs = 3}"),
            "",
            "practice.min_runs must be at most max_runs (2), got 3",
        ),
        (
            swap('name = "two-elements"', 'instructions = "Fly {conditon}"'),
            "",
            "instructions uses unknown placeholder(s) ['conditon'] in 'Fly {conditon}'; "
            "allowed: {condition}, {task}",
        ),
        (
            swap("scale = 8.0", "scale = -1.0"),
            "condition 1 (SI)",
            "scale must be a number > 0, got -1.0",
        ),
        (
            swap("amplitudes = [1.0, 0.5, 0.25]", "amplitudes = [1.0, 0.5]"),
            "condition 1 (SI)",
            "forcing: amplitudes must have one entry per frequency (3), got length 2",
        ),
        (
            swap('name = "SI"', 'name = "S I"'),
            "condition 1",
            "name must be letters, digits, '-' or '_', starting with a letter or digit (run "
            "files are named after it), got 'S I'",
        ),
        (
            swap("realisations = [0, 1, 2]", "realisation = 0\nrealisations = [1]"),
            "condition 2 (DI)",
            "give realisation or realisations, not both",
        ),
        (
            lambda text: swap('task = "compensatory"', 'task = "pursuit"')(text).replace(
                "measurement_time = 4.0\n\n[[condition]]",
                "measurement_time = 4.0\n\n[condition.forcing.disturbance]\n"
                "frequencies = [3.141592653589793]\namplitudes = [0.3]\nphases = [0.5]\n"
                "measurement_time = 4.0\n\n[[condition]]",
                1,
            ),
            "condition 1 (SI)",
            "forcing: the target and the disturbance share 1 harmonic(s) (3.14 rad/s): a "
            "pursuit display's describing function cannot tell the pilot's responses to the "
            "two apart there",
        ),
    ],
)
def test_mistakes_name_the_file_the_table_the_key_and_the_value(tmp_path, edit, where, message):
    path = write(tmp_path, edit(BASE))
    with pytest.raises(ProtocolError) as error:
        load_protocol(path)
    text = str(error.value)
    prefix = f"{path}: {where}: " if where else f"{path}: "
    assert text.startswith(prefix), text
    assert message in text, text


@pytest.mark.parametrize(
    ("task", "disturbance"), [("compensatory", 3.141592653589793), ("pursuit", 6.283185307179586)]
)
def test_target_and_disturbance_lines_may_meet_where_the_display_shows_only_the_error(
    tmp_path, task, disturbance
):
    # a compensatory display reads a shared harmonic as one line; a pursuit display
    # needs its disturbance lines apart from the target's, and these are
    text = BASE.replace('task = "compensatory"', f'task = "{task}"', 1).replace(
        "measurement_time = 4.0\n\n[[condition]]",
        "measurement_time = 4.0\n\n[condition.forcing.disturbance]\n"
        f"frequencies = [{disturbance}]\namplitudes = [0.3]\nphases = [0.5]\n"
        "measurement_time = 4.0\n\n[[condition]]",
        1,
    )
    protocol = load_protocol(write(tmp_path, text))
    assert protocol.conditions[0].task == task
    assert protocol.conditions[0].options["forcing"]["disturbance"]["frequencies"] == [disturbance]


def test_the_file_itself(tmp_path):
    with pytest.raises(ProtocolError, match="no such protocol file"):
        load_protocol(tmp_path / "missing.toml")
    with pytest.raises(ProtocolError, match="not valid TOML"):
        load_protocol(write(tmp_path, "name = "))
    assert (
        load_protocol(write(tmp_path, BASE.replace('name = "two-elements"\n', ""), "lab.toml")).name
        == "lab"
    )


def test_lane_keeping_conditions(tmp_path):
    text = """
    measurement_runs = 1
    [[condition]]
    name = "lane"
    task = "lane-keeping"
    measurement_time = 5.0
    steering = "angle"
    """
    protocol = load_protocol(write(tmp_path, text))
    (run,) = protocol.runs("P01")
    assert run.realisation is None
    with pytest.raises(
        ProtocolError, match=r"condition 1 \(lane\): element applies to the tracking"
    ):
        load_protocol(write(tmp_path, text + 'element = "SI"\n'))
    with pytest.raises(ProtocolError, match=r"\(lane\): measurement_time must fit the road"):
        load_protocol(write(tmp_path, text.replace("5.0", "1000.0")))


def test_the_example_of_the_documentation_is_a_valid_protocol(tmp_path):
    from pathlib import Path

    text = (Path(__file__).parents[2] / "docs" / "experiments.md").read_text()
    example = text.split("```toml\n", 1)[1].split("```", 1)[0]
    protocol = load_protocol(write(tmp_path, example, "si-di.toml"))
    assert [c.name for c in protocol.conditions] == ["SI", "DI"]
    assert protocol.conditions[0].practice == Practice(5, 0.7, 2)
    plan = protocol.runs("P02")
    assert len(plan) == 18 and plan[0].condition == "DI"
    assert plan[5].file_name == "06-DI-measurement-1.npz" and plan[5].realisation == 4
