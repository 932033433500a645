"""Independent numpy oracle of the RML filter bank on the compensatory precision pilot.

Written from the equations of ``estimators/members/rml.py``'s docstring without importing any
of the package's estimators: the pilot ``(K_p + K_v s) omega^2/(s^2 + 2 zeta omega s +
omega^2)`` driven by the error delayed by ``tau_v`` (read with the Keys cubic kernel,
a = -0.5, written out here), in controllable canonical form, Euler substeps with the
input read at each substep's midpoint; a first-order remnant state added to the
chain input; one linear Kalman filter per bank member (fixed ``R`` and chain-input
noise, as ``fixed_R`` and ``fixed_Q_error`` set them); the Gauss-Newton step of the
parameters from central differences across the bank.
"""

import math

import numpy as np

NAMES = ("K_p", "K_v", "tau_v", "omega_nms", "zeta_nms")


def keys_read(values, newest, position):
    """Value of ``values[0..newest]`` at fractional sample ``position`` (ends clamped)."""
    if position >= newest:
        return values[newest]
    if position <= 0.0:
        return values[0]
    n = math.floor(position)
    d = position - n

    def kernel(x):
        x = abs(x)
        if x <= 1.0:
            return 1.5 * x**3 - 2.5 * x**2 + 1.0
        if x <= 2.0:
            return -0.5 * x**3 + 2.5 * x**2 - 4.0 * x + 2.0
        return 0.0

    total = 0.0
    for i in (n - 1, n, n + 1, n + 2):
        total += kernel(i - (n + d)) * values[min(max(i, 0), newest)]
    return total


class Member:
    """One Kalman filter of the bank: states (x1, x2, remnant)."""

    def __init__(self, p0_canonical, remnant_variance):
        self.x = np.zeros(3)
        self.P = np.diag([p0_canonical, p0_canonical, remnant_variance])

    def step(self, p, e_history, k, u, dt, substeps, R, q_error, intensity, omega_r, predict):
        K_p, K_v, tau, omega, zeta = (p[name] for name in NAMES)
        A = np.array([[0.0, 1.0], [-(omega**2), -2.0 * zeta * omega]])
        if predict:
            h = dt / substeps
            x = self.x[:2].copy()
            Phi = np.eye(3)
            for m in range(substeps):
                v = keys_read(e_history, k, k - 1.0 + (m + 0.5) / substeps - tau / dt)
                x = x + h * (A @ x + np.array([0.0, v + self.x[2]]))
                step = np.eye(3)
                step[:2, :2] += h * A
                step[1, 2] += h
                Phi = step @ Phi
            decay = math.exp(-omega_r * dt)
            Phi[2, :] = [0.0, 0.0, decay]
            self.x = np.array([x[0], x[1], decay * self.x[2]])
            Q = np.diag([0.0, q_error * dt * dt, intensity * (1 - decay**2) / (2 * omega_r)])
            self.P = Phi @ self.P @ Phi.T + Q
        H = np.array([omega**2 * K_p, omega**2 * K_v, 0.0])
        z = float(H @ self.x)
        S = float(H @ self.P @ H) + R
        gain = self.P @ H / S
        self.x = self.x + gain * (u - z)
        IKH = np.eye(3) - np.outer(gain, H)
        self.P = IKH @ self.P @ IKH.T + np.outer(gain, gain) * R
        return z, S


def run_bank(e, u, dt, initial, estimated, P0, Q, settings):
    """Parameter means after each sample; ``estimated`` in model order, plus log intensity.

    ``settings["drift"] = (gain, window, threshold)`` scales each pilot parameter's
    random-walk variance by the persistence of its corrections (the RML's drift rule);
    a gain of 0 leaves it off. ``settings["r2_remnant"]`` adds ``r2_remnant K_p^2
    var(r)`` to ``R``, evaluated at the parameter mean of the sample (0: none).
    """
    var_e0 = settings["var_e0"]
    omega_r = settings["omega_r"]
    log_q = math.log(settings["remnant_variance"] * var_e0 * 2.0 * omega_r)
    theta = np.array([initial[name] for name in estimated] + [log_q])
    P = np.diag([P0[name] for name in estimated] + [settings["intensity_P0"]])
    q = np.array([Q[name] for name in estimated] + [settings["intensity_Q"]])
    n_t = len(theta)
    members = [
        Member(settings["P0_canonical"], settings["remnant_variance"] * var_e0)
        for _ in range(2 * n_t + 1)
    ]
    h = settings["step"]
    gain, window, threshold = settings.get("drift", (0.0, 1.0, 0.0))
    factor = np.ones(n_t)
    mean_correction = np.zeros(n_t - 1)
    mean_size = np.zeros(n_t - 1)
    filled = 0.0  # the moving means' accumulated weight: the rule acts from 1 - 1/e
    means = []
    for k in range(len(u)):
        if k > 0:
            P = P + np.diag(q * factor) * dt * dt
        prior_mean, prior_std = theta.copy(), np.sqrt(np.diag(P))
        L = np.linalg.cholesky(P)
        points = [theta.copy()]
        for j in range(n_t):
            points += [theta + h * L[:, j], theta - h * L[:, j]]
        z = np.zeros(len(points))
        S = np.zeros(len(points))
        # the part of R that follows the remnant: r2_remnant K_p^2 var(r) at the centre,
        # var(r) = q / (2 omega_r), the remnant state's stationary variance
        centre = dict(initial)
        centre.update(zip(estimated, theta[:-1], strict=True))
        R = settings["R"] + settings.get("r2_remnant", 0.0) * centre["K_p"] ** 2 * math.exp(
            theta[-1]
        ) / (2.0 * omega_r)
        for i, point in enumerate(points):
            p = dict(initial)
            p.update(zip(estimated, point[:-1], strict=True))
            z[i], S[i] = members[i].step(
                p,
                e,
                k,
                u[k],
                dt,
                settings["substeps"],
                R,
                settings["q_error"],
                math.exp(point[-1]),
                omega_r,
                k > 0,
            )
        nu = u[k] - z[0]
        dz = (z[1::2] - z[2::2]) / (2 * h)
        dS = (S[1::2] - S[2::2]) / (2 * h)
        g = nu / S[0] * dz - 0.5 * (1 / S[0] - nu**2 / S[0] ** 2) * dS
        Lam = np.eye(n_t) + np.outer(dz, dz) / S[0] + 0.5 * np.outer(dS, dS) / S[0] ** 2
        theta = theta + L @ np.linalg.solve(Lam, g)
        P = L @ np.linalg.solve(Lam, L.T)
        P = 0.5 * (P + P.T)
        if gain > 0.0:  # the pilot parameters (all but the last, the log intensity)
            weight = min(1.0, dt / window)
            correction = ((theta - prior_mean) / prior_std)[:-1]
            mean_correction += weight * (correction - mean_correction)
            mean_size += weight * (np.abs(correction) - mean_size)
            filled += weight * (1.0 - filled)
            size = np.where(mean_size > 0.0, mean_size, 1.0)
            persistence = np.where(mean_size > 0.0, np.abs(mean_correction) / size, 0.0)
            if filled >= 1.0 - math.exp(-1.0):
                excess = np.maximum(persistence - threshold, 0.0) / (1 - threshold)
                factor[:-1] = 1.0 + gain * excess
        means.append(theta.copy())
    return np.array(means)
