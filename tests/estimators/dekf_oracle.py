"""A plain-numpy Dual Extended Kalman Filter: the test oracle of the compiled DEKF.

Written independently of the package's internal model and compiled core:

* the model comes from the papers' formulas with numpy polynomials: Popovici eq. 1
  ``(K_p + K_v s) e^{-tau_v s} omega^2/(s^2 + 2 zeta omega s + omega^2)``, the far view
  ``K_f omega_f/(s + omega_f) e^{-tau_f* s}`` (thesis eqs. 1, 26), Padé polynomials from
  the factorial formula of thesis eq. 4, controllable canonical form of eq. 4.7, the
  far-view chain appended below the main chain (Part II eqs. 5.2-5.3);
* every derivative by the complex step, ``Im f(p + i h e_j)/h`` (exact to rounding);
* the filter equations literally as matrices: ``Phi = I + F dt``, ``Gamma = I dt``,
  ``P^- = Phi P Phi^T + Gamma Q Gamma^T``, ``K = P G^T S^{-1}`` by ``np.linalg.solve``,
  the Joseph form as the triple product, the estimate projection of eq. 20 with its
  constraint matrices ``D`` and ``d``, the retrospective variances with ``np.nanvar``.

It takes its initial values, covariances and limits from the DEKF's resolved settings
(the resolution rules are tested separately) and reports what the DEKF reports.
"""

from math import factorial

import numpy as np

H = 1e-30  # complex step


def pade_polynomials(tau, order):
    """Thesis eq. 4: numerator and denominator, descending powers of s (complex-safe)."""
    c = [factorial(2 * order - k) / (factorial(k) * factorial(order - k)) for k in range(order + 1)]
    c = np.array(c) / c[0]
    num = np.array([c[k] * (-tau) ** k for k in range(order, -1, -1)])
    den = np.array([c[k] * tau**k for k in range(order, -1, -1)])
    return num, den


def polymul(a, b):
    out = np.zeros(len(a) + len(b) - 1, dtype=np.result_type(a, b))
    for i, ai in enumerate(a):
        out[i : i + len(b)] += ai * b
    return out


def canonical(num, den):
    """Companion last row -a (ascending states), output row C and feedthrough d."""
    a = den / den[0]
    b = np.zeros(len(den), dtype=np.result_type(num, den))
    b[len(den) - len(num) :] = num / den[0]
    d = b[0]
    rem = b - d * a
    n = len(den) - 1
    negA = -a[::-1][:n]
    C = rem[::-1][:n]
    return negA, C, d


class Model:
    """f and g of the precision or preview model, from the papers' formulas."""

    def __init__(self, kind, names, order=3):
        self.kind = kind
        self.names = list(names)
        self.order = order
        self.n_main = order + 2
        self.n_far = order + 1 if kind == "preview" else 0
        self.n = self.n_main + self.n_far

    def chains(self, p):
        v = dict(zip(self.names, p, strict=True))
        w, z = v["omega_nms"], v["zeta_nms"]
        pn, pd = pade_polynomials(v["tau_v"], self.order)
        num = polymul(np.array([v["K_v"] * w * w, v["K_p"] * w * w]), pn)
        den = polymul(np.array([1.0, 2 * z * w, w * w]), pd)
        main = canonical(num, den)
        if self.kind != "preview":
            return main, None
        fn, fd = pade_polynomials(v["tau_f"], self.order)  # the slot holds tau_f*
        far = canonical(v["K_f"] * v["omega_f"] * fn, polymul(np.array([1.0, v["omega_f"]]), fd))
        return main, far

    def f(self, x, inputs, p):
        (negA, _, _), far = self.chains(p)
        out = np.zeros(self.n, dtype=np.result_type(x, p, negA))
        m = self.n_main
        out[: m - 1] = x[1:m]
        if self.kind == "preview":
            ft_ahead, y = inputs
            fnegA, fC, _ = far
            xf = x[m:]
            out[m - 1] = negA @ x[:m] + fC @ xf - y
            out[m:-1] = xf[1:]
            out[-1] = fnegA @ xf + ft_ahead
        else:
            out[m - 1] = negA @ x[:m] + inputs[0]
        return out

    def F(self, p):
        (negA, _, _), far = self.chains(p)
        F = np.zeros((self.n, self.n))
        m = self.n_main
        F[np.arange(m - 1), np.arange(1, m)] = 1.0
        F[m - 1, :m] = negA
        if far is not None:
            fnegA, fC, _ = far
            F[m - 1, m:] = fC
            F[np.arange(m, self.n - 1), np.arange(m + 1, self.n)] = 1.0
            F[-1, m:] = fnegA
        return F

    def g(self, x, p):
        (_, C, _), _ = self.chains(p)
        return C @ x[: self.n_main]

    def dfdp(self, x, inputs, p):
        out = np.zeros((self.n, len(p)))
        for j in range(len(p)):
            step = p.astype(complex)
            step[j] += 1j * H
            out[:, j] = self.f(x.astype(complex), inputs, step).imag / H
        return out

    def dgdp(self, x, p):
        out = np.zeros(len(p))
        for j in range(len(p)):
            step = p.astype(complex)
            step[j] += 1j * H
            out[j] = self.g(x.astype(complex), step).imag / H
        return out

    def dgdx(self, p):
        (_, C, _), _ = self.chains(p)
        out = np.zeros(self.n)
        out[: self.n_main] = C
        return out


def project(value, low, high):
    """Thesis eq. 20/25: ``x - D^T (D D^T)^{-1} (D x - d)`` over the violated limits."""
    rows, targets = [], []
    for i, (v, lo, hi) in enumerate(zip(value, low, high, strict=True)):
        if v < lo or v > hi:
            row = np.zeros(len(value))
            row[i] = 1.0
            rows.append(row)
            targets.append(lo if v < lo else hi)
    if not rows:
        return value
    D = np.array(rows)
    d = np.array(targets)
    return value - D.T @ np.linalg.solve(D @ D.T, D @ value - d)


class NumpyDEKF:
    """The DEKF step by step in plain numpy (see the module docstring)."""

    def __init__(self, dekf, dt, var_u0, var_e0):
        settings = dekf.settings
        dekf.reset(dt, var_u0=var_u0, var_e0=var_e0)
        resolved = dekf.resolved
        self.names = list(resolved.parameter_names)
        self.model = Model(settings.model, self.names, settings.delay_order)
        self.tau_a = settings.anticipation_time
        self.preview = settings.model == "preview"
        self.dt = dt
        self.q2, self.r2, self.r2p = resolved.q2, resolved.r2, resolved.r2_parameter
        self.window = round(settings.noise.window / dt)
        self.first_window = settings.noise.initial_variance == "first-window"
        self.var0 = (var_u0, var_e0)
        self.floor = settings.noise.variance_floor
        self.jitter = settings.guard.jitter
        self.dimensional = settings.total_derivative == "dimensional"
        self.gamma = dt if settings.noise.noise_input == "euler" else 1.0
        self.fixed_R = settings.noise.fixed_R
        self.fixed_Q = settings.noise.fixed_Q_error

        def internal(name, value):
            return self.tau_a - value if self.preview and name == "tau_f" else value

        self.p = np.array([internal(n, resolved.initial[n]) for n in self.names])
        self.gains = [self.names.index(n) for n in resolved.gains]
        self.theta = [self.names.index(n) for n in resolved.theta]
        lo = {n: -np.inf for n in self.names}
        hi = {n: np.inf for n in self.names}
        for n, (a, b) in resolved.limits.items():
            lo[n], hi[n] = (
                (self.tau_a - b, self.tau_a - a) if self.preview and n == "tau_f" else (a, b)
            )
        self.lo = np.array([lo[n] for n in self.names])
        self.hi = np.array([hi[n] for n in self.names])
        nc, ng = self.model.n, len(self.gains)
        self.nc = nc
        self.x = np.concatenate([np.zeros(nc), self.p[self.gains]])
        self.P = np.diag(
            [settings.noise.P0_canonical] * nc + [resolved.P0[n] for n in resolved.gains]
        )
        self.th = self.p[self.theta].copy()
        self.Pp = np.diag([resolved.P0[n] for n in resolved.theta]).reshape(len(self.theta), -1)
        self.Qs = np.diag([0.0] * nc + [resolved.Q[n] for n in resolved.gains])
        self.Qp = np.diag([resolved.Q[n] for n in resolved.theta]).reshape(len(self.theta), -1)
        self.error_state = self.model.n_main - 1
        self.dx = np.zeros((nc + ng, len(self.theta)))
        self.prev = None
        self.k = 0

    def params(self):
        p = self.p.copy()
        p[self.gains] = self.x[self.nc :]
        p[self.theta] = self.th
        return p

    def variance(self, signal, k):
        if self.first_window and k < self.window:
            return None
        window = signal[max(0, k - self.window) : k + 1]
        if np.all(np.isnan(window)):
            return 0.0
        return float(np.nanvar(window))

    def step(self, inputs, u, e, us, es):
        k = self.k
        dt, nc, ns = self.dt, self.nc, len(self.x)
        var_u = self.variance(us, k)
        var_e = self.variance(es, k)
        var_u = self.var0[0] if var_u is None else var_u
        var_e = self.var0[1] if var_e is None else var_e
        R = self.fixed_R or self.r2 * max(var_u, self.floor)
        R_p = self.fixed_R or self.r2p * max(var_u, self.floor)  # parameter filter
        q_e = self.fixed_Q or self.q2 * max(var_e, self.floor)
        dropped = bool(np.isnan(u) or np.any(np.isnan(inputs)))
        held = np.where(np.isnan(inputs), self.prev if self.prev is not None else 0.0, inputs)
        p = self.params()
        n_t = len(self.theta)
        G = self.gamma * np.eye(ns)
        Gp = self.gamma * np.eye(n_t)
        if k > 0:
            self.Pp = np.eye(n_t) @ self.Pp @ np.eye(n_t).T + Gp @ self.Qp @ Gp.T  # eq. 12
            Fs = np.zeros((ns, ns))
            Fs[:nc, :nc] = self.model.F(p)
            Phi = np.eye(ns) + Fs * dt
            dfdth = np.zeros((ns, n_t))
            dfdth[:nc] = self.model.dfdp(self.x[:nc], self.prev, p)[:, self.theta]
            self.dxm = dfdth * (dt if self.dimensional else 1.0) + Phi @ self.dx  # eq. 49
            f = np.zeros(ns)
            f[:nc] = self.model.f(self.x[:nc], self.prev, p)
            self.x = self.x + f * dt  # eq. 13
            Q = self.Qs.copy()
            Q[self.error_state, self.error_state] = q_e
            self.P = Phi @ self.P @ Phi.T + G @ Q @ G.T  # eq. 14
            self.P = 0.5 * (self.P + self.P.T)
        else:
            self.dxm = self.dx.copy()
        prediction = self.model.g(self.x[:nc], p)
        Gs = np.concatenate([self.model.dgdx(p), self.model.dgdp(self.x[:nc], p)[self.gains]])
        Gs = Gs[None, :]
        Gtot = self.model.dgdp(self.x[:nc], p)[self.theta][None, :] + Gs @ self.dxm  # eq. 48
        S = float((Gs @ self.P @ Gs.T)[0, 0] + R)
        if dropped:
            innovation = np.nan
            self.dx = self.dxm
        else:
            innovation = u - prediction
            S_matrix = Gs @ self.P @ Gs.T + R  # eq. 15
            K = np.linalg.solve(S_matrix.T, (self.P @ Gs.T).T).T  # eq. 17
            self.x = self.x + (K * innovation).ravel()  # eq. 18
            A = np.eye(ns) - K @ Gs
            self.P = A @ self.P @ A.T + K * R @ K.T  # eq. 19
            self.P = 0.5 * (self.P + self.P.T) + self.jitter * np.eye(ns)
            self.x[nc:] = project(self.x[nc:], self.lo[self.gains], self.hi[self.gains])  # eq. 20
            if n_t:
                Sp = Gtot @ self.Pp @ Gtot.T + R_p  # eq. 21
                Kp = np.linalg.solve(Sp.T, (self.Pp @ Gtot.T).T).T  # eq. 22
                self.th = self.th + (Kp * innovation).ravel()  # eq. 23
                Ap = np.eye(n_t) - Kp @ Gtot
                self.Pp = Ap @ self.Pp @ Ap.T + Kp * R_p @ Kp.T  # eq. 24
                self.Pp = 0.5 * (self.Pp + self.Pp.T) + self.jitter * np.eye(n_t)
                self.th = project(self.th, self.lo[self.theta], self.hi[self.theta])  # eq. 25
            self.dx = self.dxm - K @ Gtot  # eq. 50
        self.prev = held
        self.k += 1
        mean = self.params()
        std = np.zeros(len(mean))
        std[self.gains] = np.sqrt(np.diag(self.P)[nc:])
        std[self.theta] = np.sqrt(np.diag(self.Pp))
        if self.preview:
            j = self.names.index("tau_f")
            mean[j] = self.tau_a - mean[j]
        return mean, std, prediction, innovation, S

    def run(self, inputs, u, e):
        rows = [self.step(inputs[k], u[k], e[k], u, e) for k in range(len(u))]
        mean = np.array([r[0] for r in rows])
        std = np.array([r[1] for r in rows])
        scalars = np.array([r[2:] for r in rows])
        return mean, std, scalars
