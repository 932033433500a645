"""The compiled matrix exponential against scipy.linalg.expm and 60-digit arithmetic.

Tolerances, and why:
- Against scipy (the same Al-Mohy & Higham algorithm, the issue's "today's results"):
  1e-12 relative in the 1-norm for arguments of norm up to 10 (the simulations'
  augmented matrices have norms of about 1 at 100 Hz); measured about 1e-15.
- Against mpmath at 60 digits, for large norms and badly scaled Padé canonical forms,
  where both double-precision codes lose digits to conditioning: 1e-12 relative in the
  1-norm, and 1e-12 entry by entry for the Padé case (the small entries are what a
  simulation reads; a solve along the wrong axis loses five digits there).
"""

import re

import numpy as np
import pytest
import scipy.linalg

from manualcontrol.envs._expm import expm_batch
from manualcontrol.envs.dynamics import discretize, pade, tf_to_ccf


def _relative(ours, reference):
    error = np.abs(ours - reference).sum(axis=-2).max(axis=-1)
    return error / np.abs(reference).sum(axis=-2).max(axis=-1)


@pytest.mark.parametrize("n", [1, 2, 3, 6, 9, 13])
@pytest.mark.parametrize("norm", [1e-6, 1e-2, 0.2, 1.0, 3.0, 10.0])
def test_equals_scipy_expm(n, norm):
    rng = np.random.default_rng(n * 100 + int(norm * 1000))
    matrices = rng.standard_normal((40, n, n))
    matrices *= norm / np.abs(matrices).sum(axis=-2).max(axis=-1)[:, None, None]
    assert np.max(_relative(expm_batch(matrices), scipy.linalg.expm(matrices))) < 1e-12


def _pade_loop_augmented():
    # a precision pilot with a Padé-5 delay closed around 5/s^2: canonical coefficients
    # from 1e-2 to 1e7 (the vertregt2020 suites simulate exactly this kind of loop)
    num, den = pade(0.3, 5)
    delay = tf_to_ccf(num, den)
    element = tf_to_ccf([5.0], [1.0, 0.0, 0.0])
    A = scipy.linalg.block_diag(delay.A, element.A)
    A[5:, :5] = element.B @ delay.C
    A[:5, 5:] = -delay.B @ element.C
    B = np.zeros((7, 1))
    B[:5] = delay.B
    dt = 0.01
    augmented = np.zeros((9, 9))
    augmented[:7, :7] = A * dt
    augmented[:7, 7:8] = B * dt
    augmented[7, 8] = 1.0
    return augmented


def test_badly_scaled_pade_form_against_60_digits():
    mpmath = pytest.importorskip("mpmath")
    augmented = _pade_loop_augmented()
    assert np.abs(augmented).sum(axis=0).max() > 1e4
    with mpmath.workdps(60):
        exact = np.array(mpmath.expm(mpmath.matrix(augmented.tolist())).tolist(), dtype=float)
    ours = expm_batch(augmented[None])[0]
    nonzero = exact != 0.0
    entrywise = np.abs(ours - exact)[nonzero] / np.abs(exact[nonzero])
    assert entrywise.max() < 1e-12
    assert np.all(ours[~nonzero] == 0.0)


@pytest.mark.parametrize("norm", [50.0, 300.0])
def test_large_norms_against_60_digits(norm):
    mpmath = pytest.importorskip("mpmath")
    rng = np.random.default_rng(int(norm))
    matrices = rng.standard_normal((3, 4, 4))
    matrices *= norm / np.abs(matrices).sum(axis=-2).max(axis=-1)[:, None, None]
    ours = expm_batch(matrices)
    for matrix, result in zip(matrices, ours, strict=True):
        with mpmath.workdps(60):
            exact = np.array(mpmath.expm(mpmath.matrix(matrix.tolist())).tolist(), dtype=float)
        assert _relative(result, exact) < 1e-12


def test_runs_of_equal_matrices_and_special_inputs():
    rng = np.random.default_rng(5)
    a, b = rng.standard_normal((2, 4, 4)) * 0.3
    matrices = np.stack([a, a, b, b, b, a, np.zeros((4, 4))])
    result = expm_batch(matrices)
    for matrix, exponential in zip(matrices, result, strict=True):
        np.testing.assert_array_equal(exponential, expm_batch(matrix[None])[0])
    np.testing.assert_array_equal(result[-1], np.eye(4))
    assert expm_batch(np.zeros((0, 3, 3))).shape == (0, 3, 3)


def test_bad_input_raises():
    with pytest.raises(ValueError, match=re.escape("must have shape (count, n, n), got (2, 3)")):
        expm_batch(np.zeros((2, 3)))
    with pytest.raises(ValueError, match="matrices must be finite"):
        expm_batch(np.full((1, 2, 2), np.nan))


# ------------------------------------------------------------- discretize on top


def _assert_equals_the_augmented_scipy_exponential(exact, A, B, dt):
    # the earlier path, kept as the reference: one scipy expm of
    # [[A, B, 0], [0, 0, I/dt], [0, 0, 0]] dt
    n, m = A.shape[-1], B.shape[-1]
    augmented = np.zeros((A.shape[0], n + 2 * m, n + 2 * m))
    augmented[:, :n, :n] = A * dt
    augmented[:, :n, n : n + m] = B * dt
    augmented[:, n : n + m, n + m :] = np.eye(m)
    reference = scipy.linalg.expm(augmented)
    for ours, block in (
        (exact.phi, reference[:, :n, :n]),
        (exact.gamma, reference[:, :n, n : n + m]),
        (exact.gamma_ramp, reference[:, :n, n + m :]),
    ):
        assert np.max(np.abs(ours - block)) <= 1e-12 * np.max(np.abs(block))


def test_discretize_equals_the_augmented_scipy_exponential():
    rng = np.random.default_rng(2)
    A = rng.standard_normal((30, 4, 4)) * 5.0
    B = rng.standard_normal((30, 4, 2))
    _assert_equals_the_augmented_scipy_exponential(discretize(A, B, 0.01), A, B, 0.01)


def test_discretize_ramp_for_some_inputs_only():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((5, 3, 3))
    B = rng.standard_normal((5, 3, 4))
    full = discretize(A, B, 0.01)
    part = discretize(A, B, 0.01, ramp_inputs=[3, 1])
    np.testing.assert_allclose(part.phi, full.phi, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(part.gamma, full.gamma, rtol=1e-14, atol=1e-16)
    np.testing.assert_allclose(
        part.gamma_ramp[..., [1, 3]], full.gamma_ramp[..., [1, 3]], rtol=1e-13, atol=1e-17
    )
    assert np.all(part.gamma_ramp[..., [0, 2]] == 0.0)
    none = discretize(A, B, 0.01, ramp_inputs=())
    assert np.all(none.gamma_ramp == 0.0)


def test_discretize_rejects_bad_ramp_inputs_and_non_finite_matrices():
    A, B = np.zeros((2, 2)), np.ones((2, 1))
    with pytest.raises(ValueError, match=re.escape("ramp_inputs must be input indices in [0, 0]")):
        discretize(A, B, 0.01, ramp_inputs=[1])
    with pytest.raises(ValueError, match="A and B must be finite"):
        discretize(np.full((2, 2), np.inf), B, 0.01)


def test_discretize_uncoupled_state_groups_apart():
    # two blocks that A never couples (one fed by input 0, one by inputs 1 and 2):
    # exponentiated apart, equal to the whole augmented exponential to rounding
    rng = np.random.default_rng(4)
    A = np.zeros((20, 5, 5))
    A[:, :2, :2] = rng.standard_normal((20, 2, 2)) * 3.0
    A[:, 2:, 2:] = rng.standard_normal((20, 3, 3)) * 3.0
    B = np.zeros((20, 5, 3))
    B[:, :2, 0] = rng.standard_normal((20, 2))
    B[:, 2:, 1:] = rng.standard_normal((20, 3, 2))
    exact = discretize(A, B, 0.01)
    _assert_equals_the_augmented_scipy_exponential(exact, A, B, 0.01)
    assert np.all(exact.phi[:, :2, 2:] == 0.0) and np.all(exact.gamma[:, :2, 1:] == 0.0)
