"""The settings rules every pilot filter shares, pinned one by one against the papers.

Popovici et al. 2017: P0 eqs. 32-33 (0.1 for the canonical states, 10 for gains and
frequencies, 1 otherwise), Q eqs. 25-26 (100 % of the initial value for gains, 10 %
otherwise), generic initial values eqs. 27-31 (K_p0 = sigma_u/sigma_e, K_v0 = K_p0/2,
omega 10, zeta 0.3, tau_v 0.3). Thesis Sec. V-B: P0 = (p theta_0)^2 with p = 0.1 for
omega_nms and 0.5 otherwise, Q = q theta_0 with 5 % for gains and delays and 2.5 % for
frequencies and damping; the remnant preset's r^2 = 4 for DI. Every expected number is
written out here by hand, so a change of any rule fails a test.
"""

import math
import re
import warnings

import pytest

from manualcontrol.estimators import DEKF, RML, DualUKF, JointUKF
from manualcontrol.estimators.members.pilot_filter import (
    TABLE_I,
    GenericValuesWarning,
    ParameterMap,
    held_without_values,
    internal_model,
    resolve_settings,
)


def resolved(kind=DEKF, var_u0=4.0, var_e0=1.0, **settings):
    estimator = kind(**settings)
    return resolve_settings(estimator.settings, estimator.internal_model, var_u0, var_e0)


def test_popovici_preset_initial_values_P0_and_Q():
    r = resolved(model="precision")  # sigma_u / sigma_e = 2
    assert dict(r.initial) == {
        "K_p": 2.0,  # eq. 27
        "K_v": 1.0,  # eq. 28
        "tau_v": 0.3,  # eq. 31
        "omega_nms": 10.0,  # eq. 29
        "zeta_nms": 0.3,  # eq. 30
    }
    assert dict(r.P0) == {
        "K_p": 10.0,
        "K_v": 10.0,
        "tau_v": 1.0,
        "omega_nms": 10.0,
        "zeta_nms": 1.0,
    }  # eqs. 32-33
    assert r.Q["K_p"] == pytest.approx(2.0)  # eq. 25: 100 % of K_p0
    assert r.Q["K_v"] == pytest.approx(1.0)
    assert r.Q["tau_v"] == pytest.approx(0.03)  # eq. 26: 10 %
    assert r.Q["omega_nms"] == pytest.approx(1.0)
    assert r.Q["zeta_nms"] == pytest.approx(0.03)
    assert (r.q2, r.r2, r.r2_parameter) == (0.4, 0.7, 0.7)  # Sec. III-B
    assert r.gains == ("K_p", "K_v") and r.theta == ("omega_nms", "zeta_nms", "tau_v")


def test_thesis_preset_P0_and_Q():
    initial = {"K_p": 1.3, "omega_nms": 10.5, "zeta_nms": 0.35, "tau_v": 0.26}
    r = resolved(model="precision", ce="SI", preset="vertregt2020", initial=initial)
    assert r.estimated == ("K_p", "tau_v", "omega_nms", "zeta_nms")  # K_v held for SI
    assert r.P0["K_p"] == pytest.approx((0.5 * 1.3) ** 2)
    assert r.P0["tau_v"] == pytest.approx((0.5 * 0.26) ** 2)
    assert r.P0["omega_nms"] == pytest.approx((0.1 * 10.5) ** 2)
    assert r.P0["zeta_nms"] == pytest.approx((0.5 * 0.35) ** 2)
    assert r.Q["K_p"] == pytest.approx(0.05 * 1.3)
    assert r.Q["tau_v"] == pytest.approx(0.05 * 0.26)
    assert r.Q["omega_nms"] == pytest.approx(0.025 * 10.5)
    assert r.Q["zeta_nms"] == pytest.approx(0.025 * 0.35)
    assert dict(r.limits) == {k: v for k, v in TABLE_I["SI"].items() if k in r.estimated}


def test_preview_time_enters_as_the_anticipated_delay():
    tau_a = 1.5
    r = resolved(
        model="preview",
        ce="DI",
        anticipation_time=tau_a,
        preset="vertregt2020",
        initial={"K_p": 0.24, "K_v": 0.36, "tau_f": 0.6},
    )
    tau_star = tau_a - 0.6  # thesis eq. 26
    assert r.P0["tau_f"] == pytest.approx((0.5 * tau_star) ** 2)
    assert r.Q["tau_f"] == pytest.approx(0.05 * tau_star)
    assert r.limits["tau_f"] == (0.1, tau_a - 0.1)  # Table I on tau_f*
    # the DI far-view break starts where the thesis's DI benchmark did (Part II Table
    # 6.3, estimation 8.1: 1 rad/s); without an element type, the model's nominal 3.3
    assert r.initial["K_f"] == 1.0 and r.initial["omega_f"] == 1.0
    nominal = internal_model("preview", 3).model.spec("omega_f").nominal
    assert nominal == 3.3
    assert resolved(model="preview", anticipation_time=tau_a).initial["omega_f"] == nominal
    estimator = DEKF(model="preview", ce="DI", anticipation_time=tau_a)
    mapping = ParameterMap.of(estimator.settings, estimator.internal_model)
    assert mapping.internal("tau_f", 0.6) == pytest.approx(0.9)
    assert mapping.reported("tau_f", 0.9) == pytest.approx(0.6)
    assert mapping.internal_limits("tau_f", 0.1, 1.4) == pytest.approx((0.1, 1.4))
    assert mapping.internal("K_f", 0.8) == 0.8
    # the generic preview time is the middle of its limits
    assert resolved(model="preview", ce="DI", anticipation_time=tau_a).initial["tau_f"] == 0.75


def test_remnant_preset_raises_r2_for_double_integrators_only():
    assert resolved(model="precision", ce="DI", preset="vertregt2020-remnant").r2 == 4.0
    assert resolved(model="precision", ce="SI", preset="vertregt2020-remnant").r2 == 0.7
    assert resolved(model="precision", ce="DI", preset="vertregt2020").r2 == 0.7
    assert resolved(model="precision", r2=2.5, r2_parameter=9.0).r2_parameter == 9.0


def test_explicit_numbers_win_over_the_presets():
    r = resolved(
        model="precision",
        P0={"K_p": 0.5},
        Q={"tau_v": 1e-4},
        P0_fraction={"omega_nms": 0.2},
        Q_fraction={"zeta_nms": 0.5},
    )
    assert r.P0["K_p"] == 0.5 and r.Q["tau_v"] == 1e-4
    assert r.P0["omega_nms"] == pytest.approx((0.2 * 10.0) ** 2)
    assert r.Q["zeta_nms"] == pytest.approx(0.5 * 0.3)


@pytest.mark.parametrize("kind", [DEKF, JointUKF, DualUKF])
def test_every_member_resolves_the_same_numbers(kind):
    base = resolved(DEKF, model="precision", ce="DI", preset="vertregt2020")
    other = resolved(kind, model="precision", ce="DI", preset="vertregt2020")
    assert other.to_dict() == base.to_dict()


def test_generic_gain_needs_the_first_window():
    with pytest.raises(ValueError, match=re.escape("initial K_p is needed")):
        resolved(model="precision", var_u0=None, var_e0=None)
    assert math.isclose(resolved(model="precision", var_u0=2.25, var_e0=1.0).initial["K_p"], 1.5)
    # a generic value outside the limits starts at the limit (K_p's human range ends at 2.5)
    assert resolved(model="precision", var_u0=9.0, var_e0=1.0).initial["K_p"] == 2.5


#: Values a study might give for what it holds (SI-like, thesis Table II).
TYPICAL_HELD = {"K_v": 0.5, "tau_v": 0.25, "omega_nms": 10.5, "zeta_nms": 0.35}


def test_a_filter_says_which_parameters_it_holds_at_generic_values():
    # the neuromuscular parameters and the delay neither estimated nor given: Popovici's
    # eqs. 29-31 hold them all run; K_v is the single integrator's rule, not an assumption
    with pytest.warns(GenericValuesWarning) as record:
        DEKF(model="precision", ce="SI", estimated=("K_p",))
    (warning,) = record
    assert str(warning.message).startswith(
        "DEKF holds tau_v, omega_nms, zeta_nms at generic starting values all run"
    )
    assert "initial={'tau_v': ..., 'omega_nms': ..., 'zeta_nms': ...}" in str(warning.message)
    # it points at the code that built the filter, through a subclass's __init__ too
    assert warning.filename == __file__
    with pytest.warns(GenericValuesWarning, match="RML holds K_v at") as record:
        RML(model="precision", ce="DI", estimated=("K_p", "omega_nms", "zeta_nms", "tau_v"))
    assert record[0].filename == __file__
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        # given values, every parameter estimated, or held by design: nothing to say
        DEKF(model="precision", estimated=("K_p",), initial=dict(TYPICAL_HELD))
        DEKF(model="precision", ce="DI")
        DEKF(model="precision", ce="SI", estimated=("K_p", "tau_v", "omega_nms", "zeta_nms"))
        DEKF(
            model="preview",
            anticipation_time=0.0,
            initial={"omega_f": 3.3},
            estimated=("K_f", "K_p", "K_v", "tau_v", "omega_nms", "zeta_nms"),
        )


def test_held_without_values_by_hand():
    names = ("K_f", "omega_f", "tau_f", "K_p", "K_v", "tau_v")
    assert held_without_values(names, None, {}, "SI", False) == ()
    held = held_without_values(names, ("K_p",), {"tau_v": 0.3}, None, False)
    assert held == ("K_f", "omega_f", "tau_f", "K_v")
    # the single integrator's K_v and omega_f, the pursuit form's tau_f: by design
    assert held_without_values(names, ("K_p",), {"tau_v": 0.3}, "SI", True) == ("K_f",)
