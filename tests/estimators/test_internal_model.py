"""The internal model f, g against the papers' printed equations and finite differences."""

import re

import numpy as np
import pytest

from manualcontrol.envs.dynamics import pade
from manualcontrol.estimators.members.internal_model import build_internal_model
from manualcontrol.pilots.models import PreviewModel, make_model

RNG = np.random.default_rng(7)


def popovici_f5_g(x, e, K_p, K_v, tau, w, z):
    """Popovici et al. (2017) eqs. 40 (fifth row) and 41, exactly as printed."""
    x1, x2, x3, x4, x5 = x
    f5 = (
        e
        - x3 * (12 * w**2 * tau**2 + 120 * z * w * tau + 120) / tau**3
        - x2 * (60 * tau * w**2 + 240 * z * w) / tau**3
        - x4 * (w**2 * tau**3 + 24 * z * w * tau**2 + 60 * tau) / tau**3
        - x5 * (2 * z * w * tau**3 + 12 * tau**2) / tau**3
        - 120 * x1 * w**2 / tau**3
    )
    g = (
        x3 * (12 * K_p * w**2 * tau**2 - 60 * K_v * w**2 * tau) / tau**3
        - K_v * w**2 * x5
        + x2 * (120 * K_v * w**2 - 60 * K_p * w**2 * tau) / tau**3
        - x4 * (K_p * w**2 * tau**3 - 12 * K_v * w**2 * tau**2) / tau**3
        + 120 * K_p * w**2 * x1 / tau**3
    )
    return f5, g


def thesis_f5_f9_g(x, ft_ahead, y, K_f, w_f, T, K_p, K_v, tau, w, z):
    """Thesis Part I eqs. 45 (rows 5 and 9) and 46, exactly as printed (T = tau_f*)."""
    x1, x2, x3, x4, x5, x6, x7, x8, x9 = x
    f5 = (
        -y
        - 120 * x1 * w**2 / tau**3
        - x2 * (60 * tau * w**2 + 240 * z * w) / tau**3
        - x3 * (12 * w**2 * tau**2 + 120 * z * w * tau + 120) / tau**3
        - x4 * (w**2 * tau**3 + 24 * z * w * tau**2 + 60 * tau) / tau**3
        - x5 * (2 * w * z * tau**3 + 12 * tau**2) / tau**3
        + 120 * x6 * K_f * w_f / T**3
        - 60 * x7 * K_f * w_f / T**2
        + 12 * x8 * K_f * w_f / T
        - x9 * K_f * w_f
    )
    f9 = (
        ft_ahead
        - 120 * x6 * w_f / T**3
        - x7 * (60 * w_f * T + 120) / T**3
        - x8 * (12 * w_f * T**2 + 60 * T) / T**3
        - x9 * (w_f * T**3 + 12 * T**2) / T**3
    )
    g = (
        120 * x1 * K_p * w**2 / tau**3
        + x2 * (120 * K_v * w**2 - 60 * K_p * w**2 * tau) / tau**3
        + x3 * (12 * K_p * w**2 * tau**2 - 60 * K_v * w**2 * tau) / tau**3
        - x4 * (K_p * w**2 * tau**3 - 12 * K_v * w**2 * tau**2) / tau**3
        - x5 * K_v * w**2
    )
    return f5, f9, g


def random_precision():
    return np.array(
        [
            RNG.uniform(0.5, 2.0),  # K_p
            RNG.uniform(0.1, 1.0),  # K_v
            RNG.uniform(0.1, 0.4),  # tau_v
            RNG.uniform(6.0, 14.0),  # omega_nms
            RNG.uniform(0.1, 0.7),  # zeta_nms
        ]
    )


def random_preview():
    return np.array(
        [
            RNG.uniform(0.5, 1.5),  # K_f
            RNG.uniform(0.5, 5.0),  # omega_f
            RNG.uniform(0.2, 0.9),  # tau_f* in the tau_f slot
            RNG.uniform(0.2, 1.5),  # K_p
            RNG.uniform(0.0, 0.6),  # K_v
            RNG.uniform(0.1, 0.4),  # tau_v
            RNG.uniform(6.0, 14.0),  # omega_nms
            RNG.uniform(0.1, 0.7),  # zeta_nms
        ]
    )


def test_layout_follows_the_papers():
    precision = build_internal_model("precision")
    assert precision.parameter_names == ("K_p", "K_v", "tau_v", "omega_nms", "zeta_nms")
    assert precision.gain_parameters == ("K_p", "K_v")
    assert precision.n_states == 5  # Popovici eq. 38
    assert precision.input_names == ("e",)
    assert precision.input_states == (4,)
    preview = build_internal_model("preview")
    assert preview.gain_parameters == ("K_p", "K_v")  # K_f enters f (thesis eq. 45)
    assert preview.n_states == 9  # thesis eq. 40
    assert preview.input_names == ("ft_ahead", "y")
    assert preview.input_states == (4, 8)
    # the branches' own parameters: the far view and the anticipation delay
    assert precision.branch_parameters == ()
    assert preview.branch_parameters == ("K_f", "omega_f", "tau_f")
    assert build_internal_model("preview", 0).branch_parameters == ("K_f", "omega_f", "tau_f")


@pytest.mark.parametrize("trial", range(5))
def test_precision_f_and_g_equal_popovici_eqs_40_41(trial):
    model = build_internal_model("precision")
    p = random_precision()
    x = RNG.standard_normal(5)
    e = RNG.standard_normal()
    evaluation = model.evaluate(p, x, np.array([e]))
    f5, g = popovici_f5_g(x, e, *p)
    np.testing.assert_allclose(evaluation.f[:4], x[1:], rtol=0, atol=0)
    np.testing.assert_allclose(evaluation.f[4], f5, rtol=1e-12)
    np.testing.assert_allclose(evaluation.g, g, rtol=1e-12)


@pytest.mark.parametrize("trial", range(5))
def test_preview_f_and_g_equal_thesis_eqs_45_46(trial):
    model = build_internal_model("preview")
    p = random_preview()
    K_f, w_f, T, K_p, K_v, tau, w, z = p
    x = RNG.standard_normal(9)
    ft_ahead, y = RNG.standard_normal(2)
    evaluation = model.evaluate(p, x, np.array([ft_ahead, y]))
    f5, f9, g = thesis_f5_f9_g(x, ft_ahead, y, K_f, w_f, T, K_p, K_v, tau, w, z)
    np.testing.assert_array_equal(evaluation.f[[0, 1, 2, 3, 5, 6, 7]], x[[1, 2, 3, 4, 6, 7, 8]])
    np.testing.assert_allclose(evaluation.f[4], f5, rtol=1e-12)
    np.testing.assert_allclose(evaluation.f[8], f9, rtol=1e-12)
    np.testing.assert_allclose(evaluation.g, g, rtol=1e-12)


@pytest.mark.parametrize("name", ["precision", "preview", "gain-delay", "schiess-roland"])
def test_jacobians_match_central_differences(name):
    model = build_internal_model(name)
    if name == "preview":
        p = random_preview()
    elif name == "precision":
        p = random_precision()
    else:
        p = np.array([spec.nominal for spec in make_model(name).parameters]) * RNG.uniform(
            0.8, 1.2, model.n_parameters
        )
    x = RNG.standard_normal(model.n_states)
    inputs = RNG.standard_normal(len(model.input_names))
    base = model.evaluate(p, x, inputs)

    def numeric(function, at, step):
        columns = []
        for j in range(at.shape[0]):
            h = step * max(1.0, abs(at[j]))
            up, down = at.copy(), at.copy()
            up[j] += h
            down[j] -= h
            columns.append((function(up) - function(down)) / (2 * h))
        return np.stack(columns, axis=-1)

    dfdp = numeric(lambda q: model.evaluate(q, x, inputs).f, p, 1e-6)
    dgdp = numeric(lambda q: np.array(model.evaluate(q, x, inputs).g), p, 1e-6)
    F = numeric(lambda y: model.evaluate(p, y, inputs).f, x, 1e-6)
    dgdx = numeric(lambda y: np.array(model.evaluate(p, y, inputs).g), x, 1e-6)
    scale_f = np.max(np.abs(dfdp)) + 1e-12
    np.testing.assert_allclose(base.dfdp, dfdp, rtol=1e-5, atol=1e-7 * scale_f)
    np.testing.assert_allclose(base.dgdp, dgdp, rtol=1e-5, atol=1e-7 * np.max(np.abs(dgdp)))
    np.testing.assert_allclose(base.F, F, rtol=1e-6, atol=1e-9 * np.max(np.abs(F)))
    np.testing.assert_allclose(base.dgdx, dgdx, rtol=1e-6, atol=1e-9 * np.max(np.abs(dgdx)))


@pytest.mark.parametrize("order", [1, 3, 5])
def test_canonical_form_reproduces_the_structure_transfer_function(order):
    """C (sI - A)^{-1} B of the internal model equals PilotModel.transfer_function."""
    structure = make_model("precision")
    model = build_internal_model(structure, order)
    values = {"K_p": 1.3, "K_v": 0.4, "tau_v": 0.25, "omega_nms": 9.0, "zeta_nms": 0.4}
    p = np.array([values[n] for n in model.parameter_names])
    zero = model.evaluate(p, np.zeros(model.n_states), np.zeros(1))
    A = zero.F
    C = zero.dgdx
    B = model.evaluate(p, np.zeros(model.n_states), np.ones(1)).f  # f at x=0, e=1
    num, den = structure.transfer_function(values, "e", order)
    for omega in (0.3, 2.0, 9.0):
        s = 1j * omega
        ours = C @ np.linalg.solve(s * np.eye(model.n_states) - A, B)
        theirs = np.polyval(num, s) / np.polyval(den, s)
        np.testing.assert_allclose(ours, theirs, rtol=1e-10)


def test_far_view_branch_gets_the_anticipation_delay():
    """ft_ahead -> u equals K_f omega_f/(s + omega_f) Pade(tau_f*) times the main chain."""
    model = build_internal_model("preview")
    p = random_preview()
    values = dict(zip(model.parameter_names, p, strict=True))
    zero = model.evaluate(p, np.zeros(9), np.zeros(2))
    B = model.evaluate(p, np.zeros(9), np.array([1.0, 0.0])).f
    pn, pd = pade(values["tau_f"], 3)
    vn, vd = pade(values["tau_v"], 3)
    w, z = values["omega_nms"], values["zeta_nms"]
    for omega in (0.5, 3.0):
        s = 1j * omega
        ours = zero.dgdx @ np.linalg.solve(s * np.eye(9) - zero.F, B)
        far = values["K_f"] * values["omega_f"] / (s + values["omega_f"])
        far = far * np.polyval(pn, s) / np.polyval(pd, s)
        main = (values["K_p"] + values["K_v"] * s) * w * w / (s * s + 2 * z * w * s + w * w)
        main = main * np.polyval(vn, s) / np.polyval(vd, s)
        np.testing.assert_allclose(ours, far * main, rtol=1e-10)


def test_unsupported_models_raise():
    with pytest.raises(ValueError, match=re.escape("single-channel pilot models")):
        build_internal_model(PreviewModel(near_view=True))
    with pytest.raises(ValueError, match=re.escape("delay_order must be >= 0, got -1")):
        build_internal_model("precision", -1)
