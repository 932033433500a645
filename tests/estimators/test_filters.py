"""The shared Kalman core against answers computed independently, in plain numpy.

Tolerances, and why:
- EKF and UKF steps against a textbook linear Kalman filter written here with numpy
  (``inv`` allowed in the oracle, it is small and well conditioned): 1e-10 relative.
  For a linear model the unscented transform is exact, so the UKF must equal the KF
  to rounding.
- The final filtered belief, and every RTS-smoothed belief, against the fixed-interval
  posterior of the whole run computed as one dense information-form least-squares
  solve over all states (no recursion at all): 1e-8 relative (the dense normal
  equations have condition numbers near 1e4 here).
- Sigma points through a quadratic: exact to rounding (1e-12): the unscented
  transform's mean is exact for polynomials of degree two, and with the cubature rule
  so is the covariance of a linear map; the quadratic's covariance is checked against
  the closed form for Gaussian moments with the unscaled Merwe set (alpha 1, beta 0,
  kappa = 3 - n matches the fourth moment in one dimension).
"""

import numpy as np
import pytest

from manualcontrol.estimators.filters.kalman import (
    joseph_correct,
    kalman_work,
    predict_covariance,
    textbook_correct,
)
from manualcontrol.estimators.filters.linalg import (
    cholesky,
    cholesky_semidefinite,
    cholesky_semidefinite_pivoted,
)
from manualcontrol.estimators.filters.smoothers import (
    LINK_CROSS,
    LINK_RANDOM_WALK,
    LINK_TRANSITION,
    rts_smooth,
    smoother_work,
)
from manualcontrol.estimators.filters.unscented import (
    constrain_prior,
    cross_covariance,
    sigma_points,
    sigma_weights,
    unscented_correct,
    unscented_work,
    weighted_covariance,
    weighted_mean,
)

# ------------------------------------------------------------------ a linear model


def linear_model(n=3, m=2, N=40, seed=0, random_walk=False):
    rng = np.random.default_rng(seed)
    if random_walk:
        Phi = np.eye(n)
    else:
        A = rng.normal(size=(n, n)) * 0.3
        Phi = np.eye(n) + 0.1 * (A - A.T) - 0.05 * np.eye(n)
    H = rng.normal(size=(m, n))
    Q = np.diag(rng.uniform(0.01, 0.1, n))
    R = np.diag(rng.uniform(0.05, 0.2, m))
    R[0, -1] = R[-1, 0] = 0.01 if m > 1 else R[0, 0]
    m0 = rng.normal(size=n)
    P0 = np.eye(n) * 0.5
    x = m0 + rng.multivariate_normal(np.zeros(n), P0)
    zs = []
    for _ in range(N):
        zs.append(H @ x + rng.multivariate_normal(np.zeros(m), R))
        x = Phi @ x + rng.multivariate_normal(np.zeros(n), Q)
    return Phi, H, Q, R, m0, P0, np.array(zs)


def numpy_kalman(Phi, H, Q, R, m0, P0, zs):
    """Textbook KF (oracle): prior at k, then update; returns priors and posteriors."""
    x, P = m0.copy(), P0.copy()
    priors, posteriors = [], []
    for k, z in enumerate(zs):
        if k > 0:
            x = Phi @ x
            P = Phi @ P @ Phi.T + Q
        priors.append((x.copy(), P.copy()))
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        x = x + K @ (z - H @ x)
        P = P - K @ S @ K.T
        posteriors.append((x.copy(), P.copy()))
    return priors, posteriors


def dense_posterior(Phi, H, Q, R, m0, P0, zs):
    """Fixed-interval posterior of every state by one dense least-squares solve.

    Stack x_0..x_{N-1}; residuals (whitened by each block's covariance): the prior on
    x_0, the dynamics x_{k+1} - Phi x_k, the measurements z_k - H x_k. The posterior
    information is J = A^T W A, the mean J^-1 A^T W b, the covariance J^-1.
    """
    n, N = Phi.shape[0], len(zs)
    rows, rhs, weights = [], [], []

    def block(k):
        out = np.zeros((n, n * N))
        out[:, k * n : (k + 1) * n] = np.eye(n)
        return out

    rows.append(block(0))
    rhs.append(m0)
    weights.append(np.linalg.inv(P0))
    for k in range(N - 1):
        rows.append(block(k + 1) - Phi @ block(k))
        rhs.append(np.zeros(n))
        weights.append(np.linalg.inv(Q))
    for k in range(N):
        rows.append(H @ block(k))
        rhs.append(zs[k])
        weights.append(np.linalg.inv(R))
    J = sum(A.T @ W @ A for A, W in zip(rows, weights, strict=True))
    h = sum(A.T @ W @ b for A, W, b in zip(rows, weights, rhs, strict=True))
    cov = np.linalg.inv(J)
    mean = cov @ h
    means = mean.reshape(N, n)
    covs = np.array([cov[k * n : (k + 1) * n, k * n : (k + 1) * n] for k in range(N)])
    return means, covs


def run_ekf(Phi, H, Q, R, m0, P0, zs):
    """The core's EKF steps on the linear model; stored for the smoother."""
    n, m, N = Phi.shape[0], H.shape[0], len(zs)
    x, P = m0.copy(), P0.copy()
    work = kalman_work(n, m)
    store = {name: np.zeros((N, n)) for name in ("x_prior", "x_post")}
    store.update({name: np.zeros((N, n, n)) for name in ("P_prior", "P_post", "Phi")})
    for k, z in enumerate(zs):
        if k > 0:
            x = Phi @ x
            predict_covariance(P, Phi, Q, work.T)
            store["Phi"][k] = Phi
        store["x_prior"][k], store["P_prior"][k] = x, P
        assert joseph_correct(x, P, z - H @ x, H, R, work, 0.0)
        store["x_post"][k], store["P_post"][k] = x, P
    return store


def run_ukf(Phi, H, Q, R, m0, P0, zs, scheme="cubature"):
    n, m, N = Phi.shape[0], H.shape[0], len(zs)
    weights = sigma_weights(n, scheme, alpha=0.7)
    w = unscented_work(n, m)
    x, P = m0.copy(), P0.copy()
    store = {name: np.zeros((N, n)) for name in ("x_prior", "x_post")}
    store.update({name: np.zeros((N, n, n)) for name in ("P_prior", "P_post", "cross")})
    cross = np.zeros((n, n))
    for k, z in enumerate(zs):
        if k > 0:
            previous = x.copy()
            assert sigma_points(x, P, weights.spread, w.L, w.X)
            w.Y[:] = w.X @ Phi.T
            weighted_mean(w.Y, weights.mean, weights.count, x)
            weighted_covariance(w.Y, x, weights.cov, weights.count, Q, P)
            cross_covariance(w.X, previous, w.Y, x, weights.cov, weights.count, cross)
            store["cross"][k] = cross
        store["x_prior"][k], store["P_prior"][k] = x, P
        assert sigma_points(x, P, weights.spread, w.L, w.X)
        w.Z[:] = w.X @ H.T
        weighted_mean(w.Z, weights.mean, weights.count, w.z)
        weighted_covariance(w.Z, w.z, weights.cov, weights.count, R, w.S)
        cross_covariance(w.X, x, w.Z, w.z, weights.cov, weights.count, w.Cxz)
        assert unscented_correct(x, P, z - w.z, w.Cxz, w.S, w.LS, w.K, w.log_det, 0.0)
        store["x_post"][k], store["P_post"][k] = x, P
    return store


def smooth(store, link_name, kind):
    N, n = store["x_post"].shape
    x_s, P_s = np.zeros((N, n)), np.zeros((N, n, n))
    link = store[link_name] if link_name else np.zeros((0, n, n))
    status = rts_smooth(
        store["x_post"],
        store["P_post"],
        store["x_prior"],
        store["P_prior"],
        link,
        kind,
        x_s,
        P_s,
        smoother_work(n),
    )
    assert status == 0
    return x_s, P_s


def relative(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b))) / np.max(np.abs(b))


# ------------------------------------------------------------------------- tests


@pytest.mark.parametrize("m", [1, 2])
def test_ekf_steps_equal_the_linear_kalman_filter(m):
    model = linear_model(m=m)
    priors, posteriors = numpy_kalman(*model)
    store = run_ekf(*model)
    assert relative(store["x_prior"], [p[0] for p in priors]) < 1e-10
    assert relative(store["P_prior"], [p[1] for p in priors]) < 1e-10
    assert relative(store["x_post"], [p[0] for p in posteriors]) < 1e-10
    assert relative(store["P_post"], [p[1] for p in posteriors]) < 1e-10


@pytest.mark.parametrize("scheme", ["cubature", "merwe"])
def test_ukf_steps_equal_the_linear_kalman_filter(scheme):
    model = linear_model(m=2)
    _, posteriors = numpy_kalman(*model)
    store = run_ukf(*model, scheme=scheme)
    assert relative(store["x_post"], [p[0] for p in posteriors]) < 1e-10
    assert relative(store["P_post"], [p[1] for p in posteriors]) < 1e-10


def test_final_filtered_belief_equals_the_dense_posterior():
    model = linear_model(m=2)
    means, covs = dense_posterior(*model)
    for store in (run_ekf(*model), run_ukf(*model)):
        assert relative(store["x_post"][-1], means[-1]) < 1e-8
        assert relative(store["P_post"][-1], covs[-1]) < 1e-8


def test_rts_smoothers_equal_the_fixed_interval_posterior():
    model = linear_model(m=2)
    means, covs = dense_posterior(*model)
    ekf = run_ekf(*model)
    x_s, P_s = smooth(ekf, "Phi", LINK_TRANSITION)
    assert relative(x_s, means) < 1e-8
    assert relative(P_s, covs) < 1e-8
    # the unscented RTS smoother equals the linear one on a linear model
    ukf = run_ukf(*model)
    x_u, P_u = smooth(ukf, "cross", LINK_CROSS)
    assert relative(x_u, x_s) < 1e-9
    assert relative(P_u, P_s) < 1e-9
    # and the smoothed estimate is better than the filtered one in the middle
    assert np.all(
        np.diagonal(P_s, axis1=1, axis2=2)[:-1] < np.diagonal(ekf["P_post"], axis1=1, axis2=2)[:-1]
    )


def test_random_walk_smoother_equals_the_fixed_interval_posterior():
    model = linear_model(m=1, random_walk=True)
    means, covs = dense_posterior(*model)
    store = run_ekf(*model)
    x_s, P_s = smooth(store, None, LINK_RANDOM_WALK)
    assert relative(x_s, means) < 1e-8
    assert relative(P_s, covs) < 1e-8


def test_sigma_points_through_a_quadratic():
    rng = np.random.default_rng(3)
    n = 3
    mean = rng.normal(size=n)
    B = rng.normal(size=(n, n))
    P = B @ B.T + 0.5 * np.eye(n)
    A = rng.normal(size=(n, n))
    A = A + A.T
    b = rng.normal(size=n)

    def f(x):  # a quadratic form plus a linear term
        return np.array([x @ A @ x + b @ x])

    exact_mean = mean @ A @ mean + np.trace(A @ P) + b @ mean
    grad = 2 * A @ mean + b
    exact_var = grad @ P @ grad + 2 * np.trace(A @ P @ A @ P)
    for scheme, kwargs in (("cubature", {}), ("merwe", {"alpha": 1.0, "kappa": 0.0})):
        weights = sigma_weights(n, scheme, **kwargs)
        L, X = np.zeros((n, n)), np.zeros((2 * n + 1, n))
        assert sigma_points(mean, P, weights.spread, L, X)
        # the points themselves carry the mean and covariance of the Gaussian
        got_mean, got_cov = np.zeros(n), np.zeros((n, n))
        weighted_mean(X, weights.mean, weights.count, got_mean)
        weighted_covariance(X, got_mean, weights.cov, weights.count, np.zeros((n, n)), got_cov)
        np.testing.assert_allclose(got_mean, mean, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(got_cov, P, rtol=1e-12, atol=1e-12)
        Z = np.array([f(x) for x in X])
        z = np.zeros(1)
        weighted_mean(Z, weights.mean, weights.count, z)
        assert z[0] == pytest.approx(exact_mean, rel=1e-12)
    # the variance of a quadratic needs the fourth moments: the unscaled set (alpha 1,
    # beta 0) with kappa = 3 - n matches the Gaussian's along each axis; in several
    # dimensions the cross terms are off, so check a one-dimensional quadratic exactly
    w1 = sigma_weights(1, "merwe", alpha=1.0, beta=0.0, kappa=2.0)
    L1, X1 = np.zeros((1, 1)), np.zeros((3, 1))
    assert sigma_points(np.array([0.4]), np.array([[1.7]]), w1.spread, L1, X1)
    Z1 = 2.0 * X1**2 + 0.3 * X1
    zbar, var = np.zeros(1), np.zeros((1, 1))
    weighted_mean(Z1, w1.mean, w1.count, zbar)
    weighted_covariance(Z1, zbar, w1.cov, w1.count, np.zeros((1, 1)), var)
    mu, s2 = 0.4, 1.7
    assert zbar[0] == pytest.approx(2 * (mu**2 + s2) + 0.3 * mu, rel=1e-12)
    assert var[0, 0] == pytest.approx((4 * mu + 0.3) ** 2 * s2 + 2 * 4 * s2**2, rel=1e-12)
    assert exact_var > 0  # (the multivariate closed form above, for the record)


def test_joseph_keeps_a_badly_conditioned_covariance_positive_definite():
    """A near-perfect measurement of a state with a huge prior: the textbook form breaks."""
    n = 2
    P0 = np.array([[1e8, 1e8 - 1.0], [1e8 - 1.0, 1e8]])  # correlated, ill conditioned
    H = np.array([[1.0, 0.0]])
    R = np.array([[1e-9]])
    r = np.array([1.0])
    joseph_P, textbook_P = P0.copy(), P0.copy()
    x1, x2 = np.zeros(n), np.zeros(n)
    assert joseph_correct(x1, joseph_P, r, H, R, kalman_work(n, 1), 0.0)
    assert textbook_correct(x2, textbook_P, r, H, R, kalman_work(n, 1))
    # the exact posterior: var of x1 ~ 1e-9, of x2 ~ 2 - 1e-8
    assert np.all(np.linalg.eigvalsh(joseph_P) > 0.0)
    assert np.allclose(joseph_P, joseph_P.T)
    # the textbook form cancels 1e8 - (1e8 - 1e-9) to exactly 0: no longer positive definite
    textbook_eigenvalues = np.linalg.eigvalsh(0.5 * (textbook_P + textbook_P.T))
    assert textbook_eigenvalues.min() <= 0.0
    assert textbook_P[0, 0] == 0.0
    assert joseph_P[0, 0] == pytest.approx(1e-9, rel=1e-3)


def test_cholesky_refuses_indefinite_and_semidefinite_factor_accepts_rank_deficiency():
    L = np.zeros((2, 2))
    assert not cholesky(np.array([[1.0, 2.0], [2.0, 1.0]]), L)
    assert not cholesky(np.array([[1.0, 1.0], [1.0, 1.0]]), L)
    assert cholesky_semidefinite(np.array([[1.0, 1.0], [1.0, 1.0]]), L)
    np.testing.assert_allclose(L @ L.T, [[1.0, 1.0], [1.0, 1.0]], atol=1e-15)
    assert not cholesky_semidefinite(np.array([[1.0, 2.0], [2.0, 1.0]]), L)
    assert not cholesky_semidefinite(np.array([[np.nan, 0.0], [0.0, 1.0]]), L)


def test_the_pivoted_factor_takes_the_singular_covariances_rounding_pushes_below_zero():
    # covariances of rank n - 1 (one direction the data pinned) with spreads four decades
    # apart: rounding leaves some of them a last unpivoted pivot clearly below zero
    rng = np.random.default_rng(0)
    n = 6
    refused = 0
    for _ in range(20_000):
        scales = 10.0 ** rng.uniform(-3, 1, n)
        B = rng.normal(size=(n, n - 1)) * scales[:, None]
        A = B @ B.T
        L, pivoted, work = np.zeros((n, n)), np.zeros((n, n)), np.zeros((n + 2, n))
        if cholesky_semidefinite(A, L):
            continue
        refused += 1
        assert cholesky_semidefinite_pivoted(A, pivoted, work)
        # a square root (rows in A's order, not triangular), exact to rounding
        assert np.abs(pivoted @ pivoted.T - A).max() <= 1e-15 * np.abs(A).max()
    assert refused >= 2
    # a positive definite one: its factor; an indefinite one or a non-finite one: refused
    A = np.array([[4.0, 1.0, 0.5], [1.0, 9.0, 2.0], [0.5, 2.0, 1.0]])
    L, work = np.zeros((3, 3)), np.zeros((5, 3))
    assert cholesky_semidefinite_pivoted(A, L, work)
    np.testing.assert_allclose(L @ L.T, A, rtol=0, atol=1e-15)
    L, work = np.zeros((2, 2)), np.zeros((4, 2))
    assert not cholesky_semidefinite_pivoted(np.array([[1.0, 2.0], [2.0, 1.0]]), L, work)
    assert not cholesky_semidefinite_pivoted(np.array([[np.nan, 0.0], [0.0, 1.0]]), L, work)
    # a clearly negative pivot left behind where the factor stops (a zero pivot first)
    assert not cholesky_semidefinite_pivoted(np.array([[0.0, 0.0], [0.0, -1.0]]), L, work)
    L, work = np.zeros((3, 3)), np.zeros((5, 3))
    assert not cholesky_semidefinite_pivoted(np.diag([1.0, 0.0, -1.0]), L, work)
    infinite = np.diag([1.0, 0.0, 0.0])
    infinite[2, 0] = infinite[0, 2] = np.inf
    assert not cholesky_semidefinite_pivoted(infinite, L, work)
    # n = 1
    L, work = np.zeros((1, 1)), np.zeros((3, 1))
    assert cholesky_semidefinite_pivoted(np.array([[4.0]]), L, work) and L[0, 0] == 2.0
    assert cholesky_semidefinite_pivoted(np.array([[0.0]]), L, work) and L[0, 0] == 0.0
    assert not cholesky_semidefinite_pivoted(np.array([[-1.0]]), L, work)


def test_projected_points_give_a_consistent_prior():
    weights = sigma_weights(2, "cubature")
    x = np.array([0.25, 1.0])
    P = np.diag([0.04, 1.0])
    L, X = np.zeros((2, 2)), np.zeros((5, 2))
    assert sigma_points(x, P, weights.spread, L, X)
    lo, hi = np.array([0.1, -np.inf]), np.array([0.8, np.inf])
    moved = constrain_prior(
        X,
        weights.mean,
        weights.cov,
        weights.count,
        np.array([0, -1]),
        lo,
        hi,
        x,
        P,
        np.zeros((2, 2)),
    )
    assert moved == 1  # 0.25 - sqrt(2) 0.2 < 0.1
    assert X[:4, 0].min() == 0.1
    expected = np.mean(X[:4], axis=0)
    np.testing.assert_allclose(x, expected, rtol=1e-14)
    np.testing.assert_allclose(P, np.cov(X[:4].T, bias=True), rtol=1e-12, atol=1e-15)


def test_sigma_weights_reject_bad_arguments():
    with pytest.raises(ValueError, match="scheme must be one of"):
        sigma_weights(3, "julier")
    with pytest.raises(ValueError, match="n \\(number of states\\) must be an integer >= 1"):
        sigma_weights(0)
    with pytest.raises(ValueError, match="n \\+ lambda > 0"):
        sigma_weights(3, "merwe", alpha=1.0, kappa=-3.0)
    with pytest.raises(ValueError, match="alpha must be > 0"):
        sigma_weights(3, "merwe", alpha=0.0)
