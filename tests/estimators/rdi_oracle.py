"""A literal numpy recursive delay identifier (Boer & Kenyon 1998), for tests only.

Written from the paper, not from the code it checks (it imports nothing of
manualcontrol): the Appendix's polynomials f and g (their derivatives by numpy.polyder),
the ARMAX prediction of Sec. III-D with the delay as a positive lag, the random-walk EKF
of Sec. III-B in the Joseph form with plain matrix products, decimation (Sec. III-D),
the sign constraints (Sec. III-F), known coefficients left out of the filter, and a
plain Rauch-Tung-Striebel pass (Sec. III-E). Reads near the newest sample use the cubic
through the newest four samples, fitted with numpy.polyfit; identification starts once
the oldest delayed read and its stencil lie in the record (the estimator's documented
choices).
"""

from __future__ import annotations

import math

import numpy as np

F = np.array([1.5, -2.5, 0.0, 1.0])  # f(x) = 1.5 x^3 - 2.5 x^2 + 1, x in [0, 1]
G = np.array([-0.5, 2.5, -4.0, 2.0])  # g(x) = -0.5 x^3 + 2.5 x^2 - 4 x + 2, x in [1, 2]
DF = np.polyder(F)
DG = np.polyder(G)


def read(x, k, position):
    """Value and slope per sample of ``x[0..k]`` at a fractional position."""
    if position <= 0.0:
        return x[0], 0.0
    n = math.floor(position)
    if n + 2 <= k:
        d = position - n
        samples = np.array([x[max(n - 1, 0)], x[n], x[n + 1], x[n + 2]])
        weights = np.array(
            [np.polyval(G, 1 + d), np.polyval(F, d), np.polyval(F, 1 - d), np.polyval(G, 2 - d)]
        )
        slopes = np.array(
            [
                np.polyval(DG, 1 + d),
                np.polyval(DF, d),
                -np.polyval(DF, 1 - d),
                -np.polyval(DG, 2 - d),
            ]
        )
        return float(weights @ samples), float(slopes @ samples)
    s = min(position - k, 0.0)
    nodes = np.array([-3.0, -2.0, -1.0, 0.0])
    values = np.array([x[max(k + int(j), 0)] for j in nodes])
    cubic = np.polyfit(nodes, values, 3)
    return float(np.polyval(cubic, s)), float(np.polyval(np.polyder(cubic), s))


class NumpyRDI:
    """The RDI as plain equations; ``run`` returns per-sample traces."""

    def __init__(
        self,
        *,
        n_a,
        n_b,
        decimation,
        dt,
        Q_d,
        Q_c,
        R,
        P0_d,
        P0_c,
        initial,
        estimated,
        delay_limits,
        sign_constraints,
    ):
        self.n_a, self.n_b, self.lam, self.dt = n_a, n_b, decimation, dt
        self.names = [
            "d",
            *(f"a_{i}" for i in range(1, n_a + 1)),
            *(f"b_{m}" for m in range(n_b + 1)),
        ]
        self.theta = np.array([initial[name] for name in self.names], dtype=float)
        self.index = [self.names.index(name) for name in self.names if name in estimated]
        step = decimation * dt
        self.q = np.array([Q_d * step**2 if self.names[i] == "d" else Q_c for i in self.index])
        self.P = np.diag([P0_d * step**2 if self.names[i] == "d" else P0_c for i in self.index])
        self.R = R
        self.limits = delay_limits
        self.sign = sign_constraints

    def predict(self, r, y, k):
        theta, lam = self.theta, self.lam
        value, gradient = 0.0, np.zeros(theta.shape[0])
        for i in range(1, self.n_a + 1):
            past = y[k - i * lam] if k - i * lam >= 0 else 0.0
            gradient[i] = past
            value += theta[i] * past
        slope = 0.0
        for m in range(self.n_b + 1):
            j = 1 + self.n_a + m
            v, s = read(r, k, k - m * lam - theta[0] / self.dt)
            gradient[j] = v
            value += theta[j] * v
            slope += theta[j] * s
        gradient[0] = -slope / self.dt
        return value, gradient

    def run(self, r, y):
        n = len(y)
        means = np.zeros((n, len(self.names)))
        variances = np.zeros((n, len(self.names)))
        predictions = np.zeros(n)
        priors, posteriors, P_priors, P_posteriors = [], [], [], []
        for k in range(n):
            oldest_read = k - self.n_b * self.lam - self.theta[0] / self.dt
            identify = (
                k % self.lam == 0 and k >= self.n_a * self.lam and math.floor(oldest_read) - 1 >= 0
            )
            if identify:
                self.P = self.P + np.diag(self.q)
            priors.append(self.theta[self.index].copy())
            P_priors.append(self.P.copy())
            prediction, gradient = self.predict(r, y, k)
            predictions[k] = prediction
            if identify:
                held = False
                if self.sign and k >= 1:
                    previous, _ = self.predict(r, y, k - 1)
                    held = y[k] * prediction < 0 or (y[k] - y[k - 1]) * (prediction - previous) < 0
                if not held:
                    H = gradient[self.index]
                    S = H @ self.P @ H + self.R
                    K = self.P @ H / S
                    x = self.theta[self.index] + K * (y[k] - prediction)
                    A = np.eye(len(self.index)) - np.outer(K, H)
                    self.P = A @ self.P @ A.T + self.R * np.outer(K, K)
                    self.P = 0.5 * (self.P + self.P.T)
                    self.theta[self.index] = x
                    self.theta[0] = min(max(self.theta[0], self.limits[0]), self.limits[1])
            posteriors.append(self.theta[self.index].copy())
            P_posteriors.append(self.P.copy())
            means[k] = self.theta
            variances[k, self.index] = np.diag(self.P)
        self.stored = tuple(np.array(a) for a in (priors, P_priors, posteriors, P_posteriors))
        return means, np.sqrt(variances), predictions

    def smoothed_means(self):
        """Plain RTS over the stored run: G = P+_k (P-_{k+1})^-1 (random walks)."""
        x_p, P_p, x_f, P_f = self.stored
        x_s = x_f.copy()
        for k in range(len(x_f) - 2, -1, -1):
            gain = np.linalg.solve(P_p[k + 1].T, P_f[k].T).T
            x_s[k] = x_f[k] + gain @ (x_s[k + 1] - x_p[k + 1])
        return x_s
