"""A literal numpy Schiess-Roland EKF, written apart from the compiled filter it checks.

Schiess & Roland (1975) eqs. 6-22 and A1-A6 as printed (with the corrections the
estimator documents: eq. 20's +R, A4-A6's indices), one line per equation where
possible: the prediction is the matrix exponential of the augmented system (state,
delayed error, its slope) by ``scipy.linalg.expm``; the transition matrix is the
central finite difference of that one-step map; the gain is ``P H^T inv(S)``. It
imports nothing from ``manualcontrol.estimators``. Integer delay read only.
"""

import numpy as np
import scipy.linalg

N = 13
H = np.zeros((2, N))
H[0, 2] = H[0, 4] = 1.0  # stick: u + eta
H[1, 0] = 1.0  # plant output: c


def system(x, K):
    """A (6, 6) and b (6,) of eqs. 7-12 at the parameters in ``x``."""
    k1, t1, t2, t3, _, a1, a2 = x[6:]
    A = np.zeros((6, 6))
    A[0, 1] = 1.0
    A[1, 2] = A[1, 4] = K
    A[2, 2], A[2, 3] = -1.0 / t2, 1.0 / t2
    A[3, 3] = -1.0 / t1
    A[4, 5] = 1.0
    A[5, 4], A[5, 5] = -a2, -a1
    b = np.zeros(6)
    b[2] = k1 * t3 / (t1 * t2)  # eq. 9
    b[3] = k1 / t1 * (1.0 - t3 / t1)  # eq. 10
    return A, b


def step_map(x, e0, rho, dt, K):
    """z(t + dt) for z' = A z + b (e0 + rho s): expm of the augmented system."""
    A, b = system(x, K)
    M = np.zeros((8, 8))
    M[:6, :6] = A
    M[:6, 6] = b
    M[6, 7] = 1.0
    return (scipy.linalg.expm(M * dt) @ np.concatenate([x[:6], [e0, rho]]))[:6]


def noise_gain(x, dt, K):
    """G_w = int_0^dt e^(A s) e_6 ds."""
    A, _ = system(x, K)
    M = np.zeros((7, 7))
    M[:6, :6] = A
    M[5, 6] = 1.0
    return scipy.linalg.expm(M * dt)[:6, 6]


class NumpySchiessRoland:
    """The filter, sample by sample (module docstring)."""

    def __init__(self, x0, P0, *, dt, K, q, R, ramp, adaptive="off", window=20, max_delay=0.5):
        self.x = np.array(x0, dtype=float)
        self.P = np.array(P0, dtype=float)
        self.dt, self.K, self.q, self.R = dt, K, q, np.array(R, dtype=float)
        self.ramp, self.adaptive, self.window, self.max_delay = ramp, adaptive, window, max_delay
        self.D, self.c, self.c_rate, self.q_values = [], [], [], []
        if adaptive == "full":
            self.gamma = np.array([0.707, 0, 0.5, 0, 0.5, 0] + [0.0] * 7)
        else:
            self.gamma = np.array([0.707] + [0.0] * 12)

    def error(self, j, k):
        """Delayed error and its rate at sample j (history clamped as the filter's)."""
        j = min(max(j, 0), k - 1)
        lo = j - 1 if j >= 1 else j
        hi = j + 1 if j + 1 <= k else j
        rate_d = (self.D[hi] - self.D[lo]) / ((hi - lo) * self.dt)
        return self.D[j] - self.c[j], rate_d - self.c_rate[j]

    def step(self, d, u, y):
        k = len(self.D)
        self.D.append(d)
        dt = self.dt
        if k > 0:
            theta = min(max(self.x[10], 0.0), self.max_delay)
            shift = int(np.floor(theta / dt + 0.5))  # eq. 17
            e0, r0 = self.error(k - 1 - shift, k)
            e1, r1 = self.error(k - shift, k)
            rho = (e1 - e0) / dt if self.ramp else 0.0
            Phi = np.eye(N)
            for i in range(N):
                h = 1e-6 * max(1.0, abs(self.x[i]))
                up, down = self.x.copy(), self.x.copy()
                up[i] += h
                down[i] -= h
                Phi[:6, i] = (
                    step_map(up, e0, rho, dt, self.K) - step_map(down, e0, rho, dt, self.K)
                ) / (2 * h)
            # theta acts through the delayed input: d e(t - theta)/d theta = -de/dt
            h = 1e-6
            d_e0 = (
                step_map(self.x, e0 + h, rho, dt, self.K)
                - step_map(self.x, e0 - h, rho, dt, self.K)
            ) / (2 * h)
            d_rho = (
                step_map(self.x, e0, rho + h, dt, self.K)
                - step_map(self.x, e0, rho - h, dt, self.K)
            ) / (2 * h)
            if self.ramp:
                Phi[:6, 10] = -d_e0 * r0 - d_rho * (r1 - r0) / dt
            else:
                Phi[:6, 10] = -d_e0 * r0
            gw = noise_gain(self.x, dt, self.K)
            self.x[:6] = step_map(self.x, e0, rho, dt, self.K)  # eq. 18
            Q = np.zeros((N, N))
            Q[:6, :6] = self.q * np.outer(gw, gw)
            self.P = Phi @ self.P @ Phi.T + Q  # eq. 19
        m = np.array([u, y])
        r = m - H @ self.x
        q_bar = 0.0
        if self.adaptive != "off":
            rows = [0, 1] if self.adaptive == "full" else [1]
            n = len(rows)
            s = np.sqrt(np.diag(self.R))
            residual = sum(r[j] / s[j] for j in rows) / n  # A4
            expected = (
                1.0 / n
                + sum(H[j] @ self.P @ H[i] / (s[j] * s[i]) for j in rows for i in rows) / n**2
            )  # A5
            d_ = (
                sum(
                    H[j] @ np.outer(self.gamma, self.gamma) @ H[i] / (s[j] * s[i])
                    for j in rows
                    for i in rows
                )
                / n**2
            )  # A6
            self.q_values.append(max(0.0, (residual**2 - expected) / d_))  # A3
            q_bar = float(np.mean(self.q_values[-self.window :]))
            self.P = self.P + q_bar * np.outer(self.gamma, self.gamma)  # A2
        S = H @ self.P @ H.T + self.R
        gain = self.P @ H.T @ np.linalg.inv(S)  # eq. 20 with +R
        self.x = self.x + gain @ r  # eq. 21
        I_KH = np.eye(N) - gain @ H
        self.P = I_KH @ self.P @ I_KH.T + gain @ self.R @ gain.T  # eq. 22
        self.x[10] = min(max(self.x[10], 0.0), self.max_delay)
        self.c.append(self.x[0])
        self.c_rate.append(self.x[1])
        return self.x.copy(), np.sqrt(np.diag(self.P)), r, S, q_bar
