/*
 * _schiess_roland_native.c: the Schiess-Roland filter's compiled path in C, the numba
 * kernels' numbers bit for bit.
 *
 * The joint EKF of Schiess & Roland (1975, NASA TN D-8024) on the delayed pilot model:
 * the states of eqs. 6 and 14, the exact flow of eqs. 7-12 over a step (eq. 18) by a
 * Taylor series of the augmented matrix exponential and its derivative Phi (eq. 19),
 * the delayed error of eq. 17 from the histories, the Joseph correction of eqs. 20-22
 * with both measurements (eq. 16; the m = 2 Cholesky solve) or one, and the Appendix's
 * adaptive fictitious noise (eqs. A1-A6). The numba kernels (_schiess_roland_core.py and
 * what it calls) are the reference; this port does their arithmetic operation for
 * operation, in the same order, so that the results are the same bytes (numba neither
 * reassociates nor contracts to FMA without fastmath). It exists because a C compiler
 * builds it in a fraction of a second where numba compiles the same work for many
 * CPU-seconds on a machine's first use. _native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * tests/estimators/test_schiess_roland_native.py holds the two equal.
 *
 * Sources ported (manualcontrol/...):
 *   estimators/members/_schiess_roland_core.py  sr_step, sr_run, flow, _substep,
 *       _apply_a, input_gains, _input_gain_derivatives, _add_a_derivative, _series_norm,
 *       predict_covariance_structured, _ring, _error_at, delayed_error,
 *       adaptive_variance, _store_phi
 *   estimators/_pilot_core.py         report_frozen, report_row
 *   envs/_interpolation.py            bicubic_weights, bicubic_derivative_weights
 *   estimators/filters/kalman.py      joseph_correct (m = 2: the Cholesky form; m = 1:
 *                                     _joseph_scalar), _innovation_covariance, clamp
 *   estimators/filters/linalg.py      symmetrise, cholesky, cholesky_solve_rows,
 *                                     log_determinant, matmul_transposed, add_product
 *   estimators/filters/monitor.py     belief_health, track_pins
 *   estimators/filters/smoothers.py   store_belief
 *
 * The records (SRConfig, SRBelief, PilotMonitor, PilotReport, SRScratch with its two
 * KalmanWork records, SROutput: namedtuples of numpy arrays) arrive as one struct of
 * pointers to their C-contiguous data plus the sizes the kernels read from the arrays'
 * shapes; Python fills it (_schiess_roland_native.py), checking every shape.
 *
 * Python's semantics kept where C differs: max(a, b, ...) folds "v if v > acc else acc"
 * and min(a, b) "b if b < a else a" (numba's lowering of the builtins, NaN-faithful);
 * int(x) truncates; an int operand of a float operation is converted to double first
 * (rho * step * h is (rho * (double)step) * h); x**3 with a literal exponent is
 * x * (x * x) (numba unrolls it by squaring); booleans are numpy's one-byte 0/1; every
 * integer % here has non-negative operands, where C's and Python's agree.
 */

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include "_native_common.h" /* the helpers the ports share (linalg, monitor, smoothers) */

/* ---- _schiess_roland_core.py: the state layout (eqs. 6 and 14) */
enum { N_DYNAMIC = 6, N_PARAMETERS = 7, N_STATES = 13 };
enum { I_C = 0, I_C_RATE = 1, I_U = 2, I_Y4 = 3, I_ETA = 4, I_ETA_RATE = 5 };
enum { I_K1 = 6, I_TAU1 = 7, I_TAU2 = 8, I_TAU3 = 9, I_THETA = 10, I_ALPHA1 = 11,
       I_ALPHA2 = 12 };
/* indices into cfg */
enum {
    CFG_DT = 0,
    CFG_PLANT_GAIN = 1,
    CFG_PROCESS_NOISE = 2,
    CFG_JITTER = 3,
    CFG_MAX_COV = 4,
    CFG_BICUBIC = 5,
    CFG_RAMP = 6,
    CFG_ADAPTIVE = 7,
    CFG_MAX_DELAY = 8,
    CFG_NOISE_FORM = 9,
    CFG_SIZE = 10
};
enum { ADAPTIVE_OFF = 0, ADAPTIVE_FULL = 1, ADAPTIVE_MODIFIED = 2 };
/* columns of the Taylor recursion */
enum { COL_Z = 0, COL_PHI = 1, COL_PARAM = 7, COL_E0 = 13, COL_RHO = 14, COL_W = 15,
       N_COLUMNS = 16 };
/* _pilot_core.py: indices into sc (SC_*) */
enum { SC_K = 0, SC_FROZEN = 11, SC_DIV_INDEX = 12, SC_DIV_REASON = 13, SC_DIV_PARAM = 14,
       SC_SIZE = 15 };
/* filters/monitor.py: divergence codes */
enum { REASON_NONE = 0, REASON_NONFINITE = 1, REASON_COVARIANCE = 2, REASON_PINNED = 3,
       REASON_BEYOND_SAMPLE_RATE = 4 };

static const double SERIES_REACH = 4.0;     /* _SERIES_REACH */
static const double SERIES_TOLERANCE = 1e-17; /* _SERIES_TOLERANCE */
#define SERIES_TERMS 60                     /* _SERIES_TERMS */
#define FLOW_SPLIT_CAP ((int64_t)1 << 10)   /* _FLOW_SPLIT_CAP */
static const double NEGATIVE_TOLERANCE = 1e-10; /* monitor.NEGATIVE_TOLERANCE */
/* _PARAM_STATE: the state of each parameter column (theta has none) */
static const int64_t PARAM_STATE[6] = {I_K1, I_TAU1, I_TAU2, I_TAU3, I_ALPHA1, I_ALPHA2};

#define SR_ABI 1

/* Every record of sr_step. Field order must match _schiess_roland_native.py. */
typedef struct {
    /* sizes */
    int64_t size;       /* history length: belief.hist_d.shape[0] (= hist_c's, hist_rate's) */
    int64_t window;     /* belief.q_window.shape[0] */
    int64_t n_pin;      /* monitor.pin_ring.shape[1] */
    int64_t n_flag;     /* out.flag.shape[1] */
    int64_t n_state_cols; /* out.states.shape[1] */
    int64_t store_rows; /* out.x_prior.shape[0] = out.Phi.shape[0]: smoother rows (0: none) */
    /* SRConfig */
    const double *cfg, *gamma;
    const int64_t *state_limit;
    const uint8_t *estimated;
    const double *R;
    /* SRBelief */
    double *x, *P, *sc, *hist_d, *hist_c, *hist_rate, *q_window, *q_sum, *prev_d, *in_d;
    /* PilotMonitor (buf_u, buf_e unused) */
    int64_t *pins, *pin_ring;
    double *last_mean, *last_std;
    uint8_t *pinned_now;
    /* PilotReport */
    const double *lo, *hi, *offset, *sign;
    /* SRScratch */
    double *terms, *next_terms, *sums, *Z, *J, *Jrho, *Gw, *z, *v, *T1, *U;
    double *H2, *r2, *H1, *R1, *r1;
    KalmanWork work2, work1;
    double *p, *variance, *scalars;
    /* SROutput */
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *predictions, *innovations, *S, *states;
    double *x_prior, *P_prior, *x_post, *P_post, *Phi;
} SrRecords;

/* Python's max(a, b) / min(a, b) on floats as numba lowers them */

/* ===================================================================== linalg.py */

/* ===================================================================== kalman.py */

/* joseph_correct: the Joseph-form correction with an m-dimensional measurement
 * (S = H P H^T + R, K = P H^T S^-1 by a Cholesky solve; the fused scalar form for m = 1).
 * H (m, n), R (m, m), r (m,). Returns 0, x and P as they were, where S is not PD. */
static int joseph_correct(double *x, double *P, const double *r, const double *H,
                          const double *R, const KalmanWork *work, int64_t n, int64_t m,
                          double jitter)
{
    if (m == 1)
        return joseph_scalar(x, P, r, H, R, work, n, jitter);
    double *PHt = work->PHt, *S = work->S, *L = work->L, *K = work->K, *M = work->M;
    /* _innovation_covariance: PHt = P H^T, S = H P H^T + R */
    matmul_transposed(P, H, PHt, n, m, n);
    for (int64_t a = 0; a < m; a++)
        for (int64_t b = 0; b < m; b++) {
            double acc = R[a * m + b];
            for (int64_t i = 0; i < n; i++)
                acc += H[a * n + i] * PHt[i * m + b];
            S[a * m + b] = acc;
        }
    for (int64_t a = 0; a < m; a++)
        for (int64_t b = a + 1; b < m; b++) {
            double v = 0.5 * (S[a * m + b] + S[b * m + a]);
            S[a * m + b] = v;
            S[b * m + a] = v;
        }
    if (!cholesky(S, L, m))
        return 0;
    cholesky_solve_rows(L, m, PHt, K, n);
    if (work->n_log_det > 0)
        work->log_det[0] = log_determinant(L, m);
    /* add_product: x += K r */
    for (int64_t i = 0; i < n; i++) {
        double acc = 0.0;
        for (int64_t a = 0; a < m; a++)
            acc += K[i * m + a] * r[a];
        x[i] += acc;
    }
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            for (int64_t a = 0; a < m; a++)
                acc += K[i * m + a] * PHt[j * m + a];
            P[i * n + j] -= acc;
        }
    matmul_transposed(P, H, M, n, m, n);
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            for (int64_t a = 0; a < m; a++)
                acc -= M[i * m + a] * K[j * m + a];
            for (int64_t a = 0; a < m; a++)
                for (int64_t b = 0; b < m; b++)
                    acc += K[i * m + a] * R[a * m + b] * K[j * m + b];
            P[i * n + j] += acc;
        }
    symmetrise(P, n);
    if (jitter > 0.0)
        for (int64_t i = 0; i < n; i++)
            P[i * n + i] += jitter;
    return 1;
}

/* clamp: estimate projection onto box limits */
static void clamp(double *x, const int64_t *index, int64_t n, const double *lo,
                  const double *hi)
{
    for (int64_t i = 0; i < n; i++) {
        int64_t j = index[i];
        if (j < 0)
            continue;
        if (x[i] < lo[j])
            x[i] = lo[j];
        else if (x[i] > hi[j])
            x[i] = hi[j];
    }
}

/* ==================================================================== monitor.py */

/* belief_health: (finite, covariance ok) of a belief; zero_ok is True here */
static void belief_health(const double *x, const double *P, int64_t n, double max_cov,
                          int *finite_out, int *ok_out)
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
        int below = v < -NEGATIVE_TOLERANCE * largest;
        if (below || v > max_cov)
            ok = 0;
    }
    *finite_out = finite;
    *ok_out = ok;
}

/* ================================================================ _pilot_core.py */

/* report_frozen: a stopped filter's row (last estimate, NaN predictions, diverged) */
static void report_frozen(const SrRecords *rec, int dropped, int64_t row)
{
    int64_t n_p = N_PARAMETERS, nf = rec->n_flag;
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
    rec->prev_d[0] = rec->in_d[0];
    rec->sc[SC_K] = rec->sc[SC_K] + 1.0;
}

/* report_row: report one sample (means through the report transform, standard
 * deviations, pins) and record divergence */
static void report_row(const SrRecords *rec, int finite, int cov_ok, int dropped,
                       int64_t row)
{
    double *sc = rec->sc;
    const double *p = rec->p, *variance = rec->variance, *scalars = rec->scalars;
    int64_t k = (int64_t)sc[SC_K];
    int64_t n_p = N_PARAMETERS, nf = rec->n_flag;
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

/* ===================================================== _schiess_roland_core.py model */

/* _apply_a: out = A(p) v for the dynamic states (eqs. 7-12), p read from x */
static void apply_a(const double *x, double K, const double *v, double *out)
{
    double tau1 = x[I_TAU1];
    double tau2 = x[I_TAU2];
    out[0] = v[1];
    out[1] = K * (v[2] + v[4]);
    out[2] = (v[3] - v[2]) / tau2;
    out[3] = -v[3] / tau1;
    out[4] = v[5];
    out[5] = -x[I_ALPHA2] * v[4] - x[I_ALPHA1] * v[5];
}

/* input_gains: (b_u, b_y4), the coefficients of the delayed error in eqs. 9 and 10 */
static void input_gains(const double *x, double *b_u, double *b_y4)
{
    double k1 = x[I_K1], tau1 = x[I_TAU1], tau2 = x[I_TAU2], tau3 = x[I_TAU3];
    *b_u = k1 * tau3 / (tau1 * tau2);
    *b_y4 = k1 / tau1 * (1.0 - tau3 / tau1);
}

/* _input_gain_derivatives: d(b_u, b_y4)/dp for column (K_1, tau_1, tau_2, tau_3) */
static void input_gain_derivatives(const double *x, int64_t column, double *db_u,
                                   double *db_y4)
{
    double k1 = x[I_K1], tau1 = x[I_TAU1], tau2 = x[I_TAU2], tau3 = x[I_TAU3];
    if (column == 0) {
        *db_u = tau3 / (tau1 * tau2);
        *db_y4 = (1.0 - tau3 / tau1) / tau1;
    } else if (column == 1) {
        *db_u = -k1 * tau3 / (tau1 * tau1 * tau2);
        /* tau1**3: numba unrolls the literal power by squaring, tau1 * (tau1 * tau1) */
        *db_y4 = -k1 / (tau1 * tau1) + 2.0 * k1 * tau3 / (tau1 * (tau1 * tau1));
    } else if (column == 2) {
        *db_u = -k1 * tau3 / (tau1 * tau2 * tau2);
        *db_y4 = 0.0;
    } else if (column == 3) {
        *db_u = k1 / (tau1 * tau2);
        *db_y4 = -k1 / (tau1 * tau1);
    } else {
        *db_u = 0.0;
        *db_y4 = 0.0;
    }
}

/* _add_a_derivative: out += h (dA/dp) v for column (tau_1, tau_2, alpha_1, alpha_2) */
static void add_a_derivative(const double *x, int64_t column, const double *v, double *out,
                             double h)
{
    if (column == 1) {
        double tau1 = x[I_TAU1];
        out[3] += h * v[3] / (tau1 * tau1);
    } else if (column == 2) {
        double tau2 = x[I_TAU2];
        out[2] += h * (v[2] - v[3]) / (tau2 * tau2);
    } else if (column == 4) {
        out[5] -= h * v[5];
    } else if (column == 5) {
        out[5] -= h * v[4];
    }
}

/* _series_norm: ||A dt|| (infinity norm) for the Taylor series' reach */
static double series_norm(const double *x, double K, double dt)
{
    double tau1 = fabs(x[I_TAU1]);
    double tau2 = fabs(x[I_TAU2]);
    double rows = 1.0;
    rows = py_max(rows, 2.0 * fabs(K));
    rows = py_max(rows, 2.0 / tau2);
    rows = py_max(rows, 1.0 / tau1);
    rows = py_max(rows, fabs(x[I_ALPHA1]) + fabs(x[I_ALPHA2]));
    return rows * dt;
}

/* _substep: Taylor series of the exact flow over h from z with input xi + rho t; sums
 * (N_COLUMNS, N_DYNAMIC) gets, per column, the new state, e^(A h), the sensitivities */
static void substep(const SrRecords *rec, const double *x, const double *z, double xi,
                    double rho, double h, double K)
{
    double *terms = rec->terms, *nxt = rec->next_terms, *sums = rec->sums;
    double b_u, b_y4;
    input_gains(x, &b_u, &b_y4);
    for (int64_t c = 0; c < N_COLUMNS; c++)
        for (int64_t i = 0; i < N_DYNAMIC; i++) {
            terms[c * N_DYNAMIC + i] = 0.0;
            sums[c * N_DYNAMIC + i] = 0.0;
        }
    for (int64_t i = 0; i < N_DYNAMIC; i++) {
        terms[COL_Z * N_DYNAMIC + i] = z[i];
        terms[(COL_PHI + i) * N_DYNAMIC + i] = 1.0;
    }
    for (int64_t c = 0; c < N_COLUMNS; c++)
        for (int64_t i = 0; i < N_DYNAMIC; i++)
            sums[c * N_DYNAMIC + i] = terms[c * N_DYNAMIC + i];
    double xi_prev = xi;
    double dxi_e0 = 1.0;
    double dxi_rho = 0.0;
    double scale = 1.0;
    for (int64_t i = 0; i < N_DYNAMIC; i++)
        scale = py_max(scale, fabs(z[i]));
    for (int64_t k = 1; k < SERIES_TERMS + 1; k++) {
        double hk = h / (double)k;
        double biggest = 0.0;
        /* the columns of c and c' in e^(A h) are finished after two terms */
        int64_t first = k < 3 ? 0 : 1;
        for (int64_t c = 0; c < N_COLUMNS; c++) {
            if (first == 1 && (c == COL_PHI + I_C || c == COL_PHI + I_C_RATE))
                continue;
            apply_a(x, K, terms + c * N_DYNAMIC, nxt + c * N_DYNAMIC);
            for (int64_t i = 0; i < N_DYNAMIC; i++)
                nxt[c * N_DYNAMIC + i] *= hk;
        }
        nxt[COL_Z * N_DYNAMIC + 2] += hk * b_u * xi_prev;
        nxt[COL_Z * N_DYNAMIC + 3] += hk * b_y4 * xi_prev;
        for (int64_t j = 0; j < 6; j++) {
            int64_t c = COL_PARAM + j;
            if (j < 4) {
                double db_u, db_y4;
                input_gain_derivatives(x, j, &db_u, &db_y4);
                nxt[c * N_DYNAMIC + 2] += hk * db_u * xi_prev;
                nxt[c * N_DYNAMIC + 3] += hk * db_y4 * xi_prev;
            }
            if (j > 0)
                add_a_derivative(x, j, terms + COL_Z * N_DYNAMIC, nxt + c * N_DYNAMIC, hk);
        }
        nxt[COL_E0 * N_DYNAMIC + 2] += hk * b_u * dxi_e0;
        nxt[COL_E0 * N_DYNAMIC + 3] += hk * b_y4 * dxi_e0;
        nxt[COL_RHO * N_DYNAMIC + 2] += hk * b_u * dxi_rho;
        nxt[COL_RHO * N_DYNAMIC + 3] += hk * b_y4 * dxi_rho;
        if (k == 1)
            nxt[COL_W * N_DYNAMIC + 5] += hk;
        for (int64_t c = 0; c < N_COLUMNS; c++) {
            if (first == 1 && (c == COL_PHI + I_C || c == COL_PHI + I_C_RATE))
                continue;
            for (int64_t i = 0; i < N_DYNAMIC; i++) {
                double v = nxt[c * N_DYNAMIC + i];
                terms[c * N_DYNAMIC + i] = v;
                sums[c * N_DYNAMIC + i] += v;
                if (fabs(v) > biggest)
                    biggest = fabs(v);
            }
        }
        if (k == 1) {
            xi_prev = h * rho;
            dxi_e0 = 0.0;
            dxi_rho = h;
        } else {
            xi_prev = 0.0;
            dxi_rho = 0.0;
        }
        if ((double)k > SERIES_REACH && biggest <= SERIES_TOLERANCE * scale)
            break;
    }
}

/* flow: exact flow of eqs. 7-12 over dt with delayed input e0 + rho t; the new dynamic
 * states into x[:6], e^(A dt) into Z, the sensitivities into J and Jrho, G_w into Gw;
 * returns the substeps, or -1 (nothing written) past FLOW_SPLIT_CAP */
static int64_t flow(const SrRecords *rec, double *x, double e0, double rho, double dt,
                    double K)
{
    int64_t n_sub = 1;
    while (series_norm(x, K, dt) / (double)n_sub > SERIES_REACH) {
        if (n_sub >= FLOW_SPLIT_CAP)
            return -1;
        n_sub *= 2;
    }
    double h = dt / (double)n_sub;
    double *Z = rec->Z, *J = rec->J, *Jrho = rec->Jrho, *Gw = rec->Gw, *sums = rec->sums;
    double *z = rec->z, *U = rec->U, *T1 = rec->T1, *v = rec->v;
    const int64_t theta = I_THETA - N_DYNAMIC;
#define SUMS(c, i) sums[(c) * N_DYNAMIC + (i)]
    for (int64_t i = 0; i < N_DYNAMIC; i++)
        z[i] = x[i];
    for (int64_t step = 0; step < n_sub; step++) {
        substep(rec, x, z, e0 + rho * (double)step * h, rho, h, K);
        if (step == 0) {
            for (int64_t i = 0; i < N_DYNAMIC; i++) {
                for (int64_t j = 0; j < N_DYNAMIC; j++)
                    Z[i * N_DYNAMIC + j] = SUMS(COL_PHI + j, i);
                for (int64_t j = 0; j < 6; j++)
                    J[i * N_PARAMETERS + PARAM_STATE[j] - N_DYNAMIC] = SUMS(COL_PARAM + j, i);
                J[i * N_PARAMETERS + theta] = SUMS(COL_E0, i);
                Jrho[i] = SUMS(COL_RHO, i);
                Gw[i] = SUMS(COL_W, i);
            }
        } else {
            for (int64_t i = 0; i < N_DYNAMIC; i++) {
                for (int64_t j = 0; j < N_DYNAMIC; j++) {
                    double acc = 0.0;
                    for (int64_t m = 0; m < N_DYNAMIC; m++)
                        acc += SUMS(COL_PHI + m, i) * Z[m * N_DYNAMIC + j];
                    U[i * N_DYNAMIC + j] = acc;
                }
                for (int64_t j = 0; j < N_PARAMETERS; j++) {
                    double acc = 0.0;
                    for (int64_t m = 0; m < N_DYNAMIC; m++)
                        acc += SUMS(COL_PHI + m, i) * J[m * N_PARAMETERS + j];
                    T1[i * N_PARAMETERS + j] = acc;
                }
                double a_rho = 0.0;
                double a_w = 0.0;
                for (int64_t m = 0; m < N_DYNAMIC; m++) {
                    a_rho += SUMS(COL_PHI + m, i) * Jrho[m];
                    a_w += SUMS(COL_PHI + m, i) * Gw[m];
                }
                v[i] = a_rho + SUMS(COL_E0, i) * (double)step * h + SUMS(COL_RHO, i);
                v[N_DYNAMIC + i] = a_w + SUMS(COL_W, i);
            }
            for (int64_t i = 0; i < N_DYNAMIC; i++) {
                Jrho[i] = v[i];
                Gw[i] = v[N_DYNAMIC + i];
                for (int64_t j = 0; j < N_DYNAMIC; j++)
                    Z[i * N_DYNAMIC + j] = U[i * N_DYNAMIC + j];
                for (int64_t j = 0; j < N_PARAMETERS; j++)
                    J[i * N_PARAMETERS + j] = T1[i * N_PARAMETERS + j];
                for (int64_t j = 0; j < 6; j++)
                    J[i * N_PARAMETERS + PARAM_STATE[j] - N_DYNAMIC] += SUMS(COL_PARAM + j, i);
                J[i * N_PARAMETERS + theta] += SUMS(COL_E0, i);
            }
        }
        for (int64_t i = 0; i < N_DYNAMIC; i++)
            z[i] = SUMS(COL_Z, i);
    }
#undef SUMS
    for (int64_t i = 0; i < N_DYNAMIC; i++)
        x[i] = z[i];
    return n_sub;
}

/* predict_covariance_structured: P <- Phi P Phi^T for Phi = [[Z, J], [0, I]] */
static void predict_covariance_structured(const SrRecords *rec, double *P)
{
    const int64_t n_z = N_DYNAMIC, n_p = N_PARAMETERS, n = N_STATES;
    const double *Z = rec->Z, *J = rec->J;
    double *T1 = rec->T1, *U = rec->U;
    for (int64_t i = 0; i < n_z; i++) {
        for (int64_t j = 0; j < n_p; j++) {
            double acc = 0.0;
            for (int64_t m = 0; m < n_z; m++)
                acc += Z[i * n_z + m] * P[m * n + n_z + j];
            for (int64_t m = 0; m < n_p; m++)
                acc += J[i * n_p + m] * P[(n_z + m) * n + n_z + j];
            T1[i * n_p + j] = acc;
        }
        for (int64_t j = 0; j < n_z; j++) {
            double acc = 0.0;
            for (int64_t m = 0; m < n_z; m++)
                acc += Z[i * n_z + m] * P[m * n + j];
            for (int64_t m = 0; m < n_p; m++)
                acc += J[i * n_p + m] * P[(n_z + m) * n + j];
            U[i * n_z + j] = acc;
        }
    }
    for (int64_t i = 0; i < n_z; i++) {
        for (int64_t j = i; j < n_z; j++) {
            double acc = 0.0;
            for (int64_t m = 0; m < n_z; m++)
                acc += U[i * n_z + m] * Z[j * n_z + m];
            for (int64_t m = 0; m < n_p; m++)
                acc += T1[i * n_p + m] * J[j * n_p + m];
            P[i * n + j] = acc;
            P[j * n + i] = acc;
        }
        for (int64_t j = 0; j < n_p; j++) {
            P[i * n + n_z + j] = T1[i * n_p + j];
            P[(n_z + j) * n + i] = T1[i * n_p + j];
        }
    }
}

/* ================================================= _schiess_roland_core.py history */

/* _ring: sample j of a ring whose newest sample is `newest` (clamped to what it holds) */
static double ring_at(const double *hist, int64_t size, int64_t j, int64_t newest)
{
    int64_t oldest = newest - size + 1;
    if (oldest < 0)
        oldest = 0;
    if (j > newest)
        j = newest;
    if (j < oldest)
        j = oldest;
    return hist[j % size];
}

/* _error_at: delayed error e_j = D_j - c_j and its rate dD/dt - c' at sample j */
static void error_at(const SrRecords *rec, int64_t j, int64_t newest_c, int64_t newest_d,
                     double dt, double *value, double *rate)
{
    const int64_t size = rec->size;
    if (j > newest_c)
        j = newest_c;
    if (j < 0)
        j = 0;
    double d_j = ring_at(rec->hist_d, size, j, newest_d);
    double c_j = ring_at(rec->hist_c, size, j, newest_c);
    double rate_c = ring_at(rec->hist_rate, size, j, newest_c);
    int64_t lo = j >= 1 ? j - 1 : j;
    int64_t hi = j + 1 <= newest_d ? j + 1 : j;
    double rate_d;
    if (hi > lo)
        rate_d = (ring_at(rec->hist_d, size, hi, newest_d)
                  - ring_at(rec->hist_d, size, lo, newest_d))
                 / ((double)(hi - lo) * dt);
    else
        rate_d = 0.0;
    *value = d_j - c_j;
    *rate = rate_d - rate_c;
}

/* delayed_error: (e, de/dt) at fractional sample `position` (eq. 17's delayed error):
 * the sample round(position), or the bicubic interpolation */
static void delayed_error(const SrRecords *rec, double position, int64_t newest_c,
                          int64_t newest_d, double dt, int bicubic, double *value,
                          double *rate)
{
    if (!bicubic) {
        int64_t j = (int64_t)floor(position + 0.5);
        error_at(rec, j, newest_c, newest_d, dt, value, rate);
        return;
    }
    int64_t n = (int64_t)floor(position);
    double d = position - (double)n;
    double e_a, e_b, e_c, e_d, unused;
    error_at(rec, n - 1, newest_c, newest_d, dt, &e_a, &unused);
    error_at(rec, n, newest_c, newest_d, dt, &e_b, &unused);
    error_at(rec, n + 1, newest_c, newest_d, dt, &e_c, &unused);
    error_at(rec, n + 2, newest_c, newest_d, dt, &e_d, &unused);
    double w[4];
    bicubic_weights(d, w);
    *value = w[0] * e_a + w[1] * e_b + w[2] * e_c + w[3] * e_d;
    bicubic_derivative_weights(d, w);
    *rate = (w[0] * e_a + w[1] * e_b + w[2] * e_c + w[3] * e_d) / dt;
}

/* ============================================ _schiess_roland_core.py adaptive noise */

/* adaptive_variance: Jazwinski's fictitious noise variance from one residual (A3-A6) */
static double adaptive_variance(const double *P, const double *gamma,
                                const double *innovations, const int *available,
                                const double *R, int64_t mode)
{
    const int64_t n = N_STATES;
    double residual = 0.0;
    int64_t count = 0;
    double spread = 0.0;
    double gain = 0.0;
    for (int64_t j = 0; j < 2; j++) {
        if (!available[j] || (mode == ADAPTIVE_MODIFIED && j == 0))
            continue;
        count += 1;
    }
    if (count == 0)
        return 0.0;
    for (int64_t j = 0; j < 2; j++) {
        if (!available[j] || (mode == ADAPTIVE_MODIFIED && j == 0))
            continue;
        double sj = sqrt(R[j * 2 + j]);
        residual += innovations[j] / sj;
        gain += (j == 0 ? gamma[I_U] + gamma[I_ETA] : gamma[I_C]) / sj;
        for (int64_t i = 0; i < 2; i++) {
            if (!available[i] || (mode == ADAPTIVE_MODIFIED && i == 0))
                continue;
            double si = sqrt(R[i * 2 + i]);
            double hph;
            if (j == 0 && i == 0)
                hph = P[I_U * n + I_U] + 2.0 * P[I_U * n + I_ETA] + P[I_ETA * n + I_ETA];
            else if (j == 1 && i == 1)
                hph = P[I_C * n + I_C];
            else
                hph = P[I_C * n + I_U] + P[I_C * n + I_ETA];
            spread += hph / (sj * si);
        }
    }
    double nf = (double)count;
    residual /= nf;
    double expected = 1.0 / nf + spread / (nf * nf); /* A5 */
    double d = gain * gain / (nf * nf);             /* A6 */
    if (d <= 0.0)
        return 0.0;
    double value = (residual * residual - expected) / d; /* A3 */
    return value > 0.0 ? value : 0.0;
}

/* _store_phi: the transition Jacobian of row `row` (identity where not predicted) */
static void store_phi(const SrRecords *rec, int64_t row, int predicted)
{
    double *Phi = rec->Phi;
    const int64_t n = N_STATES;
    if (rec->store_rows == 0)
        return;
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++)
            Phi[(row * n + i) * n + j] = i == j ? 1.0 : 0.0;
    if (!predicted)
        return;
    for (int64_t i = 0; i < N_DYNAMIC; i++) {
        for (int64_t j = 0; j < N_DYNAMIC; j++)
            Phi[(row * n + i) * n + j] = rec->Z[i * N_DYNAMIC + j];
        for (int64_t j = 0; j < N_PARAMETERS; j++)
            Phi[(row * n + i) * n + N_DYNAMIC + j] = rec->J[i * N_PARAMETERS + j];
    }
}

/* ====================================================== _schiess_roland_core.py step */

/* _stopped_row: a stopped filter's row (its belief as it stands, no prediction, its
 * last states) */
static void stopped_row(const SrRecords *rec, int dropped, int64_t row)
{
    const double *x = rec->x, *P = rec->P;
    const int64_t n = N_STATES, rows = rec->store_rows;
    store_belief(rows, row, x, P, n, rec->x_prior, rec->P_prior);
    store_belief(rows, row, x, P, n, rec->x_post, rec->P_post);
    store_phi(rec, row, 0);
    for (int64_t i = 0; i < 2; i++) {
        rec->predictions[row * 2 + i] = NAN;
        rec->innovations[row * 2 + i] = NAN;
        for (int64_t j = 0; j < 2; j++)
            rec->S[(row * 2 + i) * 2 + j] = NAN;
    }
    if (row > 0) /* a stopped filter repeats its last states */
        for (int64_t i = 0; i < rec->n_state_cols; i++)
            rec->states[row * rec->n_state_cols + i] =
                rec->states[(row - 1) * rec->n_state_cols + i];
    report_frozen(rec, dropped, row);
}

/* sr_step: advance the belief by one sample (forcing d_k, stick u_k, plant output y_k;
 * NaN: missing); its estimate into output row `row` */
void sr_step(const SrRecords *rec, double d_k, double u_k, double y_k, int64_t row)
{
    const double *cfg = rec->cfg;
    double *x = rec->x, *P = rec->P, *sc = rec->sc;
    const int64_t n = N_STATES, rows = rec->store_rows, size = rec->size;
    const double *R = rec->R;
    double dt = cfg[CFG_DT];
    double K = cfg[CFG_PLANT_GAIN];
    int64_t k = (int64_t)sc[SC_K];
    /* the forcing in use: a missing one holds its last value and drops the sample */
    int dropped_input = isnan(d_k);
    rec->in_d[0] = dropped_input ? rec->prev_d[0] : d_k;
    rec->hist_d[k % size] = rec->in_d[0];
    int available[2] = {!isnan(u_k) && !dropped_input, !isnan(y_k) && !dropped_input};
    int dropped = !(available[0] || available[1]);

    if (sc[SC_FROZEN] > 0.0) {
        stopped_row(rec, dropped, row);
        return;
    }

    int predicted = k > 0;
    if (predicted) {
        /* delayed error from the history (eq. 17): c up to k - 1, D up to k */
        double theta = x[I_THETA];
        double max_delay = cfg[CFG_MAX_DELAY];
        double theta_read = py_min(py_max(theta, 0.0), max_delay);
        int bicubic = cfg[CFG_BICUBIC] > 0.0;
        double position = (double)(k - 1) - theta_read / dt;
        double e0, rate0, e1, rate1 = 0.0, rho = 0.0;
        delayed_error(rec, position, k - 1, k, dt, bicubic, &e0, &rate0);
        if (cfg[CFG_RAMP] > 0.0) {
            delayed_error(rec, position + 1.0, k - 1, k, dt, bicubic, &e1, &rate1);
            rho = (e1 - e0) / dt;
        }
        /* prediction, eqs. 18-19, exact over the step */
        if (flow(rec, x, e0, rho, dt, K) < 0) { /* beyond the split's cap: nothing predicted */
            sc[SC_FROZEN] = 1.0;
            if (sc[SC_DIV_REASON] == REASON_NONE || sc[SC_DIV_REASON] == REASON_PINNED) {
                sc[SC_DIV_REASON] = REASON_BEYOND_SAMPLE_RATE;
                sc[SC_DIV_INDEX] = (double)k;
                sc[SC_DIV_PARAM] = -1.0;
            }
            stopped_row(rec, dropped, row);
            return;
        }
        /* theta acts through the delayed input: d e_d / d theta = -de/dt(t - theta) */
        double *J = rec->J;
        const int64_t theta_col = I_THETA - N_DYNAMIC;
        for (int64_t i = 0; i < N_DYNAMIC; i++) {
            double sens_e0 = J[i * N_PARAMETERS + theta_col];
            if (cfg[CFG_RAMP] > 0.0)
                J[i * N_PARAMETERS + theta_col] =
                    -sens_e0 * rate0 - rec->Jrho[i] * (rate1 - rate0) / dt;
            else
                J[i * N_PARAMETERS + theta_col] = -sens_e0 * rate0;
        }
        predict_covariance_structured(rec, P);
        double q = cfg[CFG_PROCESS_NOISE];
        if (cfg[CFG_NOISE_FORM] > 0.0) {
            P[I_ETA_RATE * n + I_ETA_RATE] += q;
        } else {
            for (int64_t i = 0; i < N_DYNAMIC; i++)
                for (int64_t j = 0; j < N_DYNAMIC; j++)
                    P[i * n + j] += q * rec->Gw[i] * rec->Gw[j];
        }
        symmetrise(P, n);
    }

    /* measurement prediction (eq. 16): stick u + eta, plant output c */
    double prediction_u = x[I_U] + x[I_ETA];
    double prediction_y = x[I_C];
    double innovation_u = available[0] ? u_k - prediction_u : NAN;
    double innovation_y = available[1] ? y_k - prediction_y : NAN;

    /* adaptive fictitious noise (eqs. A1-A6), averaged over the window */
    int64_t mode = (int64_t)cfg[CFG_ADAPTIVE];
    double q_bar = 0.0;
    if (mode != ADAPTIVE_OFF) {
        rec->r2[0] = innovation_u;
        rec->r2[1] = innovation_y;
        double *window = rec->q_window, *q_sum = rec->q_sum;
        const int64_t W = rec->window;
        if (!dropped) {
            double value = adaptive_variance(P, rec->gamma, rec->r2, available, R, mode);
            int64_t slot = (int64_t)q_sum[2] % W;
            if (q_sum[1] >= (double)W)
                q_sum[0] -= window[slot];
            else
                q_sum[1] += 1.0;
            window[slot] = value;
            q_sum[0] += value;
            q_sum[2] += 1.0;
            if (slot == W - 1) { /* recompute exactly at every wrap */
                double total = 0.0;
                for (int64_t i = 0; i < W; i++)
                    total += window[i];
                q_sum[0] = total;
            }
        }
        if (q_sum[1] > 0.0)
            q_bar = py_max(q_sum[0] / q_sum[1], 0.0);
        if (q_bar > 0.0) {
            const double *gamma = rec->gamma;
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j < n; j++)
                    P[i * n + j] += q_bar * gamma[i] * gamma[j]; /* A2 */
        }
    }
    store_belief(rows, row, x, P, n, rec->x_prior, rec->P_prior);
    store_phi(rec, row, predicted);

    /* innovation covariance of both outputs (reported also for a partial correction) */
    double S_uu = P[I_U * n + I_U] + 2.0 * P[I_U * n + I_ETA] + P[I_ETA * n + I_ETA] + R[0];
    double S_yy = P[I_C * n + I_C] + R[3];
    double S_uy = P[I_C * n + I_U] + P[I_C * n + I_ETA] + R[1];

    /* correction, eqs. 20-22 (Joseph form; eq. 20's "-R" read "+R") */
    int correct_ok = 1;
    if (available[0] && available[1]) {
        rec->r2[0] = innovation_u;
        rec->r2[1] = innovation_y;
        double *H2 = rec->H2;
        for (int64_t i = 0; i < n; i++) {
            H2[i] = 0.0;
            H2[n + i] = 0.0;
        }
        H2[I_U] = 1.0;
        H2[I_ETA] = 1.0;
        H2[n + I_C] = 1.0;
        correct_ok = joseph_correct(x, P, rec->r2, H2, R, &rec->work2, n, 2, cfg[CFG_JITTER]);
    } else if (available[0] || available[1]) {
        double *H1 = rec->H1;
        for (int64_t i = 0; i < n; i++)
            H1[i] = 0.0;
        if (available[0]) {
            H1[I_U] = 1.0;
            H1[I_ETA] = 1.0;
            rec->r1[0] = innovation_u;
            rec->R1[0] = R[0];
        } else {
            H1[I_C] = 1.0;
            rec->r1[0] = innovation_y;
            rec->R1[0] = R[3];
        }
        correct_ok = joseph_correct(x, P, rec->r1, H1, rec->R1, &rec->work1, n, 1,
                                    cfg[CFG_JITTER]);
    }
    clamp(x, rec->state_limit, n, rec->lo, rec->hi);
    store_belief(rows, row, x, P, n, rec->x_post, rec->P_post);

    /* history for the delayed terms: the filtered c and c' of this sample */
    rec->hist_c[k % size] = x[I_C];
    rec->hist_rate[k % size] = x[I_C_RATE];
    rec->prev_d[0] = rec->in_d[0];

    /* health and report */
    int finite, cov_ok;
    belief_health(x, P, n, cfg[CFG_MAX_COV], &finite, &cov_ok);
    if (!correct_ok) {
        if (isfinite(S_uu) && isfinite(S_yy))
            cov_ok = 0;
        else
            finite = 0;
    }
    double *p = rec->p, *variance = rec->variance;
    for (int64_t j = 0; j < N_PARAMETERS; j++) {
        p[j] = x[N_DYNAMIC + j];
        variance[j] = P[(N_DYNAMIC + j) * n + N_DYNAMIC + j];
    }
    rec->scalars[0] = prediction_u;
    rec->scalars[1] = innovation_u;
    rec->scalars[2] = S_uu;
    report_row(rec, finite, cov_ok, dropped, row);
    rec->predictions[row * 2 + 0] = finite ? prediction_u : NAN;
    rec->predictions[row * 2 + 1] = finite ? prediction_y : NAN;
    rec->innovations[row * 2 + 0] = finite ? innovation_u : NAN;
    rec->innovations[row * 2 + 1] = finite ? innovation_y : NAN;
    rec->S[row * 4 + 0] = finite ? S_uu : NAN;
    rec->S[row * 4 + 3] = finite ? S_yy : NAN;
    rec->S[row * 4 + 1] = finite ? S_uy : NAN;
    rec->S[row * 4 + 2] = finite ? S_uy : NAN;
    const int64_t cols = rec->n_state_cols;
    if (finite) {
        for (int64_t i = 0; i < N_DYNAMIC; i++)
            rec->states[row * cols + i] = x[i];
        rec->states[row * cols + N_DYNAMIC] = q_bar;
    } else if (row > 0) {
        for (int64_t i = 0; i < cols; i++)
            rec->states[row * cols + i] = rec->states[(row - 1) * cols + i];
    }
}

/* sr_run: sr_step over every sample, sample k into row k */
void sr_run(const SrRecords *rec, const double *d, const double *u, const double *y,
            int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        sr_step(rec, d[k], u[k], y[k], k);
}

/* For the Python side to check the layout and the constants it was built against. */
int64_t sr_abi(void) { return SR_ABI; }
int64_t sr_records_size(void) { return (int64_t)sizeof(SrRecords); }
int64_t sr_constants(double *out)
{
    const double values[] = {
        PIN_FRACTION, NEGATIVE_TOLERANCE, TINY,
        REASON_NONE, REASON_NONFINITE, REASON_COVARIANCE, REASON_PINNED,
        REASON_BEYOND_SAMPLE_RATE,
        SC_K, SC_FROZEN, SC_DIV_INDEX, SC_DIV_REASON, SC_DIV_PARAM, SC_SIZE,
        N_DYNAMIC, N_PARAMETERS, N_STATES,
        I_C, I_C_RATE, I_U, I_Y4, I_ETA, I_ETA_RATE,
        I_K1, I_TAU1, I_TAU2, I_TAU3, I_THETA, I_ALPHA1, I_ALPHA2,
        CFG_DT, CFG_PLANT_GAIN, CFG_PROCESS_NOISE, CFG_JITTER, CFG_MAX_COV, CFG_BICUBIC,
        CFG_RAMP, CFG_ADAPTIVE, CFG_MAX_DELAY, CFG_NOISE_FORM, CFG_SIZE,
        ADAPTIVE_OFF, ADAPTIVE_FULL, ADAPTIVE_MODIFIED,
        COL_Z, COL_PHI, COL_PARAM, COL_E0, COL_RHO, COL_W, N_COLUMNS,
        SERIES_REACH, SERIES_TOLERANCE, SERIES_TERMS, FLOW_SPLIT_CAP,
        PARAM_STATE[0], PARAM_STATE[1], PARAM_STATE[2], PARAM_STATE[3], PARAM_STATE[4],
        PARAM_STATE[5],
    };
    int64_t n = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < n; i++)
            out[i] = values[i];
    return n;
}
