/*
 * _rdi_native.c: the RDI's compiled path in C, the numba kernels' numbers bit for bit.
 *
 * The recursive delay identifier of Boer & Kenyon (1998): an EKF over the coefficients
 * and the fractional delay of an ARMAX model (Sec. III-A, III-D), with the bicubic
 * interpolation of their Appendix, Sec. III-D's decimation and Sec. III-F's sign
 * constraints. The numba kernels (_rdi_core.py and what it calls) are the reference;
 * this port does their arithmetic operation for operation, in the same order, so that
 * the results are the same bytes (numba neither reassociates nor contracts to FMA
 * without fastmath). It exists because a C compiler builds it in a fraction of a second
 * where numba compiles the same work for many CPU-seconds on a machine's first use.
 * _native.py builds it with IEEE semantics kept:
 *
 *     cc -std=c99 -O2 -fno-fast-math -ffp-contract=off -fPIC -shared ... -lm
 *
 * tests/estimators/test_rdi_native.py holds the two equal.
 *
 * Sources ported (manualcontrol/...):
 *   estimators/members/_rdi_core.py  rdi_step, rdi_run, predict, _read, _past_output,
 *                                    _report, simulate_output
 *   envs/_interpolation.py           bicubic_weights, bicubic_derivative_weights
 *   estimators/filters/kalman.py     joseph_correct (scalar measurement: _joseph_scalar),
 *                                    clamp
 *   estimators/filters/linalg.py     symmetrise
 *   estimators/filters/monitor.py    belief_health
 *   estimators/filters/smoothers.py  store_belief
 *
 * The records (RDIConfig, RDIBelief, RDIScratch with its KalmanWork, RDIOutput:
 * namedtuples of numpy arrays) arrive as one struct of pointers to their C-contiguous
 * data plus the sizes the kernels read from the arrays' shapes; Python fills it
 * (_rdi_native.py), checking every shape.
 *
 * Python's semantics kept where C differs: int(x) truncates (int(np.floor(x)) is
 * (int64_t)floor(x)); an int operand of a float operation is converted to double first
 * (k - m lam - d/dt is (double)(k - m lam) - d/dt, as numba types it); comparisons of a
 * float with an int constant compare doubles; booleans are numpy's one-byte 0/1; every
 * integer % here has non-negative operands, where C's and Python's agree.
 */

#include <math.h>
#include <stddef.h>
#include <stdint.h>
#include "_native_common.h" /* the helpers the ports share (linalg, monitor, smoothers) */

/* ---- _rdi_core.py: indices into cfg (CFG_*) and sc (SC_*) */
enum {
    CFG_DT = 0,
    CFG_LAMBDA = 1,
    CFG_R = 2,
    CFG_SIGN = 3,
    CFG_JITTER = 4,
    CFG_MAX_COV = 5,
    CFG_NA = 6,
    CFG_NB = 7,
    CFG_SIZE = 8
};
enum { SC_K = 0, SC_FROZEN = 1, SC_DIV_INDEX = 2, SC_DIV_REASON = 3, SC_STEPS = 4,
       SC_HELD = 5, SC_SIZE = 6 };
/* filters/monitor.py: divergence codes */
enum { REASON_NONE = 0, REASON_NONFINITE = 1, REASON_COVARIANCE = 2 };

static const double NEGATIVE_TOLERANCE = 1e-10; /* monitor.NEGATIVE_TOLERANCE */

#define RDI_ABI 2
#define N_FLAGS 6 /* scratch.flags and out.flag columns */

/* Every record of rdi_step. Field order must match _rdi_native.py. */
typedef struct {
    /* sizes */
    int64_t n_s;        /* filter states: belief.x.shape[0] */
    int64_t n_p;        /* parameters: belief.p.shape[0] */
    int64_t size;       /* ring length: belief.ring_r.shape[0] (= ring_y's) */
    int64_t store_rows; /* out.x_prior.shape[0]: smoother storage rows (0: none) */
    /* RDIConfig */
    const double *cfg, *q;
    const int64_t *state_param, *limit;
    const double *lo, *hi;
    /* RDIBelief */
    double *x, *P, *p, *ring_r, *ring_y, *sc;
    /* RDIScratch */
    double *H, *R, *r;
    KalmanWork work;
    double *variance, *gradient;
    uint8_t *flags;
    /* RDIOutput */
    double *mean, *std, *scalar;
    uint8_t *flag, *pinned;
    double *x_prior, *P_prior, *x_post, *P_post;
} RdiRecords;

/* ===================================================================== kalman.py */

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

/* belief_health: (finite, covariance ok) of a belief; zero_ok is False for the RDI */
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
        int below = v <= -NEGATIVE_TOLERANCE * largest;
        if (below || v > max_cov)
            ok = 0;
    }
    *finite_out = finite;
    *ok_out = ok;
}

/* ================================================================== _rdi_core.py */

/* _read: value and slope (per sample) at fractional sample `position` from the ring
 * holding samples max(0, k - size + 1) .. k (the bicubic kernel inside, the one-sided
 * cubic through the newest four samples near k) */
static void read_ring(const double *ring, int64_t size, int64_t k, double position,
                      double *value_out, double *slope_out)
{
    int64_t oldest = k - size + 1;
    if (oldest < 0)
        oldest = 0;
    if (position <= (double)oldest) {
        *value_out = ring[oldest % size];
        *slope_out = 0.0;
        return;
    }
    int64_t n = (int64_t)floor(position);
    if (n + 2 <= k) {
        double d = position - (double)n;
        int64_t i_m1 = n - 1 >= oldest ? n - 1 : oldest;
        double x_m1 = ring[i_m1 % size];
        double x_0 = ring[n % size];
        double x_1 = ring[(n + 1) % size];
        double x_2 = ring[(n + 2) % size];
        double w[4];
        bicubic_weights(d, w);
        *value_out = w[0] * x_m1 + w[1] * x_0 + w[2] * x_1 + w[3] * x_2;
        bicubic_derivative_weights(d, w);
        *slope_out = w[0] * x_m1 + w[1] * x_0 + w[2] * x_1 + w[3] * x_2;
        return;
    }
    /* one-sided cubic through k, k-1, k-2, k-3 at s = position - k in [-1, 0] */
    double s = position - (double)k;
    if (s > 0.0)
        s = 0.0;
    double x0 = ring[k % size];
    double x1 = ring[(k - 1 >= oldest ? k - 1 : oldest) % size];
    double x2 = ring[(k - 2 >= oldest ? k - 2 : oldest) % size];
    double x3 = ring[(k - 3 >= oldest ? k - 3 : oldest) % size];
    double p1 = s + 1.0, p2 = s + 2.0, p3 = s + 3.0;
    *value_out = x0 * p1 * p2 * p3 / 6.0
                 - x1 * s * p2 * p3 / 2.0
                 + x2 * s * p1 * p3 / 2.0
                 - x3 * s * p1 * p2 / 6.0;
    *slope_out = x0 * (p2 * p3 + p1 * p3 + p1 * p2) / 6.0
                 - x1 * (p2 * p3 + s * p3 + s * p2) / 2.0
                 + x2 * (p1 * p3 + s * p3 + s * p1) / 2.0
                 - x3 * (p1 * p2 + s * p2 + s * p1) / 6.0;
}

/* _past_output: y[k - back], 0 before the first sample (the system starts at rest) */
static double past_output(const double *ring_y, int64_t size, int64_t k, int64_t back)
{
    int64_t j = k - back;
    if (j < 0 || back >= size)
        return 0.0;
    return ring_y[j % size];
}

/* predict: y_hat at sample k for parameters p (Sec. III-D); gradient gets dy_hat/dp
 * (eq. 2b's H: -sum_m b_m r'/dt for the delay, y[k - i lam], r(k - m lam - d/dt)) */
static double predict(const RdiRecords *rec, const double *p, int64_t k, double *gradient)
{
    const double *cfg = rec->cfg;
    double dt = cfg[CFG_DT];
    int64_t lam = (int64_t)cfg[CFG_LAMBDA];
    int64_t n_a = (int64_t)cfg[CFG_NA];
    int64_t n_b = (int64_t)cfg[CFG_NB];
    double shift = p[0] / dt;
    double value = 0.0;
    double slope_sum = 0.0;
    for (int64_t i = 1; i < n_a + 1; i++) {
        double y_past = past_output(rec->ring_y, rec->size, k, i * lam);
        gradient[i] = y_past;
        value += p[i] * y_past;
    }
    for (int64_t m = 0; m < n_b + 1; m++) {
        int64_t j = 1 + n_a + m;
        double r_value, r_slope;
        read_ring(rec->ring_r, rec->size, k, (double)(k - m * lam) - shift, &r_value,
                  &r_slope);
        gradient[j] = r_value;
        value += p[j] * r_value;
        slope_sum += p[j] * r_slope;
    }
    gradient[0] = -slope_sum / dt;
    return value;
}

/* _report: the row's means, deviations, pins, scalars and flags */
static void report(const RdiRecords *rec, int64_t row, double prediction, double innovation,
                   double S, const uint8_t *flags)
{
    const int64_t n_s = rec->n_s, n_p = rec->n_p;
    const double *P = rec->P, *p = rec->p;
    double *variance = rec->variance;
    for (int64_t j = 0; j < n_p; j++)
        variance[j] = 0.0;
    for (int64_t i = 0; i < n_s; i++)
        variance[rec->state_param[i]] = P[i * n_s + i];
    for (int64_t j = 0; j < n_p; j++) {
        rec->mean[row * n_p + j] = p[j];
        rec->std[row * n_p + j] = variance[j] > 0.0 ? sqrt(variance[j]) : 0.0;
        rec->pinned[row * n_p + j] = 0;
    }
    for (int64_t i = 0; i < n_s; i++) {
        int64_t j = rec->state_param[i];
        if (rec->limit[i] >= 0 && (p[j] <= rec->lo[j] || p[j] >= rec->hi[j]))
            rec->pinned[row * n_p + j] = 1;
    }
    rec->scalar[row * 3 + 0] = prediction;
    rec->scalar[row * 3 + 1] = innovation;
    rec->scalar[row * 3 + 2] = S;
    for (int64_t f = 0; f < N_FLAGS; f++)
        rec->flag[row * N_FLAGS + f] = flags[f];
}

/* rdi_step: consume one sample (r_k, y_k); its estimate into output row `row` */
void rdi_step(const RdiRecords *rec, double r_k, double y_k, int64_t row)
{
    const double *cfg = rec->cfg;
    double *x = rec->x, *P = rec->P, *p = rec->p, *sc = rec->sc, *H = rec->H;
    double *ring_y = rec->ring_y;
    const int64_t size = rec->size, n_s = rec->n_s, rows = rec->store_rows;
    int64_t k = (int64_t)sc[SC_K];
    rec->ring_r[k % size] = r_k;
    ring_y[k % size] = y_k;
    sc[SC_K] = (double)(k + 1);
    int64_t lam = (int64_t)cfg[CFG_LAMBDA];
    int64_t n_a = (int64_t)cfg[CFG_NA];
    uint8_t *flags = rec->flags; /* finite, cov ok, dropped, diverged, identified, held */
    double *gradient = rec->gradient;
    for (int64_t f = 0; f < N_FLAGS; f++)
        flags[f] = 0;

    if (sc[SC_FROZEN] > 0.0) {
        /* a diverged filter repeats its last estimate and predicts nothing */
        store_belief(rows, row, x, P, n_s, rec->x_prior, rec->P_prior);
        store_belief(rows, row, x, P, n_s, rec->x_post, rec->P_post);
        flags[0] = sc[SC_DIV_REASON] != (double)REASON_NONFINITE;
        flags[1] = sc[SC_DIV_REASON] != (double)REASON_COVARIANCE;
        flags[3] = 1;
        report(rec, row, NAN, NAN, NAN, flags);
        return;
    }

    /* identify on the decimated grid once every regressor lies in the recorded history */
    double oldest_read = (double)(k - (int64_t)cfg[CFG_NB] * lam) - p[0] / cfg[CFG_DT];
    int64_t available = k - size + 1 > 0 ? k - size + 1 : 0;
    int identify = k % lam == 0 && k >= n_a * lam
                   && floor(oldest_read) - 1.0 >= (double)available;
    if (identify)
        /* time update, eqs. 1a/2a with f = I: P^- = P^+ + Q */
        for (int64_t i = 0; i < n_s; i++)
            P[i * n_s + i] += rec->q[i];
    store_belief(rows, row, x, P, n_s, rec->x_prior, rec->P_prior);

    double prediction = predict(rec, p, k, gradient);
    for (int64_t i = 0; i < n_s; i++)
        H[i] = gradient[rec->state_param[i]];
    double S = cfg[CFG_R];
    for (int64_t i = 0; i < n_s; i++) {
        double acc = 0.0;
        for (int64_t j = 0; j < n_s; j++)
            acc += P[i * n_s + j] * H[j];
        S += H[i] * acc;
    }
    int dropped = !(isfinite(y_k) && isfinite(prediction) && isfinite(S));
    double innovation = dropped ? NAN : y_k - prediction;
    int correct_ok = 1;
    if (identify && !dropped) {
        sc[SC_STEPS] += 1.0;
        int held = 0;
        if (cfg[CFG_SIGN] > 0.0 && k >= 1) {
            /* Sec. III-F: sign of the magnitude and of the rate, measured vs predicted */
            double previous = predict(rec, p, k - 1, gradient);
            double y_previous = ring_y[(k - 1) % size];
            if (y_k * prediction < 0.0 || (y_k - y_previous) * (prediction - previous) < 0.0)
                held = 1;
        }
        if (held) {
            sc[SC_HELD] += 1.0;
            flags[5] = 1;
        } else {
            flags[4] = 1;
            rec->r[0] = innovation;
            rec->R[0] = cfg[CFG_R];
            correct_ok = joseph_scalar(x, P, rec->r, H, rec->R, &rec->work, n_s,
                                       cfg[CFG_JITTER]);
            S = rec->work.S[0];
            clamp(x, rec->limit, n_s, rec->lo, rec->hi);
            for (int64_t i = 0; i < n_s; i++)
                p[rec->state_param[i]] = x[i];
        }
    }
    store_belief(rows, row, x, P, n_s, rec->x_post, rec->P_post);

    int finite, cov_ok;
    belief_health(x, P, n_s, cfg[CFG_MAX_COV], &finite, &cov_ok);
    if (!correct_ok) {
        if (isfinite(S))
            cov_ok = 0;
        else
            finite = 0;
    }
    if (!dropped && !isfinite(innovation))
        finite = 0;
    flags[0] = (uint8_t)finite;
    flags[1] = (uint8_t)cov_ok;
    flags[2] = (uint8_t)dropped;
    if (!(finite && cov_ok)) {
        sc[SC_FROZEN] = 1.0;
        sc[SC_DIV_INDEX] = (double)row;
        sc[SC_DIV_REASON] = !finite ? REASON_NONFINITE : REASON_COVARIANCE;
        flags[3] = 1;
    }
    report(rec, row, prediction, innovation, S, flags);
}

/* rdi_run: rdi_step over every sample of r and y, sample k into row k */
void rdi_run(const RdiRecords *rec, const double *r, const double *y, int64_t n)
{
    for (int64_t k = 0; k < n; k++)
        rdi_step(rec, r[k], y[k], k);
}

/* simulate_output: the model's output from the input alone, its own past outputs fed
 * back (the output error counterpart of predict, started at rest): p (n, n_p) the
 * parameters of every sample, r (n,) the input, out (n,); ring_r, ring_y (n,) and
 * gradient (n_p,) the caller's scratch (numba allocates them: zeros, zeros, any) */
void rdi_simulate_output(const double *p, int64_t n_p, const double *r, int64_t n, double dt,
                         double lam, double n_a, double n_b, double *ring_r, double *ring_y,
                         double *gradient, double *out)
{
    double cfg[CFG_SIZE] = {0.0};
    cfg[CFG_DT] = dt;
    cfg[CFG_LAMBDA] = lam;
    cfg[CFG_NA] = n_a;
    cfg[CFG_NB] = n_b;
    RdiRecords rec = {0};
    rec.n_p = n_p;
    rec.size = n;
    rec.cfg = cfg;
    rec.ring_r = ring_r;
    rec.ring_y = ring_y;
    for (int64_t k = 0; k < n; k++) {
        ring_r[k] = r[k];
        double value = predict(&rec, p + k * n_p, k, gradient);
        ring_y[k] = value;
        out[k] = value;
    }
}

/* For the Python side to check the layout and the constants it was built against. */
int64_t rdi_abi(void) { return RDI_ABI; }
int64_t rdi_records_size(void) { return (int64_t)sizeof(RdiRecords); }
int64_t rdi_constants(double *out)
{
    const double values[] = {
        NEGATIVE_TOLERANCE, TINY, REASON_NONE, REASON_NONFINITE, REASON_COVARIANCE,
        CFG_DT, CFG_LAMBDA, CFG_R, CFG_SIGN, CFG_JITTER, CFG_MAX_COV, CFG_NA, CFG_NB,
        CFG_SIZE, SC_K, SC_FROZEN, SC_DIV_INDEX, SC_DIV_REASON, SC_STEPS, SC_HELD, SC_SIZE,
        N_FLAGS,
    };
    int64_t n = (int64_t)(sizeof values / sizeof values[0]);
    if (out != NULL)
        for (int64_t i = 0; i < n; i++)
            out[i] = values[i];
    return n;
}
