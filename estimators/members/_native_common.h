/*
 * _native_common.h: the helpers every estimator's C port shares, defined once.
 *
 * Each port (_dekf_native.c, _rml_native.c, _ukf_native.c, _rdi_native.c,
 * _schiess_roland_native.c, _zhao_native.c) includes this file; a port uses the
 * helpers its numba kernels call and leaves the others unused (static: nothing is
 * exported). Each helper is its numba kernel's arithmetic operation for operation, as
 * the ports' own code is (the IEEE flags of envs/_native.py: no reassociation, no
 * fused multiply-add), so every port keeps the numba kernels' numbers bit for bit
 * (tests/estimators/test_*_native.py). The build hash covers this file as well as
 * the port's source, so editing it rebuilds every port.
 *
 * Sources ported (manualcontrol/estimators/...):
 *   filters/linalg.py    TINY, SEMIDEFINITE_TOLERANCE, symmetrise, cholesky,
 *                        cholesky_solve_rows, matmul_transposed,
 *                        semidefinite_floor, cholesky_semidefinite,
 *                        cholesky_semidefinite_pivoted,
 *                        log_determinant, add_product
 *   filters/unscented.py weighted_mean, weighted_covariance
 *   filters/kalman.py    KalmanWork, joseph_scalar
 *   filters/monitor.py   PIN_FRACTION, track_pins, window_push, window_variance
 *   filters/smoothers.py store_belief
 *   _pilot_core.py       inputs_in_use
 *   members/internal_model.py  _pade_jet
 *   members/_schiess_roland_kernels.py, members/_rdi_kernels.py  bicubic weights
 */
#ifndef MANUALCONTROL_NATIVE_COMMON_H
#define MANUALCONTROL_NATIVE_COMMON_H

#include <math.h>
#include <stdint.h>

static const double PIN_FRACTION = 0.9;            /* monitor.PIN_FRACTION */
static const double TINY = 1e-290;                 /* linalg.TINY */
static const double SEMIDEFINITE_TOLERANCE = 1e-13; /* linalg.SEMIDEFINITE_TOLERANCE */

/* kalman.KalmanWork: PHt (n,1), S and L (1,1), K and M (n,1), T (n,n), log_det (0 or 1,) */
typedef struct {
    double *PHt, *S, *L, *K, *M, *T, *log_det;
    int64_t n_log_det;
} KalmanWork;

/* Python's max(a, b) and min(a, b) on floats as numba lowers them: b if b > a else a,
 * b if b < a else a */
static double py_max(double a, double b) { return b > a ? b : a; }
static double py_min(double a, double b) { return b < a ? b : a; }

/* symmetrise: P <- (P + P^T)/2 in place, flushing entries below TINY to zero */
static void symmetrise(double *P, int64_t n)
{
    for (int64_t i = 0; i < n; i++) {
        if (fabs(P[i * n + i]) < TINY)
            P[i * n + i] = 0.0;
        for (int64_t j = i + 1; j < n; j++) {
            double v = 0.5 * (P[i * n + j] + P[j * n + i]);
            if (fabs(v) < TINY)
                v = 0.0;
            P[i * n + j] = v;
            P[j * n + i] = v;
        }
    }
}

/* cholesky: lower factor of the symmetric A (n, n) into L; 0 where A is not positive
 * definite or not finite (L then undefined). Reads A's lower triangle only. */
static int cholesky(const double *A, double *L, int64_t n)
{
    for (int64_t j = 0; j < n; j++) {
        double s = A[j * n + j];
        for (int64_t k = 0; k < j; k++)
            s -= L[j * n + k] * L[j * n + k];
        if (!(s > 0.0) || !isfinite(s))
            return 0;
        double d = sqrt(s);
        L[j * n + j] = d;
        for (int64_t i = j + 1; i < n; i++) {
            s = A[i * n + j];
            for (int64_t k = 0; k < j; k++)
                s -= L[i * n + k] * L[j * n + k];
            L[i * n + j] = s / d;
        }
        for (int64_t i = 0; i < j; i++)
            L[i * n + j] = 0.0;
    }
    return 1;
}

/* cholesky_solve_rows: X S = B for the rows of B (rows, m), S = L L^T; X may be B */
static void cholesky_solve_rows(const double *L, int64_t m, const double *B, double *X,
                                int64_t rows)
{
    for (int64_t r = 0; r < rows; r++) {
        for (int64_t i = 0; i < m; i++) {
            double s = B[r * m + i];
            for (int64_t k = 0; k < i; k++)
                s -= L[i * m + k] * X[r * m + k];
            X[r * m + i] = s / L[i * m + i];
        }
        for (int64_t i = m - 1; i > -1; i--) {
            double s = X[r * m + i];
            for (int64_t k = i + 1; k < m; k++)
                s -= L[k * m + i] * X[r * m + k];
            X[r * m + i] = s / L[i * m + i];
        }
    }
}

/* matmul_transposed: out = A B^T, A (a, c), B (b, c), out (a, b) */
static void matmul_transposed(const double *A, const double *B, double *out, int64_t a,
                              int64_t b, int64_t c)
{
    for (int64_t i = 0; i < a; i++)
        for (int64_t j = 0; j < b; j++) {
            double acc = 0.0;
            for (int64_t k = 0; k < c; k++)
                acc += A[i * c + k] * B[j * c + k];
            out[i * b + j] = acc;
        }
}

/* semidefinite_floor: SEMIDEFINITE_TOLERANCE times A's largest diagonal entry (at least
 * 0); -1 where a diagonal entry is not finite */
static double semidefinite_floor(const double *A, int64_t n)
{
    double largest = 0.0;
    for (int64_t i = 0; i < n; i++) {
        if (!isfinite(A[i * n + i]))
            return -1.0;
        largest = py_max(largest, A[i * n + i]);
    }
    return SEMIDEFINITE_TOLERANCE * largest;
}

/* cholesky_semidefinite: a lower factor of a positive semidefinite A; pivots under
 * SEMIDEFINITE_TOLERANCE times the largest diagonal entry count as zero */
static int cholesky_semidefinite(const double *A, double *L, int64_t n)
{
    double floor_ = semidefinite_floor(A, n);
    if (floor_ < 0.0)
        return 0;
    for (int64_t j = 0; j < n; j++) {
        double s = A[j * n + j];
        for (int64_t k = 0; k < j; k++)
            s -= L[j * n + k] * L[j * n + k];
        for (int64_t i = 0; i < j; i++)
            L[i * n + j] = 0.0;
        if (s <= floor_) {
            if (s < -1e3 * floor_ - 1e-300)
                return 0;
            for (int64_t i = j; i < n; i++)
                L[i * n + j] = 0.0;
            continue;
        }
        double d = sqrt(s);
        L[j * n + j] = d;
        for (int64_t i = j + 1; i < n; i++) {
            s = A[i * n + j];
            for (int64_t k = 0; k < j; k++)
                s -= L[i * n + k] * L[j * n + k];
            L[i * n + j] = s / d;
        }
    }
    return 1;
}

/* cholesky_semidefinite_pivoted: a square root L (A = L L^T, rows in A's order, not
 * triangular) of a positive semidefinite A by Cholesky with diagonal pivoting, the
 * largest remaining pivot first; work is scratch of (n + 2, n): the factor in pivoted
 * order, the remaining pivots and the order */
static int cholesky_semidefinite_pivoted(const double *A, double *L, double *work, int64_t n)
{
    double floor_ = semidefinite_floor(A, n);
    if (floor_ < 0.0)
        return 0;
    double *pivots = work + n * n;
    double *order = work + (n + 1) * n;
    for (int64_t i = 0; i < n; i++) {
        order[i] = (double)i;
        pivots[i] = A[i * n + i];
        for (int64_t j = 0; j < n; j++)
            work[i * n + j] = 0.0;
    }
    for (int64_t k = 0; k < n; k++) {
        int64_t m = k;
        double best = pivots[k];
        for (int64_t i = k + 1; i < n; i++)
            if (pivots[i] > best) {
                best = pivots[i];
                m = i;
            }
        if (!isfinite(best))
            return 0;
        if (m != k) {
            pivots[m] = pivots[k];
            pivots[k] = best;
            double held = order[k];
            order[k] = order[m];
            order[m] = held;
            for (int64_t j = 0; j < k; j++) {
                held = work[k * n + j];
                work[k * n + j] = work[m * n + j];
                work[m * n + j] = held;
            }
        }
        if (best <= floor_) {
            for (int64_t i = k; i < n; i++)
                if (!(pivots[i] >= -1e3 * floor_ - 1e-300))
                    return 0;
            break;
        }
        double d = sqrt(best);
        work[k * n + k] = d;
        int64_t at = (int64_t)order[k];
        for (int64_t i = k + 1; i < n; i++) {
            int64_t other = (int64_t)order[i];
            double s = other > at ? A[other * n + at] : A[at * n + other];
            for (int64_t j = 0; j < k; j++)
                s -= work[i * n + j] * work[k * n + j];
            work[i * n + k] = s / d;
            pivots[i] -= work[i * n + k] * work[i * n + k];
        }
    }
    for (int64_t i = 0; i < n; i++) {
        int64_t row = (int64_t)order[i];
        for (int64_t j = 0; j < n; j++)
            L[row * n + j] = work[i * n + j];
    }
    return 1;
}

/* log_determinant: log det(L L^T) from a Cholesky factor */
static double log_determinant(const double *L, int64_t m)
{
    double total = 0.0;
    for (int64_t i = 0; i < m; i++)
        total += log(L[i * m + i]);
    return 2.0 * total;
}

/* add_product: x += K r, K (n, m) */
static void add_product(double *x, const double *K, const double *r, int64_t n, int64_t m)
{
    for (int64_t i = 0; i < n; i++) {
        double acc = 0.0;
        for (int64_t a = 0; a < m; a++)
            acc += K[i * m + a] * r[a];
        x[i] += acc;
    }
}

/* weighted_mean: out = sum_i w_i Y_i over the first count rows of Y (rows, d) */
static void weighted_mean(const double *Y, int64_t d, const double *weights, int64_t count,
                          double *out)
{
    for (int64_t j = 0; j < d; j++)
        out[j] = 0.0;
    for (int64_t i = 0; i < count; i++) {
        double w = weights[i];
        for (int64_t j = 0; j < d; j++)
            out[j] += w * Y[i * d + j];
    }
}

/* weighted_covariance: out = sum_i w_i (Y_i - mean)(Y_i - mean)^T + noise, symmetrised */
static void weighted_covariance(const double *Y, int64_t d, const double *mean,
                                const double *weights, int64_t count, const double *noise,
                                double *out)
{
    for (int64_t a = 0; a < d; a++)
        for (int64_t b = 0; b < d; b++)
            out[a * d + b] = noise[a * d + b];
    for (int64_t i = 0; i < count; i++) {
        double w = weights[i];
        for (int64_t a = 0; a < d; a++) {
            double da = w * (Y[i * d + a] - mean[a]);
            for (int64_t b = a; b < d; b++)
                out[a * d + b] += da * (Y[i * d + b] - mean[b]);
        }
    }
    for (int64_t a = 0; a < d; a++)
        for (int64_t b = a + 1; b < d; b++)
            out[b * d + a] = out[a * d + b];
    symmetrise(out, d);
}

/* _joseph_scalar: joseph_correct for a scalar measurement, fused (Joseph form,
 * P+ = (I - K H) P- (I - K H)^T + K R K^T, symmetrised). H is (1, n), R (1, 1). */
static int joseph_scalar(double *x, double *P, const double *r, const double *H,
                         const double *R, const KalmanWork *work, int64_t n, double jitter)
{
    double *PHt = work->PHt, *K = work->K, *M = work->M;
    double s = R[0];
    for (int64_t i = 0; i < n; i++) {
        double acc = 0.0;
        for (int64_t j = 0; j < n; j++)
            acc += P[i * n + j] * H[j];
        PHt[i] = acc;
        s += H[i] * acc;
    }
    work->S[0] = s;
    if (!(s > 0.0) || !isfinite(s))
        return 0;
    double r0 = r[0];
    for (int64_t i = 0; i < n; i++) {
        double k_i = PHt[i] / s;
        K[i] = k_i;
        double acc = 0.0;
        acc += k_i * r0;
        x[i] += acc;
    }
    if (work->n_log_det > 0)
        work->log_det[0] = log(s);
    for (int64_t i = 0; i < n; i++) {
        double k_i = K[i];
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            acc += k_i * PHt[j];
            P[i * n + j] -= acc;
        }
    }
    for (int64_t i = 0; i < n; i++) {
        double acc = 0.0;
        for (int64_t j = 0; j < n; j++)
            acc += P[i * n + j] * H[j];
        M[i] = acc;
    }
    double rv = R[0];
    for (int64_t i = 0; i < n; i++) {
        double m_i = M[i];
        double k_i = K[i];
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            acc -= m_i * K[j];
            acc += k_i * rv * K[j];
            P[i * n + j] += acc;
        }
    }
    symmetrise(P, n);
    if (jitter > 0.0)
        for (int64_t i = 0; i < n; i++)
            P[i * n + i] += jitter;
    return 1;
}

/* track_pins: samples at a limit over the last n_pin; first parameter pinned or -1 */
static int64_t track_pins(const uint8_t *pinned_now, int64_t *pins, int64_t *ring,
                          int64_t n_params, int64_t n_pin, int64_t k)
{
    if (n_pin == 0)
        return -1;
    int64_t pos = k % n_pin;
    for (int64_t j = 0; j < n_params; j++) {
        int64_t now = pinned_now[j] ? 1 : 0;
        pins[j] += now - ring[j * n_pin + pos];
        ring[j * n_pin + pos] = now;
    }
    if (k + 1 >= n_pin)
        for (int64_t j = 0; j < n_params; j++)
            if ((double)pins[j] >= PIN_FRACTION * (double)n_pin)
                return j;
    return -1;
}

/* window_push: append a value to the variance ring, update the running sums in sc
 * (Popovici eqs. 24-25, thesis eqs. 29-30) */
static void window_push(double *buf, int64_t size, double *sc, int64_t base, double value,
                        int64_t k)
{
    int64_t pos = k % size;
    double old = buf[pos];
    if (!isnan(old)) {
        double dv = old - sc[base];
        sc[base + 1] -= dv;
        sc[base + 2] -= dv * dv;
        sc[base + 3] -= 1.0;
        if (sc[base + 3] <= 0.0) {
            sc[base + 1] = 0.0;
            sc[base + 2] = 0.0;
            sc[base + 3] = 0.0;
        }
    }
    buf[pos] = value;
    if (!isnan(value)) {
        if (sc[base + 3] == 0.0)
            sc[base] = value;
        double dv = value - sc[base];
        sc[base + 1] += dv;
        sc[base + 2] += dv * dv;
        sc[base + 3] += 1.0;
    }
    if (pos == size - 1) {
        double s = 0.0, ss = 0.0, c = 0.0;
        for (int64_t i = 0; i < size; i++) {
            double v = buf[i];
            if (!isnan(v)) {
                double dv = v - sc[base];
                s += dv;
                ss += dv * dv;
                c += 1.0;
            }
        }
        sc[base + 1] = s;
        sc[base + 2] = ss;
        sc[base + 3] = c;
    }
}

/* window_variance: population variance of the finite values in the ring */
static double window_variance(const double *sc, int64_t base)
{
    double c = sc[base + 3];
    if (c < 1.0)
        return 0.0;
    double mean = sc[base + 1] / c;
    double var = sc[base + 2] / c - mean * mean;
    return var > 0.0 ? var : 0.0;
}

/* store_belief: copy a belief into row `row` of the smoother storage (no-op without) */
static void store_belief(int64_t rows, int64_t row, const double *x, const double *P,
                         int64_t n, double *x_store, double *P_store)
{
    if (rows == 0)
        return;
    for (int64_t i = 0; i < n; i++) {
        x_store[row * n + i] = x[i];
        for (int64_t j = 0; j < n; j++)
            P_store[(row * n + i) * n + j] = P[i * n + j];
    }
}

/* inputs_in_use: a dropped input holds its last value; true if the sample is dropped */
static int inputs_in_use(const double *inputs_k, double u_k, const double *prev_in,
                         double *in_use, int64_t n_in)
{
    int dropped = isnan(u_k) ? 1 : 0;
    for (int64_t i = 0; i < n_in; i++) {
        if (isnan(inputs_k[i])) {
            dropped = 1;
            in_use[i] = prev_in[i];
        } else {
            in_use[i] = inputs_k[i];
        }
    }
    return dropped;
}

/* _pade_jet: Padé polynomial (thesis Part I eq. 4) in descending powers, constant term 1,
 * and its derivative in tau, into row `row` of value and slope (row length order + 1) */
static void pade_jet(double tau, int64_t order, double sign, double *value, double *slope,
                     int64_t row)
{
    int64_t cols = order + 1;
    double c = 1.0;
    double power = 1.0;
    double previous = 1.0;
    for (int64_t k = 0; k < order + 1; k++) {
        if (k > 0) {
            c = c * (double)(order - k + 1) / (double)(k * (2 * order - k + 1));
            previous = power;
            power = power * sign * tau;
        }
        value[row * cols + order - k] = c * power;
        slope[row * cols + order - k] = k == 0 ? 0.0 : c * (double)k * sign * previous;
    }
}

/* bicubic_weights: weights of samples n-1, n, n+1, n+2 for the value at n + d
 * (Boer & Kenyon's Appendix: the Keys kernel, a = -0.5) */
static void bicubic_weights(double d, double *w)
{
    double e = 1.0 - d;
    w[0] = -0.5 * d * e * e;
    w[1] = 1.5 * d * d * d - 2.5 * d * d + 1.0;
    w[2] = 1.5 * e * e * e - 2.5 * e * e + 1.0;
    w[3] = -0.5 * d * d * e;
}

/* bicubic_derivative_weights: d/dd of bicubic_weights (per sample interval) */
static void bicubic_derivative_weights(double d, double *w)
{
    double x = 1.0 + d;
    w[0] = -1.5 * x * x + 5.0 * x - 4.0;
    w[1] = 4.5 * d * d - 5.0 * d;
    double e = 1.0 - d;
    w[2] = -(4.5 * e * e - 5.0 * e);
    x = 2.0 - d;
    w[3] = -(-1.5 * x * x + 5.0 * x - 4.0);
}

#endif /* MANUALCONTROL_NATIVE_COMMON_H */
