"""Simulation options: a start time, a start state, measurement noise, q.

The run from Schiess & Roland's Table I state is checked against an independent
method-of-steps integration of their retarded equations 7-12 (``solve_ivp``, the
delayed error before the start held at its first value, the forcing continuous).
Tolerance 2e-3 of the signals' range: the simulation holds the forcing over each
sample (0.25 sin t moves by up to 0.0025 per sample) and reads the delayed signal
with second-order error; measured 7.0e-4 (c), 5.6e-4 (stick), 2e-13 (remnant).
"""

import math
import re

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from manualcontrol.pilots import Pilot, SchiessRolandRemnant, simulate

TABLE_I = {
    "c": -0.9590,
    "c_rate": -5.6363,
    "u": 0.6237,
    "y4": -0.6880,
    "eta": 0.4105,
    "eta_rate": 2.5484,
}
PILOT = {"K_1": 1.0, "tau_1": 0.1, "tau_2": 0.1, "tau_3": 0.5, "theta": 0.05}
ALPHA = (4.427, 10.0)
T0 = 0.25


def table_i_conditions():
    """Table I as loop outputs and rates, the delayed error's past held at e(t0)."""
    s = TABLE_I
    e0 = 0.25 * math.sin(T0) - s["c"]
    b_u = PILOT["K_1"] * PILOT["tau_3"] / PILOT["tau_1"]
    u_rate = (s["y4"] - s["u"] + b_u * e0) / PILOT["tau_2"]  # eq. 6
    return {
        "y": (s["c"], s["c_rate"]),
        "u": (s["u"] + s["eta"], u_rate + s["eta_rate"]),
        "n": (s["eta"], s["eta_rate"]),
    }


def method_of_steps(t_end):
    """Eqs. 7-12 without remnant noise, integrated delay interval by delay interval."""
    k1, t1, t2, t3, theta = (PILOT[n] for n in ("K_1", "tau_1", "tau_2", "tau_3", "theta"))
    a1, a2 = ALPHA
    K = 10.0
    b3, b4 = k1 * t3 / (t1 * t2), k1 / t1 * (1.0 - t3 / t1)
    e0 = 0.25 * math.sin(T0) - TABLE_I["c"]
    segments = []

    def delayed_error(t):
        s = t - theta
        if s <= T0:
            return e0
        for segment in segments:
            if segment.t_min <= s <= segment.t_max:
                return 0.25 * math.sin(s) - segment(s)[0]
        raise AssertionError("history not covered")

    def f(t, y):
        e = delayed_error(t)
        return [
            y[1],
            K * (y[2] + y[4]),
            (y[3] - y[2]) / t2 + b3 * e,
            -y[3] / t1 + b4 * e,
            y[5],
            -a1 * y[5] - a2 * y[4],
        ]

    y = [TABLE_I[n] for n in ("c", "c_rate", "u", "y4", "eta", "eta_rate")]
    start = T0
    while start < t_end - 1e-12:
        stop = min(start + theta, t_end)
        solution = solve_ivp(f, (start, stop), y, rtol=1e-11, atol=1e-12, dense_output=True)
        segments.append(solution.sol)
        y = solution.y[:, -1]
        start = stop
    return segments


def test_start_state_and_time_against_the_method_of_steps():
    pilot = Pilot("schiess-roland", PILOT, remnant=SchiessRolandRemnant(noise_variance=0.0))
    recording = simulate(
        pilot,
        "schiess-roland1975",
        "schiess-roland1975",
        run_in=0.0,
        measurement_time=1.0,
        start_time=T0,
        initial_state=table_i_conditions(),
        seed=0,
    )
    t = np.asarray(recording.t)
    assert t[0] == T0 and np.allclose(np.diff(t), 0.01)
    assert recording.metadata["start_time"] == T0
    assert recording.ft[0] == pytest.approx(0.25 * math.sin(T0), abs=1e-15)
    assert recording.y[0] == pytest.approx(TABLE_I["c"], abs=1e-12)
    assert recording.n[0] == pytest.approx(TABLE_I["eta"], abs=1e-12)
    assert recording.u[0] == pytest.approx(TABLE_I["u"] + TABLE_I["eta"], abs=1e-12)
    segments = method_of_steps(float(t[-1]) + 1e-9)

    def reference(time):
        for segment in segments:
            if segment.t_min - 1e-12 <= time <= segment.t_max + 1e-12:
                return segment(time)
        raise AssertionError(time)

    states = np.array([reference(time) for time in t])
    for name, ours, theirs in (
        ("c", recording.y, states[:, 0]),
        ("delta", recording.u, states[:, 2] + states[:, 4]),
        ("eta", recording.n, states[:, 4]),
    ):
        error = np.max(np.abs(np.asarray(ours) - theirs)) / np.ptp(theirs)
        assert error < 2e-3, f"{name}: {error:.2g} of its range"


def test_measurement_noise_leaves_the_run_and_the_remnant_alone():
    pilot = Pilot("schiess-roland", PILOT, remnant=SchiessRolandRemnant(noise_variance=576.0))
    common = dict(run_in=2.0, measurement_time=30.0, seed=4)
    clean = simulate(pilot, "schiess-roland1975", "schiess-roland1975", **common)
    noisy = simulate(
        pilot,
        "schiess-roland1975",
        "schiess-roland1975",
        measurement_noise={"u": 0.00092, "y": 0.01},
        **common,
    )
    np.testing.assert_array_equal(noisy.n, clean.n)
    np.testing.assert_array_equal(noisy.e, clean.e)  # the pilot saw the clean signals
    noise_u = np.asarray(noisy.u) - clean.u
    noise_y = np.asarray(noisy.y) - clean.y
    # 3,000 samples: the sample variance is within 10 % (about 4 standard errors)
    assert np.var(noise_u) == pytest.approx(0.00092, rel=0.1)
    assert np.var(noise_y) == pytest.approx(0.01, rel=0.1)
    assert abs(np.corrcoef(noise_u, noise_y)[0, 1]) < 0.08
    assert noisy.metadata["measurement_noise"] == {"y": 0.01, "u": 0.00092}
    # the noise does not depend on whether the run-in is kept
    kept = simulate(
        pilot,
        "schiess-roland1975",
        "schiess-roland1975",
        measurement_noise={"u": 0.00092, "y": 0.01},
        keep_run_in=True,
        **common,
    )
    np.testing.assert_array_equal(np.asarray(kept.u)[200:], noisy.u)


def test_noise_variance_sets_the_remnant_gain():
    remnant = SchiessRolandRemnant(noise_variance=576.0)
    assert remnant.K_r == 24.0 and "q=576" in remnant.describe()
    assert remnant.with_gain(24.0).noise_variance == 576.0
    assert remnant.with_gain(3.0) == SchiessRolandRemnant(K_r=3.0)
    pilot = Pilot("schiess-roland", PILOT, remnant=remnant)
    recording = simulate(pilot, "schiess-roland1975", "schiess-roland1975", run_in=0.0,
                         measurement_time=5.0, seed=1)  # fmt: skip
    twice = simulate(
        pilot.with_remnant(SchiessRolandRemnant(K_r=24.0)),
        "schiess-roland1975",
        "schiess-roland1975",
        run_in=0.0,
        measurement_time=5.0,
        seed=1,
    )
    np.testing.assert_array_equal(recording.u, twice.u)
    assert recording.metadata["remnant"]["noise_variance"] == 576.0


START = dict(run_in=0.0, measurement_time=1.0, seed=0)


@pytest.mark.parametrize(
    ("options", "error", "message"),
    [
        (
            {"initial_state": {"y": (1.0, 0.0), "x": (1.0,)}},
            TypeError,
            "initial_state got unknown key(s) 'x'; known: 'e', 'n', 'u', 'y'",
        ),
        (
            {"initial_state": {"y": (1.0, 0.0)}},
            ValueError,
            "initial_state must determine the loop's 6 states exactly: it gives 2 values and "
            "derivatives of rank 2",
        ),
        (
            {"initial_state": table_i_conditions(), "loop": "sampled"},
            ValueError,
            "initial_state needs loop='continuous'",
        ),
        (
            {"initial_state": {"y": ()}},
            ValueError,
            "initial_state['y'] must have at least 1 entries, got 0",
        ),
        (
            {"measurement_noise": {"n": 0.1}},
            TypeError,
            "measurement_noise got unknown key(s) 'n'; known: 'e', 'u', 'y'",
        ),
        (
            {"measurement_noise": {"u": -0.1}},
            ValueError,
            "measurement_noise['u'] must be >= 0, got -0.1",
        ),
        ({"start_time": math.nan}, ValueError, "start_time must be finite, got nan"),
    ],
)
def test_bad_options_raise(options, error, message):
    pilot = Pilot("schiess-roland", PILOT, remnant=SchiessRolandRemnant(noise_variance=1.0))
    with pytest.raises(error, match=re.escape(message)):
        simulate(pilot, "schiess-roland1975", "schiess-roland1975", **{**START, **options})


def test_noise_variance_and_power_ratio_exclude_each_other():
    with pytest.raises(ValueError, match=re.escape("give either P_r")):
        SchiessRolandRemnant(P_r=0.5, noise_variance=25.0)
    with pytest.raises(ValueError, match=re.escape("noise_variance must be >= 0, got -1.0")):
        SchiessRolandRemnant(noise_variance=-1.0)
