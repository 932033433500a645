/*
 * _rml_native.c: the RML filter bank's compiled path in C, the numba kernels' numbers
 * bit for bit.
 *
 * The numba kernels (_rml_core.py and what it calls) are the reference; this port does
 * their arithmetic operation for operation, in the same order, so that the results are
 * the same bytes (numba neither reassociates nor contracts to FMA without fastmath; the
 * libm functions exp, log and sqrt are the ones numba calls). It exists because it is
 * built in under a CPU-second where numba compiles the same work for about thirty (a
 * first RML estimate in a fresh process: 0.85 CPU-s against 33, build or compile
 * included), and runs each sample in about a quarter of the time (the design of
 * _dekf_native.c, measured for it in benchmarks/numba_alternatives.py).
 * _native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * tests/estimators/test_rml_native.py holds the two equal.
 *
 * Sources ported (manualcontrol/estimators/...):
 *   members/_rml_core.py       bank_step, bank_step_many, _read,
 *                              _delayed_inputs, _member_parameters, _member_step,
 *                              _bank_points, _update_parameters, _adapt_process_noise,
 *                              _remnant_weight
 *   envs/_interpolation.py     bicubic_weights (Boer & Kenyon 1998, App.)
 *   _pilot_core.py             noise_levels, inputs_in_use, report_frozen, report_row
 *   filters/monitor.py         belief_health, track_pins, window_push, window_variance
 *   filters/kalman.py          joseph_correct (scalar measurement: _joseph_scalar),
 *                              predict_covariance
 *   filters/linalg.py          symmetrise, cholesky, cholesky_solve_rows, matmul,
 *                              matmul_transposed
 *   filters/smoothers.py       store_belief
 *   members/internal_model.py  _pade_jet, _chain_polynomial, evaluate_coefficients,
 *                              model_f, model_g (here at a bank member's parameters
 *                              point_p, not the belief's p)
 *
 * What the Python cites: the bank of 2 n + 1 linear Kalman filters at theta and
 * theta +- h L e_j, their central differences giving the score
 * g = nu/S dz - (1/S - nu^2/S^2) dS/2 and the Fisher information
 * F = dz dz^T/S + dS dS^T/(2 S^2), the posterior Lambda = I + F, xi = Lambda^-1 g,
 * theta+ = theta- + L xi, P+ = L Lambda^-1 L^T (Ljung & Soderstrom's recursive
 * prediction-error method in its Gauss-Newton form); Levison et al. (1969, thesis eq. 5)
 * for the first-order remnant filter; the bicubic delay lines of Boer & Kenyon (1998);
 * the drift rule of Jacobs (1988) and Sutton (1992); Popovici eqs. 24-25 (thesis eqs.
 * 29-30) for the variance windows. See _rml_core.py's and rml.py's docstrings.
 *
 * The records (namedtuples of numpy arrays and a few scalars) arrive as one struct of
 * pointers to their C-contiguous data plus the sizes the kernels read from the arrays'
 * shapes and the records' scalar fields (BankConfig's step, substeps, inject,
 * has_remnant, noise_first; DelayLines' delay_slot); Python fills it (_rml_native.py),
 * with arrays shared between records (the belief's p is the report's, cfg the common
 * one) passed as the same pointer. The kernel writes config.base[0] on a causal start,
 * as numba does, into the record's array.
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

/* _rml_core.py: special parameter slots and remnant injection points */
enum { SLOT_LOG_INTENSITY = -2, SLOT_LOG_BREAK = -3 };
enum { INJECT_INPUT = 0, INJECT_OUTPUT = 1 };
/* _rml_core._FILLED = 1 - exp(-1), the value Python computed at import (checked) */
static const double FILLED = 0x1.43a54e4e98864p-1;

#define RML_ABI 1

/* Every record of bank_step: ModelKernel, BankConfig, DelayLines, BankBelief,
 * PilotMonitor, PilotReport, BankScratch and BankOutput. Field order must match
 * _rml_native.py. */
typedef struct {
    /* sizes */
    int64_t n_c;        /* canonical states: scratch.f.shape[0] */
    int64_t n_s;        /* a member's states (canonical + remnant): belief.X.shape[1] */
    int64_t n_t;        /* bank parameters: belief.th.shape[0] */
    int64_t n_m;        /* bank members 2 n_t + 1: belief.X.shape[0] */
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
    int64_t store_rows; /* out.th_prior.shape[0]: smoother storage rows (0: none) */
    int64_t gradients;  /* model.gradients */
    int64_t hist_size;  /* lines.hist.shape[1] */
    /* scalar fields of BankConfig and DelayLines */
    int64_t substeps, inject, has_remnant, noise_first, delay_slot;
    double step;
    /* ModelKernel tables */
    const double *term_coef;
    const int64_t *term_var, *term_exp, *term_slot;
    const int64_t *chain_num, *chain_den, *chain_pade, *chain_offset, *chain_size;
    const int64_t *chain_num_length, *chain_den_length, *branch_chain, *branch_input;
    const int64_t *active;
    /* ModelKernel scratch and outputs */
    double *raw, *raw_grad, *num, *num_grad, *den, *den_grad, *pade_value, *pade_slope;
    double *negA, *negA_grad, *C, *C_grad, *d, *d_grad;
    /* BankConfig (th_lo, th_hi: its lo, hi) */
    const double *cfg;
    const int64_t *slot;
    const double *th_lo, *th_hi, *q, *remnant;
    const uint8_t *estimated;
    double *base;
    const uint8_t *variance_score;
    const double *spread_cap, *drift_rule, *remnant_weight;
    /* DelayLines */
    double *hist;
    const int64_t *extra_slot;
    double *point_in;
    /* BankBelief */
    double *th, *P, *X, *PX, *prev_in, *p, *sc, *drift;
    /* PilotMonitor */
    double *buf_u, *buf_e;
    int64_t *pins, *pin_ring;
    double *last_mean, *last_std;
    uint8_t *pinned_now;
    /* PilotReport */
    const double *lo, *hi, *offset, *sign;
    /* BankScratch */
    double *L, *points, *z, *S, *dz, *dS, *g, *Lam, *LamL, *B, *xi, *Phi, *sub, *Q, *T;
    double *H, *r, *R;
    KalmanWork work;
    double *xs, *f, *F, *dfdp, *dgdx, *dgdp, *point_p, *in_use, *variance, *scalars;
    double *h_dir, *prior;
    /* BankOutput */
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *th_prior, *P_prior, *th_post, *P_post, *extra;
} RmlRecords;

/* Python's max(a, b) on floats as numba lowers it: b if b > a else a */

/* ========================================================= linalg.py (continued) */

/* ===================================================================== kalman.py */

/* predict_covariance: P <- Phi P Phi^T + Q in place (T (n, n) scratch), symmetrised;
 * matmul and matmul_transposed of linalg.py inlined in their loop order */
static void predict_covariance(double *P, const double *Phi, const double *Q, double *T,
                               int64_t n)
{
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            for (int64_t k = 0; k < n; k++)
                acc += Phi[i * n + k] * P[k * n + j];
            T[i * n + j] = acc;
        }
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++) {
            double acc = 0.0;
            for (int64_t k = 0; k < n; k++)
                acc += T[i * n + k] * Phi[j * n + k];
            P[i * n + j] = acc;
        }
    for (int64_t i = 0; i < n; i++)
        for (int64_t j = 0; j < n; j++)
            P[i * n + j] += Q[i * n + j];
    symmetrise(P, n);
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
static void noise_levels(const RmlRecords *rec, double u_k, double e_k, double *R_out,
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
static void report_frozen(const RmlRecords *rec, int dropped, int64_t row)
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
static void report_row(const RmlRecords *rec, int finite, int cov_ok, int dropped,
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
static void chain_polynomial(const RmlRecords *rec, const double *p, int64_t start, int64_t length,
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
static void evaluate_coefficients(const RmlRecords *rec, const double *p)
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
static void model_f(const RmlRecords *rec, const double *x, const double *inputs, double *f,
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
static double model_g(const RmlRecords *rec, const double *x, const double *inputs,
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

/* ================================================================= _rml_core.py */

/* _read: bicubic read of input `row` at fractional sample `position` (ring buffer);
 * before the oldest kept sample the oldest, after `newest` the newest */
static double read_line(const RmlRecords *rec, int64_t row, int64_t newest, double position)
{
    const int64_t size = rec->hist_size;
    const double *hist = rec->hist + row * size;
    int64_t oldest = newest - size + 1;
    if (oldest < 0)
        oldest = 0;
    if (position >= (double)newest)
        return hist[newest % size];
    if (position <= (double)oldest)
        return hist[oldest % size];
    /* position > oldest >= 0: truncation is the floor. A NaN position (no comparison
     * holds) reads a row inside the window: its NaN weights make the value NaN, as
     * numba's, without the undefined conversion of NaN to an integer. */
    int64_t n = position == position ? (int64_t)position : oldest;
    double d = position - (double)n;
    /* envs/_interpolation.bicubic_weights */
    double e = 1.0 - d;
    double w_m1 = -0.5 * d * e * e;
    double w_0 = 1.5 * d * d * d - 2.5 * d * d + 1.0;
    double w_1 = 1.5 * e * e * e - 2.5 * e * e + 1.0;
    double w_2 = -0.5 * d * d * e;
    int64_t i_m1 = n - 1 > oldest ? n - 1 : oldest;
    int64_t i_1 = n + 1 < newest ? n + 1 : newest;
    int64_t i_2 = n + 2 < newest ? n + 2 : newest;
    return w_m1 * hist[i_m1 % size] + w_0 * hist[n % size] + w_1 * hist[i_1 % size]
           + w_2 * hist[i_2 % size];
}

/* _delayed_inputs: the inputs of a point with parameters point_p at sample `position` */
static void delayed_inputs(const RmlRecords *rec, const double *point_p, int64_t newest,
                           double position, double dt)
{
    double tau = point_p[rec->delay_slot];
    for (int64_t i = 0; i < rec->n_in; i++) {
        double delay = tau;
        if (rec->extra_slot[i] >= 0)
            delay += point_p[rec->extra_slot[i]];
        rec->point_in[i] = read_line(rec, i, newest, position - delay / dt);
    }
}

/* _member_parameters: model parameters of a bank point into point_p; (intensity, break).
 * intensity = exp(log_rel + log var_e) 2 omega_r (the intensity is relative) */
static void member_parameters(const RmlRecords *rec, const double *th, double *point_p,
                              double *intensity, double *omega_out)
{
    double log_rel = rec->remnant[0];
    double log_w = rec->remnant[1];
    for (int64_t j = 0; j < rec->n_t; j++) {
        int64_t slot = rec->slot[j];
        if (slot >= 0)
            point_p[slot] = th[j];
        else if (slot == SLOT_LOG_INTENSITY)
            log_rel = th[j];
        else if (slot == SLOT_LOG_BREAK)
            log_w = th[j];
    }
    double omega = exp(log_w);
    *intensity = exp(log_rel + rec->base[0]) * 2.0 * omega;
    *omega_out = omega;
}

/* _member_step: predict (unless the first sample) and correct member i; its z and S */
static void member_step(const RmlRecords *rec, int64_t i, int64_t k, double u_k, double R,
                        double q_error, int dropped, int predict)
{
    const double *cfg = rec->cfg;
    const double dt = cfg[CFG_DT];
    const double gamma2 = cfg[CFG_GAMMA2];
    const int64_t ns = rec->n_s, n_c = rec->n_c;
    double *x = rec->X + i * ns;
    double *P = rec->PX + i * ns * ns;
    const int64_t err = (int64_t)cfg[CFG_ERROR_STATE];
    const int has_r = rec->has_remnant != 0;
    double *xs = rec->xs, *H = rec->H;
    double intensity, omega;
    member_parameters(rec, rec->points + i * rec->n_t, rec->point_p, &intensity, &omega);
    evaluate_coefficients(rec, rec->point_p);
    if (predict) {
        const int64_t substeps = rec->substeps;
        double h = dt / (double)substeps;
        double *Phi = rec->Phi, *sub = rec->sub, *T = rec->T, *F = rec->F;
        for (int64_t a = 0; a < ns; a++)
            for (int64_t b = 0; b < ns; b++)
                Phi[a * ns + b] = a == b ? 1.0 : 0.0;
        double n = has_r && rec->inject == INJECT_INPUT ? x[n_c] : 0.0;
        for (int64_t c = 0; c < n_c; c++)
            xs[c] = x[c];
        for (int64_t m = 0; m < substeps; m++) {
            delayed_inputs(rec, rec->point_p, k,
                           (double)k - 1.0 + ((double)m + 0.5) / (double)substeps, dt);
            model_f(rec, xs, rec->point_in, rec->f, F, rec->dfdp, 0);
            for (int64_t c = 0; c < n_c; c++)
                xs[c] += rec->f[c] * h;
            xs[err] += n * h;
            /* sub = I + h [F, e_err (remnant)]; Phi <- sub Phi */
            for (int64_t a = 0; a < ns; a++)
                for (int64_t b = 0; b < ns; b++)
                    sub[a * ns + b] = a == b ? 1.0 : 0.0;
            for (int64_t a = 0; a < n_c; a++)
                for (int64_t b = 0; b < n_c; b++)
                    sub[a * ns + b] += h * F[a * n_c + b];
            if (has_r && rec->inject == INJECT_INPUT)
                sub[err * ns + n_c] += h;
            for (int64_t a = 0; a < ns; a++)
                for (int64_t b = 0; b < ns; b++) {
                    double acc = 0.0;
                    for (int64_t c = 0; c < ns; c++)
                        acc += sub[a * ns + c] * Phi[c * ns + b];
                    T[a * ns + b] = acc;
                }
            for (int64_t a = 0; a < ns; a++)
                for (int64_t b = 0; b < ns; b++)
                    Phi[a * ns + b] = T[a * ns + b];
        }
        for (int64_t c = 0; c < n_c; c++)
            x[c] = xs[c];
        double *Q = rec->Q;
        for (int64_t a = 0; a < ns; a++)
            for (int64_t b = 0; b < ns; b++)
                Q[a * ns + b] = 0.0;
        Q[err * ns + err] = q_error * gamma2;
        if (has_r) {
            double decay = exp(-omega * dt);
            Phi[n_c * ns + n_c] = decay;
            for (int64_t b = 0; b < n_c; b++)
                Phi[n_c * ns + b] = 0.0;
            x[n_c] = decay * x[n_c];
            Q[n_c * ns + n_c] = intensity * (1.0 - decay * decay) / (2.0 * omega);
        }
        predict_covariance(P, Phi, Q, T, ns);
    }
    /* measurement */
    delayed_inputs(rec, rec->point_p, k, (double)k, dt);
    for (int64_t c = 0; c < n_c; c++)
        xs[c] = x[c];
    double z = model_g(rec, xs, rec->point_in, rec->dgdx, rec->dgdp, 0);
    for (int64_t c = 0; c < n_c; c++)
        H[c] = rec->dgdx[c]; /* model_g writes dg/dx whatever its last argument */
    if (has_r) {
        H[n_c] = rec->inject == INJECT_OUTPUT ? 1.0 : 0.0;
        if (rec->inject == INJECT_OUTPUT)
            z += x[n_c];
    }
    rec->z[i] = z;
    if (dropped) {
        double S = R;
        for (int64_t a = 0; a < ns; a++) {
            double acc = 0.0;
            for (int64_t b = 0; b < ns; b++)
                acc += P[a * ns + b] * H[b];
            S += H[a] * acc;
        }
        rec->S[i] = S;
        return;
    }
    rec->r[0] = u_k - z;
    rec->R[0] = R;
    joseph_scalar(x, P, rec->r, H, rec->R, &rec->work, ns, 0.0); /* x, P kept if S <= 0 */
    rec->S[i] = rec->work.S[0];
}

/* _bank_points: L = chol(P) and the points theta, theta +- h_j L e_j (projected), h_j
 * the spread reduced where it would move a parameter further than its spread_cap */
static int bank_points(const RmlRecords *rec)
{
    const double *th = rec->th;
    const int64_t n_t = rec->n_t;
    double *L = rec->L, *points = rec->points;
    if (!cholesky(rec->P, L, n_t))
        return 0;
    for (int64_t a = 0; a < n_t; a++)
        points[a] = th[a];
    for (int64_t j = 0; j < n_t; j++) {
        double h = rec->step;
        for (int64_t a = 0; a < n_t; a++)
            if (fabs(L[a * n_t + j]) * h > rec->spread_cap[a])
                h = rec->spread_cap[a] / fabs(L[a * n_t + j]);
        rec->h_dir[j] = h;
        for (int64_t a = 0; a < n_t; a++) {
            double d = h * L[a * n_t + j];
            points[(1 + 2 * j) * n_t + a] = th[a] + d;
            points[(2 + 2 * j) * n_t + a] = th[a] - d;
        }
    }
    for (int64_t r = 0; r < rec->n_m; r++)
        for (int64_t a = 0; a < n_t; a++) {
            double *v = points + r * n_t + a;
            if (*v < rec->th_lo[a])
                *v = rec->th_lo[a];
            else if (*v > rec->th_hi[a])
                *v = rec->th_hi[a];
        }
    return 1;
}

/* _update_parameters: the Gauss-Newton (Bayesian) step; before noise_first only the
 * noise parameters learn */
static int update_parameters(const RmlRecords *rec, double u_k, int64_t k)
{
    double *th = rec->th, *P = rec->P;
    const int64_t n_t = rec->n_t;
    double *dz = rec->dz, *dS = rec->dS, *g = rec->g, *Lam = rec->Lam, *L = rec->L;
    const int noise_only = k < rec->noise_first;
    double z0 = rec->z[0];
    double S0 = rec->S[0];
    if (!(S0 > 0.0) || !isfinite(z0))
        return 0;
    double nu = u_k - z0;
    for (int64_t j = 0; j < n_t; j++) {
        dz[j] = (rec->z[1 + 2 * j] - rec->z[2 + 2 * j]) / (2.0 * rec->h_dir[j]);
        dS[j] = (rec->S[1 + 2 * j] - rec->S[2 + 2 * j]) / (2.0 * rec->h_dir[j]);
    }
    for (int64_t j = 0; j < n_t; j++)
        if (rec->slot[j] >= 0 && !rec->variance_score[rec->slot[j]])
            dS[j] = 0.0;
    if (noise_only)
        for (int64_t j = 0; j < n_t; j++)
            if (rec->slot[j] >= 0) {
                dz[j] = 0.0;
                dS[j] = 0.0;
            }
    double w = 1.0 / S0 - nu * nu / (S0 * S0);
    for (int64_t j = 0; j < n_t; j++)
        g[j] = nu / S0 * dz[j] - 0.5 * w * dS[j];
    for (int64_t a = 0; a < n_t; a++) {
        for (int64_t b = 0; b < n_t; b++)
            Lam[a * n_t + b] = dz[a] * dz[b] / S0 + 0.5 * dS[a] * dS[b] / (S0 * S0);
        Lam[a * n_t + a] += 1.0;
    }
    if (!cholesky(Lam, rec->LamL, n_t))
        return 0;
    /* xi = Lambda^-1 g (g as a row), then theta += L xi */
    for (int64_t j = 0; j < n_t; j++)
        rec->xi[j] = g[j];
    cholesky_solve_rows(rec->LamL, n_t, rec->xi, rec->xi, 1);
    for (int64_t a = 0; a < n_t; a++) {
        double acc = 0.0;
        for (int64_t j = 0; j < n_t; j++)
            acc += L[a * n_t + j] * rec->xi[j];
        th[a] += acc;
    }
    /* P = L Lambda^-1 L^T: the rows of B solve B Lambda = L */
    cholesky_solve_rows(rec->LamL, n_t, L, rec->B, n_t);
    for (int64_t a = 0; a < n_t; a++)
        for (int64_t b = 0; b < n_t; b++) {
            double acc = 0.0;
            for (int64_t j = 0; j < n_t; j++)
                acc += rec->B[a * n_t + j] * L[b * n_t + j];
            P[a * n_t + b] = acc;
        }
    symmetrise(P, n_t);
    for (int64_t a = 0; a < n_t; a++) {
        if (th[a] < rec->th_lo[a])
            th[a] = rec->th_lo[a];
        else if (th[a] > rec->th_hi[a])
            th[a] = rec->th_hi[a];
    }
    return 1;
}

/* _adapt_process_noise: raise a pilot parameter's process noise while its corrections
 * keep one sign (delta-bar-delta, Jacobs 1988; IDBD, Sutton 1992) */
static void adapt_process_noise(const RmlRecords *rec)
{
    const double gain = rec->drift_rule[0], weight = rec->drift_rule[1];
    const double threshold = rec->drift_rule[2];
    const int64_t n_t = rec->n_t;
    const double *th = rec->th, *prior = rec->prior;
    double *drift = rec->drift;
    for (int64_t a = 0; a < n_t; a++) {
        if (rec->slot[a] < 0 || !(prior[n_t + a] > 0.0))
            continue;
        double c = (th[a] - prior[a]) / prior[n_t + a];
        drift[a] += weight * (c - drift[a]);
        drift[n_t + a] += weight * (fabs(c) - drift[n_t + a]);
        drift[3 * n_t + a] += weight * (1.0 - drift[3 * n_t + a]);
        if (drift[3 * n_t + a] < FILLED || !(drift[n_t + a] > 0.0))
            continue;
        double rho = fabs(drift[a]) / drift[n_t + a];
        double excess = (rho - threshold) / (1.0 - threshold);
        drift[2 * n_t + a] = excess > 0.0 ? 1.0 + gain * excess : 1.0;
    }
}

/* _remnant_weight: r2_remnant g^2 var(r) at the bank's centre `point` */
static double remnant_weight(const RmlRecords *rec, const double *point, const double *p)
{
    int64_t index = (int64_t)rec->remnant_weight[1];
    double gain = index < 0 ? 1.0 : p[index];
    double log_rel = rec->remnant[0];
    for (int64_t j = 0; j < rec->n_t; j++) {
        if (index >= 0 && rec->slot[j] == index)
            gain = point[j];
        else if (rec->slot[j] == SLOT_LOG_INTENSITY)
            log_rel = point[j];
    }
    return rec->remnant_weight[0] * gain * gain * exp(log_rel + rec->base[0]);
}

/* bank_step: one sample of the filter bank; writes row `row` of the output */
void bank_step(const RmlRecords *rec, const double *inputs_k, double u_k, double e_k,
               int64_t row)
{
    const double *cfg = rec->cfg;
    double *th = rec->th, *P = rec->P, *X = rec->X, *prev_in = rec->prev_in, *p = rec->p;
    double *sc = rec->sc, *drift = rec->drift, *in_use = rec->in_use;
    const int64_t n_t = rec->n_t, rows = rec->store_rows;
    const int64_t k = (int64_t)sc[SC_K];
    double R, R_p, q_error;
    noise_levels(rec, u_k, e_k, &R, &R_p, &q_error);
    int dropped = inputs_in_use(inputs_k, u_k, prev_in, in_use, rec->n_in);
    const int64_t size = rec->hist_size;
    for (int64_t i = 0; i < rec->n_in; i++)
        rec->hist[i * size + k % size] = in_use[i];
    if (sc[SC_FROZEN] > 0.0) {
        store_belief(rows, row, th, P, n_t, rec->th_prior, rec->P_prior);
        store_belief(rows, row, th, P, n_t, rec->th_post, rec->P_post);
        report_frozen(rec, dropped, row);
        return;
    }
    const double gamma2 = cfg[CFG_GAMMA2];
    const int anchored = (double)k >= rec->base[1];
    if (!anchored) /* a causal start: the error variance of the samples so far, floored */
        rec->base[0] = log(py_max(window_variance(sc, SC_E), cfg[CFG_FLOOR]));
    if (k > 0 && anchored)
        for (int64_t a = 0; a < n_t; a++)
            if (k >= rec->noise_first || rec->slot[a] < 0)
                P[a * n_t + a] += rec->q[a] * drift[2 * n_t + a] * gamma2;
    store_belief(rows, row, th, P, n_t, rec->th_prior, rec->P_prior);
    for (int64_t a = 0; a < n_t; a++) {
        rec->prior[a] = th[a];
        rec->prior[n_t + a] = sqrt(P[a * n_t + a]);
    }
    for (int64_t j = 0; j < rec->n_p; j++)
        rec->point_p[j] = p[j];
    int ok = bank_points(rec);
    if (ok) {
        if (rec->remnant_weight[0] > 0.0 && rec->has_remnant)
            R += remnant_weight(rec, rec->points, p);
        /* R is a sample's variance at 100 Hz, a white noise's density at any rate */
        R *= PAPERS_DT / cfg[CFG_DT];
        for (int64_t i = 0; i < rec->n_m; i++)
            member_step(rec, i, k, u_k, R, q_error, dropped, k > 0);
        if (!dropped && anchored) {
            ok = update_parameters(rec, u_k, k);
            if (ok && rec->drift_rule[0] > 0.0 && k >= rec->noise_first)
                adapt_process_noise(rec);
        }
    }
    store_belief(rows, row, th, P, n_t, rec->th_post, rec->P_post);
    for (int64_t i = 0; i < rec->n_in; i++)
        prev_in[i] = in_use[i];

    int finite, cov_ok;
    belief_health(th, P, n_t, cfg[CFG_MAX_COV], 0, &finite, &cov_ok);
    finite = finite && isfinite(rec->z[0]) && isfinite(rec->S[0]);
    const int64_t n_s = rec->n_s;
    for (int64_t i = 0; i < rec->n_m; i++)
        for (int64_t a = 0; a < n_s; a++)
            if (!isfinite(X[i * n_s + a]))
                finite = 0;
    cov_ok = ok && cov_ok;
    double *variance = rec->variance;
    for (int64_t a = 0; a < n_t; a++) {
        int64_t slot = rec->slot[a];
        if (slot >= 0) {
            p[slot] = th[a];
            variance[slot] = P[a * n_t + a];
        }
    }
    double prediction = rec->z[0];
    double innovation = dropped ? NAN : u_k - prediction;
    rec->scalars[0] = prediction;
    rec->scalars[1] = innovation;
    rec->scalars[2] = rec->S[0];
    report_row(rec, finite, cov_ok, dropped, row);
    double intensity, omega;
    member_parameters(rec, th, rec->point_p, &intensity, &omega);
    const int has_r = rec->has_remnant != 0;
    rec->extra[row * 3 + 0] = has_r ? X[n_s - 1] : 0.0;
    rec->extra[row * 3 + 1] = has_r ? intensity : 0.0;
    rec->extra[row * 3 + 2] = has_r ? omega : 0.0;
}

/* bank_run: bank_step over every sample, sample k into row k (numba: bank_step_many on a
 * stack of one); inputs has shape (n, n_in) */
void bank_run(const RmlRecords *rec, const double *inputs, const double *u, const double *e,
              int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        bank_step(rec, inputs + k * rec->n_in, u[k], e[k], k);
}

/* bank_step_many on a stack of one (the online update_block): every sample into row 0 */
void bank_block(const RmlRecords *rec, const double *inputs, const double *u, const double *e,
                int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        bank_step(rec, inputs + k * rec->n_in, u[k], e[k], 0);
}

/* bank_step_many on many filter banks (FilterBatch): sample i steps bank i where
 * active[i], its estimate into row 0 of its own one-row output */
void bank_step_many(const RmlRecords *const *recs, const double *inputs, const double *u,
                    const double *e, const uint8_t *active, int64_t n)
{
    for (int64_t i = 0; i < n; i++)
        if (active[i])
            bank_step(recs[i], inputs + i * recs[i]->n_in, u[i], e[i], 0);
}

/* For the Python side to check the layout and the constants it was built against. */
int64_t rml_abi(void) { return RML_ABI; }
int64_t rml_records_size(void) { return (int64_t)sizeof(RmlRecords); }
int64_t rml_constants(double *out)
{
    const double values[] = {
        PAPERS_DT, PIN_FRACTION, NEGATIVE_TOLERANCE, TINY,
        REASON_NONE, REASON_NONFINITE, REASON_COVARIANCE, REASON_PINNED,
        CFG_DT, CFG_Q2, CFG_R2, CFG_WINDOW, CFG_FIRST_WINDOW, CFG_FLOOR, CFG_JITTER,
        CFG_MAX_COV, CFG_DIMENSIONAL, CFG_FIXED_R, CFG_FIXED_QE, CFG_ERROR_STATE,
        CFG_GAMMA2, CFG_R2_PARAMETER, CFG_SUBSTEPS, CFG_SIZE,
        SC_K, SC_VAR_U0, SC_VAR_E0, SC_U, SC_E, SC_FROZEN, SC_DIV_INDEX, SC_DIV_REASON,
        SC_DIV_PARAM, SC_SIZE,
        SLOT_LOG_INTENSITY, SLOT_LOG_BREAK, INJECT_INPUT, INJECT_OUTPUT, FILLED,
    };
    int64_t n = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < n; i++)
            out[i] = values[i];
    return n;
}
