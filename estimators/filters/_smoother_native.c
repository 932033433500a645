/*
 * _smoother_native.c: the Rauch-Tung-Striebel smoother's pass in C (rts_smooth), the
 * numba kernel's numbers bit for bit.
 *
 * The numba kernel (_smoother_kernels.py, rts_smooth and _factor_prior, with the
 * linear algebra of _linalg_kernels.py they call) is the reference; this port does its
 * arithmetic operation for operation, in the same order, so that the results are the
 * same bytes. envs/_native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * tests/estimators/test_smoother_native.py holds the two equal. Arrays are C-contiguous
 * float64: a run of N beliefs of n states (x: N*n, P: N*n*n), the link (cross-
 * covariances or transition Jacobians, N*n*n; unread for a random walk) and six n*n
 * scratch matrices.
 *
 * Sources ported (manualcontrol/estimators/...):
 *   filters/_smoother_kernels.py  rts_smooth, _factor_prior
 *   filters/_linalg_kernels.py    matmul (symmetrise, cholesky, cholesky_solve_rows and
 *                                 matmul_transposed: ../members/_native_common.h)
 */
#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include "../members/_native_common.h" /* the helpers the ports share (linalg) */

/* smoothers.py: how a block's cross-covariance is known, and the prior's loading */
enum { LINK_CROSS = 0, LINK_TRANSITION = 1, LINK_RANDOM_WALK = 2 };
static const double REGULARISATION = 1e-12; /* smoothers.REGULARISATION */

#define SMOOTHER_ABI 1

/* linalg.matmul: out = A B, all n x n */
static void matmul_square(const double *A, const double *B, double *out, int64_t n)
{
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            for (int64_t k = 0; k < n; k++)
                acc += A[i * n + k] * B[k * n + j];
            out[i * n + j] = acc;
        }
}

/* _factor_prior: the Cholesky factor of P into L, loaded only if it must be; the
 * loadings used (0 normally), -1 if none succeeded */
static int64_t factor_prior(const double *P, double *A, double *L, int64_t n)
{
    if (cholesky(P, L, n))
        return 0;
    double load = REGULARISATION;
    for (int64_t attempt = 1; attempt < 7; attempt++) {
        for (int64_t i = 0; i < n; i++) {
            for (int64_t j = 0; j < n; j++)
                A[i * n + j] = P[i * n + j];
            A[i * n + i] += load * fabs(P[i * n + i]) + 1e-300;
        }
        if (cholesky(A, L, n))
            return attempt;
        load *= 1e3;
    }
    return -1;
}

/* rts_smooth: smooth a stored run backwards; regularised-sample count, or minus the
 * count of samples whose prior could not be factored (they keep their filtered belief) */
int64_t smoother_rts(int64_t N, int64_t n, const double *x_filtered, const double *P_filtered,
                     const double *x_predicted, const double *P_predicted, const double *link,
                     int64_t kind, double *x_smooth, double *P_smooth, double *C, double *G,
                     double *A, double *L, double *D, double *T)
{
    int64_t nn = n * n;
    int64_t regularised = 0;
    int64_t failed = 0;
    if (N == 0)
        return 0;
    for (int64_t i = 0; i < n; i++) {
        x_smooth[(N - 1) * n + i] = x_filtered[(N - 1) * n + i];
        for (int64_t j = 0; j < n; j++)
            P_smooth[(N - 1) * nn + i * n + j] = P_filtered[(N - 1) * nn + i * n + j];
    }
    for (int64_t k = N - 2; k > -1; k--) {
        const double *Pf = P_filtered + k * nn;
        const double *Pp = P_predicted + (k + 1) * nn;
        if (kind == LINK_CROSS) {
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j < n; j++)
                    C[i * n + j] = link[(k + 1) * nn + i * n + j];
        } else if (kind == LINK_TRANSITION) {
            matmul_transposed(Pf, link + (k + 1) * nn, C, n, n, n);
        } else {
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j < n; j++)
                    C[i * n + j] = Pf[i * n + j];
        }
        int64_t status = factor_prior(Pp, A, L, n);
        if (status < 0) {
            failed += 1;
            for (int64_t i = 0; i < n; i++) {
                x_smooth[k * n + i] = x_filtered[k * n + i];
                for (int64_t j = 0; j < n; j++)
                    P_smooth[k * nn + i * n + j] = Pf[i * n + j];
            }
            continue;
        }
        regularised += status > 0 ? 1 : 0;
        cholesky_solve_rows(L, n, C, G, n);
        for (int64_t i = 0; i < n; i++) {
            double acc = x_filtered[k * n + i];
            for (int64_t j = 0; j < n; j++)
                acc += G[i * n + j] * (x_smooth[(k + 1) * n + j] - x_predicted[(k + 1) * n + j]);
            x_smooth[k * n + i] = acc;
        }
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                D[i * n + j] = P_smooth[(k + 1) * nn + i * n + j] - Pp[i * n + j];
        matmul_square(G, D, T, n);
        matmul_transposed(T, G, A, n, n, n);
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                A[i * n + j] += Pf[i * n + j];
        symmetrise(A, n);
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                P_smooth[k * nn + i * n + j] = A[i * n + j];
    }
    return failed == 0 ? regularised : -failed;
}

int64_t smoother_abi(void) { return SMOOTHER_ABI; }

/* the constants this file repeats, for the binding to check against smoothers.py */
int64_t smoother_constants(double *out)
{
    const double values[] = {LINK_CROSS, LINK_TRANSITION, LINK_RANDOM_WALK, REGULARISATION,
                             TINY};
    int64_t count = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < count; i++)
            out[i] = values[i];
    return count;
}
