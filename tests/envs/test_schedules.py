"""envs.schedules against the thesis formulas (eqs. 36 / 4.2, A.1, 4.3) and each other."""

import json
import math
import pickle
import re
import warnings

import numpy as np
import pytest

from manualcontrol.envs.schedules import (
    Constant,
    Ramp,
    RandomWalk,
    Schedule,
    Sequence,
    Sigmoid,
    Sine,
    Step,
    Sum,
    as_schedule,
)

ALL_KINDS = [
    Constant(1.3),
    Sigmoid(0.3, 0.6, 50.0, 10.0),
    Sine(0.4, 0.2, 40.0, 5.0),
    Step(1.0, 2.0, 10.0),
    Ramp(1.0, 3.0, 10.0, 20.0),
    RandomWalk(1.0, 0.1, 60.0, seed=7, dt=0.05, lower=0.5, upper=1.5),
    RandomWalk(0.0, 0.2, 10.0, seed=3),
    Sum((Sigmoid(1.35, 0.85, 70.0, 5.0), Sine(0.0, 0.1, 20.0))),
    Sequence(((0.0, 1.0), (30.0, Ramp(1.0, 2.0, 30.0, 40.0)), (60.0, Step(2.0, 0.5, 80.0)))),
]


# -------------------------------------------------------------------------- sigmoid


def test_sigmoid_midpoint_and_99_percent_transition():
    start, end, t_mid, width = 0.3, 0.6, 50.0, 10.0
    s = Sigmoid(start, end, t_mid, width)
    assert s(t_mid) == pytest.approx(0.45, abs=1e-15)
    # thesis eq. A.2 with b = 0.99: 0.5 % and 99.5 % of the change at t_mid -/+ dT/2
    assert s(t_mid - width / 2) == pytest.approx(start + 0.005 * (end - start), abs=1e-14)
    assert s(t_mid + width / 2) == pytest.approx(start + 0.995 * (end - start), abs=1e-14)


def test_sigmoid_matches_thesis_eq_4_2():
    s = Sigmoid(1.35, 0.85, 70.0, 5.0)
    t = np.linspace(0.0, 120.0, 1201)
    expected = 1.35 + (0.85 - 1.35) / (1.0 + np.exp(-(2.0 * np.log(199.0) / 5.0) * (t - 70.0)))
    np.testing.assert_allclose(s(t), expected, rtol=1e-14, atol=1e-15)


def test_sigmoid_from_max_rate_is_the_delta_t_form_of_eq_a1():
    G = 0.8
    s = Sigmoid.from_max_rate(0.3, 0.6, 50.0, G)
    assert s.transition_time == pytest.approx(2.0 * math.log(199.0) / G, rel=1e-15)
    assert s.rate_g == pytest.approx(G, rel=1e-15)
    t = np.linspace(0.0, 100.0, 501)
    eq_a1 = 0.3 + (0.6 - 0.3) / (1.0 + np.exp(-G * (t - 50.0)))
    np.testing.assert_allclose(s(t), eq_a1, rtol=1e-14)
    np.testing.assert_allclose(s(t), Sigmoid(0.3, 0.6, 50.0, 2 * math.log(199) / G)(t), rtol=1e-14)


def test_sigmoid_far_tails_are_exact_and_silent():
    s = Sigmoid(2.0, 5.0, 0.0, 0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        values = s(np.array([-1e6, -1e3, 1e3, 1e6]))
    np.testing.assert_array_equal(values, [2.0, 2.0, 5.0, 5.0])


# ---------------------------------------------------------------------- other kinds


def test_sine_matches_thesis_eq_4_3_with_phase_in_seconds():
    s = Sine(mean=0.4, amplitude=0.2, period=40.0, phase=5.0)
    t = np.linspace(-10.0, 100.0, 777)
    np.testing.assert_allclose(s(t), 0.4 + 0.2 * np.sin(2 * np.pi * (t - 5.0) / 40.0), rtol=1e-15)
    assert s(5.0) == pytest.approx(0.4, abs=1e-15)  # upward crossing at t = phase
    assert s(15.0) == pytest.approx(0.6, abs=1e-15)


def test_step_switches_at_t_step_inclusive():
    s = Step(1.0, 2.0, 10.0)
    np.testing.assert_array_equal(s([9.999, 10.0, 10.001]), [1.0, 2.0, 2.0])


def test_ramp_is_linear_between_and_constant_outside():
    r = Ramp(1.0, 3.0, 10.0, 20.0)
    np.testing.assert_allclose(r([0.0, 10.0, 12.5, 15.0, 20.0, 99.0]), [1, 1, 1.5, 2, 3, 3])


def test_constant_is_constant_and_others_not():
    assert Constant(2.0).is_constant
    assert (Constant(1.0) + 2.0).is_constant
    assert not Sigmoid(1, 2, 3, 4).is_constant
    assert not (Constant(1.0) + Sine(0, 1, 10)).is_constant
    np.testing.assert_array_equal(Constant(2.5)(np.zeros((2, 3))), np.full((2, 3), 2.5))


@pytest.mark.parametrize("schedule", ALL_KINDS, ids=lambda s: type(s).__name__)
def test_scalar_and_array_evaluation_agree(schedule):
    t = np.linspace(-5.0, 100.0, 210).reshape(3, 70)
    values = schedule(t)
    assert isinstance(values, np.ndarray)
    assert values.shape == t.shape and values.dtype == np.float64
    scalars = np.array([[schedule(float(x)) for x in row] for row in t])
    assert all(isinstance(schedule(float(x)), float) for x in t[0, :3])
    np.testing.assert_array_equal(values, scalars)


# --------------------------------------------------------------------- composition


def test_sum_adds_pointwise_and_flattens():
    a, b, c = Sigmoid(1, 2, 10, 4), Sine(0, 1, 10), Ramp(0, 1, 0, 5)
    t = np.linspace(0, 20, 41)
    total = a + b + c
    assert isinstance(total, Sum) and total.terms == (a, b, c)
    np.testing.assert_allclose(total(t), a(t) + b(t) + c(t), rtol=1e-15)
    assert sum([a, b, c]) == total  # 0 + a is a itself
    np.testing.assert_allclose((a + 2.0)(t), a(t) + 2.0)
    np.testing.assert_allclose((2.0 + a)(t), a(t) + 2.0)
    assert total.describe() == f"{a.describe()} + {b.describe()} + {c.describe()}"


def test_sequence_uses_absolute_time_and_segment_bounds():
    sig = Sigmoid(0.3, 0.6, 50.0, 10.0)
    seq = Sequence([(10.0, 1.0), (20.0, sig), (60.0, Step(5.0, 6.0, 70.0))])
    t = np.array([0.0, 10.0, 19.999, 20.0, 50.0, 59.9, 60.0, 69.0, 70.0, 1000.0])
    expected = [1.0, 1.0, 1.0, sig(20.0), 0.45, sig(59.9), 5.0, 5.0, 6.0, 6.0]
    np.testing.assert_allclose(seq(t), expected, rtol=1e-15)


# --------------------------------------------------------------------- random walk


def test_random_walk_is_reproducible_whatever_the_evaluation_times():
    walk = RandomWalk(1.0, 0.3, 50.0, seed=11, dt=0.01)
    grid = np.arange(5001) * 0.01
    on_grid = walk(grid)
    again = RandomWalk(1.0, 0.3, 50.0, seed=11, dt=0.01)
    subset = np.array([3.0, 0.0, 42.17, 7.5])
    np.testing.assert_array_equal(again(subset), walk(subset))
    np.testing.assert_allclose(walk(grid[::7]), on_grid[::7], rtol=0, atol=1e-14)
    assert RandomWalk(1.0, 0.3, 50.0, seed=12)(25.0) != walk(25.0)
    assert walk(0.0) == 1.0
    assert walk(-3.0) == 1.0 and walk(80.0) == walk(50.0)


def test_random_walk_increment_statistics():
    sigma, dt = 0.4, 0.01
    walk = RandomWalk(0.0, sigma, 1000.0, seed=5, dt=dt)
    increments = np.diff(walk(np.arange(100_001) * dt))
    assert np.std(increments) == pytest.approx(sigma * math.sqrt(dt), rel=0.02)
    assert abs(np.mean(increments)) < 3 * sigma * math.sqrt(dt) / math.sqrt(increments.size)


def test_random_walk_is_reflected_into_bounds():
    walk = RandomWalk(1.0, 0.5, 200.0, seed=1, dt=0.01, lower=0.5, upper=1.5)
    free = RandomWalk(1.0, 0.5, 200.0, seed=1, dt=0.01)
    t = np.arange(20_001) * 0.01
    values = walk(t)
    assert values.min() >= 0.5 and values.max() <= 1.5
    assert values.min() < 0.52 and values.max() > 1.48  # it reaches both walls
    # reflection keeps the step sizes of the free walk except at the bounces (folding);
    # clipping would instead stall the walk at a wall with zero steps
    steps_bounded = np.abs(np.diff(values))
    steps_free = np.abs(np.diff(free(t)))
    assert np.mean(np.isclose(steps_bounded, steps_free, atol=1e-9)) > 0.9
    one_sided = RandomWalk(0.0, 1.0, 100.0, seed=2, upper=0.2)(t[:10_001])
    assert one_sided.max() <= 0.2


def test_random_walk_grid_step_fits_duration():
    walk = RandomWalk(0.0, 1.0, 1.0, seed=0, dt=0.3)  # 4 steps of 0.25 s
    times, values = walk.grid
    np.testing.assert_allclose(times, [0.0, 0.25, 0.5, 0.75, 1.0])
    assert values.shape == (5,) and not values.flags.writeable


# ------------------------------------------------------------------ saving, identity


@pytest.mark.parametrize("schedule", ALL_KINDS, ids=lambda s: type(s).__name__)
def test_to_dict_from_dict_round_trip_through_json(schedule):
    data = json.loads(json.dumps(schedule.to_dict()))
    assert data["kind"] == schedule.kind
    rebuilt = Schedule.from_dict(data)
    assert rebuilt == schedule and hash(rebuilt) == hash(schedule)
    t = np.linspace(-5, 100, 300)
    np.testing.assert_array_equal(rebuilt(t), schedule(t))
    assert pickle.loads(pickle.dumps(schedule)) == schedule
    assert isinstance(schedule.describe(), str) and schedule.describe()


def test_from_dict_reads_bare_numbers_as_constants():
    assert Schedule.from_dict(2.5) == Constant(2.5)
    assert Schedule.from_dict({"kind": "sum", "terms": [1.0, {"kind": "constant", "value": 2}]})(
        0.0
    ) == pytest.approx(3.0)


def test_describe_examples():
    assert Sigmoid(0.3, 0.6, 50, 10).describe() == "sigmoid(0.3 -> 0.6 at 50 s, 99 % in 10 s)"
    assert Constant(2).describe() == "2"
    assert RandomWalk(1, 0.1, 10, 3, upper=2).describe() == (
        "random walk(from 1, 0.1/sqrt(s), seed 3, in [-inf, 2])"
    )


def test_as_schedule():
    s = Sine(0, 1, 2)
    assert as_schedule(s) is s
    assert as_schedule(3) == Constant(3.0)
    assert as_schedule(np.float64(0.5)) == Constant(0.5)
    with pytest.raises(
        TypeError, match=re.escape("a schedule or a real number is required, got 'x'")
    ):
        as_schedule("x")
    with pytest.raises(TypeError, match=re.escape("got None")):
        as_schedule(None)


# ----------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (lambda: Constant(float("nan")), "value must be finite, got nan"),
        (lambda: Sigmoid(0, 1, 5, 0.0), "transition_time must be > 0, got 0.0"),
        (lambda: Sigmoid(0, 1, 5, -2), "transition_time must be > 0, got -2.0"),
        (lambda: Sigmoid(0, float("inf"), 5, 1), "end must be finite, got inf"),
        (lambda: Sigmoid.from_max_rate(0, 1, 5, 0.0), "rate_g must be > 0, got 0.0"),
        (lambda: Sine(0, 1, 0.0), "period must be > 0, got 0.0"),
        (lambda: Sine(0, 1, 10, float("nan")), "phase must be finite, got nan"),
        (lambda: Step(0, 1, float("-inf")), "t_step must be finite, got -inf"),
        (lambda: Ramp(0, 1, 5.0, 5.0), "t_end must be > t_start = 5.0, got t_end = 5.0"),
        (lambda: Ramp(0, 1, 5.0, 2.0), "t_end must be > t_start = 5.0, got t_end = 2.0"),
        (lambda: RandomWalk(0, -0.1, 10, 1), "std_per_sqrt_s must be >= 0, got -0.1"),
        (lambda: RandomWalk(0, 0.1, 0.0, 1), "duration must be > 0, got 0.0"),
        (lambda: RandomWalk(0, 0.1, 10, -1), "seed must be >= 0, got -1"),
        (lambda: RandomWalk(0, 0.1, 1, 1, dt=2.0), "dt must be <= duration = 1.0 s, got dt = 2.0"),
        (
            lambda: RandomWalk(0, 0.1, 10, 1, lower=1.0, upper=1.0),
            "upper must be > lower = 1.0, got upper = 1.0",
        ),
        (
            lambda: RandomWalk(3.0, 0.1, 10, 1, lower=0.0, upper=2.0),
            "initial must lie in [0.0, 2.0], got 3.0",
        ),
        (
            lambda: Sequence([(0.0, 1.0), (10.0, 2.0), (10.0, 3.0)]),
            "segments[2] t_start must be > 10.0 (the start of segments[1]; "
            "starts must strictly increase), got 10.0",
        ),
        (
            lambda: Sequence([(5.0, 1.0), (float("nan"), 2.0)]),
            "segments[1] t_start must be finite, got nan",
        ),
        (
            lambda: Sequence([]),
            "segments must hold at least one (t_start, schedule) pair, got none",
        ),
        (lambda: Sum([]), "terms must hold at least one schedule, got none"),
    ],
)
def test_bad_arguments_raise_value_error_naming_them(build, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        build()


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (lambda: Constant("1"), TypeError, "value must be a real number, got '1'"),
        (lambda: Step(True, 1, 0), TypeError, "before must be a real number, got True"),
        (lambda: RandomWalk(0, 0.1, 10, 1.5), TypeError, "seed must be an integer, got 1.5"),
        (lambda: Sequence([(0.0,)]), TypeError, "segments[0] must be a (t_start, schedule) pair"),
        (lambda: Sum(Constant(1.0)), TypeError, "terms must be an iterable of schedules"),
    ],
)
def test_bad_argument_types_raise_type_error(build, error, message):
    with pytest.raises(error, match=re.escape(message)):
        build()


def test_evaluating_at_nan_or_infinite_times_raises():
    s = Sigmoid(0, 1, 5, 1)
    with pytest.raises(
        ValueError,
        match=re.escape("t must be finite, found 2 non-finite time(s), the first at flat index 1"),
    ):
        s(np.array([0.0, np.nan, 2.0, np.inf]))
    with pytest.raises(ValueError, match=re.escape("t must be finite")):
        Constant(1.0)(float("nan"))
    with pytest.raises(TypeError, match=re.escape("t must be a time in s or an array of times")):
        s("soon")


def test_from_dict_rejects_unknown_kind_keys_and_missing_keys():
    with pytest.raises(ValueError, match=re.escape("schedule kind must be one of 'constant'")):
        Schedule.from_dict({"kind": "wobble"})
    with pytest.raises(TypeError, match=re.escape("Sine.from_dict got unknown key(s) 'phse'")):
        Schedule.from_dict({"kind": "sine", "mean": 0, "amplitude": 1, "period": 2, "phse": 1})
    with pytest.raises(
        TypeError, match=re.escape("Sigmoid.from_dict is missing key(s) t_mid, transition_time")
    ):
        Schedule.from_dict({"kind": "sigmoid", "start": 0, "end": 1})
    with pytest.raises(TypeError, match=re.escape("schedule must be a number or a dict")):
        Schedule.from_dict([1, 2])
    with pytest.raises(TypeError, match=re.escape("needs keys 't_start' and 'schedule'")):
        Schedule.from_dict({"kind": "sequence", "segments": [{"t_start": 0}]})


def test_schedules_are_frozen():
    s = Sigmoid(0, 1, 5, 1)
    with pytest.raises(AttributeError):
        s.start = 2.0  # type: ignore[misc]
