"""The sigmoid-schedule output-error fit against pilots whose change is known."""

import math
import re

import numpy as np
import pytest

from manualcontrol.envs.schedules import Sigmoid
from manualcontrol.estimators import make_estimator
from manualcontrol.estimators.analysis.metrics import vaf
from manualcontrol.estimators.offline.schedule_fit import _Layout, fit_pilot_sigmoid
from manualcontrol.estimators.protocol import reporting_progress
from manualcontrol.pilots import Pilot, simulate
from manualcontrol.pilots.simulation import isolated_pilot_output
from manualcontrol.pilots.spec import HumanLimitWarning

DI_PILOT = dict(K_p=0.24, K_v=0.36, tau_v=0.3, omega_nms=8.0, zeta_nms=0.45)
K_P = Sigmoid(0.24, 0.40, 22.0, 6.0)
K_V = Sigmoid(0.36, 0.28, 22.0, 6.0)


def _changing_recording(**options):
    # the sampled loop is what the isolated model reproduces exactly (parameters frozen
    # over each sample in both), so a remnant-free fit must find the schedule to rounding
    pilot = Pilot("precision", {**DI_PILOT, "K_p": K_P, "K_v": K_V}, **options)
    return simulate(
        pilot, "DI", "vanderel-bw4", loop="sampled", run_in=10.0, measurement_time=40.0, seed=3
    )


@pytest.fixture(scope="module")
def changing():
    return _changing_recording()


def test_recovers_a_remnant_free_sigmoid_change(changing):
    lines = []
    with reporting_progress(lines.append):  # each start is said as it begins
        fit = fit_pilot_sigmoid(
            changing, "precision", initial=DI_PILOT, varying=("K_p", "K_v"), starts=2
        )
    assert [line.split(" (")[0] for line in lines] == [
        "sigmoid fit: start 1 of 2",
        "sigmoid fit: start 2 of 2",
    ]
    # the least squares stop at scipy's default tolerances (ftol = xtol = 1e-8), which
    # leave errors of order 1e-4 here (VAF 99.999999 %); a wrong local optimum, or a
    # schedule read one sample off, is off by percent
    assert fit.start["K_p"] == pytest.approx(0.24, rel=1e-3)
    assert fit.end["K_p"] == pytest.approx(0.40, rel=1e-3)
    assert fit.start["K_v"] == pytest.approx(0.36, rel=1e-3)
    assert fit.end["K_v"] == pytest.approx(0.28, rel=1e-3)
    assert fit.t_mid == pytest.approx(22.0, abs=0.01)
    assert fit.transition_time == pytest.approx(6.0, rel=1e-3)
    for name in ("tau_v", "omega_nms", "zeta_nms"):
        assert fit.start[name] == fit.end[name] == pytest.approx(DI_PILOT[name], rel=1e-3)
    assert fit.varying == ("K_p", "K_v") and fit.success and fit.vaf > 99.9999
    traces = fit.traces(changing.t)
    np.testing.assert_allclose(traces["K_p"], changing.parameters["K_p"], rtol=1e-3)


def test_a_clean_change_has_no_warnings(changing):
    fit = fit_pilot_sigmoid(changing, "precision", initial=DI_PILOT, varying=("K_p",), starts=1)
    assert fit.success and fit.warnings == ()


@pytest.mark.parametrize(
    ("schedule", "warning"),
    [
        # a step (0.02 s) is shorter than the shortest transition (10 samples)
        (Sigmoid(0.24, 0.40, 22.0, 0.02), "the transition time is at its shortest (0.10 s)"),
        # 99 % of the change over 2000 s: inside a 40-s window, a drift
        (Sigmoid(0.20, 0.60, 22.0, 2000.0), "the transition time is at its longest (160 s)"),
        # the change is mostly over when the fitted window starts (at 2 s, after the skip)
        (Sigmoid(0.40, 0.24, 1.0, 6.0), "the inflection (3.90 s) is at the edge"),
    ],
)
def test_a_fit_that_ends_on_a_bound_says_so(schedule, warning):
    pilot = Pilot("precision", {**DI_PILOT, "K_p": schedule})
    recording = simulate(
        pilot, "DI", "vanderel-bw4", loop="sampled", run_in=10.0, measurement_time=40.0, seed=3
    )
    fit = fit_pilot_sigmoid(recording, "precision", initial=DI_PILOT, varying=("K_p",), starts=1)
    assert any(text.startswith(warning) for text in fit.warnings), fit.warnings


def test_an_optimiser_that_did_not_converge_is_reported():
    from types import SimpleNamespace

    from manualcontrol.estimators.offline.schedule_fit import _fit_warnings

    best = SimpleNamespace(success=False, message="the maximum number of evaluations")
    bounds = {"t_mid": (20.0, 2.0, 38.0), "transition": (5.0, 0.1, 160.0)}
    (text,) = _fit_warnings(best, changed=True, **bounds)
    assert text == "the optimiser stopped without converging (the maximum number of evaluations)"
    # a fit without change has no inflection or transition to speak of
    assert _fit_warnings(SimpleNamespace(success=True, message=""), changed=False, **bounds) == ()


def test_a_constant_pilot_gets_a_flat_sigmoid():
    pilot = Pilot("precision", DI_PILOT)
    recording = simulate(
        pilot, "DI", "vanderel-bw4", loop="sampled", run_in=10.0, measurement_time=40.0
    )
    fit = fit_pilot_sigmoid(recording, "precision", initial=DI_PILOT, starts=1)
    # the isolated model starts at rest where the recorded loop had run in: a change at
    # the window's first edge absorbs what is left of that start (0.2 % of K_p here);
    # any real step would be tens of percent
    for name, value in DI_PILOT.items():
        assert fit.start[name] == pytest.approx(value, rel=5e-3), name
        assert fit.end[name] == pytest.approx(value, rel=5e-3), name
    assert fit.warnings == ()  # no change, so no inflection at an edge to warn of


def test_estimator_reports_the_traces_their_spread_and_the_fit(changing):
    noisy = _changing_recording(remnant="popovici2017")
    estimator = make_estimator(
        {
            "name": "sigmoid-fit",
            "model": "precision",
            "initial": DI_PILOT,
            "estimated": ["K_p", "K_v", "tau_v"],
            "starts": 2,
            "preset": "vertregt2020",  # a filter's tuning key: accepted, not used
        }
    )
    result = estimator.estimate(noisy)
    assert result.smoothed and result.estimated == ("K_p", "K_v", "tau_v")
    fit = result.settings["sigmoid"]
    names = list(result.parameter_names)
    # the traces are the reported sigmoid, and the held parameters sit at their initial value
    expected = Sigmoid(fit["start"]["K_p"], fit["end"]["K_p"], fit["t_mid"], fit["transition_time"])
    np.testing.assert_allclose(result.mean[:, names.index("K_p")], expected(noisy.t), rtol=1e-12)
    assert np.all(result.mean[:, names.index("omega_nms")] == 8.0)
    assert np.all(result.std[:, names.index("omega_nms")] == 0.0)
    assert np.all(result.std[:, names.index("K_p")] > 0.0)
    # far from the change a value's spread is its start's (end's) least-squares spread:
    # x = (K_p, K_v, tau_v starts, their ends, t_mid, log transition time)
    covariance = estimator.fit(noisy).covariance
    before, after = np.searchsorted(noisy.t, [10.0, 39.0])
    spread = result.std[:, names.index("K_p")]
    assert spread[before] == pytest.approx(math.sqrt(covariance[0, 0]), rel=1e-6)
    assert spread[after] == pytest.approx(math.sqrt(covariance[3, 3]), rel=1e-6)
    assert np.all(np.isnan(result.predictions))
    # the VAF recomputed from the traces with the isolated model, over the fitted window
    values = {n: result.mean[:, j] for j, n in enumerate(names)}
    u_hat = isolated_pilot_output("precision", values, {"e": np.asarray(noisy.e)}, noisy.dt)
    window = noisy.t >= noisy.t[0] + 2.0 - 1e-9
    assert fit["vaf"] == pytest.approx(vaf(noisy.u[window], u_hat[window]), abs=1e-9)
    # with 30 % remnant the change is still found when and as it happened; the values
    # carry output error's closed-loop bias (K_p 0.35 -> 0.46 here, the truth 0.24 -> 0.40)
    assert fit["t_mid"] == pytest.approx(22.0, abs=1.0)
    assert fit["transition_time"] == pytest.approx(6.0, rel=0.25)
    assert fit["end"]["K_p"] - fit["start"]["K_p"] > 0.05
    assert fit["end"]["K_v"] - fit["start"]["K_v"] < -0.05


def test_trace_gradients_match_finite_differences():
    layout = _Layout(("a", "b", "c"), ("a", "c"), {"d": 2.0})
    x = np.array([0.7, 1.0, 3.0, 2.0, 1.5, 4.0, math.log(5.0)])
    t = np.linspace(0.0, 8.0, 41)
    analytic = layout.gradients(x, t)
    for name in ("a", "b", "c"):
        numeric = np.empty((len(t), len(x)))
        for i in range(len(x)):
            step = np.zeros(len(x))
            step[i] = 1e-6
            up = np.broadcast_to(layout.traces(x + step, t)[name], t.shape)
            down = np.broadcast_to(layout.traces(x - step, t)[name], t.shape)
            numeric[:, i] = (up - down) / 2e-6
        # central differences of smooth functions: error of order step^2 times the third
        # derivative, far below 1e-6 here
        np.testing.assert_allclose(analytic[name], numeric, atol=1e-6)
    assert layout.traces(x, t)["d"] == 2.0


@pytest.mark.parametrize(
    ("settings", "error", "message"),
    [
        ({"strts": 2}, TypeError, "unknown key(s) 'strts'"),
        ({"starts": 0}, ValueError, "starts must be >= 1, got 0"),
        ({"varying": ["K_f"]}, ValueError, "varying names ['K_f']"),
        ({"estimated": ["K_p"], "varying": ["K_v"]}, ValueError, "varying names ['K_v']"),
        ({"varying": "K_p"}, TypeError, "varying must be a sequence of parameter names"),
        ({"initial": {"K_f": 1.0}}, ValueError, "initial names ['K_f']"),
        ({"skip": -1.0}, ValueError, "skip must be >= 0, got -1.0"),
        ({"ce": "TI"}, ValueError, "ce must be one of"),
        ({"varying": []}, ValueError, "varying must name at least one parameter, got []"),
        ({"varying": ["K_p", "K_p"]}, ValueError, "varying names a parameter twice"),
        ({"estimated": []}, ValueError, "estimated must name at least one parameter"),
        ({"limits": {"K_p": (0.1,)}}, ValueError, "limits of K_p must be (low, high)"),
        ({"model": "postview"}, ValueError, "the postview model perceives ft_edge"),
        (
            {"model": "preview", "anticipation_time": 0.15},
            ValueError,
            "anticipation_time must exceed 0.2 s",
        ),
        ({"highpass": "always"}, ValueError, "highpass must be one of"),
        ({"highpass": -0.1}, ValueError, "highpass must be > 0, got -0.1"),
        ({"limits": "tabel-I"}, ValueError, "limits must be one of"),
        ({"limits": 5}, TypeError, "limits must be 'table-I', 'none' or"),
        ({"limits": {"K_p": (1.0, 0.5)}}, ValueError, "limits of K_p must satisfy low < high"),
        ({"limits": {"K_f": (0.0, 1.0)}}, ValueError, "limits names ['K_f']"),
    ],
)
def test_bad_settings_are_refused_by_name(settings, error, message):
    with pytest.raises(error, match=re.escape(message)):
        make_estimator({"name": "sigmoid-fit", "model": "precision", **settings})


def test_bad_recordings_and_calls_are_refused(changing):
    with pytest.raises(ValueError, match=re.escape("skip = 30 s leaves less than half")):
        fit_pilot_sigmoid(changing, "precision", skip=30.0)
    u = np.array(changing.u)
    u[3000] = np.nan
    with pytest.raises(ValueError, match="u has dropped samples"):
        fit_pilot_sigmoid(changing.with_signals(u=u), "precision")
    with pytest.raises(ValueError, match="every parameter is fixed"):
        fit_pilot_sigmoid(changing, "precision", fixed=DI_PILOT)
    e = np.array(changing.e)
    e[10] = np.nan  # even inside the skipped seconds: the model runs from the first sample
    with pytest.raises(ValueError, match="e has dropped samples"):
        fit_pilot_sigmoid(changing.with_signals(e=e), "precision")
    with pytest.raises(ValueError, match="the recording has 100 samples; a sigmoid fit"):
        fit_pilot_sigmoid(changing.slice_samples(0, 100), "precision")
    estimator = make_estimator({"name": "sigmoid-fit"})
    with pytest.raises(
        TypeError, match=re.escape("takes forcing= (and target_period=), got smooth")
    ):
        estimator.estimate(changing, smooth=True)
    with pytest.raises(TypeError, match="works on whole recordings"):
        estimator.reset(0.01)
    with pytest.raises(ValueError, match=r"pass forcing= .* instead of target_period="):
        estimator.estimate(changing, target_period=40.0)
    with pytest.raises(TypeError, match="forcing must be a ForcingPair"):
        estimator.estimate(changing, forcing=np.sin)


def test_the_familys_limits_bound_the_fit_and_pinned_values_are_reported(changing):
    # K_p truly ends at 0.40: held under 0.3, the fit ends on that bound, says so in its
    # health, and the model's human range (no ce) is what applies otherwise
    estimator = make_estimator(
        {
            "name": "sigmoid-fit",
            "initial": DI_PILOT,
            "estimated": ["K_p", "K_v"],
            "limits": {"K_p": (0.1, 0.3)},
            "starts": 1,
        }
    )
    result = estimator.estimate(changing)
    fit = result.settings["sigmoid"]
    assert fit["end"]["K_p"] == pytest.approx(0.3, abs=1e-6)
    assert result.health.pinned_fraction["K_p"] > 0.3
    assert result.health.pinned_fraction["K_v"] == 0.0
    assert result.settings["settings"]["limits"] == {"K_p": [0.1, 0.3]}
    # ce="SI" holds the parameters the filters hold there, and takes Table I
    si = make_estimator({"name": "sigmoid-fit", "ce": "SI", "starts": 1})
    assert "K_v" not in si.settings["estimated"]
    # the DI pilot's gain on SI, a low loop gain the pilot rightly warns about
    with pytest.warns(HumanLimitWarning, match="outside the gains humans use"):
        single = simulate(
            Pilot("precision", {"K_p": K_P, "K_v": 0.0}),
            "SI",
            "vanderel-bw4",
            loop="sampled",
            run_in=10.0,
            measurement_time=30.0,
        )
    held = si.estimate(single)
    assert np.all(held.mean[:, list(held.parameter_names).index("K_v")] == 0.0)
    assert held.settings["sigmoid"]["end"]["K_p"] == pytest.approx(0.40, rel=1e-2)
    assert si.settings["limits"]["omega_nms"] == [6.0, 15.0]
    preview = make_estimator(
        {"name": "sigmoid-fit", "model": "preview", "ce": "DI", "anticipation_time": 1.5}
    )
    assert preview.settings["limits"]["tau_f"] == [0.1, 1.4]


def test_the_parameter_figure_of_a_fit_without_innovations_has_no_innovation_panel(
    changing, tmp_path
):
    import dataclasses

    import matplotlib.image

    from manualcontrol.bench.report import plot_estimation

    estimator = make_estimator(
        {"name": "sigmoid-fit", "initial": DI_PILOT, "estimated": ["K_p"], "starts": 1}
    )
    result = estimator.estimate(changing)
    with_innovations = dataclasses.replace(
        result,
        innovations=np.zeros_like(result.innovations),
        innovation_covariance=np.ones_like(result.innovation_covariance),
    )
    heights = []
    for label, shown in (("fit", result), ("filter", with_innovations)):
        path = plot_estimation(changing, shown, tmp_path / f"{label}.png")
        heights.append(matplotlib.image.imread(path).shape[0])
    # 1.8 inches at 100 dpi a panel: one parameter alone, or with the innovation panel
    assert heights == [180, 360]


def test_the_highpass_prefilter_takes_a_drift_below_it_out_of_the_cost(changing):
    # u drifts at 0.01 rad/s (amplitude 1 against a stick of std 2), as the double
    # integrator's remnant does: the plain output error bends the sigmoid to it; the
    # error high-passed at 0.05 rad/s (the drift attenuated to 0.2^4 by the zero-phase
    # filter) finds the change again, but for the filter's edge transients on a 38-s
    # window (measured: values 0.2 %, transition time 10 %)
    drifting = changing.with_signals(u=changing.u + np.sin(0.01 * changing.t + 0.3))
    options = dict(initial=DI_PILOT, varying=("K_p", "K_v"), starts=1)
    plain = fit_pilot_sigmoid(drifting, "precision", **options)
    assert plain.transition_time < 3.0  # bent: 0.4 s measured, for the truth's 6 s
    fit = fit_pilot_sigmoid(drifting, "precision", highpass=0.05, **options)
    assert fit.start["K_p"] == pytest.approx(0.24, rel=0.01)
    assert fit.end["K_p"] == pytest.approx(0.40, rel=0.01)
    assert fit.t_mid == pytest.approx(22.0, abs=0.3)
    assert fit.transition_time == pytest.approx(6.0, rel=0.2)
    assert fit.highpass == 0.05 and fit.vaf < 99.0  # the VAF is of the unfiltered error


def test_highpass_is_automatic_on_the_double_integrator_only(changing):
    common = {"name": "sigmoid-fit", "initial": DI_PILOT, "estimated": ["K_p"], "starts": 1}
    di = make_estimator({**common, "ce": "DI"}).estimate(changing)
    # half the lowest frequency of vanderel-bw4 (0.1047 rad/s)
    assert di.settings["sigmoid"]["highpass"] == pytest.approx(0.1047198 / 2, rel=1e-6)
    si = make_estimator({**common, "ce": "SI"}).estimate(changing)
    assert si.settings["sigmoid"]["highpass"] is None
    bare = type(changing)({n: changing[n] for n in changing.signal_names}, changing.dt)
    with pytest.raises(ValueError, match="no multisine forcing"):
        make_estimator({**common, "ce": "DI"}).estimate(bare)
    with pytest.raises(ValueError, match="highpass must lie below the Nyquist frequency"):
        fit_pilot_sigmoid(changing, "precision", highpass=1000.0)


def test_the_double_integrator_starts_the_far_view_break_where_the_filters_do():
    preview = dict(DI_PILOT, K_f=0.9, omega_f=1.0, tau_f=0.8)
    recording = simulate(
        Pilot("preview", preview), "DI", "vanderel-bw4", loop="sampled", measurement_time=8.0
    )
    settings = {
        "name": "sigmoid-fit",
        "model": "preview",
        "anticipation_time": 1.5,
        "estimated": ["K_p"],
        "starts": 1,
    }
    held = make_estimator({**settings, "ce": "DI"}).estimate(recording).final()
    assert held["omega_f"] == 1.0  # pilot_filter.DI_FAR_BREAK, thesis Table 6.3
    assert make_estimator(settings).estimate(recording).final()["omega_f"] == 3.3  # nominal


def test_a_sigmoid_fit_of_the_lag_model_names_it_so_its_settings_rebuild_it():
    # the lag's precision model is the class "precision" with a lag: saved by its class
    # name, its settings rebuilt a fit without T_I and refused its own estimated names
    from manualcontrol.estimators.offline.schedule_fit import SigmoidFitEstimator

    estimator = make_estimator({"name": "sigmoid-fit", "model": "precision-lag"})
    assert estimator.settings["model"] == "precision-lag"
    rebuilt = SigmoidFitEstimator.from_settings(estimator.settings)
    assert rebuilt.settings == estimator.settings and "T_I" in rebuilt.settings["estimated"]
