"""Independent closed-loop references: polynomial algebra plus scipy.signal.

The analytic closed-loop transfer functions are built here from the papers' formulas
with numpy polynomials (Popovici eq. 1, thesis eqs. 1-4), not from the package's
block diagrams, and simulated with scipy.signal.lsim / dlsim. Nothing of the package
is imported: the Padé approximant too comes from thesis eq. 4's factorials here.
"""

from math import factorial

import numpy as np
import scipy.signal

P = np.polymul


def pade(tau, order):
    """Thesis eq. 4: e^{-tau s} ~ N(s)/D(s), descending powers of s.

    c_k = (2m - k)! m! / ((2m)! k! (m - k)!); N has (-tau s)^k, D has (tau s)^k.
    """
    c = [
        factorial(2 * order - k)
        * factorial(order)
        / (factorial(2 * order) * factorial(k) * factorial(order - k))
        for k in range(order + 1)
    ]
    num = np.array([c[k] * (-tau) ** k for k in range(order, -1, -1)])
    den = np.array([c[k] * tau**k for k in range(order, -1, -1)])
    return num, den


def pilot_polynomials(values, delay_order):
    """(K_p + K_v s) Pade(tau_v) omega^2/(s^2 + 2 zeta omega s + omega^2)."""
    w, z = values["omega_nms"], values["zeta_nms"]
    pn, pd = pade(values["tau_v"], delay_order)
    num = P(P([values["K_v"], values["K_p"]], pn), [w * w])
    den = P(pd, [1.0, 2 * z * w, w * w])
    return num, den


def far_view_polynomials(values):
    return np.array([values["K_f"] * values["omega_f"]]), np.array([1.0, values["omega_f"]])


def closed_loop_outputs(values, ce, signals, delay_order, preview, dt):
    """u and y of the continuous closed loop for ZOH-held inputs (lsim interp=False).

    u = [H_p F ft_far - H_p fd + n] / (1 + H_p H_c) (compensatory: F = 1, ft_far = ft),
    y = H_c u + fd, with the remnant n added at the pilot output.
    """
    np_, dp = pilot_polynomials(values, delay_order)
    nc, dc = ce
    if preview:
        nf, df = far_view_polynomials(values)
        drive = signals["ft_far"]
    else:
        nf, df = np.array([1.0]), np.array([1.0])
        drive = signals["ft"]
    char = np.polyadd(P(dp, dc), P(np_, nc))  # (1 + Hp Hc) Dp Dc
    t = np.arange(len(drive)) * dt
    u_tfs = [
        (P(P(np_, nf), dc), P(df, char), drive),
        (-P(np_, dc), char, signals["fd"]),
        (P(dp, dc), char, signals["n"]),
    ]
    u = sum(scipy.signal.lsim((num, den), x, t, interp=False)[1] for num, den, x in u_tfs)
    # y = Hc u + fd, expanded per input to stay an LTI map of the held inputs
    y_tfs = [
        (P(P(P(np_, nf), dc), nc), P(P(df, char), dc), drive),
        (P(dp, dc), char, signals["fd"]),  # fd (1 - Hp Hc/(1 + Hp Hc)) = fd/(1 + Hp Hc)
        (P(P(dp, dc), nc), P(char, dc), signals["n"]),
    ]
    y = sum(scipy.signal.lsim((num, den), x, t, interp=False)[1] for num, den, x in y_tfs)
    return u, y


def sampled_loop_outputs(values, ce, signals, delay_order, dt):
    """Compensatory sampled-data loop stepped by hand from scipy's own realisations.

    Pilot and element are realised by ``scipy.signal.tf2ss`` (controller form, not
    ours), discretised by ``cont2discrete`` and connected sample by sample: the pilot
    sees the held error ``e[k]``, its output ``u[k] + n[k]`` is held into the element.
    (A transfer-function ``dlsim`` of the closed loop loses ~5e-6 to the conditioning
    of the z-domain polynomials, so the state-space route is the reference.)
    """
    pilot = scipy.signal.cont2discrete(
        scipy.signal.tf2ss(*pilot_polynomials(values, delay_order)), dt
    )
    element = scipy.signal.cont2discrete(scipy.signal.tf2ss(*ce), dt)
    xp = np.zeros(pilot[0].shape[0])
    xc = np.zeros(element[0].shape[0])
    u = np.empty(len(signals["ft"]))
    for k in range(len(u)):
        y = (element[2] @ xc)[0] + signals["fd"][k]
        e = signals["ft"][k] - y
        u[k] = (pilot[2] @ xp)[0] + pilot[3][0, 0] * e + signals["n"][k]
        xp = pilot[0] @ xp + pilot[1][:, 0] * e
        xc = element[0] @ xc + element[1][:, 0] * u[k]
    return u
