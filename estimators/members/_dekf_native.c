/*
 * _dekf_native.c: the DEKF's compiled path in C, the numba kernels' numbers bit for bit.
 *
 * The numba kernels (_dekf_core.py and what it calls) are the reference; this port does
 * their arithmetic operation for operation, in the same order, so that the results are
 * the same bytes (numba neither reassociates nor contracts to FMA without fastmath).
 * It exists because it is built in under a CPU-second where numba compiles the same
 * work for about thirty, and runs each sample in about half the time
 * (benchmarks/numba_alternatives.py). _native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * (-ffp-contract=off matters: allowed to fuse multiply-adds, GCC's results differ from
 * the first samples on.) tests/estimators/test_dekf_native.py holds the two equal.
 *
 * Sources ported (manualcontrol/estimators/...):
 *   members/_dekf_core.py      dekf_step, dekf_step_many, _apply_phi, _apply_phi_transpose,
 *                              _store_phi
 *   _pilot_core.py             noise_levels, inputs_in_use, report_frozen, report_row
 *   filters/monitor.py         belief_health, track_pins, window_push, window_variance
 *   filters/kalman.py          joseph_correct (scalar measurement: _joseph_scalar), clamp
 *   filters/linalg.py          symmetrise
 *   filters/smoothers.py       store_belief
 *   members/internal_model.py  _pade_jet, _chain_polynomial, evaluate_coefficients,
 *                              model_f, model_g
 *
 * The records (namedtuples of numpy arrays) arrive as one struct of pointers to their
 * C-contiguous data plus the sizes the kernels read from the arrays' shapes; Python
 * fills it (_dekf_native.py), with arrays shared between records (the belief's p is
 * the report's) passed as the same pointer.
 *
 * Python's semantics kept where C differs: max(a, b) is "b if b > a else a" (numba's
 * lowering of the builtin, NaN-faithful); int(x) truncates; an int operand of a float
 * operation is converted to double first; booleans are numpy's one-byte 0/1.
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

static const double PAPERS_DT = 0.01;           /* _pilot_core.PAPERS_DT */
static const double NEGATIVE_TOLERANCE = 1e-10; /* monitor.NEGATIVE_TOLERANCE */

#define DEKF_ABI 1

/* Every record of dekf_step: ModelKernel, DEKFConfig, DEKFBelief, PilotMonitor,
 * PilotReport, DEKFScratch and DEKFOutput. Field order must match _dekf_native.py. */
typedef struct {
    /* sizes */
    int64_t n_c;        /* canonical states: scratch.f.shape[0] */
    int64_t n_s;        /* state-filter states: belief.x.shape[0] */
    int64_t n_g;        /* gains in the state filter: config.gain_index.shape[0] */
    int64_t n_t;        /* parameter-filter states: belief.th.shape[0] */
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
    int64_t store_rows; /* out.Phi.shape[0]: smoother storage rows (0: none) */
    int64_t gradients;  /* model.gradients */
    /* ModelKernel tables */
    const double *term_coef;
    const int64_t *term_var, *term_exp, *term_slot;
    const int64_t *chain_num, *chain_den, *chain_pade, *chain_offset, *chain_size;
    const int64_t *chain_num_length, *chain_den_length, *branch_chain, *branch_input;
    const int64_t *active;
    /* ModelKernel scratch and outputs */
    double *raw, *raw_grad, *num, *num_grad, *den, *den_grad, *pade_value, *pade_slope;
    double *negA, *negA_grad, *C, *C_grad, *d, *d_grad;
    /* DEKFConfig */
    const double *cfg;
    const uint8_t *is_dense;
    const int64_t *gain_index, *theta_index;
    const double *q_state, *q_theta;
    const int64_t *state_limit, *theta_limit;
    const uint8_t *estimated;
    /* DEKFBelief */
    double *x, *P, *th, *Pp, *dx, *prev_in, *p, *sc;
    /* PilotMonitor */
    double *buf_u, *buf_e;
    int64_t *pins, *pin_ring;
    double *last_mean, *last_std;
    uint8_t *pinned_now;
    /* PilotReport */
    const double *lo, *hi, *offset, *sign;
    /* DEKFScratch */
    double *F, *f, *dfdp, *dgdx, *dgdp, *M, *H_state, *H_theta, *R_state, *R_theta, *r;
    KalmanWork state_work, theta_work;
    double *dxm, *in_use, *variance, *scalars;
    /* DEKFOutput */
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *x_prior, *P_prior, *x_post, *P_post, *Phi;
    double *th_prior, *Pp_prior, *th_post, *Pp_post;
} DekfRecords;

/* Python's max(a, b) on floats as numba lowers it: b if b > a else a */

/* ===================================================================== kalman.py */

/* joseph_correct, for the DEKF's scalar measurements only (m = 1: every DEKF
 * correction). The general m-dimensional branch (Cholesky solve) is not reachable from
 * the DEKF and is not ported; the Python side checks m = 1. */
static int joseph_correct(double *x, double *P, const double *r, const double *H,
                          const double *R, const KalmanWork *work, int64_t n, double jitter)
{
    return joseph_scalar(x, P, r, H, R, work, n, jitter);
}

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
static void noise_levels(const DekfRecords *rec, double u_k, double e_k, double *R_out,
                         double *R_p_out, double *q_error_out)
{
    const double *cfg = rec->cfg;
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
static void report_frozen(const DekfRecords *rec, int dropped, int64_t row)
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
static void report_row(const DekfRecords *rec, int finite, int cov_ok, int dropped,
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
static void chain_polynomial(const DekfRecords *rec, int64_t start, int64_t length,
                             int64_t total, int64_t k, double sign, int64_t c, int64_t which,
                             double *out, double *out_grad)
{
    const int64_t n_p = rec->n_p, longest = rec->longest;
    const int64_t *active = rec->active + (c * 3 + which) * n_p;
    const double *raw = rec->raw, *raw_grad = rec->raw_grad, *p = rec->p;
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
static void evaluate_coefficients(const DekfRecords *rec)
{
    const int64_t n_p = rec->n_p, longest = rec->longest;
    const double *p = rec->p, *term_coef = rec->term_coef;
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
        chain_polynomial(rec, rec->chain_num[c * 2 + 0], rec->chain_num[c * 2 + 1],
                         rec->chain_num_length[c], rec->chain_pade[c], -1.0, c, 0, num,
                         num_grad);
        chain_polynomial(rec, rec->chain_den[c * 2 + 0], rec->chain_den[c * 2 + 1],
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
static void model_f(const DekfRecords *rec, const double *x, const double *inputs, double *f,
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
static double model_g(const DekfRecords *rec, const double *x, const double *inputs,
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

/* ================================================================= _dekf_core.py */

/* _apply_phi: dst = (I + dt F) src for src (rows, cols), F acting on canonical rows */
static void apply_phi(const double *F, const uint8_t *is_dense, int64_t n_c, double dt,
                      const double *src, int64_t rows, int64_t cols, double *dst)
{
    for (int64_t i = 0; i < rows; i++) {
        if (i < n_c && is_dense[i]) {
            for (int64_t c = 0; c < cols; c++) {
                double acc = 0.0;
                for (int64_t j = 0; j < n_c; j++)
                    acc += F[i * n_c + j] * src[j * cols + c];
                dst[i * cols + c] = src[i * cols + c] + dt * acc;
            }
        } else if (i < n_c) {
            for (int64_t c = 0; c < cols; c++)
                dst[i * cols + c] = src[i * cols + c] + dt * src[(i + 1) * cols + c];
        } else {
            for (int64_t c = 0; c < cols; c++)
                dst[i * cols + c] = src[i * cols + c];
        }
    }
}

/* _apply_phi_transpose: dst = src (I + dt F)^T for src (rows, cols) */
static void apply_phi_transpose(const double *F, const uint8_t *is_dense, int64_t n_c,
                                double dt, const double *src, int64_t rows, int64_t cols,
                                double *dst)
{
    for (int64_t i = 0; i < cols; i++) {
        if (i < n_c && is_dense[i]) {
            for (int64_t r = 0; r < rows; r++) {
                double acc = 0.0;
                for (int64_t j = 0; j < n_c; j++)
                    acc += src[r * cols + j] * F[i * n_c + j];
                dst[r * cols + i] = src[r * cols + i] + dt * acc;
            }
        } else if (i < n_c) {
            for (int64_t r = 0; r < rows; r++)
                dst[r * cols + i] = src[r * cols + i] + dt * src[r * cols + i + 1];
        } else {
            for (int64_t r = 0; r < rows; r++)
                dst[r * cols + i] = src[r * cols + i];
        }
    }
}

/* _store_phi: Phi_s of this sample's prediction into out.Phi[row] (identity at k = 0) */
static void store_phi(const DekfRecords *rec, int64_t row, double dt, int64_t k)
{
    if (rec->store_rows == 0)
        return;
    const int64_t n_s = rec->n_s, n_c = rec->n_c;
    double *Phi = rec->Phi + row * n_s * n_s;
    for (int64_t i = 0; i < n_s; i++)
        for (int64_t j = 0; j < n_s; j++)
            Phi[i * n_s + j] = i == j ? 1.0 : 0.0;
    if (k == 0)
        return;
    for (int64_t i = 0; i < n_c; i++) {
        if (rec->is_dense[i]) {
            for (int64_t j = 0; j < n_c; j++)
                Phi[i * n_s + j] += dt * rec->F[i * n_c + j];
        } else {
            Phi[i * n_s + i + 1] += dt;
        }
    }
}

/* dekf_step: advance the belief by one sample and write its estimate into output row
 * `row` (thesis Part I eqs. 11-25, Popovici et al. 2017 eqs. 6-15; see _dekf_core.py) */
void dekf_step(const DekfRecords *rec, const double *inputs_k, double u_k, double e_k,
               int64_t row)
{
    const double *cfg = rec->cfg;
    double *x = rec->x, *P = rec->P, *th = rec->th, *Pp = rec->Pp, *dx = rec->dx;
    double *prev_in = rec->prev_in, *p = rec->p, *sc = rec->sc;
    double *F = rec->F, *f = rec->f, *dfdp = rec->dfdp, *dgdx = rec->dgdx, *dgdp = rec->dgdp;
    double *H = rec->H_state, *Ht = rec->H_theta, *dxm = rec->dxm, *in_use = rec->in_use;
    const int64_t *gain_index = rec->gain_index, *theta_index = rec->theta_index;
    const uint8_t *is_dense = rec->is_dense;
    const int64_t rows = rec->store_rows;

    const int64_t n_c = rec->n_c, n_s = rec->n_s, n_g = rec->n_g, n_t = rec->n_t;
    const double dt = cfg[CFG_DT];
    const double gamma2 = cfg[CFG_GAMMA2];
    const int64_t k = (int64_t)sc[SC_K];

    /* retrospective variances (Popovici eqs. 24-25, thesis eqs. 29-30) */
    double R, R_p, q_error;
    noise_levels(rec, u_k, e_k, &R, &R_p, &q_error);
    int dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use, rec->n_in);

    if (sc[SC_FROZEN] > 0.0) {
        store_belief(rows, row, x, P, n_s, rec->x_prior, rec->P_prior);
        store_belief(rows, row, x, P, n_s, rec->x_post, rec->P_post);
        store_belief(rows, row, th, Pp, n_t, rec->th_prior, rec->Pp_prior);
        store_belief(rows, row, th, Pp, n_t, rec->th_post, rec->Pp_post);
        store_phi(rec, row, dt, 0);
        report_frozen(rec, dropped, row);
        return;
    }

    /* current parameter vector: gains from the state filter, theta^- = theta^+ (eq. 11) */
    for (int64_t g = 0; g < n_g; g++)
        p[gain_index[g]] = x[n_c + g];
    for (int64_t t = 0; t < n_t; t++)
        p[theta_index[t]] = th[t];
    evaluate_coefficients(rec);

    if (k > 0) {
        /* ---- 1. parameter prediction (eq. 12) */
        for (int64_t t = 0; t < n_t; t++)
            Pp[t * n_t + t] += rec->q_theta[t] * gamma2;
        /* ---- 2. state prediction (eqs. 13-14) at x^+_{k-1}, in_{k-1}, theta^-_k: Euler
         * substeps of h = dt / m, Phi_s their product */
        int64_t m_sub = (int64_t)cfg[CFG_SUBSTEPS];
        int64_t m = m_sub > 1 ? m_sub : 1; /* max(1, int(cfg[CFG_SUBSTEPS])) */
        double h = dt / (double)m;
        /* eq. 49's weight of df/dtheta per substep: h (dimensional), h / 0.01 s (printed) */
        double scale = cfg[CFG_DIMENSIONAL] > 0.0 ? h : h / PAPERS_DT;
        int store = rows > 0;
        if (store)
            store_phi(rec, row, h, 0);
        for (int64_t j = 0; j < m; j++) {
            model_f(rec, x, prev_in, f, F, dfdp, 1);
            /* total-derivative recursion, eq. 49: dx^-_k = df/dtheta (dt) + Phi dx^+_{k-1} */
            if (j > 0)
                for (int64_t i = 0; i < n_s; i++)
                    for (int64_t t = 0; t < n_t; t++)
                        dx[i * n_t + t] = dxm[i * n_t + t];
            apply_phi(F, is_dense, n_c, h, dx, n_s, n_t, dxm);
            for (int64_t i = 0; i < n_c; i++)
                for (int64_t t = 0; t < n_t; t++)
                    dxm[i * n_t + t] += dfdp[i * rec->n_p + theta_index[t]] * scale;
            for (int64_t i = 0; i < n_c; i++)
                x[i] += f[i] * h;
            apply_phi(F, is_dense, n_c, h, P, n_s, n_s, rec->M);
            apply_phi_transpose(F, is_dense, n_c, h, rec->M, n_s, n_s, P);
            if (store) {
                double *Phi = rec->Phi + row * n_s * n_s;
                apply_phi(F, is_dense, n_c, h, Phi, n_s, n_s, rec->M);
                for (int64_t a = 0; a < n_s; a++)
                    for (int64_t b = 0; b < n_s; b++)
                        Phi[a * n_s + b] = rec->M[a * n_s + b];
            }
        }
        for (int64_t i = 0; i < n_s; i++)
            P[i * n_s + i] += rec->q_state[i] * gamma2;
        int64_t es = (int64_t)cfg[CFG_ERROR_STATE];
        P[es * n_s + es] += q_error * gamma2;
        symmetrise(P, n_s);
    } else {
        for (int64_t i = 0; i < n_s; i++)
            for (int64_t t = 0; t < n_t; t++)
                dxm[i * n_t + t] = dx[i * n_t + t];
        store_phi(rec, row, dt, k);
    }
    store_belief(rows, row, x, P, n_s, rec->x_prior, rec->P_prior);
    store_belief(rows, row, th, Pp, n_t, rec->th_prior, rec->Pp_prior);

    /* ---- output equation at x^-_k, theta^-_k */
    double prediction = model_g(rec, x, in_use, dgdx, dgdp, 1);
    for (int64_t i = 0; i < n_c; i++)
        H[i] = dgdx[i];
    for (int64_t g = 0; g < n_g; g++)
        H[n_c + g] = dgdp[gain_index[g]];
    /* G_p^tot = dg/dtheta + dg/dx dx^-/dtheta (eq. 48) */
    for (int64_t t = 0; t < n_t; t++) {
        double acc = dgdp[theta_index[t]];
        for (int64_t i = 0; i < n_s; i++)
            acc += H[i] * dxm[i * n_t + t];
        Ht[t] = acc;
    }

    int correct_ok = 1;
    double innovation, S;
    if (dropped) {
        innovation = NAN;
        S = R;
        for (int64_t i = 0; i < n_s; i++) {
            double acc = 0.0;
            for (int64_t j = 0; j < n_s; j++)
                acc += P[i * n_s + j] * H[j];
            S += H[i] * acc;
        }
        /* no correction: K_s = 0, so dx^+ = dx^- (eq. 50) */
        for (int64_t i = 0; i < n_s; i++)
            for (int64_t t = 0; t < n_t; t++)
                dx[i * n_t + t] = dxm[i * n_t + t];
    } else {
        innovation = u_k - prediction; /* eq. 16 */
        rec->r[0] = innovation;
        /* ---- 3. state correction (eqs. 15-19) */
        rec->R_state[0] = R;
        const KalmanWork *sw = &rec->state_work;
        correct_ok = joseph_correct(x, P, rec->r, H, rec->R_state, sw, n_s, cfg[CFG_JITTER]);
        S = sw->S[0];
        const double *K = sw->K;
        /* ---- 4. state limitation (eq. 20): with unit-row D, the projection clamps */
        clamp(x, rec->state_limit, n_s, rec->lo, rec->hi);
        /* ---- 5. parameter correction (eqs. 21-24) */
        if (n_t > 0 && correct_ok) {
            rec->R_theta[0] = R_p;
            const KalmanWork *tw = &rec->theta_work;
            correct_ok = joseph_correct(th, Pp, rec->r, Ht, rec->R_theta, tw, n_t,
                                        cfg[CFG_JITTER]);
            /* ---- 6. parameter limitation (eq. 25) */
            clamp(th, rec->theta_limit, n_t, rec->lo, rec->hi);
        }
        /* eq. 50 for the next step: dx^+_k = dx^-_k - K_s,k G_p,k^tot */
        for (int64_t i = 0; i < n_s; i++)
            for (int64_t t = 0; t < n_t; t++)
                dx[i * n_t + t] = dxm[i * n_t + t] - K[i] * Ht[t];
    }
    store_belief(rows, row, x, P, n_s, rec->x_post, rec->P_post);
    store_belief(rows, row, th, Pp, n_t, rec->th_post, rec->Pp_post);

    for (int64_t i = 0; i < rec->n_in; i++)
        prev_in[i] = in_use[i];

    /* ---- health and report */
    double max_cov = cfg[CFG_MAX_COV];
    int finite_s, cov_ok_s, finite_t, cov_ok_t;
    belief_health(x, P, n_s, max_cov, 1, &finite_s, &cov_ok_s);
    belief_health(th, Pp, n_t, max_cov, 0, &finite_t, &cov_ok_t);
    int finite = isfinite(prediction) && finite_s && finite_t;
    int cov_ok = cov_ok_s && cov_ok_t;
    if (!dropped && !isfinite(innovation))
        finite = 0;
    if (!correct_ok) {
        /* an innovation variance that is not positive: non-finite, or the covariance broke */
        if (isfinite(S))
            cov_ok = 0;
        else
            finite = 0;
    }
    double *variance = rec->variance;
    for (int64_t g = 0; g < n_g; g++) {
        p[gain_index[g]] = x[n_c + g];
        variance[gain_index[g]] = P[(n_c + g) * n_s + n_c + g];
    }
    for (int64_t t = 0; t < n_t; t++) {
        p[theta_index[t]] = th[t];
        variance[theta_index[t]] = Pp[t * n_t + t];
    }
    double *scalars = rec->scalars;
    scalars[0] = prediction;
    scalars[1] = innovation;
    scalars[2] = S;
    report_row(rec, finite, cov_ok, dropped, row);
}

/* dekf_run: dekf_step over every sample, sample k into row k (numba: dekf_step_many on a
 * stack of one); inputs has shape (n, n_in) */
void dekf_run(const DekfRecords *rec, const double *inputs, const double *u, const double *e,
              int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        dekf_step(rec, inputs + k * rec->n_in, u[k], e[k], k);
}

/* dekf_step_many on a stack of one (the online update_block): every sample into row 0 */
void dekf_block(const DekfRecords *rec, const double *inputs, const double *u, const double *e,
                int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        dekf_step(rec, inputs + k * rec->n_in, u[k], e[k], 0);
}

/* dekf_step_many on many filters (FilterBatch): sample i steps filter i where active[i],
 * its estimate into row 0 of its own one-row output */
void dekf_step_many(const DekfRecords *const *recs, const double *inputs, const double *u,
                    const double *e, const uint8_t *active, int64_t n)
{
    for (int64_t i = 0; i < n; i++)
        if (active[i])
            dekf_step(recs[i], inputs + i * recs[i]->n_in, u[i], e[i], 0);
}

/* For the Python side to check the layout and the constants it was built against. */
int64_t dekf_abi(void) { return DEKF_ABI; }
int64_t dekf_records_size(void) { return (int64_t)sizeof(DekfRecords); }
int64_t dekf_constants(double *out)
{
    const double values[] = {
        PAPERS_DT, PIN_FRACTION, NEGATIVE_TOLERANCE, TINY,
        REASON_NONE, REASON_NONFINITE, REASON_COVARIANCE, REASON_PINNED,
        CFG_DT, CFG_Q2, CFG_R2, CFG_WINDOW, CFG_FIRST_WINDOW, CFG_FLOOR, CFG_JITTER,
        CFG_MAX_COV, CFG_DIMENSIONAL, CFG_FIXED_R, CFG_FIXED_QE, CFG_ERROR_STATE,
        CFG_GAMMA2, CFG_R2_PARAMETER, CFG_SUBSTEPS, CFG_SIZE,
        SC_K, SC_VAR_U0, SC_VAR_E0, SC_U, SC_E, SC_FROZEN, SC_DIV_INDEX, SC_DIV_REASON,
        SC_DIV_PARAM, SC_SIZE,
    };
    int64_t n = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < n; i++)
            out[i] = values[i];
    return n;
}
