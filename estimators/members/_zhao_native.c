/*
 * _zhao_native.c: Zhao et al.'s UKF on the cybernetic driver model in C, the numba
 * kernels' numbers bit for bit.
 *
 * The numba kernels (_zhao_kernels.py and what it calls) are the reference; this port does
 * their arithmetic operation for operation, in the same order, so that the results are
 * the same bytes (numba neither reassociates nor contracts to FMA without fastmath).
 * It exists because it is built in under a CPU-second where numba compiles the same
 * work for tens of CPU-seconds. _native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * tests/estimators/test_zhao_native.py holds the two equal.
 *
 * Sources ported (manualcontrol/...):
 *   estimators/members/_zhao_kernels.py zhao_step, zhao_run, _parameters, _measure,
 *                                     _propagate, _store (Zhao et al. 2019, Algorithm 2:
 *                                     output prediction eq. 6, correction, Euler
 *                                     prediction of eq. 6 with eq. 2's matrices);
 *                                     the multi-UKF (Sec. 4.2, the fusion rule of
 *                                     zhao_ukf.MultiUKF): fuse_step, multi_step, multi_run
 *   pilots/driver.py                  _eq2_matrices (Zhao eq. 2, corrected; B and D
 *                                     with four columns: the filter's own)
 *   estimators/filters/unscented.py   sigma_points, weighted_mean, weighted_covariance,
 *                                     cross_covariance, unscented_correct (Algorithm 1,
 *                                     Algorithm 2 step 3)
 *   estimators/filters/linalg.py      symmetrise, cholesky, cholesky_semidefinite,
 *                                     cholesky_semidefinite_pivoted,
 *                                     cholesky_solve_rows, log_determinant, add_product
 *   estimators/filters/kalman.py      clamp (estimate projection onto limits)
 *   estimators/filters/monitor.py     belief_health, track_pins
 *   estimators/_pilot_core.py         report_frozen, report_row
 *
 * The records (namedtuples of numpy arrays) arrive as one struct of pointers to their
 * C-contiguous data plus the sizes the kernels read from the arrays' shapes; Python
 * fills it (_zhao_native.py), with arrays shared between records passed as the same
 * pointer; the multi-UKF passes its two members' structs and one of its fusion's.
 *
 * Python's semantics kept where C differs: max(a, b) is "b if b > a else a" and
 * min(a, b) "b if b < a else a" (numba's lowering of the builtins, NaN-faithful);
 * int(x) truncates; an int operand of a float operation is converted to double first;
 * a sum starts from 0.0 as the Python's does (0.0 + -0.0 is +0.0: signed zeros as
 * numba gives them); unary minus binds before * and / as in Python; booleans are
 * numpy's one-byte 0/1.
 */

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include "_native_common.h" /* the helpers the ports share (linalg, monitor, smoothers) */

/* ---- _zhao_core.py: indices into cfg (CFG_*) and sizes */
enum {
    CFG_VX = 0,
    CFG_H = 1,
    CFG_SUBSTEPS = 2,
    CFG_SPREAD = 3,
    CFG_COUNT = 4,
    CFG_JITTER = 5,
    CFG_MAX_COV = 6,
    CFG_SIZE = 7
};
enum { N_STATES = 3, N_OUTPUTS = 2, N_INPUTS = 4 };
/* _pilot_core.py: indices into sc (SC_*) */
enum {
    SC_K = 0,
    SC_FROZEN = 11,
    SC_DIV_INDEX = 12,
    SC_DIV_REASON = 13,
    SC_DIV_PARAM = 14,
    SC_SIZE = 15
};
/* filters/monitor.py: divergence codes */
enum { REASON_NONE = 0, REASON_NONFINITE = 1, REASON_COVARIANCE = 2, REASON_PINNED = 3 };

static const double NEGATIVE_TOLERANCE = 1e-10;       /* monitor.NEGATIVE_TOLERANCE */

#define ZHAO_ABI 1

/* Every record of zhao_step: ZhaoConfig, ZhaoBelief, PilotMonitor, PilotReport,
 * ZhaoScratch (its UnscentedWork inline) and ZhaoOutput. Field order must match
 * _zhao_native.py. */
typedef struct {
    /* sizes */
    int64_t n;          /* augmented states: belief.x.shape[0] */
    int64_t n_t;        /* estimated parameters: config.theta_index.shape[0] */
    int64_t n_p;        /* model parameters: belief.p.shape[0] (= 8) */
    int64_t points;     /* sigma points: work.X.shape[0] (2n + 1) */
    int64_t n_pin;      /* monitor.pin_ring.shape[1] */
    int64_t n_flag;     /* out.flag.shape[1] */
    int64_t store_rows; /* out.x_prior.shape[0]: smoother storage rows (0: none) */
    int64_t link_rows;  /* out.link.shape[0] */
    /* ZhaoConfig */
    const double *cfg, *base;
    const int64_t *theta_index;
    const double *Q, *R, *w_mean, *w_cov;
    const int64_t *limit;
    const uint8_t *estimated;
    /* ZhaoBelief */
    double *x, *P, *prev_in, *p, *sc, *link;
    /* PilotMonitor (buf_u and buf_e are not read) */
    int64_t *pins, *pin_ring;
    double *last_mean, *last_std;
    uint8_t *pinned_now;
    /* PilotReport */
    const double *lo, *hi, *offset, *sign;
    /* ZhaoScratch.work (UnscentedWork) */
    double *L, *X, *Y, *Z, *z, *S, *LS, *Cxz, *K, *xbar, *log_det;
    /* ZhaoScratch */
    double *A, *B, *C, *D, *Bu, *y, *r, *in_use, *variance, *scalars, *point;
    /* ZhaoOutput */
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *predictions, *innovations, *S_out, *states;
    double *x_prior, *P_prior, *x_post, *P_post, *link_out;
} ZhaoRecords;

/* The multi-UKF's fusion (_zhao_core.py: FusionConfig, FusionState, MultiOutput); the
 * members' records and outputs are their own ZhaoRecords. Field order must match
 * _zhao_native.py. */
typedef struct {
    int64_t n_t;      /* fusion.theta_index.shape[0] */
    int64_t n_p;      /* out.mean.shape[1] */
    int64_t n_flag;   /* out.flag.shape[1] */
    int64_t feedback; /* fusion.feedback */
    double a_short, a_long;
    const double *dead_zone;
    const int64_t *theta_index;
    double *smooth, *level, *started;
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *predictions, *innovations, *S_out, *states, *gate, *members;
} FusionRecords;

/* Python's max(a, b) and min(a, b) on floats as numba lowers them: b if b > a else a,
 * b if b < a else a */

/* ===================================================================== linalg.py */

/* ================================================================== unscented.py */

/* sigma_points: points of (x, P) into the rows of X (centre last); 0 when P is not
 * positive semidefinite or not finite */
static int sigma_points(const double *x, const double *P, double spread, double *L,
                        double *X, int64_t n)
{
    if (!cholesky_semidefinite(P, L, n) && !cholesky_semidefinite_pivoted(P, L, X, n))
        return 0;
    for (int64_t i = 0; i < n; i++) {
        for (int64_t j = 0; j < n; j++) {
            double d = spread * L[j * n + i];
            X[i * n + j] = x[j] + d;
            X[(n + i) * n + j] = x[j] - d;
        }
    }
    for (int64_t j = 0; j < n; j++)
        X[2 * n * n + j] = x[j];
    return 1;
}

/* cross_covariance: out (nx, nz) = sum_i w_i (X_i - xmean)(Z_i - zmean)^T */
static void cross_covariance(const double *X, int64_t nx, const double *xmean, const double *Z,
                             int64_t nz, const double *zmean, const double *weights,
                             int64_t count, double *out)
{
    for (int64_t a = 0; a < nx; a++)
        for (int64_t b = 0; b < nz; b++)
            out[a * nz + b] = 0.0;
    for (int64_t i = 0; i < count; i++) {
        double w = weights[i];
        for (int64_t a = 0; a < nx; a++) {
            double da = w * (X[i * nx + a] - xmean[a]);
            for (int64_t b = 0; b < nz; b++)
                out[a * nz + b] += da * (Z[i * nz + b] - zmean[b]);
        }
    }
}

/* unscented_correct: K = C_xz S^-1, x += K r, P -= K C_xz^T (Zhao Algorithm 2 step 3);
 * 0, x and P unchanged, when S (m, m) is not positive definite */
static int unscented_correct(double *x, double *P, int64_t n, const double *r, int64_t m,
                             const double *Cxz, const double *S, double *LS, double *K,
                             double *log_det, double jitter)
{
    if (!cholesky(S, LS, m))
        return 0;
    cholesky_solve_rows(LS, m, Cxz, K, n);
    log_det[0] = log_determinant(LS, m);
    add_product(x, K, r, n, m);
    for (int64_t i = 0; i < n; i++) {
        for (int64_t j = i; j < n; j++) {
            double acc = 0.0;
            for (int64_t a = 0; a < m; a++)
                acc += K[i * m + a] * Cxz[j * m + a];
            P[i * n + j] -= acc;
            if (j != i)
                P[j * n + i] = P[i * n + j];
        }
    }
    symmetrise(P, n);
    if (jitter > 0.0)
        for (int64_t i = 0; i < n; i++)
            P[i * n + i] += jitter;
    return 1;
}

/* ===================================================================== kalman.py */

/* clamp: estimate projection onto box limits */
static int64_t clamp(double *x, const int64_t *index, int64_t n, const double *lo,
                     const double *hi)
{
    int64_t moved = 0;
    for (int64_t i = 0; i < n; i++) {
        int64_t j = index[i];
        if (j < 0)
            continue;
        if (x[i] < lo[j]) {
            x[i] = lo[j];
            moved += 1;
        } else if (x[i] > hi[j]) {
            x[i] = hi[j];
            moved += 1;
        }
    }
    return moved;
}

/* ==================================================================== monitor.py */

/* belief_health: (finite, covariance ok) of a belief */
static void belief_health(const double *x, const double *P, int64_t n, double max_cov,
                          int zero_ok, int *finite_out, int *ok_out)
{
    int finite = 1;
    double largest = 0.0;
    for (int64_t i = 0; i < n; i++) {
        if (!isfinite(x[i]) || !isfinite(P[i * n + i]))
            finite = 0;
        else if (P[i * n + i] > largest)
            largest = P[i * n + i];
    }
    int ok = 1;
    for (int64_t i = 0; i < n; i++) {
        double v = P[i * n + i];
        int below = zero_ok ? v < -NEGATIVE_TOLERANCE * largest
                            : v <= -NEGATIVE_TOLERANCE * largest;
        if (below || v > max_cov)
            ok = 0;
    }
    *finite_out = finite;
    *ok_out = ok;
}

/* ================================================================ _pilot_core.py */

/* report_frozen: a stopped filter's row (last estimate, NaN predictions, diverged) */
static void report_frozen(const ZhaoRecords *rec, int dropped, int64_t row)
{
    int64_t n_p = rec->n_p, nf = rec->n_flag;
    for (int64_t j = 0; j < n_p; j++) {
        rec->mean[row * n_p + j] = rec->last_mean[j];
        rec->std[row * n_p + j] = rec->last_std[j];
        rec->pinned[row * n_p + j] = 0;
    }
    rec->scalar[row * 3 + 0] = NAN;
    rec->scalar[row * 3 + 1] = NAN;
    rec->scalar[row * 3 + 2] = NAN;
    rec->flag[row * nf + 0] = 0;
    rec->flag[row * nf + 1] = 0;
    rec->flag[row * nf + 2] = (uint8_t)dropped;
    rec->flag[row * nf + 3] = 1;
    for (int64_t i = 0; i < N_INPUTS; i++)
        rec->prev_in[i] = rec->in_use[i];
    rec->sc[SC_K] = rec->sc[SC_K] + 1.0;
}

/* report_row: report one sample (means in model order through the report transform,
 * standard deviations, pins) and record divergence */
static void report_row(const ZhaoRecords *rec, int finite, int cov_ok, int dropped,
                       int64_t row)
{
    double *sc = rec->sc;
    const double *p = rec->p, *variance = rec->variance, *scalars = rec->scalars;
    int64_t k = (int64_t)sc[SC_K];
    int64_t n_p = rec->n_p, nf = rec->n_flag;
    double *mean = rec->mean + row * n_p, *std = rec->std + row * n_p;
    uint8_t *pinned_row = rec->pinned + row * n_p;
    uint8_t *pinned_now = rec->pinned_now;
    for (int64_t j = 0; j < n_p; j++) {
        pinned_row[j] = 0;
        pinned_now[j] = 0;
    }
    if (finite) {
        for (int64_t j = 0; j < n_p; j++) {
            mean[j] = p[j];
            if (rec->estimated[j]) {
                std[j] = sqrt(py_max(variance[j], 0.0));
                pinned_now[j] = (p[j] <= rec->lo[j] || p[j] >= rec->hi[j]) ? 1 : 0;
            } else {
                std[j] = 0.0;
            }
        }
        for (int64_t j = 0; j < n_p; j++)
            pinned_row[j] = pinned_now[j];
        int64_t pinned = track_pins(pinned_now, rec->pins, rec->pin_ring, n_p, rec->n_pin, k);
        for (int64_t j = 0; j < n_p; j++) {
            mean[j] = rec->offset[j] + rec->sign[j] * mean[j];
            rec->last_mean[j] = mean[j];
            rec->last_std[j] = std[j];
        }
        if (sc[SC_DIV_REASON] == REASON_NONE && pinned >= 0) {
            sc[SC_DIV_REASON] = REASON_PINNED;
            sc[SC_DIV_INDEX] = (double)k;
            sc[SC_DIV_PARAM] = (double)pinned;
        }
    } else {
        for (int64_t j = 0; j < n_p; j++) {
            mean[j] = rec->last_mean[j];
            std[j] = rec->last_std[j];
        }
    }
    if (!finite || !cov_ok) {
        sc[SC_FROZEN] = 1.0;
        if (sc[SC_DIV_REASON] == REASON_NONE || sc[SC_DIV_REASON] == REASON_PINNED) {
            sc[SC_DIV_REASON] = !finite ? REASON_NONFINITE : REASON_COVARIANCE;
            sc[SC_DIV_INDEX] = (double)k;
            sc[SC_DIV_PARAM] = -1.0;
        }
    }
    for (int64_t i = 0; i < 3; i++)
        rec->scalar[row * 3 + i] = finite ? scalars[i] : NAN;
    rec->flag[row * nf + 0] = (uint8_t)finite;
    rec->flag[row * nf + 1] = (uint8_t)cov_ok;
    rec->flag[row * nf + 2] = (uint8_t)dropped;
    rec->flag[row * nf + 3] = sc[SC_DIV_REASON] != REASON_NONE;
    sc[SC_K] = (double)(k + 1);
}

/* ===================================================================== driver.py */

/* driver_matrices: Zhao eq. 2 (corrected) into A (3, 3), B (3, 4), C (2, 3), D (2, 4) */
static void driver_matrices(const double *p, double v_x, double *A, double *B, double *C,
                            double *D)
{
    double K_p = p[0], K_c = p[1], T_I = p[2], T_L = p[3], tau_p = p[4], K_r = p[5],
           K_t = p[6], T_N = p[7];
    double G = K_r * v_x + K_t;
    double lead = T_L / T_I;
    double c = K_c / v_x;
    double pade_rate = 2.0 / tau_p;
    for (int i = 0; i < 3; i++) {
        for (int j = 0; j < 3; j++)
            A[i * 3 + j] = 0.0;
        for (int j = 0; j < N_INPUTS; j++)
            B[i * N_INPUTS + j] = 0.0;
    }
    for (int i = 0; i < 2; i++) {
        for (int j = 0; j < 3; j++)
            C[i * 3 + j] = 0.0;
        for (int j = 0; j < N_INPUTS; j++)
            D[i * N_INPUTS + j] = 0.0;
    }
    A[0 * 3 + 0] = -1.0 / T_I;
    A[1 * 3 + 0] = c * pade_rate * (1.0 - lead);
    A[1 * 3 + 1] = -pade_rate;
    A[2 * 3 + 0] = -G * c * (1.0 - lead) / T_N;
    A[2 * 3 + 1] = 2.0 * G / T_N;
    A[2 * 3 + 2] = -1.0 / T_N;
    B[0 * N_INPUTS + 1] = 1.0 / T_I;
    B[1 * N_INPUTS + 0] = K_p * pade_rate;
    B[1 * N_INPUTS + 1] = c * pade_rate * lead;
    B[2 * N_INPUTS + 0] = -K_p * G / T_N;
    B[2 * N_INPUTS + 1] = -G * c * lead / T_N;
    B[2 * N_INPUTS + 2] = -K_t / T_N;
    B[2 * N_INPUTS + 3] = -1.0 / T_N;
    C[0 * 3 + 2] = 1.0;
    C[1 * 3 + 0] = -c * (1.0 - lead);
    C[1 * 3 + 1] = 2.0;
    D[1 * N_INPUTS + 0] = -K_p;
    D[1 * N_INPUTS + 1] = -c * lead;
}

/* ================================================================= _zhao_kernels.py */

/* _parameters: the model parameter vector of sigma point `row` into p */
static void parameters(const ZhaoRecords *rec, const double *X, int64_t row, double *p)
{
    for (int64_t j = 0; j < rec->n_p; j++)
        p[j] = rec->base[j];
    for (int64_t t = 0; t < rec->n_t; t++)
        p[rec->theta_index[t]] = X[row * rec->n + N_STATES + t];
}

/* _measure: Z[i] = C(theta_i) x_i + D(theta_i) u for the first count points */
static void measure(const ZhaoRecords *rec, const double *X, int64_t count, const double *inputs,
                    double *Z)
{
    double *p = rec->point, *A = rec->A, *B = rec->B, *C = rec->C, *D = rec->D;
    const int64_t n = rec->n;
    double v_x = rec->cfg[CFG_VX];
    for (int64_t i = 0; i < count; i++) {
        parameters(rec, X, i, p);
        driver_matrices(p, v_x, A, B, C, D);
        for (int r = 0; r < N_OUTPUTS; r++) {
            double acc = 0.0;
            for (int j = 0; j < N_STATES; j++)
                acc += C[r * 3 + j] * X[i * n + j];
            for (int j = 0; j < N_INPUTS; j++)
                acc += D[r * N_INPUTS + j] * inputs[j];
            Z[i * N_OUTPUTS + r] = acc;
        }
    }
}

/* _propagate: Y[i] = f_d(X[i], u), Euler sub-steps of eq. 6, parameters unchanged */
static void propagate(const ZhaoRecords *rec, const double *X, int64_t count,
                      const double *inputs, double *Y)
{
    double *p = rec->point, *A = rec->A, *B = rec->B, *C = rec->C, *D = rec->D;
    double *Bu = rec->Bu, *y = rec->y;
    const double *cfg = rec->cfg;
    double v_x = cfg[CFG_VX];
    double h = cfg[CFG_H];
    int64_t substeps = (int64_t)cfg[CFG_SUBSTEPS];
    const int64_t n = rec->n;
    for (int64_t i = 0; i < count; i++) {
        parameters(rec, X, i, p);
        driver_matrices(p, v_x, A, B, C, D);
        for (int r = 0; r < N_STATES; r++) {
            double acc = 0.0;
            for (int j = 0; j < N_INPUTS; j++)
                acc += B[r * N_INPUTS + j] * inputs[j];
            Bu[r] = acc;
            y[r] = X[i * n + r];
        }
        /* eq. 2's A is lower triangular */
        double a00 = A[0], a10 = A[3], a11 = A[4];
        double a20 = A[6], a21 = A[7], a22 = A[8];
        double y0 = y[0], y1 = y[1], y2 = y[2];
        for (int64_t s = 0; s < substeps; s++) {
            double d0 = a00 * y0 + Bu[0];
            double d1 = a10 * y0 + a11 * y1 + Bu[1];
            double d2 = a20 * y0 + a21 * y1 + a22 * y2 + Bu[2];
            y0 += h * d0;
            y1 += h * d1;
            y2 += h * d2;
        }
        y[0] = y0;
        y[1] = y1;
        y[2] = y2;
        for (int r = 0; r < N_STATES; r++)
            Y[i * n + r] = y[r];
        for (int64_t r = N_STATES; r < n; r++)
            Y[i * n + r] = X[i * n + r];
    }
}

/* _store: a belief into row `row` of the smoother storage (no-op without) */
static void store(int64_t rows, int64_t row, const double *x, const double *P, int64_t n,
                  double *target_x, double *target_P)
{
    if (rows == 0)
        return;
    for (int64_t i = 0; i < n; i++) {
        target_x[row * n + i] = x[i];
        for (int64_t j = 0; j < n; j++)
            target_P[(row * n + i) * n + j] = P[i * n + j];
    }
}

static void nan_outputs(const ZhaoRecords *rec, int64_t row)
{
    for (int r = 0; r < N_OUTPUTS; r++) {
        rec->predictions[row * N_OUTPUTS + r] = NAN;
        rec->innovations[row * N_OUTPUTS + r] = NAN;
        for (int c = 0; c < N_OUTPUTS; c++)
            rec->S_out[(row * N_OUTPUTS + r) * N_OUTPUTS + c] = NAN;
    }
}

/* zhao_step: advance the belief by one sample (Zhao Algorithm 2; see _zhao_kernels.py) and
 * write row `row` of the output */
void zhao_step(const ZhaoRecords *rec, const double *inputs_k, const double *y_k, int64_t row)
{
    const double *cfg = rec->cfg;
    double *x = rec->x, *P = rec->P, *prev_in = rec->prev_in, *p = rec->p, *sc = rec->sc;
    double *link = rec->link;
    const int64_t n = rec->n, n_t = rec->n_t;
    const int64_t k = (int64_t)sc[SC_K];
    double *in_use = rec->in_use;
    int dropped = 0;
    for (int i = 0; i < N_INPUTS; i++) {
        if (isnan(inputs_k[i])) {
            dropped = 1;
            in_use[i] = prev_in[i];
        } else {
            in_use[i] = inputs_k[i];
        }
    }
    for (int r = 0; r < N_OUTPUTS; r++)
        if (isnan(y_k[r]))
            dropped = 1;
    if (sc[SC_FROZEN] > 0.0) {
        store(rec->store_rows, row, x, P, n, rec->x_prior, rec->P_prior);
        store(rec->store_rows, row, x, P, n, rec->x_post, rec->P_post);
        if (rec->link_rows > 0)
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j < n; j++)
                    rec->link_out[(row * n + i) * n + j] = 0.0;
        nan_outputs(rec, row);
        for (int i = 0; i < N_STATES; i++)
            rec->states[row * N_STATES + i] = x[i];
        report_frozen(rec, dropped, row);
        return;
    }
    store(rec->store_rows, row, x, P, n, rec->x_prior, rec->P_prior);
    if (rec->link_rows > 0)
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                rec->link_out[(row * n + i) * n + j] = link[i * n + j];

    /* ---- output prediction (Algorithm 2 step 2) */
    double spread = cfg[CFG_SPREAD];
    int64_t count = (int64_t)cfg[CFG_COUNT];
    int correct_ok = sigma_points(x, P, spread, rec->L, rec->X, n);
    if (!correct_ok) {
        nan_outputs(rec, row);
    } else {
        measure(rec, rec->X, count, in_use, rec->Z);
        weighted_mean(rec->Z, N_OUTPUTS, rec->w_mean, count, rec->z);
        weighted_covariance(rec->Z, N_OUTPUTS, rec->z, rec->w_cov, count, rec->R, rec->S);
        for (int r = 0; r < N_OUTPUTS; r++) {
            rec->predictions[row * N_OUTPUTS + r] = rec->z[r];
            rec->r[r] = y_k[r] - rec->z[r];
            rec->innovations[row * N_OUTPUTS + r] = dropped ? NAN : rec->r[r];
            for (int c = 0; c < N_OUTPUTS; c++)
                rec->S_out[(row * N_OUTPUTS + r) * N_OUTPUTS + c] = rec->S[r * N_OUTPUTS + c];
        }
        /* ---- correction (step 3) */
        if (!dropped) {
            cross_covariance(rec->X, n, x, rec->Z, N_OUTPUTS, rec->z, rec->w_cov, count,
                             rec->Cxz);
            correct_ok = unscented_correct(x, P, n, rec->r, N_OUTPUTS, rec->Cxz, rec->S,
                                           rec->LS, rec->K, rec->log_det, cfg[CFG_JITTER]);
            clamp(x, rec->limit, n, rec->lo, rec->hi);
        }
    }
    store(rec->store_rows, row, x, P, n, rec->x_post, rec->P_post);
    for (int i = 0; i < N_STATES; i++)
        rec->states[row * N_STATES + i] = x[i];
    for (int i = 0; i < N_INPUTS; i++)
        prev_in[i] = in_use[i];

    /* ---- health and report (before the prediction: the estimate after this sample) */
    int finite, cov_ok;
    belief_health(x, P, n, cfg[CFG_MAX_COV], 1, &finite, &cov_ok);
    if (!correct_ok)
        cov_ok = 0;
    double *variance = rec->variance;
    for (int64_t j = 0; j < rec->n_p; j++) {
        p[j] = rec->base[j];
        variance[j] = 0.0;
    }
    for (int64_t t = 0; t < n_t; t++) {
        p[rec->theta_index[t]] = x[N_STATES + t];
        variance[rec->theta_index[t]] = P[(N_STATES + t) * n + N_STATES + t];
    }
    double *scalars = rec->scalars;
    scalars[0] = rec->predictions[row * N_OUTPUTS + 0];
    scalars[1] = rec->innovations[row * N_OUTPUTS + 0];
    scalars[2] = rec->S_out[(row * N_OUTPUTS + 0) * N_OUTPUTS + 0];
    report_row(rec, finite, cov_ok, dropped, row);
    if (sc[SC_FROZEN] > 0.0)
        return;

    /* ---- prediction of the next prior (step 4) */
    if (sigma_points(x, P, spread, rec->L, rec->X, n)) {
        propagate(rec, rec->X, count, in_use, rec->Y);
        weighted_mean(rec->Y, n, rec->w_mean, count, rec->xbar);
        cross_covariance(rec->X, n, x, rec->Y, n, rec->xbar, rec->w_cov, count, link);
        weighted_covariance(rec->Y, n, rec->xbar, rec->w_cov, count, rec->Q, P);
        for (int64_t i = 0; i < n; i++)
            x[i] = rec->xbar[i];
    } else { /* the posterior covariance is not positive definite: stop here */
        sc[SC_FROZEN] = 1.0;
        if (sc[SC_DIV_REASON] == REASON_NONE) {
            sc[SC_DIV_REASON] = REASON_COVARIANCE;
            sc[SC_DIV_INDEX] = (double)k;
            sc[SC_DIV_PARAM] = -1.0;
        }
    }
}

/* zhao_step_values: zhao_step on a sample given by value (the online path: no array
 * addresses to look up from Python) */
void zhao_step_values(const ZhaoRecords *rec, double in0, double in1, double in2, double in3,
                      double y0, double y1, int64_t row)
{
    const double inputs_k[N_INPUTS] = {in0, in1, in2, in3};
    const double y_k[N_OUTPUTS] = {y0, y1};
    zhao_step(rec, inputs_k, y_k, row);
}

/* zhao_run: zhao_step over every sample: inputs (n, 4), outputs (n, 2) */
void zhao_run(const ZhaoRecords *rec, const double *inputs, const double *outputs, int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        zhao_step(rec, inputs + k * N_INPUTS, outputs + k * N_OUTPUTS, k);
}

/* ================================================== _zhao_kernels.py: the multi-UKF */

/* fuse_step: fuse row `row` of the members' outputs into the fusion's output; re-centre
 * the slow member (see _zhao_kernels.fuse_step and MultiUKF for the rule) */
static void fuse_step(const FusionRecords *fu, const ZhaoRecords *slow, const ZhaoRecords *fast,
                      int64_t row)
{
    const int64_t n_p = fu->n_p, nf = fu->n_flag, n_t = fu->n_t;
    const int64_t sp = slow->n_p, fp = fast->n_p, snf = slow->n_flag, fnf = fast->n_flag;
    for (int64_t j = 0; j < n_p; j++) {
        fu->mean[row * n_p + j] = slow->mean[row * sp + j];
        fu->std[row * n_p + j] = slow->std[row * sp + j];
        fu->pinned[row * n_p + j] = slow->pinned[row * sp + j] || fast->pinned[row * fp + j];
    }
    for (int i = 0; i < 3; i++)
        fu->scalar[row * 3 + i] = slow->scalar[row * 3 + i];
    for (int r = 0; r < N_OUTPUTS; r++) {
        fu->predictions[row * N_OUTPUTS + r] = slow->predictions[row * N_OUTPUTS + r];
        fu->innovations[row * N_OUTPUTS + r] = slow->innovations[row * N_OUTPUTS + r];
        for (int c = 0; c < N_OUTPUTS; c++)
            fu->S_out[(row * N_OUTPUTS + r) * N_OUTPUTS + c] =
                slow->S_out[(row * N_OUTPUTS + r) * N_OUTPUTS + c];
    }
    for (int i = 0; i < N_STATES; i++)
        fu->states[row * N_STATES + i] = slow->states[row * N_STATES + i];
    fu->flag[row * nf + 0] = slow->flag[row * snf + 0] && fast->flag[row * fnf + 0];
    fu->flag[row * nf + 1] = slow->flag[row * snf + 1] && fast->flag[row * fnf + 1];
    fu->flag[row * nf + 2] = slow->flag[row * snf + 2];
    int diverged = slow->flag[row * snf + 3] || fast->flag[row * fnf + 3];
    fu->flag[row * nf + 3] = (uint8_t)diverged;
    int first = fu->started[0] == 0.0;
    fu->started[0] = 1.0;
    int moved = 0;
    double *smooth = fu->smooth, *level = fu->level;
    for (int64_t t = 0; t < n_t; t++) {
        int64_t j = fu->theta_index[t];
        double s = slow->mean[row * sp + j];
        double f = fast->mean[row * fp + j];
        fu->members[row * 2 * n_t + t] = s;
        fu->members[row * 2 * n_t + n_t + t] = f;
        double d = f - s;
        fu->gate[row * n_t + t] = 0.0;
        if (diverged || !isfinite(d))
            continue;
        if (first) {
            smooth[t] = d;
            level[t] = d * d;
        } else {
            smooth[t] += fu->a_short * (d - smooth[t]);
        }
        double dbar = smooth[t];
        double floor_ = level[t] + fu->dead_zone[t] * fu->dead_zone[t];
        double lam = 0.0;
        if (dbar * dbar > floor_)
            lam = 1.0 - floor_ / (dbar * dbar);
        else /* the usual level is learnt while the members agree, not from a change */
            level[t] += fu->a_long * (dbar * dbar - level[t]);
        double step = lam * dbar;
        /* never beyond the fast member's current value */
        if (step > 0.0 && step > d)
            step = py_max(d, 0.0);
        else if (step < 0.0 && step < d)
            step = py_min(d, 0.0);
        double fused = s + step;
        fu->gate[row * n_t + t] = lam;
        fu->mean[row * n_p + j] = fused;
        double vs = slow->std[row * sp + j] * slow->std[row * sp + j];
        double vf = fast->std[row * fp + j] * fast->std[row * fp + j];
        fu->std[row * n_p + j] = sqrt((1.0 - lam) * vs + lam * vf + lam * (1.0 - lam) * d * d);
        if (fu->feedback && lam > 0.0) {
            slow->x[N_STATES + t] += fused - s;
            smooth[t] -= fused - s;
            moved = 1;
        }
    }
    if (moved)
        clamp(slow->x, slow->limit, slow->n, slow->lo, slow->hi);
}

/* multi_step: both members' zhao_step on one sample, then fuse_step */
void multi_step(const ZhaoRecords *slow, const ZhaoRecords *fast, const FusionRecords *fusion,
                const double *inputs_k, const double *y_k, int64_t row)
{
    zhao_step(slow, inputs_k, y_k, row);
    zhao_step(fast, inputs_k, y_k, row);
    fuse_step(fusion, slow, fast, row);
}

/* multi_step_values: multi_step on a sample given by value (the online path) */
void multi_step_values(const ZhaoRecords *slow, const ZhaoRecords *fast,
                       const FusionRecords *fusion, double in0, double in1, double in2,
                       double in3, double y0, double y1, int64_t row)
{
    const double inputs_k[N_INPUTS] = {in0, in1, in2, in3};
    const double y_k[N_OUTPUTS] = {y0, y1};
    multi_step(slow, fast, fusion, inputs_k, y_k, row);
}

/* multi_run: multi_step over every sample: inputs (n, 4), outputs (n, 2) */
void multi_run(const ZhaoRecords *slow, const ZhaoRecords *fast, const FusionRecords *fusion,
               const double *inputs, const double *outputs, int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        multi_step(slow, fast, fusion, inputs + k * N_INPUTS, outputs + k * N_OUTPUTS, k);
}

/* For the Python side to check the layout and the constants it was built against. */
int64_t zhao_abi(void) { return ZHAO_ABI; }
int64_t zhao_records_size(void) { return (int64_t)sizeof(ZhaoRecords); }
int64_t zhao_fusion_size(void) { return (int64_t)sizeof(FusionRecords); }
int64_t zhao_constants(double *out)
{
    const double values[] = {
        PIN_FRACTION, NEGATIVE_TOLERANCE, TINY, SEMIDEFINITE_TOLERANCE,
        REASON_NONE, REASON_NONFINITE, REASON_COVARIANCE, REASON_PINNED,
        CFG_VX, CFG_H, CFG_SUBSTEPS, CFG_SPREAD, CFG_COUNT, CFG_JITTER, CFG_MAX_COV, CFG_SIZE,
        N_STATES, N_OUTPUTS, N_INPUTS,
        SC_K, SC_FROZEN, SC_DIV_INDEX, SC_DIV_REASON, SC_DIV_PARAM, SC_SIZE,
    };
    int64_t n = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < n; i++)
            out[i] = values[i];
    return n;
}
