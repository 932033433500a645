"""Closed-loop simulation against independent references.

Tolerances, and why:
- Padé delays, constant parameters: the simulation is the exact zero-order-hold
  solution of the closed loop, so it equals lsim(interp=False) of the analytic
  closed-loop transfer functions up to rounding and the conditioning of high-order
  polynomials: 1e-9 of the signal's standard deviation (the issue asks 1e-6).
- Sampled loop: exact discrete interconnection, 1e-11.
- Time-varying parameters frozen per sample against solve_ivp frozen the same way:
  ODE tolerance, 1e-8. Against solve_ivp with continuously varying parameters the
  difference is the freezing error, of order dt times the parameters' rate of change:
  a few 1e-3 for the fast schedules below.
- Exact delay against Padé order 10: the Padé error plus the delay line's O(dt^2):
  below 0.5 % at every forcing frequency.
"""

import functools
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import scipy.integrate
import scipy.signal

from manualcontrol.envs.dynamics import pade
from manualcontrol.envs.schedules import Schedule, Sigmoid, Sine
from manualcontrol.envs.signals import forcing_preset
from manualcontrol.pilots import (
    HumanLimitWarning,
    LevisonRemnant,
    Pilot,
    SimulationSetup,
    UnstableLoopWarning,
    remnant_power_ratio,
    simulate,
    simulate_many,
)

sys.path.insert(0, str(Path(__file__).parent))
from closed_loop_reference import closed_loop_outputs, sampled_loop_outputs

DT = 0.01
SI = ([1.5], [1.0, 0.0])
DI = ([5.0], [1.0, 0.0, 0.0])
# thesis Table 6.1: Sim 2 (SI) and Sim 8 (DI). Sim 1's compensatory gains (K_p 0.1,
# K_v 1.5 on 5/s^2) close an unstable loop with a 0.3 s delay, so the compensatory DI
# case uses Sim 8's equalisation, which crosses over near 2 rad/s.
PREVIEW_SI = dict(
    K_f=1.0, omega_f=3.3, tau_f=0.6, K_p=1.3, K_v=0.0, omega_nms=10.5, zeta_nms=0.35, tau_v=0.26
)
PREVIEW_DI = dict(
    K_f=0.9, omega_f=1.0, tau_f=0.6, K_p=0.24, K_v=0.36, omega_nms=8.0, zeta_nms=0.45, tau_v=0.3
)
COMPENSATORY = {
    key: value for key, value in PREVIEW_DI.items() if key not in ("K_f", "omega_f", "tau_f")
}


def _inputs_of(pilot, element, **kwargs):
    setup = SimulationSetup.create(pilot, element, "vanderel-bw4", **kwargs)
    return setup, setup.forcing_signals(setup.parameter_traces())


CASES = [
    ("precision", "SI", SI, {k: PREVIEW_SI[k] for k in COMPENSATORY}),
    ("precision", "DI", DI, COMPENSATORY),
    ("preview", "SI", SI, PREVIEW_SI),
    ("preview", "DI", DI, PREVIEW_DI),
]


@pytest.mark.parametrize(("model", "element", "ce", "values"), CASES)
@pytest.mark.parametrize("order", [3, 5])
def test_pade_loop_equals_lsim_of_analytic_closed_loop(model, element, ce, values, order):
    pilot = Pilot(model, values, delay_order=order)
    setup, signals = _inputs_of(pilot, element)
    signals["n"] = 0.3 * np.random.default_rng(0).standard_normal(setup.n_samples)
    recording = simulate(pilot, element, "vanderel-bw4", remnant_signal=signals["n"])
    u, y = closed_loop_outputs(values, ce, signals, order, model == "preview", DT)
    measured = slice(setup.n_run_in, None)
    for name, reference in (("u", u[measured]), ("y", y[measured])):
        error = np.max(np.abs(recording[name] - reference)) / np.std(reference)
        assert error < 1e-9, (name, error)
    np.testing.assert_allclose(recording.e, recording.ft - recording.y, atol=1e-12)


@pytest.mark.parametrize("element", ["SI", "DI"])
def test_sampled_loop_equals_discrete_interconnection(element):
    values = COMPENSATORY if element == "DI" else {k: PREVIEW_SI[k] for k in COMPENSATORY}
    pilot = Pilot("precision", values, delay_order=3)
    setup, signals = _inputs_of(pilot, element, run_in=10.0, measurement_time=30.0)
    signals["n"] = 0.3 * np.random.default_rng(1).standard_normal(setup.n_samples)
    recording = simulate(
        pilot,
        element,
        "vanderel-bw4",
        run_in=10.0,
        measurement_time=30.0,
        loop="sampled",
        remnant_signal=signals["n"],
    )
    u = sampled_loop_outputs(values, DI if element == "DI" else SI, signals, 3, DT)
    error = np.max(np.abs(recording.u - u[setup.n_run_in :])) / np.std(u)
    assert error < 1e-11


def test_time_varying_loop_against_fine_ode_integration():
    # The same LPV system (Padé block feeding the equalisation/neuromuscular block,
    # each in its own canonical state coordinates) integrated by solve_ivp: once with
    # parameters frozen over each sample like the simulation, once varying within it.
    schedules = dict(
        K_p=Sigmoid(0.3, 0.2, 5.0, 3.0),
        K_v=Sigmoid(0.3, 0.45, 5.0, 3.0),
        omega_nms=Sigmoid(8.0, 6.0, 5.0, 3.0),
        zeta_nms=Sigmoid(0.3, 0.5, 5.0, 3.0),
        tau_v=Sine(0.2, 0.05, 10.0, 0.0),
    )
    pilot = Pilot("precision", schedules, delay_order=3)
    kwargs = dict(run_in=0.0, measurement_time=10.0)
    recording = simulate(pilot, "DI", "vanderel-bw4", **kwargs)
    _, signals = _inputs_of(pilot, "DI", **kwargs)
    element = scipy.signal.tf2ss(*DI)

    @functools.lru_cache(maxsize=4)  # the frozen pass reads each sample's blocks ~50 times
    def blocks(t):
        th = {name: float(schedule(t)) for name, schedule in schedules.items()}
        delay = scipy.signal.tf2ss(*pade(th["tau_v"], 3))
        w, z = th["omega_nms"], th["zeta_nms"]
        equalised = scipy.signal.tf2ss(
            [th["K_v"] * w * w, th["K_p"] * w * w], [1, 2 * z * w, w * w]
        )
        return delay, equalised

    def signals_at(x, k, t):
        delay, equalised = blocks(t)
        y = (element[2] @ x[5:])[0] + signals["fd"][k]
        e = signals["ft"][k] - y
        w = (delay[2] @ x[:3])[0] + delay[3][0, 0] * e
        u = (equalised[2] @ x[3:5])[0]
        return delay, equalised, e, w, u

    def rhs(t, x, k, frozen):
        delay, equalised, e, w, u = signals_at(x, k, k * DT if frozen else t)
        return np.concatenate(
            [
                delay[0] @ x[:3] + delay[1][:, 0] * e,
                equalised[0] @ x[3:5] + equalised[1][:, 0] * w,
                element[0] @ x[5:] + element[1][:, 0] * u,
            ]
        )

    for frozen, bound in ((True, 1e-8), (False, 1e-2)):
        x = np.zeros(7)
        u = np.empty(len(recording))
        for k in range(len(recording)):
            u[k] = signals_at(x, k, k * DT)[4]
            x = scipy.integrate.solve_ivp(
                rhs, (k * DT, (k + 1) * DT), x, args=(k, frozen), rtol=1e-10, atol=1e-12
            ).y[:, -1]
        error = np.max(np.abs(recording.u - u)) / np.std(u)
        assert error < bound, (frozen, error)


@pytest.mark.parametrize(("model", "element", "ce", "values"), CASES)
@pytest.mark.parametrize("loop", ["continuous", "sampled"])
def test_exact_delay_close_to_high_order_pade_in_the_forcing_band(model, element, ce, values, loop):
    exact = simulate(Pilot(model, values), element, "vanderel-bw4", loop=loop)
    approximated = simulate(
        Pilot(model, values, delay_order=10), element, "vanderel-bw4", loop=loop
    )
    forcing = forcing_preset("vanderel-bw4")
    bins = np.concatenate([forcing.target.harmonics, forcing.disturbance.harmonics])
    spectrum_exact = np.fft.rfft(exact.u)[bins]
    spectrum_pade = np.fft.rfft(approximated.u)[bins]
    relative = np.abs(spectrum_exact - spectrum_pade) / np.abs(spectrum_pade)
    assert relative.max() < 5e-3


@pytest.mark.parametrize(("element", "ratio"), [("SI", 0.35), ("DI", 0.55)])
def test_remnant_power_ratio_within_five_percent(element, ratio):
    values = PREVIEW_SI if element == "SI" else PREVIEW_DI
    tau_f = Sigmoid(0.6, 0.3, 60.0, 20.0) if element == "SI" else Sigmoid(0.6, 1.0, 60.0, 20.0)
    remnant = LevisonRemnant(
        omega_r=10.0 if element == "SI" else 0.01, injection="feedback", P_r=ratio
    )
    pilot = Pilot("preview", {**values, "tau_f": tau_f}, remnant=remnant)
    for seed in range(5):
        recording = simulate(pilot, element, "vanderel-bw4", realisation=seed, seed=seed)
        assert abs(recording.metadata["remnant_power_ratio"] - ratio) <= 0.05 * ratio
        # independent check of the reported ratio: the remnant-free run by superposition
        free = simulate(pilot.with_remnant(None), element, "vanderel-bw4", realisation=seed)
        measured = remnant_power_ratio(recording.u, recording.u - free.u)
        assert measured == pytest.approx(recording.metadata["remnant_power_ratio"], rel=1e-9)


def test_constant_pilot_hits_the_power_ratio_exactly():
    pilot = Pilot("precision", COMPENSATORY, remnant="popovici2017")
    recording = simulate(pilot, "DI", "vanderel-bw4", seed=3)
    assert recording.metadata["remnant_power_ratio"] == pytest.approx(0.30, rel=1e-9)
    assert recording.metadata["remnant"]["K_r"] > 0


@pytest.mark.parametrize(
    ("model", "task", "element", "forcing", "options"),
    [
        ("precision", "compensatory", "SI", "vanderel-bw4", {}),
        ("preview", "preview", "SI", "vanderel-bw4", {}),
        (
            "postview",
            "postview",
            "gain",
            "boer-kenyon1998-postview",
            {"dt": 1 / 36, "run_in": 0.0, "loop": "sampled"},
        ),
    ],
)
def test_the_remnant_part_is_the_remnant_alone(model, task, element, forcing, options):
    # u_n is the loop driven by the remnant alone: with a fixed gain it is the same
    # whatever the forcing (a postview pilot's track edge once leaked into it), and the
    # rest of u is the remnant-free run
    pilot = Pilot(model, Pilot.typical(model, element).parameters, remnant=LevisonRemnant(K_r=0.5))
    kwargs = {"task": task, "measurement_time": 30.0, "seed": 4, **options}
    first = simulate(pilot, element, forcing, realisation=0, **kwargs)
    second = simulate(pilot, element, forcing, realisation=1, **kwargs)
    assert not np.array_equal(first.ft, second.ft)
    np.testing.assert_array_equal(first["u_n"], second["u_n"])
    free = simulate(pilot.with_remnant(None), element, forcing, realisation=1, **kwargs)
    np.testing.assert_allclose(second.u - second["u_n"], free.u, rtol=0, atol=1e-12)


def _bytes(recording):
    arrays = {**dict(recording.signals), **{f"p:{k}": v for k, v in recording.parameters.items()}}
    return {name: (np.asarray(v).dtype.str, np.asarray(v).tobytes()) for name, v in arrays.items()}


@pytest.mark.parametrize(
    ("pilot", "element", "forcing", "options"),
    [
        # time-varying, remnant calibrated to P_r: the linear loop at the mean values too
        (
            Pilot(
                "preview",
                {**PREVIEW_SI, "tau_f": Sigmoid(0.6, 0.3, 10.0, 5.0)},
                remnant=LevisonRemnant(omega_r=10.0, injection="feedback", P_r=0.35),
            ),
            "SI",
            "vanderel-bw4",
            {"run_in": 5.0, "measurement_time": 20.0, "keep_run_in": True},
        ),
        # no remnant, measurement noise drawn from the seed, a start state
        (
            Pilot("precision", COMPENSATORY),
            "DI",
            "vanderel-bw4",
            {
                "run_in": 0.0,
                "measurement_time": 20.0,
                "measurement_noise": {"u": 0.01},
                "initial_state": {"y": (0.1, 0.0), "u": (0.0, 0.0)},
            },
        ),
        # sampled loop, the postview display's edge among the forcing inputs
        (
            Pilot("postview", remnant=LevisonRemnant(K_r=0.5)),
            "gain",
            "boer-kenyon1998-postview",
            {"dt": 1 / 36, "run_in": 0.0, "measurement_time": 20.0, "loop": "sampled"},
        ),
    ],
)
def test_simulate_many_gives_simulate_bit_for_bit(pilot, element, forcing, options):
    runs = [(0, 1), (1, 1), (0, 2), (1, 2), (1, None)]
    together = list(simulate_many(pilot, element, forcing, runs=runs, **options))
    for (realisation, seed), recording in zip(runs[:-1], together, strict=False):
        alone = simulate(pilot, element, forcing, realisation=realisation, seed=seed, **options)
        assert _bytes(recording) == _bytes(alone)
        assert recording.metadata == alone.metadata
    # a seed of None draws fresh noise: not another run's remnant
    assert not np.array_equal(together[-1].u, together[1].u)


def test_simulate_many_steps_the_loop_once_per_realisation_and_once_per_seed(monkeypatch):
    from manualcontrol.pilots import simulation

    steps = []
    step = simulation._run
    monkeypatch.setattr(
        simulation, "_run", lambda *args, **kwargs: steps.append(1) or step(*args, **kwargs)
    )
    pilot = Pilot(
        "preview",
        {**PREVIEW_SI, "tau_f": Sigmoid(0.6, 0.3, 10.0, 5.0)},
        remnant=LevisonRemnant(omega_r=10.0, injection="feedback", P_r=0.35),
    )
    runs = [(realisation, seed) for seed in range(3) for realisation in range(2)]
    recordings = simulate_many(pilot, "SI", runs=runs, run_in=5.0, measurement_time=10.0)
    assert len(list(recordings)) == 6
    # the time-varying loop and the linear one at the mean values (which calibrates the
    # remnant): each stepped by the forcing once per realisation, by the remnant once
    # per seed; 2 x (2 + 3) against 4 x 6 run by run
    assert len(steps) == 10


def test_simulate_many_warns_each_run_as_simulate_does_at_the_callers_line():
    # a gain below the human range on 1/s: the shared parameter traces warn once, but
    # every run is told, as it is alone
    pilot = Pilot("precision", {**Pilot.typical("precision", "1/s").parameters, "K_p": 0.2})
    options = {"measurement_time": 10.0, "run_in": 0.0}
    runs = [(0, 1), (1, 1), (0, 2)]
    with warnings.catch_warnings(record=True) as alone:
        warnings.simplefilter("always")
        for realisation, seed in runs:
            simulate(pilot, "1/s", realisation=realisation, seed=seed, **options)
    with warnings.catch_warnings(record=True) as together:
        warnings.simplefilter("always")
        list(simulate_many(pilot, "1/s", runs=runs, **options))
    said = [(w.category, str(w.message)) for w in together]
    assert said == [(w.category, str(w.message)) for w in alone]
    assert len(said) >= 3 and all(category is HumanLimitWarning for category, _ in said)
    assert {w.filename for w in alone + together} == {__file__}


def test_simulate_many_warns_as_simulate_does_before_a_run_fails():
    # a gain far above the human range warns, then the preview time beyond the 1 s
    # shown fails: both from the parameter traces, which simulate_many shares
    pilot = Pilot("preview", {"K_p": 30.0, "tau_f": 1.5})

    def said(call):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with pytest.raises(ValueError, match="tau_f"):
                call()
        return [(w.category, str(w.message)) for w in caught]

    alone = said(lambda: simulate(pilot, "SI", seed=1, measurement_time=5.0))
    together = said(lambda: next(simulate_many(pilot, "SI", runs=[(0, 1)], measurement_time=5.0)))
    assert together == alone
    assert [category for category, _ in alone] == [HumanLimitWarning]


def test_simulate_many_drops_a_realisations_and_a_seeds_runs_after_their_last_use(monkeypatch):
    from manualcontrol.pilots import simulation

    works = []
    original_init = simulation._SharedWork.__init__

    def keeping(self):
        original_init(self)
        works.append(self)

    monkeypatch.setattr(simulation._SharedWork, "__init__", keeping)
    pilot = Pilot("precision", COMPENSATORY, remnant="popovici2017")
    # numpy integers (np.arange) own the same runs as the ints they equal
    runs = [(np.int64(0), 1), (0, np.int64(2)), (1, 2)]
    recordings = simulate_many(pilot, "DI", runs=runs, run_in=0.0, measurement_time=5.0)

    def kept():
        return sorted({tag for tag, _ in works[0]._kept})

    next(recordings)  # seed 1 is done with, realisation 0 is used again
    assert kept() == ["forced", "forcing", "loop", "traces"]
    next(recordings)  # realisation 0 is done with, seed 2 is used again
    assert kept() == ["loop", "remnant", "traces"]
    list(recordings)
    assert kept() == ["loop", "traces"]  # nothing a realisation or a seed owned


@pytest.mark.parametrize(
    ("kwargs", "error", "message"),
    [
        ({"runs": [(0, 1)], "seed": 3}, TypeError, "in runs, not seed="),
        ({"runs": [(0, 1)], "realisation": 1}, TypeError, "in runs, not realisation="),
        (
            {"runs": [(0, 1)], "run_time": 3.0},
            TypeError,
            "simulate_many got unknown key(s) 'run_time'",
        ),
        (
            {"runs": [0, 1]},
            TypeError,
            "runs must be a sequence of (realisation, seed) pairs, got [0, 1]",
        ),
        ({"runs": "01"}, TypeError, "runs must be a sequence of (realisation, seed) pairs"),
        ({"runs": [(0, 1), (12, 1)]}, ValueError, "runs[1]: realisation must lie in [0, 9]"),
        (
            {"runs": [(0, "x")]},
            TypeError,
            "runs[0]: seed must be an int, a numpy Generator or None",
        ),
        ({"runs": [(0, -1)]}, ValueError, "runs[0]: seed must be >= 0, got -1"),
    ],
)
def test_simulate_many_refuses_bad_runs_and_options_when_called(kwargs, error, message):
    with pytest.raises(error, match=re.escape(message)):
        simulate_many(Pilot("precision"), **kwargs)


def test_same_seed_same_recording_bit_for_bit():
    pilot = Pilot("preview", {"tau_f": Sigmoid(0.6, 0.3, 50.0, 10.0)}, remnant="vertregt2020-SI")
    first = simulate(pilot, "SI", "vanderel-bw4", seed=11)
    again = simulate(pilot, "SI", "vanderel-bw4", seed=11)
    other = simulate(pilot, "SI", "vanderel-bw4", seed=12)
    assert first.equals(again)
    assert not np.array_equal(first.n, other.n)
    generator = simulate(pilot, "SI", "vanderel-bw4", seed=np.random.default_rng(11))
    np.testing.assert_array_equal(generator.u, first.u)


def test_recording_contents():
    schedule = Sigmoid(0.6, 0.3, 50.0, 10.0)
    pilot = Pilot("preview", {"tau_f": schedule})
    recording = simulate(pilot, "SI", "vanderel-bw4", run_in=30.0, measurement_time=60.0)
    assert len(recording) == 6000 and recording.t[0] == 0.0
    np.testing.assert_allclose(recording.parameters["tau_f"], schedule(recording.t))
    # the previewed target is the target read tau_f ahead (bicubic interpolation of
    # the displayed samples: 2e-5 error from the weak 20 rad/s components)
    target = forcing_preset("vanderel-bw4").target
    np.testing.assert_allclose(
        recording["ft_far"], target(recording.t + schedule(recording.t)), atol=5e-5
    )
    assert recording.metadata["task"] == "preview"
    assert Pilot.from_dict(recording.metadata["pilot"]).to_dict() == pilot.to_dict()


def test_pursuit_is_preview_without_preview():
    pilot = Pilot("preview", {"tau_f": 0.0})
    recording = simulate(
        pilot, "SI", "vanderel-bw4", task="pursuit", run_in=5.0, measurement_time=20.0
    )
    np.testing.assert_array_equal(recording["ft_far"], recording.ft)
    with pytest.raises(
        ValueError, match=re.escape("tau_f must not exceed the available preview of 0 s")
    ) as caught:
        simulate(Pilot("preview"), "SI", task="pursuit")
    # and says which pilot flies a pursuit display
    assert "a pursuit pilot is the preview model with tau_f = 0" in str(caught.value)


class _NotANumber(Schedule):
    def _evaluate(self, t):
        return np.full_like(t, np.nan)

    def to_dict(self):
        return {"kind": "nan"}

    def describe(self):
        return "nan"


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (lambda: Pilot("crossover"), ValueError, "pilot model must be one of"),
        (
            lambda: Pilot("precision", {"T_L": 0.3}),
            ValueError,
            "PrecisionModel has no parameter(s) 'T_L'",
        ),
        (
            lambda: Pilot("precision", {"tau_v": -0.1}),
            ValueError,
            "pilot parameter tau_v must lie in [0, inf] s, got -0.1",
        ),
        (
            lambda: Pilot("precision", {"omega_nms": 0.0}),
            ValueError,
            "pilot parameter omega_nms must lie in (0, inf] rad/s, got 0.0",
        ),
        (lambda: Pilot("precision", delay_order=0), ValueError, "delay_order must be >= 1, got 0"),
        (
            lambda: simulate(Pilot("preview", {"tau_f": -0.2})),
            ValueError,
            "pilot parameter tau_f must lie in [0, inf] s, got -0.2",
        ),
        (
            lambda: simulate(
                Pilot("preview", {"tau_f": Sine(0.5, 0.4, 20.0)}), available_preview=0.8
            ),
            ValueError,
            "tau_f must not exceed the available preview of 0.8 s in a preview task, got 0.9",
        ),
        (
            lambda: simulate(Pilot("precision"), task="preview"),
            ValueError,
            "task 'preview' does not fit the 'precision' pilot model, "
            "which is a compensatory model",
        ),
        (lambda: simulate(Pilot("precision"), loop="hybrid"), ValueError, "loop must be one of"),
        (
            lambda: simulate(Pilot("precision"), "TI"),
            ValueError,
            "controlled element must be one of",
        ),
        (
            lambda: simulate(Pilot.typical("precision", "SI"), remnant_signal=np.zeros(10)),
            ValueError,
            "remnant_signal must have length 18000, got length 10",
        ),
        (
            lambda: simulate(Pilot("precision", {"K_p": _NotANumber()})),
            ValueError,
            "pilot parameter K_p must be finite",
        ),
    ],
)
def test_bad_input_raises(build, error, message):
    with pytest.raises(error, match=re.escape(message)):
        build()


def test_parameters_outside_human_limits_warn():
    with pytest.warns(
        HumanLimitWarning,
        match=re.escape("omega_nms = 20 rad/s is outside the human range [6, 15]"),
    ):
        Pilot("precision", {"omega_nms": 20.0})
    # schedules warn when evaluated
    pilot = Pilot.typical("precision", "DI", {"tau_v": Sigmoid(0.2, 0.9, 30.0, 5.0)})
    # tau_v 0.9 s on a DI also diverges: flagged, kept with on_unstable="warn"
    with pytest.warns(UnstableLoopWarning), pytest.warns(HumanLimitWarning, match="tau_v"):
        simulate(pilot, "DI", run_in=0.0, measurement_time=60.0, on_unstable="warn")


def test_closed_loop_model_has_the_analytic_response():
    from closed_loop_reference import pilot_polynomials

    from manualcontrol.envs.dynamics import frequency_response
    from manualcontrol.pilots import closed_loop

    pilot = Pilot("precision", COMPENSATORY, delay_order=4)
    loop = closed_loop(SimulationSetup.create(pilot, "DI", "vanderel-bw4"))
    assert loop.inputs == ("ft", "fd") and loop.outputs == ("u", "y", "e", "n")
    omega = np.logspace(-1, 1.2, 20)
    num, den = pilot_polynomials(COMPENSATORY, 4)
    s = 1j * omega
    hp = np.polyval(num, s) / np.polyval(den, s)
    hc = 5.0 / s**2
    np.testing.assert_allclose(frequency_response(loop.system, omega)[:, 0, 0], hp / (1 + hp * hc))
    assert np.all(np.linalg.eigvals(loop.system.A).real < 0)  # Sim 8 gains: a stable loop


def test_keep_run_in_returns_the_whole_run():
    pilot = Pilot("precision", COMPENSATORY, remnant="popovici2017")
    whole = simulate(pilot, "DI", run_in=10.0, measurement_time=20.0, seed=1, keep_run_in=True)
    cut = simulate(pilot, "DI", run_in=10.0, measurement_time=20.0, seed=1)
    assert whole.t[0] == pytest.approx(-10.0) and len(whole) == 3000
    np.testing.assert_array_equal(whole.slice_time(0.0).u, cut.u)
    assert whole.metadata["remnant_power_ratio"] == cut.metadata["remnant_power_ratio"]


def test_the_preview_read_in_numpy_gives_the_bytes_of_the_compiled_read():
    """:func:`read_preview` against numba's ``interpolate_at`` of each sample's window.

    The same bicubic read for every sample at once: equal to the bit, positions before
    the window, past its last sample, on whole samples and between, windows cut short
    by the end of the array.
    """
    from manualcontrol.envs._interpolation import interpolate_at
    from manualcontrol.pilots.loop import read_preview

    rng = np.random.default_rng(7)
    target = rng.normal(size=400)
    for window in (1, 2, 5, 60, 500):
        positions = rng.uniform(-3.0, window + 3.0, size=target.shape[0])
        positions[::7] = np.round(positions[::7])  # whole samples
        positions[:4] = (0.0, window - 1.0, -0.0, window - 1.0 + 1e-12)
        value, slope = read_preview(target, positions, window)
        for k in range(target.shape[0]):
            expected = interpolate_at(target[k : k + window], positions[k])
            assert value[k : k + 1].tobytes() == np.float64(expected[0]).tobytes(), (window, k)
            assert slope[k : k + 1].tobytes() == np.float64(expected[1]).tobytes(), (window, k)
