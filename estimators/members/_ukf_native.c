/*
 * _ukf_native.c: the unscented pilot filters' compiled path in C (JointUKF, DualUKF),
 * the numba kernels' numbers bit for bit.
 *
 * The numba kernels (_ukf_core.py and what it calls) are the reference; this port does
 * their arithmetic operation for operation, in the same order, so that the results are
 * the same bytes (numba neither reassociates nor contracts to FMA without fastmath).
 * _native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * tests/estimators/test_ukf_native.py holds the two equal. The helpers shared with the
 * DEKF's port (_dekf_native.c: noise rules, report, monitor, internal model) are copied
 * from it, the records struct aside; evaluate_coefficients takes its parameter vector as
 * an argument, as the Python does (the unscented filters evaluate it at sigma points).
 *
 * Sources ported (manualcontrol/estimators/...):
 *   members/_ukf_core.py       joint_step, joint_step_many, dual_step, dual_step_many,
 *                              _point_parameters,
 *                              _propagate, _measure, _set_point, _predict_sensitivity,
 *                              _output_at, _theta_images, _correct_sensitivity
 *   filters/unscented.py       sigma_points, triangular_sigma_points, _spread_points,
 *                              weighted_mean, weighted_covariance,
 *                              cross_covariance, unscented_correct, project_points,
 *                              constrain_prior (Julier & Uhlmann 1997; Zhao et al. 2019
 *                              Algorithms 1-2; Kandepu, Foss & Imsland 2008)
 *   filters/linalg.py          symmetrise, cholesky, cholesky_semidefinite,
 *                              cholesky_semidefinite_pivoted,
 *                              cholesky_solve_rows, log_determinant, add_product
 *   _pilot_core.py             noise_levels, inputs_in_use, report_frozen, report_row
 *                              (Popovici eqs. 24-25, thesis eqs. 29-30)
 *   filters/monitor.py         belief_health, track_pins, window_push, window_variance
 *   filters/kalman.py          clamp (thesis Part I eqs. 20, 25)
 *   filters/smoothers.py       store_belief
 *   members/internal_model.py  _pade_jet, _chain_polynomial, evaluate_coefficients,
 *                              model_f, model_g (values only: the unscented filters'
 *                              kernel has gradients off and calls without Jacobians)
 *
 * The records (namedtuples of numpy arrays, the dual filter's DualTheta with its own
 * config and work nested) arrive as one struct of pointers to their C-contiguous data
 * plus the sizes the kernels read from the arrays' shapes; Python fills it
 * (_ukf_native.py), with arrays shared between records (the belief's p is the report's)
 * passed as the same pointer.
 *
 * Python's semantics kept where C differs: max(a, b) is "b if b > a else a" (numba's
 * lowering of the builtin, NaN-faithful); int(x) truncates; an int operand of a float
 * operation is converted to double first; "a * b * c" is (a * b) * c; "f() or i == 0"
 * calls f first, always; booleans are numpy's one-byte 0/1; np.sqrt/np.log are libm's
 * sqrt/log.
 */

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include "_native_common.h" /* the helpers the ports share (linalg, monitor, smoothers) */

/* ---- _pilot_core.py: indices into cfg (CFG_*) and sc (SC_*) */
enum {
    CFG_DT = 0,
    CFG_Q2 = 1,
    CFG_R2 = 2,
    CFG_WINDOW = 3,
    CFG_FIRST_WINDOW = 4,
    CFG_FLOOR = 5,
    CFG_JITTER = 6,
    CFG_MAX_COV = 7,
    CFG_DIMENSIONAL = 8,
    CFG_FIXED_R = 9,
    CFG_FIXED_QE = 10,
    CFG_ERROR_STATE = 11,
    CFG_GAMMA2 = 12,
    CFG_R2_PARAMETER = 13,
    CFG_SPREAD = 14,
    CFG_COUNT = 15,
    CFG_SUBSTEPS = 16,
    CFG_SIZE = 17
};
enum {
    SC_K = 0,
    SC_VAR_U0 = 1,
    SC_VAR_E0 = 2,
    SC_U = 3,
    SC_E = 7,
    SC_FROZEN = 11,
    SC_DIV_INDEX = 12,
    SC_DIV_REASON = 13,
    SC_DIV_PARAM = 14,
    SC_SIZE = 15
};
/* filters/monitor.py: divergence codes */
enum { REASON_NONE = 0, REASON_NONFINITE = 1, REASON_COVARIANCE = 2, REASON_PINNED = 3 };

static const double NEGATIVE_TOLERANCE = 1e-10; /* monitor.NEGATIVE_TOLERANCE */

/* _ukf_core.py: relative step of the central differences along the sigma directions */
static const double SENSITIVITY_STEP = 1e-3;
/* linalg.SEMIDEFINITE_TOLERANCE */

#define UKF_ABI 1

/* unscented.UnscentedWork: L (n, n), X and Y (2n + 1, n), Z (2n + 1, m), z (m,), S and
 * LS (m, m), Cxz and K (n, m), xbar (n,), log_det (1,) */
typedef struct {
    double *L, *X, *Y, *Z, *z, *S, *LS, *Cxz, *K, *xbar, *log_det;
} UnscentedWork;

/* _ukf_core.UKFConfig without its estimated (shared: the records' own) */
typedef struct {
    const double *cfg, *wm, *wc, *q;
    const int64_t *slot, *limit;
    int64_t n_param, n_moving;
} UkfConfig;

/* Every record of joint_step / dual_step: ModelKernel, UKFConfig, UKFBelief,
 * PilotMonitor, PilotReport, UKFScratch, DualTheta (dual only) and UKFOutput.
 * Field order must match _ukf_native.py. */
typedef struct {
    /* sizes */
    int64_t n_c;        /* canonical states: scratch.f.shape[0] */
    int64_t n;          /* filter states: belief.z.shape[0] */
    int64_t n_p;        /* model parameters: belief.p.shape[0] (= every table's n_p axis) */
    int64_t n_in;       /* filter inputs: belief.prev_in.shape[0] */
    int64_t n_terms;    /* monomials: model.term_coef.shape[0] */
    int64_t n_chain;    /* chains: model.chain_num.shape[0] */
    int64_t n_branch;   /* branches: model.branch_chain.shape[0] */
    int64_t longest;    /* model.num.shape[1] */
    int64_t pade_cols;  /* model.pade_value.shape[1] = delay order + 1 */
    int64_t window;     /* monitor.buf_u.shape[0] */
    int64_t n_pin;      /* monitor.pin_ring.shape[1] */
    int64_t n_flag;     /* out.flag.shape[1] */
    int64_t store_rows; /* out.x_prior.shape[0] (= every storage array's): 0: none */
    int64_t gradients;  /* model.gradients */
    int64_t dual;       /* 1: dual_step (theta present), 0: joint_step */
    int64_t n_t;        /* dual: parameter-filter states theta.th.shape[0] */
    /* ModelKernel tables */
    const double *term_coef;
    const int64_t *term_var, *term_exp, *term_slot;
    const int64_t *chain_num, *chain_den, *chain_pade, *chain_offset, *chain_size;
    const int64_t *chain_num_length, *chain_den_length, *branch_chain, *branch_input;
    const int64_t *active;
    /* ModelKernel scratch and outputs */
    double *raw, *raw_grad, *num, *num_grad, *den, *den_grad, *pade_value, *pade_slope;
    double *negA, *negA_grad, *C, *C_grad, *d, *d_grad;
    /* UKFConfig */
    UkfConfig config;
    const uint8_t *estimated;
    /* UKFBelief */
    double *z, *P, *prev_in, *p, *sc;
    /* PilotMonitor */
    double *buf_u, *buf_e;
    int64_t *pins, *pin_ring;
    double *last_mean, *last_std;
    uint8_t *pinned_now;
    /* PilotReport */
    const double *lo, *hi, *offset, *sign;
    /* UKFScratch */
    UnscentedWork work;
    double *Q, *zero, *R, *r, *z_prev, *cross, *point_p, *f, *F, *dfdp, *dgdx, *dgdp;
    double *in_use, *variance, *scalars;
    /* DualTheta (dual only) */
    UkfConfig t_config;
    double *th, *Pp;
    UnscentedWork t_work;
    double *t_R, *D, *M, *E, *t_zero, *point_s, *point_x, *t_point_p;
    /* UKFOutput */
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *x_prior, *P_prior, *x_post, *P_post, *out_cross;
    double *x_prior_2, *P_prior_2, *x_post_2, *P_post_2;
} UkfRecords;

/* Python's max(a, b) on floats as numba lowers it: b if b > a else a */

/* ===================================================================== linalg.py */

/* ================================================================= unscented.py */

/* spread_points: x plus and minus spread times each column of L into X, centre last */
static void spread_points(const double *x, double spread, const double *L, double *X,
                          int64_t n)
{
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            double d = spread * L[j * n + i];
            X[i * n + j] = x[j] + d;
            X[(n + i) * n + j] = x[j] - d;
        }
    for (int64_t j = 0; j < n; j++)
        X[2 * n * n + j] = x[j];
}

/* sigma_points: the points of (x, P) into the rows of X (2n + 1, n), centre last; the
 * pivoted factor where the unpivoted one refuses P (X its scratch) */
static int sigma_points(const double *x, const double *P, double spread, double *L, double *X,
                        int64_t n)
{
    if (!cholesky_semidefinite(P, L, n) && !cholesky_semidefinite_pivoted(P, L, X, n))
        return 0;
    spread_points(x, spread, L, X, n);
    return 1;
}

/* triangular_sigma_points: sigma_points from the unpivoted factor alone (L lower
 * triangular) */
static int triangular_sigma_points(const double *x, const double *P, double spread, double *L,
                                   double *X, int64_t n)
{
    if (!cholesky_semidefinite(P, L, n))
        return 0;
    spread_points(x, spread, L, X, n);
    return 1;
}

/* cross_covariance: out = sum_i w_i (X_i - xmean)(Z_i - zmean)^T, X (rows, dx), Z (rows, dz) */
static void cross_covariance(const double *X, int64_t dx, const double *xmean, const double *Z,
                             int64_t dz, const double *zmean, const double *weights,
                             int64_t count, double *out)
{
    for (int64_t a = 0; a < dx; a++)
        for (int64_t b = 0; b < dz; b++)
            out[a * dz + b] = 0.0;
    for (int64_t i = 0; i < count; i++) {
        double w = weights[i];
        for (int64_t a = 0; a < dx; a++) {
            double da = w * (X[i * dx + a] - xmean[a]);
            for (int64_t b = 0; b < dz; b++)
                out[a * dz + b] += da * (Z[i * dz + b] - zmean[b]);
        }
    }
}

/* unscented_correct: K = C_xz S^-1, x += K r, P -= K C_xz^T (Zhao Algorithm 2 step 3),
 * symmetrised; 0 (x, P unchanged) when S (m, m) is not positive definite */
static int unscented_correct(double *x, double *P, const double *r, int64_t n, int64_t m,
                             const UnscentedWork *w, double jitter)
{
    if (!cholesky(w->S, w->LS, m))
        return 0;
    cholesky_solve_rows(w->LS, m, w->Cxz, w->K, n);
    w->log_det[0] = log_determinant(w->LS, m);
    add_product(x, w->K, r, n, m);
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = i; j < n; j++) {
            double acc = 0.0;
            for (int64_t a = 0; a < m; a++)
                acc += w->K[i * m + a] * w->Cxz[j * m + a];
            P[i * n + j] -= acc;
            if (j != i)
                P[j * n + i] = P[i * n + j];
        }
    symmetrise(P, n);
    if (jitter > 0.0)
        for (int64_t i = 0; i < n; i++)
            P[i * n + i] += jitter;
    return 1;
}

/* project_points: clamp column i of the first count points (and the centre, last) into
 * [lo[j], hi[j]], j = index[i] (-1: free); X (n_points, n). Returns the entries moved. */
static int64_t project_points(double *X, int64_t n_points, int64_t n, int64_t count,
                              const int64_t *index, const double *lo, const double *hi)
{
    int64_t moved = 0;
    for (int64_t i = 0; i < n; i++) {
        int64_t j = index[i];
        if (j < 0)
            continue;
        for (int64_t r = 0; r < n_points; r++) {
            if (r >= count && r != n_points - 1)
                continue;
            if (X[r * n + i] < lo[j]) {
                X[r * n + i] = lo[j];
                moved += 1;
            } else if (X[r * n + i] > hi[j]) {
                X[r * n + i] = hi[j];
                moved += 1;
            }
        }
    }
    return moved;
}

/* constrain_prior: project the points of (x, P); if any moved, (x, P) become their moments */
static int64_t constrain_prior(double *X, int64_t n, const UkfConfig *config, int64_t count,
                               const double *lo, const double *hi, double *x, double *P,
                               const double *zero)
{
    int64_t moved = project_points(X, 2 * n + 1, n, count, config->limit, lo, hi);
    if (moved > 0) {
        weighted_mean(X, n, config->wm, count, x);
        weighted_covariance(X, n, x, config->wc, count, zero, P);
    }
    return moved;
}

/* ===================================================================== kalman.py */

/* clamp: estimate projection onto box limits (thesis Part I eqs. 20, 25) */
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

/* noise_levels: push the sample into the variance windows; (R, R_parameter, q_error)
 * (R = r^2 var(u), Q = q^2 var(e): Popovici eqs. 24-25, thesis eqs. 29-30) */
static void noise_levels(const UkfRecords *rec, double u_k, double e_k, double *R_out,
                         double *R_p_out, double *q_error_out)
{
    const double *cfg = rec->config.cfg;
    double *sc = rec->sc;
    int64_t k = (int64_t)sc[SC_K];
    window_push(rec->buf_u, rec->window, sc, SC_U, u_k, k);
    window_push(rec->buf_e, rec->window, sc, SC_E, e_k, k);
    double var_u, var_e;
    if (cfg[CFG_FIRST_WINDOW] > 0.0 && k < (int64_t)cfg[CFG_WINDOW]) {
        var_u = sc[SC_VAR_U0];
        var_e = sc[SC_VAR_E0];
    } else {
        var_u = window_variance(sc, SC_U);
        var_e = window_variance(sc, SC_E);
    }
    double floor_ = cfg[CFG_FLOOR];
    var_u = py_max(var_u, floor_);
    *R_out = cfg[CFG_FIXED_R] > 0.0 ? cfg[CFG_FIXED_R] : cfg[CFG_R2] * var_u;
    *R_p_out = cfg[CFG_FIXED_R] > 0.0 ? cfg[CFG_FIXED_R] : cfg[CFG_R2_PARAMETER] * var_u;
    *q_error_out = cfg[CFG_FIXED_QE] > 0.0 ? cfg[CFG_FIXED_QE]
                                            : cfg[CFG_Q2] * py_max(var_e, floor_);
}

/* report_frozen: a stopped filter's row (last estimate, NaN predictions, diverged) */
static void report_frozen(const UkfRecords *rec, int dropped, int64_t row)
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
    for (int64_t i = 0; i < rec->n_in; i++)
        rec->prev_in[i] = rec->in_use[i];
    rec->sc[SC_K] = rec->sc[SC_K] + 1.0;
}

/* report_row: report one sample (means in model order through the report transform,
 * standard deviations, pins) and record divergence */
static void report_row(const UkfRecords *rec, int finite, int cov_ok, int dropped,
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

/* ============================================================= internal_model.py */

/* _chain_polynomial: out[c] = raw[start:start+length] times the Padé polynomial of p[k]
 * (if k >= 0), with gradients in the parameters active[c, which] only */
static void chain_polynomial(const UkfRecords *rec, const double *p, int64_t start, int64_t length,
                             int64_t total, int64_t k, double sign, int64_t c, int64_t which,
                             double *out, double *out_grad)
{
    const int64_t n_p = rec->n_p, longest = rec->longest;
    const int64_t *active = rec->active + (c * 3 + which) * n_p;
    const double *raw = rec->raw, *raw_grad = rec->raw_grad;
    for (int64_t i = 0; i < total; i++) {
        out[c * longest + i] = 0.0;
        for (int64_t jj = 0; jj < n_p; jj++) {
            int64_t j = active[jj];
            if (j < 0)
                break;
            out_grad[(c * longest + i) * n_p + j] = 0.0;
        }
    }
    if (k < 0) {
        for (int64_t i = 0; i < length; i++) {
            out[c * longest + i] = raw[start + i];
            for (int64_t jj = 0; jj < n_p; jj++) {
                int64_t j = active[jj];
                if (j < 0)
                    break;
                out_grad[(c * longest + i) * n_p + j] = raw_grad[(start + i) * n_p + j];
            }
        }
        return;
    }
    int64_t order = rec->pade_cols - 1;
    pade_jet(p[k], order, sign, rec->pade_value, rec->pade_slope, which);
    const double *pade_value = rec->pade_value + which * rec->pade_cols;
    const double *pade_slope = rec->pade_slope + which * rec->pade_cols;
    for (int64_t i = 0; i < length; i++) {
        double r = raw[start + i];
        for (int64_t m = 0; m < order + 1; m++) {
            double w = pade_value[m];
            out[c * longest + i + m] += r * w;
            for (int64_t jj = 0; jj < n_p; jj++) {
                int64_t j = active[jj];
                if (j < 0)
                    break;
                out_grad[(c * longest + i + m) * n_p + j] += raw_grad[(start + i) * n_p + j] * w;
            }
            out_grad[(c * longest + i + m) * n_p + k] += r * pade_slope[m];
        }
    }
}

/* evaluate_coefficients: canonical-form coefficients of every chain (negA, C, d; thesis
 * Part II eq. 4.7) and their gradients in p (monomials, Padé factor, monic normalisation) */
static void evaluate_coefficients(const UkfRecords *rec, const double *p)
{
    const int64_t n_p = rec->n_p, longest = rec->longest;
    const double *term_coef = rec->term_coef;
    const int64_t *term_var = rec->term_var, *term_exp = rec->term_exp;
    const int64_t *term_slot = rec->term_slot, *active = rec->active;
    double *raw = rec->raw, *raw_grad = rec->raw_grad;
    double *num = rec->num, *num_grad = rec->num_grad, *den = rec->den, *den_grad = rec->den_grad;
    double *negA = rec->negA, *negA_grad = rec->negA_grad, *C = rec->C, *C_grad = rec->C_grad;
    double *d = rec->d, *d_grad = rec->d_grad;
    const int gradients = rec->gradients != 0;
    for (int64_t t = 0; t < rec->n_terms; t++) {
        raw[term_slot[t]] = 0.0;
        if (!gradients)
            continue;
        for (int64_t i = 0; i < n_p; i++) {
            int64_t j = term_var[t * n_p + i];
            if (j < 0)
                break;
            raw_grad[term_slot[t] * n_p + j] = 0.0;
        }
    }
    for (int64_t t = 0; t < rec->n_terms; t++) {
        /* integer powers by multiplication (exponents are small) */
        double value = term_coef[t];
        int64_t n_var = 0;
        for (int64_t i = 0; i < n_p; i++) {
            int64_t j = term_var[t * n_p + i];
            if (j < 0)
                break;
            n_var += 1;
            for (int64_t e = 0; e < term_exp[t * n_p + i]; e++)
                value *= p[j];
        }
        int64_t slot = term_slot[t];
        raw[slot] += value;
        if (!gradients)
            continue;
        for (int64_t i = 0; i < n_var; i++) {
            int64_t j = term_var[t * n_p + i];
            double derivative = term_coef[t] * (double)term_exp[t * n_p + i];
            for (int64_t e = 0; e < term_exp[t * n_p + i] - 1; e++)
                derivative *= p[j];
            for (int64_t other = 0; other < n_var; other++) {
                if (other != i) {
                    int64_t jj = term_var[t * n_p + other];
                    for (int64_t e = 0; e < term_exp[t * n_p + other]; e++)
                        derivative *= p[jj];
                }
            }
            raw_grad[slot * n_p + j] += derivative;
        }
    }
    for (int64_t c = 0; c < rec->n_chain; c++) {
        /* numerator and denominator of the chain, with the Padé factor when it has one */
        chain_polynomial(rec, p, rec->chain_num[c * 2 + 0], rec->chain_num[c * 2 + 1],
                         rec->chain_num_length[c], rec->chain_pade[c], -1.0, c, 0, num,
                         num_grad);
        chain_polynomial(rec, p, rec->chain_den[c * 2 + 0], rec->chain_den[c * 2 + 1],
                         rec->chain_den_length[c], rec->chain_pade[c], 1.0, c, 1, den,
                         den_grad);
        /* monic normalisation and canonical form (thesis eq. 4.7) */
        int64_t n = rec->chain_size[c];
        int64_t off = rec->chain_offset[c];
        double inv_lead = 1.0 / den[c * longest + 0];
        int64_t pad = rec->chain_den_length[c] - rec->chain_num_length[c];
        const int64_t *act1 = active + (c * 3 + 1) * n_p;
        const int64_t *act2 = active + (c * 3 + 2) * n_p;
        /* feedthrough d = b_0 / lead (zero for strictly proper chains) */
        if (pad == 0) {
            d[c] = num[c * longest + 0] * inv_lead;
            for (int64_t jj = 0; jj < n_p; jj++) {
                int64_t j = act2[jj];
                if (j < 0)
                    break;
                d_grad[c * n_p + j] = (num_grad[(c * longest + 0) * n_p + j]
                                       - d[c] * den_grad[(c * longest + 0) * n_p + j])
                                      * inv_lead;
            }
        } else {
            d[c] = 0.0;
        }
        double dc = d[c];
        for (int64_t i = 0; i < n; i++) {
            /* ascending state index i <-> descending coefficient index n - i */
            int64_t q = n - i;
            double a = den[c * longest + q] * inv_lead;
            negA[off + i] = -a;
            for (int64_t jj = 0; jj < n_p; jj++) {
                int64_t j = act1[jj];
                if (j < 0)
                    break;
                negA_grad[(off + i) * n_p + j] =
                    -(den_grad[(c * longest + q) * n_p + j]
                      - a * den_grad[(c * longest + 0) * n_p + j])
                    * inv_lead;
            }
            int has_b = q - pad >= 0;
            double b = has_b ? num[c * longest + q - pad] * inv_lead : 0.0;
            C[off + i] = b - dc * a;
            for (int64_t jj = 0; jj < n_p; jj++) {
                int64_t j = act2[jj];
                if (j < 0)
                    break;
                double b_grad = 0.0;
                if (has_b)
                    b_grad = (num_grad[(c * longest + q - pad) * n_p + j]
                              - b * den_grad[(c * longest + 0) * n_p + j])
                             * inv_lead;
                C_grad[(off + i) * n_p + j] =
                    b_grad - d_grad[c * n_p + j] * a + dc * negA_grad[(off + i) * n_p + j];
            }
        }
    }
}

/* model_f: f = x' of the canonical states; with jacobians also F = df/dx (shift rows
 * too) and dfdp = df/dp (F is (n_c, n_c), dfdp (n_c, n_p)) */
static void model_f(const UkfRecords *rec, const double *x, const double *inputs, double *f,
                    double *F, double *dfdp, int jacobians)
{
    const int64_t n_c = rec->n_c;
    const int64_t n_p = jacobians ? rec->n_p : 0;
    const int64_t *chain_offset = rec->chain_offset, *chain_size = rec->chain_size;
    const int64_t *branch_chain = rec->branch_chain, *branch_input = rec->branch_input;
    const double *negA = rec->negA, *negA_grad = rec->negA_grad;
    const double *C = rec->C, *C_grad = rec->C_grad, *d = rec->d, *d_grad = rec->d_grad;
    const int64_t stride = rec->n_p; /* dfdp.shape[1], gradient tables' n_p */
    for (int64_t c = 0; c < rec->n_chain; c++) {
        int64_t n = chain_size[c];
        int64_t off = chain_offset[c];
        for (int64_t i = 0; i < n - 1; i++) {
            f[off + i] = x[off + i + 1];
            F[(off + i) * n_c + off + i + 1] = 1.0;
            for (int64_t j = 0; j < n_p; j++)
                dfdp[(off + i) * stride + j] = 0.0;
        }
        if (n == 0)
            continue;
        int64_t last = off + n - 1;
        double acc = 0.0;
        for (int64_t j = 0; j < n_p; j++)
            dfdp[last * stride + j] = 0.0;
        for (int64_t i = 0; i < n; i++) {
            acc += negA[off + i] * x[off + i];
            F[last * n_c + off + i] = negA[off + i];
            for (int64_t j = 0; j < n_p; j++)
                dfdp[last * stride + j] += negA_grad[(off + i) * stride + j] * x[off + i];
        }
        if (c == 0) {
            /* main chain input v = sum over branches of (C_b x_b + d_b in_b) */
            for (int64_t b = 0; b < rec->n_branch; b++) {
                int64_t cb = branch_chain[b];
                int64_t ob = chain_offset[cb];
                for (int64_t i = 0; i < chain_size[cb]; i++) {
                    acc += C[ob + i] * x[ob + i];
                    F[last * n_c + ob + i] = C[ob + i];
                    for (int64_t j = 0; j < n_p; j++)
                        dfdp[last * stride + j] += C_grad[(ob + i) * stride + j] * x[ob + i];
                }
                double u_b = inputs[branch_input[b]];
                acc += d[cb] * u_b;
                for (int64_t j = 0; j < n_p; j++)
                    dfdp[last * stride + j] += d_grad[cb * stride + j] * u_b;
            }
        } else {
            /* a branch chain is driven by its own input */
            for (int64_t b = 0; b < rec->n_branch; b++)
                if (branch_chain[b] == c)
                    acc += inputs[branch_input[b]];
        }
        f[last] = acc;
    }
}

/* model_g: g (returned); with jacobians also dg/dx (n_c,) and dg/dp (n_p,) */
static double model_g(const UkfRecords *rec, const double *x, const double *inputs,
                      double *dgdx, double *dgdp, int jacobians)
{
    const int64_t n_p = jacobians ? rec->n_p : 0;
    const int64_t stride = rec->n_p;
    const int64_t *chain_offset = rec->chain_offset, *chain_size = rec->chain_size;
    const int64_t *branch_chain = rec->branch_chain, *branch_input = rec->branch_input;
    const double *C = rec->C, *C_grad = rec->C_grad, *d = rec->d, *d_grad = rec->d_grad;
    int64_t n0 = chain_size[0];
    double g = 0.0;
    for (int64_t j = 0; j < n_p; j++)
        dgdp[j] = 0.0;
    for (int64_t i = 0; i < n0; i++) {
        g += C[i] * x[i];
        dgdx[i] = C[i];
        for (int64_t j = 0; j < n_p; j++)
            dgdp[j] += C_grad[i * stride + j] * x[i];
    }
    /* feedthrough of the main chain: d_0 v */
    double v = 0.0;
    for (int64_t j = 0; j < rec->n_c - n0; j++)
        dgdx[n0 + j] = 0.0;
    for (int64_t b = 0; b < rec->n_branch; b++) {
        int64_t cb = branch_chain[b];
        int64_t ob = chain_offset[cb];
        for (int64_t i = 0; i < chain_size[cb]; i++) {
            v += C[ob + i] * x[ob + i];
            dgdx[ob + i] = d[0] * C[ob + i];
            for (int64_t j = 0; j < n_p; j++)
                dgdp[j] += d[0] * C_grad[(ob + i) * stride + j] * x[ob + i];
        }
        double u_b = inputs[branch_input[b]];
        v += d[cb] * u_b;
        for (int64_t j = 0; j < n_p; j++)
            dgdp[j] += d[0] * d_grad[cb * stride + j] * u_b;
    }
    g += d[0] * v;
    for (int64_t j = 0; j < n_p; j++)
        dgdp[j] += d_grad[0 * stride + j] * v;
    return g;
}

/* ================================================================= _ukf_core.py */

/* _point_parameters: point_p = p with filter states first..last-1 of point i (X rows of
 * width n) in their slots; 1 when those entries differ from what point_p held */
static int point_parameters(const UkfConfig *config, const double *X, int64_t n, int64_t i,
                            int64_t first, int64_t last, double *point_p)
{
    int changed = 0;
    for (int64_t j = first; j < last; j++) {
        double value = X[i * n + j];
        int64_t slot = config->slot[j];
        if (point_p[slot] != value) {
            point_p[slot] = value;
            changed = 1;
        }
    }
    return changed;
}

/* _propagate: Y_i = X_i with canonical states (from offset) advanced by one Euler step
 * (in cfg[CFG_SUBSTEPS] substeps); the parameters of point i are filter states
 * first .. n_moving - 1 */
static void propagate(const UkfRecords *rec, const double *X, double *Y, int64_t count,
                      const double *prev_in, double dt, int64_t first, int64_t offset)
{
    const UkfConfig *config = &rec->config;
    const int64_t n_c = rec->n_c, n = rec->n;
    double *point_p = rec->point_p, *x = rec->dgdx, *f = rec->f;
    int64_t m_sub = (int64_t)config->cfg[CFG_SUBSTEPS];
    int64_t m = m_sub > 1 ? m_sub : 1; /* max(1, int(cfg[CFG_SUBSTEPS])) */
    double h = dt / (double)m;
    for (int64_t i = 0; i < count; i++) {
        int changed = point_parameters(config, X, n, i, first, config->n_moving, point_p);
        if (changed || i == 0)
            evaluate_coefficients(rec, point_p);
        for (int64_t j = 0; j < n; j++)
            Y[i * n + j] = X[i * n + j];
        for (int64_t c = 0; c < n_c; c++)
            x[c] = X[i * n + offset + c];
        for (int64_t s = 0; s < m; s++) {
            model_f(rec, x, prev_in, f, rec->F, rec->dfdp, 0);
            for (int64_t c = 0; c < n_c; c++)
                x[c] += f[c] * h;
        }
        for (int64_t c = 0; c < n_c; c++)
            Y[i * n + offset + c] = x[c];
    }
}

/* _measure: Z_i = g(x_i, in_k, p_i); the parameters of point i are states first..last-1 */
static void measure(const UkfRecords *rec, const double *X, double *Z, int64_t count,
                    const double *in_use, int64_t first, int64_t last, int64_t offset)
{
    const UkfConfig *config = &rec->config;
    const int64_t n_c = rec->n_c, n = rec->n;
    double *point_p = rec->point_p;
    for (int64_t i = 0; i < count; i++) {
        int changed = point_parameters(config, X, n, i, first, last, point_p);
        if (changed || i == 0)
            evaluate_coefficients(rec, point_p);
        for (int64_t c = 0; c < n_c; c++)
            rec->f[c] = X[i * n + offset + c];
        Z[i] = model_g(rec, rec->f, in_use, rec->dgdx, rec->dgdp, 0);
    }
}

/* the prediction's process noise: Q = diag(q) Gamma^2, plus q_error Gamma^2 on the chain
 * input state (as the DEKF's) */
static void process_noise(const UkfRecords *rec, double gamma2, double q_error, int64_t offset)
{
    const int64_t n = rec->n;
    double *Q = rec->Q;
    for (int64_t i = 0; i < n; i++) {
        for (int64_t j = 0; j < n; j++)
            Q[i * n + j] = 0.0;
        Q[i * n + i] = rec->config.q[i] * gamma2;
    }
    int64_t es = offset + (int64_t)rec->config.cfg[CFG_ERROR_STATE];
    Q[es * n + es] += q_error * gamma2;
}

/* the state (or joint) filter's prediction: sigma points of z^+_{k-1} through the Euler
 * step, their moments plus Q, and the smoother's cross-covariance */
static int predict(const UkfRecords *rec, double *z, double *P, double spread, int64_t count,
                   double dt, double gamma2, double q_error, int64_t offset, int64_t row)
{
    const int64_t n = rec->n;
    const UnscentedWork *work = &rec->work;
    for (int64_t i = 0; i < n; i++)
        rec->z_prev[i] = z[i];
    int ok = sigma_points(z, P, spread, work->L, work->X, n);
    if (ok) {
        project_points(work->X, 2 * n + 1, n, count, rec->config.limit, rec->lo, rec->hi);
        propagate(rec, work->X, work->Y, count, rec->prev_in, dt, 0, offset);
        weighted_mean(work->Y, n, rec->config.wm, count, z);
        process_noise(rec, gamma2, q_error, offset);
        weighted_covariance(work->Y, n, z, rec->config.wc, count, rec->Q, P);
        if (rec->store_rows > 0) {
            cross_covariance(work->X, n, rec->z_prev, work->Y, n, z, rec->config.wc, count,
                             rec->cross);
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j < n; j++)
                    rec->out_cross[(row * n + i) * n + j] = rec->cross[i * n + j];
        }
    }
    return ok;
}

/* the output's moments: sigma points of z^-_k (constrained) through g; returns ok */
static int output_moments(const UkfRecords *rec, double *z, double *P, double spread,
                          int64_t count, double R, int64_t offset)
{
    const int64_t n = rec->n;
    const UnscentedWork *work = &rec->work;
    for (int64_t j = 0; j < rec->n_p; j++)
        rec->point_p[j] = rec->p[j];
    int ok = sigma_points(z, P, spread, work->L, work->X, n);
    if (ok) {
        constrain_prior(work->X, n, &rec->config, count, rec->lo, rec->hi, z, P, rec->zero);
        measure(rec, work->X, work->Z, count, rec->in_use, 0, rec->config.n_param, offset);
        weighted_mean(work->Z, 1, rec->config.wm, count, work->z);
        rec->R[0] = R;
        weighted_covariance(work->Z, 1, work->z, rec->config.wc, count, rec->R, work->S);
    }
    return ok;
}

/* joint_step: one sample of the joint UKF on z = [theta; gains; x] (_ukf_core.py
 * docstring); writes row `row` of the output */
void joint_step(const UkfRecords *rec, const double *inputs_k, double u_k, double e_k,
                int64_t row)
{
    const double *cfg = rec->config.cfg;
    double *z = rec->z, *P = rec->P, *prev_in = rec->prev_in, *p = rec->p, *sc = rec->sc;
    const UnscentedWork *work = &rec->work;
    const int64_t n = rec->n, n_param = rec->config.n_param, rows = rec->store_rows;
    const int64_t offset = n_param;
    const double dt = cfg[CFG_DT];
    const double gamma2 = cfg[CFG_GAMMA2];
    const double spread = cfg[CFG_SPREAD];
    const int64_t count = (int64_t)cfg[CFG_COUNT];
    const int64_t k = (int64_t)sc[SC_K];

    double R, R_p, q_error;
    noise_levels(rec, u_k, e_k, &R, &R_p, &q_error);
    int dropped = inputs_in_use(inputs_k, u_k, prev_in, rec->in_use, rec->n_in);
    if (sc[SC_FROZEN] > 0.0) {
        store_belief(rows, row, z, P, n, rec->x_prior, rec->P_prior);
        store_belief(rows, row, z, P, n, rec->x_post, rec->P_post);
        report_frozen(rec, dropped, row);
        return;
    }

    for (int64_t j = 0; j < rec->n_p; j++)
        rec->point_p[j] = p[j];
    int ok = 1;
    if (k > 0)
        ok = predict(rec, z, P, spread, count, dt, gamma2, q_error, offset, row);
    store_belief(rows, row, z, P, n, rec->x_prior, rec->P_prior);

    /* ---- output: sigma points of z^-_k through g */
    double prediction = NAN, innovation = NAN, S = NAN;
    if (ok)
        ok = output_moments(rec, z, P, spread, count, R, offset);
    if (ok) {
        prediction = work->z[0];
        S = work->S[0];
        if (!dropped) {
            cross_covariance(work->X, n, z, work->Z, 1, work->z, rec->config.wc, count,
                             work->Cxz);
            innovation = u_k - prediction;
            rec->r[0] = innovation;
            ok = unscented_correct(z, P, rec->r, n, 1, work, cfg[CFG_JITTER]);
            clamp(z, rec->config.limit, n, rec->lo, rec->hi);
        }
    }
    store_belief(rows, row, z, P, n, rec->x_post, rec->P_post);
    for (int64_t i = 0; i < rec->n_in; i++)
        prev_in[i] = rec->in_use[i];

    int finite, cov_ok;
    belief_health(z, P, n, cfg[CFG_MAX_COV], 1, &finite, &cov_ok);
    finite = finite && isfinite(prediction);
    if (!dropped && !isfinite(innovation))
        finite = 0;
    if (!ok)
        cov_ok = 0;
    double *variance = rec->variance;
    for (int64_t j = 0; j < n_param; j++) {
        p[rec->config.slot[j]] = z[j];
        variance[rec->config.slot[j]] = P[j * n + j];
    }
    rec->scalars[0] = prediction;
    rec->scalars[1] = innovation;
    rec->scalars[2] = S;
    report_row(rec, finite, cov_ok, dropped, row);
}

/* ------------------------------------------------------------------------- dual */

/* _set_point: point_p at theta + sign th_scale E_j and point_s at base + sign s state_j */
static void set_point(const UkfRecords *rec, double th_scale, int64_t j, double sign,
                      const double *state, double in_state_scale, const double *base_state)
{
    const int64_t n_t = rec->n_t, n = rec->n;
    const UkfConfig *tc = &rec->t_config;
    double *point_p = rec->t_point_p, *point_s = rec->point_s;
    for (int64_t t = 0; t < n_t; t++)
        point_p[tc->slot[t]] = rec->th[t] + sign * th_scale * rec->E[t * n_t + j];
    for (int64_t i = 0; i < n; i++)
        point_s[i] = base_state[i] + sign * in_state_scale * state[i * n_t + j];
    for (int64_t g = 0; g < rec->config.n_param; g++)
        point_p[rec->config.slot[g]] = point_s[g];
}

/* _predict_sensitivity: M^- = D^- E, the Euler step differenced along each sigma
 * direction of theta: (x(+) - x(-))/(2 h), x(+-) = step(s^+ +- h D^+ E_j, theta +- h E_j) */
static void predict_sensitivity(const UkfRecords *rec, const double *s_post,
                                const double *prev_in, double dt, int64_t offset)
{
    const int64_t n_t = rec->n_t, n_c = rec->n_c, n = rec->n;
    const double step = SENSITIVITY_STEP;
    int64_t m_sub = (int64_t)rec->config.cfg[CFG_SUBSTEPS];
    int64_t m = m_sub > 1 ? m_sub : 1;
    double h = dt / (double)m;
    const double *D = rec->D, *E = rec->E;
    double *M = rec->M, *z_prev = rec->z_prev, *point_s = rec->point_s;
    double *point_x = rec->point_x, *point_p = rec->t_point_p, *f = rec->f;
    for (int64_t j = 0; j < n_t; j++)
        for (int64_t i = 0; i < n; i++) {
            double acc = 0.0;
            for (int64_t t = 0; t < n_t; t++)
                acc += D[i * n_t + t] * E[t * n_t + j];
            M[i * n_t + j] = acc;
        }
    static const double signs[2] = {1.0, -1.0};
    for (int64_t j = 0; j < n_t; j++) {
        for (int64_t i = 0; i < n; i++)
            z_prev[i] = M[i * n_t + j];
        for (int si = 0; si < 2; si++) {
            double sign = signs[si];
            for (int64_t i = 0; i < n; i++)
                point_s[i] = s_post[i] + sign * step * z_prev[i];
            for (int64_t t = 0; t < n_t; t++)
                point_p[rec->t_config.slot[t]] = rec->th[t] + sign * step * E[t * n_t + j];
            evaluate_coefficients(rec, point_p);
            for (int64_t c = 0; c < n_c; c++)
                point_x[c] = point_s[offset + c];
            for (int64_t s = 0; s < m; s++) {
                model_f(rec, point_x, prev_in, f, rec->F, rec->dfdp, 0);
                for (int64_t c = 0; c < n_c; c++)
                    point_x[c] += f[c] * h;
            }
            for (int64_t i = 0; i < n; i++) {
                double value = i < offset ? point_s[i] : point_x[i - offset];
                if (sign > 0.0)
                    M[i * n_t + j] = value;
                else
                    M[i * n_t + j] = (M[i * n_t + j] - value) / (2.0 * step);
            }
        }
    }
}

/* _output_at: g at point_s (gains and canonical states) and point_p */
static double output_at(const UkfRecords *rec, const double *in_use, int64_t offset)
{
    evaluate_coefficients(rec, rec->t_point_p);
    for (int64_t c = 0; c < rec->n_c; c++)
        rec->point_x[c] = rec->point_s[offset + c];
    return model_g(rec, rec->point_x, in_use, rec->dgdx, rec->dgdp, 0);
}

/* _theta_images: Z = g(s^- + M^- e, theta + E e) at the sigma points (+E_i, -E_i, centre) */
static void theta_images(const UkfRecords *rec, const double *s_prior, const double *in_use,
                         int64_t count, int64_t offset)
{
    const int64_t n_t = rec->n_t;
    double *Z = rec->t_work.Z;
    for (int64_t i = 0; i < count; i++) {
        if (i < 2 * n_t) {
            int64_t j = i % n_t;
            double sign = i < n_t ? 1.0 : -1.0;
            set_point(rec, 1.0, j, sign, rec->M, 1.0, s_prior);
        } else {
            set_point(rec, 0.0, 0, 1.0, rec->M, 0.0, s_prior);
        }
        Z[i] = output_at(rec, in_use, offset);
    }
}

/* _correct_sensitivity: M^+ = M^- - K_s G_tot E (eq. 50), G_tot E_j differenced; then
 * D^+ = M^+ E^-1 (E lower triangular; a zero pivot carries no sensitivity) */
static void correct_sensitivity(const UkfRecords *rec, const double *s_prior, const double *K,
                                const double *in_use, int64_t offset, int corrected)
{
    const int64_t n_t = rec->n_t, n = rec->n;
    const double h = SENSITIVITY_STEP;
    double *M = rec->M, *D = rec->D;
    const double *E = rec->E;
    for (int64_t j = 0; j < (corrected ? n_t : 0); j++) {
        set_point(rec, h, j, 1.0, M, h, s_prior);
        double up = output_at(rec, in_use, offset);
        set_point(rec, h, j, -1.0, M, h, s_prior);
        double down = output_at(rec, in_use, offset);
        double slope = (up - down) / (2.0 * h);
        for (int64_t i = 0; i < n; i++)
            M[i * n_t + j] -= K[i] * slope;
    }
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = n_t - 1; j >= 0; j--) {
            if (E[j * n_t + j] <= 0.0) {
                D[i * n_t + j] = 0.0;
                continue;
            }
            double acc = M[i * n_t + j];
            for (int64_t t = j + 1; t < n_t; t++)
                acc -= D[i * n_t + t] * E[t * n_t + j];
            D[i * n_t + j] = acc / E[j * n_t + j];
        }
}

/* dual_step: one sample of the dual UKF (state filter on [gains; x], parameter filter on
 * theta, Wan & van der Merwe 2001; _ukf_core.py docstring); writes row `row` */
void dual_step(const UkfRecords *rec, const double *inputs_k, double u_k, double e_k,
               int64_t row)
{
    const double *cfg = rec->config.cfg;
    double *s_mean = rec->z, *P = rec->P, *prev_in = rec->prev_in, *p = rec->p, *sc = rec->sc;
    const UnscentedWork *work = &rec->work, *tw = &rec->t_work;
    const UkfConfig *tc = &rec->t_config;
    double *th = rec->th, *Pp = rec->Pp;
    const int64_t n = rec->n, n_g = rec->config.n_param, n_t = rec->n_t;
    const int64_t rows = rec->store_rows;
    const int64_t offset = n_g;
    const double dt = cfg[CFG_DT];
    const double gamma2 = cfg[CFG_GAMMA2];
    const double spread = cfg[CFG_SPREAD];
    const int64_t count = (int64_t)cfg[CFG_COUNT];
    const double t_spread = tc->cfg[CFG_SPREAD];
    const int64_t t_count = (int64_t)tc->cfg[CFG_COUNT];
    const int64_t k = (int64_t)sc[SC_K];
    double *in_use = rec->in_use;

    double R, R_p, q_error;
    noise_levels(rec, u_k, e_k, &R, &R_p, &q_error);
    int dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use, rec->n_in);
    if (sc[SC_FROZEN] > 0.0) {
        store_belief(rows, row, s_mean, P, n, rec->x_prior, rec->P_prior);
        store_belief(rows, row, s_mean, P, n, rec->x_post, rec->P_post);
        store_belief(rows, row, th, Pp, n_t, rec->x_prior_2, rec->P_prior_2);
        store_belief(rows, row, th, Pp, n_t, rec->x_post_2, rec->P_post_2);
        report_frozen(rec, dropped, row);
        return;
    }

    /* theta^- = theta^+ in p (the state filter's parameters) */
    for (int64_t t = 0; t < n_t; t++)
        p[tc->slot[t]] = th[t];
    int ok = 1;
    if (k > 0) /* ---- parameter prediction: random walk */
        for (int64_t t = 0; t < n_t; t++)
            Pp[t * n_t + t] += tc->q[t] * gamma2;
    store_belief(rows, row, th, Pp, n_t, rec->x_prior_2, rec->P_prior_2);
    /* ---- parameter sigma directions and the state sensitivity along them */
    int with_theta = n_t > 0 && k > 0;
    if (with_theta) {
        for (int64_t j = 0; j < rec->n_p; j++)
            rec->t_point_p[j] = p[j];
        /* E below is read as lower triangular (correct_sensitivity) */
        ok = triangular_sigma_points(th, Pp, t_spread, tw->L, tw->X, n_t);
        if (ok) {
            if (constrain_prior(tw->X, n_t, tc, t_count, rec->lo, rec->hi, th, Pp,
                                rec->t_zero)) {
                ok = triangular_sigma_points(th, Pp, t_spread, tw->L, tw->X, n_t);
                project_points(tw->X, 2 * n_t + 1, n_t, t_count, tc->limit, rec->lo, rec->hi);
            }
        }
        if (ok) {
            for (int64_t t = 0; t < n_t; t++)
                for (int64_t j = 0; j < n_t; j++)
                    rec->E[t * n_t + j] = t_spread * tw->L[t * n_t + j];
            predict_sensitivity(rec, s_mean, prev_in, dt, offset);
        }
    }

    /* ---- state filter with theta^-: prediction */
    for (int64_t j = 0; j < rec->n_p; j++)
        rec->point_p[j] = p[j];
    if (k > 0 && ok)
        ok = predict(rec, s_mean, P, spread, count, dt, gamma2, q_error, offset, row);
    store_belief(rows, row, s_mean, P, n, rec->x_prior, rec->P_prior);

    /* ---- parameter images: the output along the sigma directions, states moving with theta */
    if (with_theta && ok) {
        for (int64_t j = 0; j < rec->n_p; j++)
            rec->t_point_p[j] = p[j];
        for (int64_t i = 0; i < n; i++)
            rec->point_s[i] = s_mean[i];
        theta_images(rec, s_mean, in_use, t_count, offset);
        weighted_mean(tw->Z, 1, tc->wm, t_count, tw->z);
        rec->t_R[0] = R_p;
        weighted_covariance(tw->Z, 1, tw->z, tc->wc, t_count, rec->t_R, tw->S);
        cross_covariance(tw->X, n_t, th, tw->Z, 1, tw->z, tc->wc, t_count, tw->Cxz);
        for (int64_t i = 0; i < n; i++)
            rec->z_prev[i] = s_mean[i]; /* the state prior, for the sensitivity correction */
    }

    /* ---- state filter: output and correction */
    double prediction = NAN, innovation = NAN, S = NAN;
    int corrected = 0;
    if (ok)
        ok = output_moments(rec, s_mean, P, spread, count, R, offset);
    if (ok) {
        prediction = work->z[0];
        S = work->S[0];
        if (!dropped) {
            cross_covariance(work->X, n, s_mean, work->Z, 1, work->z, rec->config.wc, count,
                             work->Cxz);
            innovation = u_k - prediction;
            rec->r[0] = innovation;
            ok = unscented_correct(s_mean, P, rec->r, n, 1, work, cfg[CFG_JITTER]);
            corrected = ok;
            clamp(s_mean, rec->config.limit, n, rec->lo, rec->hi);
        }
    }
    if (with_theta && ok) {
        /* eq. 50: the state filter's correction moves the sensitivity too */
        correct_sensitivity(rec, rec->z_prev, work->K, in_use, offset, corrected);
        /* ---- parameter correction with the state filter's innovation (as the DEKF) */
        if (corrected) {
            rec->r[0] = innovation;
            ok = unscented_correct(th, Pp, rec->r, n_t, 1, tw, cfg[CFG_JITTER]);
            clamp(th, tc->limit, n_t, rec->lo, rec->hi);
        }
    }
    store_belief(rows, row, s_mean, P, n, rec->x_post, rec->P_post);
    store_belief(rows, row, th, Pp, n_t, rec->x_post_2, rec->P_post_2);
    for (int64_t i = 0; i < rec->n_in; i++)
        prev_in[i] = in_use[i];

    int finite_s, cov_ok_s, finite_t, cov_ok_t;
    belief_health(s_mean, P, n, cfg[CFG_MAX_COV], 1, &finite_s, &cov_ok_s);
    belief_health(th, Pp, n_t, cfg[CFG_MAX_COV], 0, &finite_t, &cov_ok_t);
    int finite = finite_s && finite_t && isfinite(prediction);
    int cov_ok = cov_ok_s && cov_ok_t && ok;
    if (!dropped && !isfinite(innovation))
        finite = 0;
    double *variance = rec->variance;
    for (int64_t g = 0; g < n_g; g++) {
        p[rec->config.slot[g]] = s_mean[g];
        variance[rec->config.slot[g]] = P[g * n + g];
    }
    for (int64_t t = 0; t < n_t; t++) {
        p[tc->slot[t]] = th[t];
        variance[tc->slot[t]] = Pp[t * n_t + t];
    }
    rec->scalars[0] = prediction;
    rec->scalars[1] = innovation;
    rec->scalars[2] = S;
    report_row(rec, finite, cov_ok, dropped, row);
}

/* ---------------------------------------------------------------- entry points */

/* ukf_step: joint_step or dual_step, as the records are */
void ukf_step(const UkfRecords *rec, const double *inputs_k, double u_k, double e_k,
              int64_t row)
{
    if (rec->dual)
        dual_step(rec, inputs_k, u_k, e_k, row);
    else
        joint_step(rec, inputs_k, u_k, e_k, row);
}

/* ukf_run: the step over every sample, sample k into row k (numba: joint_step_many /
 * dual_step_many on a stack of one); inputs (n, n_in) */
void ukf_run(const UkfRecords *rec, const double *inputs, const double *u, const double *e,
             int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        ukf_step(rec, inputs + k * rec->n_in, u[k], e[k], k);
}

/* joint_step_many / dual_step_many on a stack of one (the online update_block): every
 * sample into row 0 */
void ukf_block(const UkfRecords *rec, const double *inputs, const double *u, const double *e,
               int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        ukf_step(rec, inputs + k * rec->n_in, u[k], e[k], 0);
}

/* joint_step_many / dual_step_many on many filters (FilterBatch): sample i steps filter i
 * where active[i], its estimate into row 0 of its own one-row output */
void ukf_step_many(const UkfRecords *const *recs, const double *inputs, const double *u,
                   const double *e, const uint8_t *active, int64_t n)
{
    for (int64_t i = 0; i < n; i++)
        if (active[i])
            ukf_step(recs[i], inputs + i * recs[i]->n_in, u[i], e[i], 0);
}

/* For the Python side to check the layout and the constants it was built against. */
int64_t ukf_abi(void) { return UKF_ABI; }
int64_t ukf_records_size(void) { return (int64_t)sizeof(UkfRecords); }
int64_t ukf_constants(double *out)
{
    const double values[] = {
        PIN_FRACTION, NEGATIVE_TOLERANCE, TINY, SEMIDEFINITE_TOLERANCE, SENSITIVITY_STEP,
        REASON_NONE, REASON_NONFINITE, REASON_COVARIANCE, REASON_PINNED,
        CFG_DT, CFG_Q2, CFG_R2, CFG_WINDOW, CFG_FIRST_WINDOW, CFG_FLOOR, CFG_JITTER,
        CFG_MAX_COV, CFG_FIXED_R, CFG_FIXED_QE, CFG_ERROR_STATE, CFG_GAMMA2,
        CFG_R2_PARAMETER, CFG_SPREAD, CFG_COUNT, CFG_SUBSTEPS, CFG_SIZE,
        SC_K, SC_VAR_U0, SC_VAR_E0, SC_U, SC_E, SC_FROZEN, SC_DIV_INDEX, SC_DIV_REASON,
        SC_DIV_PARAM, SC_SIZE,
    };
    int64_t n = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < n; i++)
            out[i] = values[i];
    return n;
}
