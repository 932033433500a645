"""Controlled elements: presets, time-varying parameters, realisations and bad input."""

import re

import numpy as np
import pytest
import scipy.signal

from manualcontrol.envs.dynamics import frequency_response
from manualcontrol.envs.elements import (
    ELEMENT_PRESETS,
    DoubleIntegrator,
    Gain,
    Integrator,
    IntegratorWithLag,
    TransferFunctionElement,
    UnstableFirstOrder,
    critical_task,
    make_element,
    parse_element,
)
from manualcontrol.envs.schedules import Ramp, Sigmoid


@pytest.mark.parametrize(
    ("name", "num", "den"),
    [
        ("SI", [1.5], [1.0, 0.0]),
        ("DI", [5.0], [1.0, 0.0, 0.0]),
        ("schiess-roland1975", [10.0], [1.0, 0.0, 0.0]),
        ("popovici2017", [4.0], [1.0, 3.0, 0.0]),
        ("gain", [1.0], [1.0]),
    ],
)
def test_presets_carry_the_papers_values(name, num, den):
    got_num, got_den = make_element(name).transfer_function(0.0)
    np.testing.assert_array_equal(got_num, num)
    np.testing.assert_array_equal(got_den, den)


@pytest.mark.parametrize("name", ELEMENT_PRESETS)
def test_every_preset_realisation_has_its_transfer_function(name):
    element = make_element(name)
    num, den = element.transfer_function(10.0)
    omega = np.array([0.3, 1.0, 4.0, 12.0])
    expected = np.polyval(num, 1j * omega) / np.polyval(den, 1j * omega)
    got = frequency_response(element.state_space(10.0), omega)[:, 0, 0]
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_time_varying_break_frequency_follows_its_schedule():
    element = make_element("popovici2017-tv")
    assert element.is_time_varying
    t = np.array([0.0, 40.0, 45.0, 90.0])
    omega_b = element.parameters_at(t)["omega_b"]
    assert omega_b[0] == pytest.approx(3.0, abs=1e-3)
    assert omega_b[2] == pytest.approx(2.0)  # midpoint of the sigmoid
    assert omega_b[3] == pytest.approx(1.0, abs=1e-3)
    model = element.state_space(t)
    assert model.batch_shape == (4,)
    np.testing.assert_allclose(model.A[:, 1, 1], -omega_b)


def test_discretisation_matches_cont2discrete():
    element = IntegratorWithLag(4.0, 3.0)
    exact, model = element.discretize(0.01)
    phi, gamma, *_ = scipy.signal.cont2discrete((model.A, model.B, model.C, model.D), 0.01)
    np.testing.assert_allclose(exact.phi, phi, rtol=1e-13)
    np.testing.assert_allclose(exact.gamma, gamma, rtol=1e-13, atol=1e-16)


def test_general_transfer_function_with_scheduled_coefficient():
    element = TransferFunctionElement([4.0], [1.0, Sigmoid(3.0, 1.0, 40.0, 10.0), 0.0])
    reference = IntegratorWithLag(4.0, Sigmoid(3.0, 1.0, 40.0, 10.0))
    t = np.linspace(0, 80, 9)
    np.testing.assert_allclose(element.state_space(t).A, reference.state_space(t).A)
    assert element.order == 2


def test_critical_task_instability_ramps_up():
    element = critical_task(start=1.0, rate=0.1)
    values = element.parameters_at(np.array([0.0, 10.0, 20.0]))["instability"]
    np.testing.assert_allclose(values, [1.0, 2.0, 3.0])
    # lambda/(s - lambda) has its pole in the right half plane
    assert np.linalg.eigvals(element.state_space(0.0).A)[0] == pytest.approx(1.0)


@pytest.mark.parametrize(
    "element",
    [
        Gain(2.0),
        Integrator(Sigmoid(1.5, 3.0, 30.0, 5.0)),
        DoubleIntegrator(5.0),
        IntegratorWithLag(4.0, Ramp(3.0, 1.0, 20.0, 60.0)),
        UnstableFirstOrder(2.0),
        TransferFunctionElement([1.0, 2.0], [1.0, 3.0, 2.0]),
    ],
)
def test_round_trip_through_dict(element):
    restored = make_element(element.to_dict())
    t = np.linspace(0, 90, 7)
    np.testing.assert_array_equal(restored.transfer_function(t)[1], element.transfer_function(t)[1])
    assert type(restored) is type(element)


def test_unknown_preset_lists_the_allowed_names():
    message = "controlled element must be one of " + ", ".join(map(repr, ELEMENT_PRESETS))
    with pytest.raises(ValueError, match=re.escape(message + ", got 'TI'")):
        make_element("TI")


@pytest.mark.parametrize(
    ("build", "error", "message"),
    [
        (lambda: Integrator(0.0), ValueError, "Integrator parameter K must be non-zero, got 0.0"),
        (
            lambda: IntegratorWithLag(4.0, -1.0),
            ValueError,
            "IntegratorWithLag parameter omega_b must be > 0, got minimum -1.0",
        ),
        (
            lambda: UnstableFirstOrder(float("nan")),
            ValueError,
            "UnstableFirstOrder parameter instability: value must be finite, got nan",
        ),
        (
            lambda: TransferFunctionElement([1.0, 0.0, 0.0], [1.0, 1.0]),
            ValueError,
            "transfer function must be proper: num has 3 coefficients, den has 2",
        ),
        (
            lambda: make_element({"kind": "integrator", "gain": 2.0}),
            TypeError,
            "Integrator got unknown parameter(s) ['gain']; allowed: ['K']",
        ),
        (lambda: make_element(3.0), TypeError, "controlled element must be a preset name"),
    ],
)
def test_bad_parameters_raise(build, error, message):
    with pytest.raises(error, match=re.escape(message)):
        build()


def test_schedule_leaving_the_valid_range_raises_where_it_is_evaluated():
    element = IntegratorWithLag(4.0, Ramp(1.0, -1.0, 0.0, 10.0))
    element.parameters_at(np.array([0.0, 4.0]))  # still positive
    with pytest.raises(ValueError, match="omega_b must be > 0"):
        element.parameters_at(np.linspace(0, 10, 11))


# --------------------------------------------------------------- written transfer functions


@pytest.mark.parametrize(
    ("text", "kind", "values"),
    [
        ("SI", "integrator", {"K": 1.5}),
        ("1", "gain", {"K": 1.0}),
        ("1/s", "integrator", {"K": 1.0}),
        ("-2/s", "integrator", {"K": -2.0}),
        ("2.5/s^2", "double_integrator", {"K": 2.5}),
        ("1/(s(s+1))", "integrator_with_lag", {"K": 1.0, "omega_b": 1.0}),
        ("4/(s^2 + 3s)", "integrator_with_lag", {"K": 4.0, "omega_b": 3.0}),
        ("2/(2s^2 + 6*s)", "integrator_with_lag", {"K": 1.0, "omega_b": 3.0}),
        ("num=[1]; den=[1, 1, 0]", "integrator_with_lag", {"K": 1.0, "omega_b": 1.0}),
        ("s/s^3", "double_integrator", {"K": 1.0}),
    ],
)
def test_written_elements_become_the_named_ones(text, kind, values):
    element = parse_element(text)
    assert element.kind == kind
    for name, value in values.items():
        assert getattr(element, name)(0.0) == pytest.approx(value)


def test_a_general_written_element_matches_scipy():
    element = parse_element("(s + 2)/(s^2 + 0.5 s + 4)")
    assert element.kind == "transfer_function"
    omega = np.array([0.3, 1.0, 2.0, 7.0])
    _, expected = scipy.signal.freqs([1.0, 2.0], [1.0, 0.5, 4.0], worN=omega)
    np.testing.assert_allclose(element.frequency_response(omega), expected, rtol=1e-12)
    unstable = parse_element("1/(s(s-1))")  # outside IntegratorWithLag's range: kept general
    assert unstable.kind == "transfer_function"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("s", "is not proper (numerator degree 1 > denominator degree 0)"),
        ("1/(s", "cannot be read (the expression ends too early)"),
        ("x/s", "cannot be read (unexpected character 'x')"),
        ("1/0", "cannot be read (division by zero)"),
        ("s^1.5", "an exponent must be a non-negative integer, got '1.5'"),
        ("num=[1]", "give exactly num=[...] and den=[...]"),
        ("0/s", "is zero or not finite"),
        ("", "element must be a preset name or a transfer function, got ''"),
    ],
)
def test_unreadable_elements_say_what_is_allowed(text, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        parse_element(text)


def test_make_element_reads_written_transfer_functions():
    # every place that takes an element by name takes a written one through make_element
    for text in ("1/(s(s+1))", "1/s", "num=[1]; den=[1, 1, 0]"):
        assert make_element(text) == parse_element(text)
    listed = ", ".join(map(repr, ELEMENT_PRESETS))
    message = (
        f"controlled element must be one of {listed}, got '1/(s'; read as a transfer "
        "function in s, element '1/(s' cannot be read (the expression ends too early); "
        "write one as '1/s', '2.5/s^2', '1/(s(s+1))', '(s+2)/(s^2+0.5s+4)' or "
        "'num=[1]; den=[1, 1, 0]'"
    )
    with pytest.raises(ValueError, match=re.escape(message)):
        make_element("1/(s")
