"""Pilot model structures and remnant models against the papers' formulas."""

import re

import numpy as np
import pytest
import scipy.signal

from manualcontrol.pilots import (
    MODEL_NAMES,
    HumanLimitWarning,
    LevisonRemnant,
    Pilot,
    SchiessRolandRemnant,
    ZaalRemnant,
    make_model,
    make_remnant,
    simulate,
)
from manualcontrol.pilots.models import PrecisionModel, model_for_element

OMEGA = np.logspace(-1, 1.3, 25)


def test_precision_model_is_popovici_eq1():
    values = dict(K_p=1.5, K_v=0.5, tau_v=0.2, omega_nms=8.0, zeta_nms=0.3)
    s = 1j * OMEGA
    expected = (1.5 + 0.5 * s) * np.exp(-0.2 * s) * 64.0 / (s**2 + 2 * 0.3 * 8.0 * s + 64.0)
    got = make_model("precision").frequency_response(values, OMEGA, "e")
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_precision_model_with_its_lag_is_mcruers_lag_equaliser():
    """The lag form against scipy.signal's rational response times the exact delay."""
    values = dict(K_p=10.0, K_v=0.4, T_I=3.0, tau_v=0.26, omega_nms=10.5, zeta_nms=0.35)
    model = make_model("precision", lag=True)
    assert model.parameter_names == ("K_p", "K_v", "T_I", "tau_v", "omega_nms", "zeta_nms")
    num = np.polymul([0.4, 10.0], [10.5**2])
    den = np.polymul([3.0, 1.0], [1.0, 2 * 0.35 * 10.5, 10.5**2])
    _, rational = scipy.signal.freqs(num, den, worN=OMEGA)
    expected = rational * np.exp(-0.26j * OMEGA)
    np.testing.assert_allclose(model.frequency_response(values, OMEGA, "e"), expected, rtol=1e-12)
    # T_I = 0 is Popovici's eq. 1, the model without its lag
    plain = {k: v for k, v in values.items() if k != "T_I"}
    np.testing.assert_allclose(
        model.frequency_response({**values, "T_I": 0.0}, OMEGA, "e"),
        make_model("precision").frequency_response(plain, OMEGA, "e"),
        rtol=1e-12,
    )
    assert make_model("precision") == make_model("precision", lag=False) != model
    with pytest.raises(TypeError, match="lag must be True or False, got 'yes'"):
        make_model("precision", lag="yes")


def test_a_lagging_pilot_keeps_its_lag_through_its_dict():
    from manualcontrol.estimators.analysis.human_likeness import reference_pilot

    values = reference_pilot("gain")
    pilot = Pilot(make_model("precision", lag=True), values)
    data = pilot.to_dict()
    assert data["model_options"] == {"lag": True}
    assert Pilot.from_dict(data).model == make_model("precision", lag=True)
    # a plain precision pilot's dict is as it always was
    assert Pilot.typical("precision", "SI").to_dict()["model_options"] == {}


def test_preview_model_far_view_and_feedback_paths():
    model = make_model("preview")
    values = model.nominal()
    s = 1j * OMEGA
    loop = (values["K_p"] + values["K_v"] * s) * np.exp(-values["tau_v"] * s)
    loop *= values["omega_nms"] ** 2 / (
        s**2 + 2 * values["zeta_nms"] * values["omega_nms"] * s + values["omega_nms"] ** 2
    )
    far = values["K_f"] * values["omega_f"] / (s + values["omega_f"])
    np.testing.assert_allclose(model.frequency_response(values, OMEGA, "ft_far"), far * loop)
    np.testing.assert_allclose(model.frequency_response(values, OMEGA, "y"), -loop)


def test_near_view_adds_a_rate_response_that_bypasses_equalisation():
    model = make_model("preview", near_view=True)
    assert model.perceptions == ("ft_far", "y", "ft_near_rate")
    values = model.nominal()
    s = 1j * OMEGA
    nms = values["omega_nms"] ** 2 / (
        s**2 + 2 * values["zeta_nms"] * values["omega_nms"] * s + values["omega_nms"] ** 2
    )
    expected = values["K_n"] * np.exp(-values["tau_v"] * s) * nms
    np.testing.assert_allclose(model.frequency_response(values, OMEGA, "ft_near_rate"), expected)
    recording = simulate(Pilot(model), "SI", run_in=5.0, measurement_time=20.0)
    assert "ft_near_rate" in recording


def test_schiess_roland_model_is_their_eq1():
    model = make_model("schiess-roland")
    values = model.nominal()
    s = 1j * OMEGA
    expected = 1.0 * (0.5 * s + 1) * np.exp(-0.05 * s) / ((0.1 * s + 1) * (0.1 * s + 1))
    np.testing.assert_allclose(model.frequency_response(values, OMEGA, "e"), expected, rtol=1e-12)


def test_gain_delay_model():
    values = dict(K_p=2.0, tau_v=0.3)
    got = make_model("gain-delay").frequency_response(values, OMEGA, "e")
    np.testing.assert_allclose(got, 2.0 * np.exp(-0.3j * OMEGA))


@pytest.mark.parametrize("name", MODEL_NAMES)
def test_rational_transfer_function_converges_to_the_exact_delay(name):
    model = make_model(name)
    values = model.nominal()
    signal = model.perceptions[0]
    omega = np.linspace(0.1, 8.0, 30)
    exact = model.frequency_response(values, omega, signal)
    num, den = model.transfer_function(values, signal, delay_order=8)
    approximated = np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega)
    np.testing.assert_allclose(approximated, exact, rtol=1e-6, atol=1e-9)


def test_parameter_specs_follow_thesis_table_1():
    model = make_model("preview")
    assert model.spec("K_f").human == (0.2, 2.5)
    assert model.spec("omega_nms").human == (6.0, 15.0)
    assert model.spec("zeta_nms").human == (0.1, 0.8)
    assert model.spec("tau_v").human == (0.1, 0.8)
    with pytest.raises(ValueError, match="PreviewModel parameter must be one of"):
        model.spec("K_q")


def test_pade_delay_must_be_positive():
    with pytest.warns(HumanLimitWarning):
        pilot = Pilot("precision", {"tau_v": 0.0}, delay_order=3)
    with (
        pytest.warns(HumanLimitWarning),
        pytest.raises(
            ValueError, match=re.escape("tau_v must be > 0 s with a Padé delay (delay_order=3)")
        ),
    ):
        simulate(pilot, "DI", run_in=0.0, measurement_time=1.0)


# ---------------------------------------------------------------------- remnant


def test_remnant_filters_are_the_papers():
    num, den = LevisonRemnant(K_r=2.0, omega_r=3.0).filter()  # thesis eq. 5
    np.testing.assert_array_equal(num, [2.0])
    np.testing.assert_array_equal(den, [1.0, 3.0])
    num, den = SchiessRolandRemnant(K_r=1.0).filter()  # Schiess-Roland eq. 2
    np.testing.assert_array_equal(den, [1.0, 4.427, 10.0])
    zaal = ZaalRemnant(K_r=1.0, omega_r=10.0, zeta_r=0.5)  # thesis eq. 2.4
    num, den = zaal.filter()
    s = 1j * OMEGA
    expected = 1000.0 / ((s**2 + 10.0 * s + 100.0) * (s + 10.0))
    np.testing.assert_allclose(np.polyval(num, s) / np.polyval(den, s), expected, rtol=1e-12)


@pytest.mark.parametrize(
    "remnant",
    [
        LevisonRemnant(K_r=0.7, omega_r=10.0, injection="feedback", P_r=0.35),
        SchiessRolandRemnant(),
        ZaalRemnant(),
    ],
)
def test_remnant_round_trip(remnant):
    assert make_remnant(remnant.to_dict()) == remnant


def test_remnant_presets_carry_the_papers_settings():
    assert make_remnant("popovici2017") == LevisonRemnant(omega_r=3.0, injection="input", P_r=0.30)
    si = make_remnant("vertregt2020-SI")
    assert (si.omega_r, si.injection, si.P_r) == (10.0, "feedback", 0.35)
    assert make_remnant("vertregt2020-DI").omega_r == 0.01


@pytest.mark.parametrize(
    ("build", "message"),
    [
        (
            lambda: LevisonRemnant(injection="stick"),
            "injection must be one of 'output', 'input', 'feedback', got 'stick'",
        ),
        (lambda: LevisonRemnant(P_r=1.2), "P_r must lie in (0, 1), got 1.2"),
        (lambda: LevisonRemnant(omega_r=-3.0), "omega_r must be > 0, got -3.0"),
        (lambda: make_remnant("white"), "remnant must be one of"),
    ],
)
def test_remnant_bad_input(build, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        build()


@pytest.mark.parametrize("injection", ["output", "input", "feedback"])
def test_injection_point_decides_where_n_enters(injection):
    # Starting at rest, nothing goes round the loop before the pilot delay has passed:
    # remnant at the output is in u at once, remnant at the input or the feedback
    # only after tau_v (20 samples).
    pilot = Pilot.typical(
        "precision", "SI", {"tau_v": 0.2}, remnant=LevisonRemnant(K_r=1.0, injection=injection)
    )
    kwargs = dict(run_in=0.0, measurement_time=5.0)
    noisy = simulate(pilot, "SI", "plaetinck2018", seed=4, **kwargs)
    free = simulate(pilot.with_remnant(None), "SI", "plaetinck2018", **kwargs)
    u_n = noisy.u - free.u
    before_delay = slice(0, 20)
    if injection == "output":
        np.testing.assert_allclose(u_n[before_delay], noisy.n[before_delay], atol=1e-12)
    else:
        np.testing.assert_allclose(u_n[before_delay], 0.0, atol=1e-12)
        assert np.max(np.abs(u_n[30:])) > 0.01


def test_the_lag_model_has_a_name_and_is_the_one_humans_fly_on_a_gain():
    lagging = make_model("precision-lag")
    assert lagging == PrecisionModel(lag=True) and "T_I" in lagging.parameter_names
    assert lagging.registered_name == "precision-lag"
    assert make_model("precision").registered_name == "precision"
    assert make_model(lagging.registered_name) == lagging  # the name builds it back
    assert model_for_element("precision", "gain") == "precision-lag"
    assert model_for_element("precision", {"kind": "gain", "K": 2.0}) == "precision-lag"
    for element in ("SI", "DI", None):
        assert model_for_element("precision", element) == "precision"
    assert model_for_element("preview", "gain") == "preview"  # the rule is the precision model's
    with pytest.raises(ValueError, match="'precision-lag' model has its lag; got lag=False"):
        make_model("precision-lag", lag=False)
