/* The LPV toolkit's compiled kernels in C: the batched matrix exponential and the
 * whole-run LPV simulation, the same numbers bit for bit as the numba kernels of
 * _dynamics_kernels.py.
 *
 * expm_batch: Al-Mohy & Higham (2009), Algorithm 3.1, on the transpose of each matrix
 * as scipy does (see _expm.py), every loop, bracket and library call (pow, log2, ceil)
 * as in expm_batch_kernel. simulate_lpv: simulate_lpv_kernel with lpv_output_step,
 * lpv_state_step, read_smooth, read_held and bicubic_weights (Boer & Kenyon 1998,
 * Appendix) inlined in the same order of operations.
 *
 * Built with -ffp-contract=off and without fast-math (see _native.py): no fused
 * multiply-add, no reassociation, as numba compiles without fastmath. Python's
 * max(a, b) and min(a, b) are numba's `b > a ? b : a` and `b < a ? b : a`, and a
 * float raised to an integer power is numba's exponentiation by squaring (int_power).
 * All arrays are C-contiguous, checked by the binding (_dynamics_native.py).
 */

#include <math.h>
#include <stdint.h>
#include <string.h>

/* The argument lists below; bumped with them (checked at load by the binding). */
#define DYNAMICS_ABI 1
/* The shapes of the Padé tables the exponential reads: coefficient rows and columns,
 * number of orders (expm_batch_kernel's tables, _expm.py). */
#define TABLE_ROWS 12
#define TABLE_POWERS 5
#define N_ORDERS 5

int64_t dynamics_abi(void) { return DYNAMICS_ABI; }

int64_t dynamics_constants(double *out)
{
    if (out != 0) {
        out[0] = TABLE_ROWS;
        out[1] = TABLE_POWERS;
        out[2] = N_ORDERS;
    }
    return 3;
}

static inline double py_max(double a, double b) { return b > a ? b : a; }
static inline double py_min(double a, double b) { return b < a ? b : a; }
static inline int64_t py_max_int(int64_t a, int64_t b) { return b > a ? b : a; }

/* numba's float ** int: exponentiation by squaring, inverted for a negative power
 * (math.pow beyond 0x10000). */
static double int_power(double a, int64_t b)
{
    double r = 1.0;
    int64_t exponent;
    int invert;
    if (b < 0) {
        invert = 1;
        exponent = -b;
    } else {
        invert = 0;
        exponent = b;
    }
    if (exponent > 0x10000)
        return pow(a, (double)b);
    while (exponent != 0) {
        if (exponent & 1)
            r *= a;
        exponent >>= 1;
        a *= a;
    }
    return invert ? 1.0 / r : r;
}

/* ------------------------------------------------------------ matrix exponential */

static void matmul(const double *a, const double *b, double *out, int64_t n)
{
    for (int64_t i = 0; i < n; i++) {
        for (int64_t j = 0; j < n; j++)
            out[i * n + j] = 0.0;
        for (int64_t k = 0; k < n; k++) {
            double aik = a[i * n + k];
            if (aik != 0.0) {
                for (int64_t j = 0; j < n; j++)
                    out[i * n + j] += aik * b[k * n + j];
            }
        }
    }
}

/* Maximum absolute column sum. */
static double norm1(const double *a, int64_t n)
{
    double best = 0.0;
    for (int64_t j = 0; j < n; j++) {
        double total = 0.0;
        for (int64_t i = 0; i < n; i++)
            total += fabs(a[i * n + j]);
        best = py_max(best, total);
    }
    return best;
}

/* ell(scale A, m) with power = 2m + 1: || |A|^p ||_1 by p vector-matrix products. */
static int64_t ell(const double *a, double scale, double norm_a, int64_t power, double recip,
                   double unit_roundoff, double *v, double *w, int64_t n)
{
    for (int64_t j = 0; j < n; j++)
        v[j] = 1.0;
    for (int64_t step = 0; step < power; step++) {
        for (int64_t j = 0; j < n; j++) {
            double total = 0.0;
            for (int64_t i = 0; i < n; i++)
                total += v[i] * fabs(a[i * n + j]);
            w[j] = scale * total;
        }
        for (int64_t j = 0; j < n; j++)
            v[j] = w[j];
    }
    double abs_norm = 0.0;
    for (int64_t j = 0; j < n; j++)
        abs_norm = py_max(abs_norm, v[j]);
    if (abs_norm == 0.0)
        return 0;
    double alpha = abs_norm / (scale * norm_a * recip);
    int64_t value = (int64_t)ceil(log2(alpha / unit_roundoff) / (double)(power - 1));
    return py_max_int(value, 0);
}

/* out (+)= sum_p c_p A^(2p) over p = 0 .. top, top the highest non-zero coefficient. */
static void polynomial(double *out, int add, const double *coefficients, const double *powers,
                       int64_t n)
{
    int64_t top = 1;
    for (int64_t p = 2; p < 5; p++) {
        if (coefficients[p] != 0.0)
            top = p;
    }
    for (int64_t i = 0; i < n; i++) {
        for (int64_t j = 0; j < n; j++) {
            double total = i == j ? coefficients[0] : 0.0;
            for (int64_t p = 1; p < top + 1; p++)
                total = coefficients[p] * powers[(p * n + i) * n + j] + total;
            out[i * n + j] = add ? out[i * n + j] + total : total;
        }
    }
}

/* q <- p^{-1} q by Gaussian elimination with partial pivoting (p destroyed). */
static void solve_in_place(double *p, double *q, int64_t n)
{
    for (int64_t col = 0; col < n; col++) {
        int64_t pivot = col;
        double biggest = fabs(p[col * n + col]);
        for (int64_t r = col + 1; r < n; r++) {
            if (fabs(p[r * n + col]) > biggest) {
                biggest = fabs(p[r * n + col]);
                pivot = r;
            }
        }
        if (pivot != col) {
            for (int64_t j = 0; j < n; j++) {
                double swap = p[col * n + j];
                p[col * n + j] = p[pivot * n + j];
                p[pivot * n + j] = swap;
                swap = q[col * n + j];
                q[col * n + j] = q[pivot * n + j];
                q[pivot * n + j] = swap;
            }
        }
        double inverse = 1.0 / p[col * n + col];
        for (int64_t r = col + 1; r < n; r++) {
            double factor = p[r * n + col] * inverse;
            if (factor != 0.0) {
                for (int64_t j = col + 1; j < n; j++)
                    p[r * n + j] -= factor * p[col * n + j];
                for (int64_t j = 0; j < n; j++)
                    q[r * n + j] -= factor * q[col * n + j];
            }
        }
    }
    for (int64_t col = n - 1; col >= 0; col--) {
        double inverse = 1.0 / p[col * n + col];
        for (int64_t j = 0; j < n; j++) {
            double total = q[col * n + j];
            for (int64_t k = col + 1; k < n; k++)
                total -= p[col * n + k] * q[k * n + j];
            q[col * n + j] = total * inverse;
        }
    }
}

/* expm_batch_kernel: result[k] = exp(matrices[k]), count matrices of n x n. work holds
 * 9 n^2 + 2 n doubles: powers (5 n^2), U, V and a scratch matrix (3 n^2), out (n^2),
 * v and w (n each). */
void dynamics_expm_batch(const double *matrices, int64_t count, int64_t n,
                         const double *coefficients, const double *theta, const int64_t *orders,
                         const double *ell_reciprocal, double unit_roundoff, double *result,
                         double *work)
{
    int64_t nn = n * n;
    double *powers = work;
    double *works = powers + 5 * nn;
    double *out = works + 3 * nn;
    double *v = out + nn;
    double *w = v + n;
    double *a = powers;
    for (int64_t k = 0; k < count; k++) {
        const double *matrix = matrices + k * nn;
        double *target = result + k * nn;
        if (k > 0) {
            int same = 1;
            for (int64_t i = 0; i < nn; i++) {
                if (matrix[i] != matrix[i - nn]) {
                    same = 0;
                    break;
                }
            }
            if (same) {
                memcpy(target, target - nn, (size_t)nn * sizeof(double));
                continue;
            }
        }
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                a[i * n + j] = matrix[j * n + i];
        for (int64_t step = 0; step < 3; step++)
            matmul(powers + (step ? 1 : 0) * nn, powers + step * nn, powers + (step + 1) * nn, n);
        double norm_a = norm1(a, n);
        if (norm_a == 0.0) {
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j < n; j++)
                    target[i * n + j] = i == j ? 1.0 : 0.0;
            continue;
        }
        double d6 = pow(norm1(powers + 3 * nn, n), 1.0 / 6.0);
        double eta = py_max(pow(norm1(powers + 2 * nn, n), 0.25), d6);
        int64_t choice = -1;
        int64_t s = 0;
        double d8 = 0.0;
        for (int64_t option = 0; option < 4; option++) {
            if (option == 2) {
                matmul(powers + 2 * nn, powers + 2 * nn, powers + 4 * nn, n);
                d8 = pow(norm1(powers + 4 * nn, n), 0.125);
                eta = py_max(d6, d8);
            }
            if (eta < theta[option]
                && ell(a, 1.0, norm_a, 2 * orders[option] + 1, ell_reciprocal[option],
                       unit_roundoff, v, w, n)
                       == 0) {
                choice = option;
                break;
            }
        }
        if (choice < 0) {
            choice = 4;
            matmul(powers + 2 * nn, powers + 3 * nn, works + 2 * nn, n);
            double eta5 = py_min(eta, py_max(d8, pow(norm1(works + 2 * nn, n), 0.1)));
            if (eta5 > 0.0)
                s = py_max_int((int64_t)ceil(log2(eta5 / theta[4])), 0);
            s += ell(a, int_power(2.0, -s), norm_a, 27, ell_reciprocal[4], unit_roundoff, v, w,
                     n);
            for (int64_t i = 0; i < n; i++) {
                for (int64_t j = 0; j < n; j++) {
                    powers[(1 * n + i) * n + j] *= int_power(2.0, -2 * s);
                    powers[(2 * n + i) * n + j] *= int_power(2.0, -4 * s);
                    powers[(3 * n + i) * n + j] *= int_power(2.0, -6 * s);
                    powers[(4 * n + i) * n + j] = int_power(2.0, -s) * a[i * n + j];
                }
            }
            /* U = B [B6 (b13 B6 + b11 B4 + b9 B2) + b7 B6 + ... + b1 I], V likewise */
            for (int64_t part = 0; part < 2; part++) {
                polynomial(out, 0, coefficients + (8 + 2 * part) * TABLE_POWERS, powers, n);
                matmul(powers + 3 * nn, out, works + part * nn, n);
                polynomial(works + part * nn, 1, coefficients + (9 + 2 * part) * TABLE_POWERS,
                           powers, n);
            }
        } else {
            for (int64_t part = 0; part < 2; part++)
                polynomial(works + part * nn, 0,
                           coefficients + (2 * choice + part) * TABLE_POWERS, powers, n);
        }
        /* U = A (odd part); r_m = (V - U)^{-1} (V + U) */
        matmul(choice == 4 ? powers + 4 * nn : a, works, works + 2 * nn, n);
        double *u = works + 2 * nn, *vv = works + nn, *scratch = works;
        for (int64_t i = 0; i < nn; i++) {
            scratch[i] = vv[i] - u[i];
            out[i] = vv[i] + u[i];
        }
        solve_in_place(scratch, out, n);
        for (int64_t step = 0; step < s; step++) {
            matmul(out, out, scratch, n);
            memcpy(out, scratch, (size_t)nn * sizeof(double));
        }
        for (int64_t i = 0; i < n; i++)
            for (int64_t j = 0; j < n; j++)
                target[i * n + j] = out[j * n + i];
    }
}

/* ------------------------------------------------------------------ LPV stepping */

/* read_smooth: bicubic read of history[0..newest] at fractional index position. */
static double read_smooth(const double *history, int64_t newest, double position)
{
    if (position <= 0.0)
        return history[0];
    int64_t n = (int64_t)floor(position);
    if (n >= newest)
        return history[newest];
    double d = position - n;
    int64_t i_m1 = n >= 1 ? n - 1 : 0;
    int64_t i_1 = n + 1 <= newest ? n + 1 : newest;
    int64_t i_2 = n + 2 <= newest ? n + 2 : newest;
    /* bicubic_weights(d) */
    double e = 1.0 - d;
    double a = -0.5 * d * e * e;
    double b = 1.5 * d * d * d - 2.5 * d * d + 1.0;
    double c = 1.5 * e * e * e - 2.5 * e * e + 1.0;
    double w = -0.5 * d * d * e;
    return a * history[i_m1] + b * history[n] + c * history[i_1] + w * history[i_2];
}

/* read_held: mean of a delayed staircase over one sample from position. */
static double read_held(const double *history, int64_t newest, double position)
{
    if (position <= 0.0)
        return history[0];
    int64_t n = (int64_t)floor(position);
    if (n >= newest)
        return history[newest];
    double d = position - n;
    return (1.0 - d) * history[n] + d * history[n + 1];
}

/* simulate_lpv_kernel. Per-sample arrays have n_phi, n_gamma (also gamma_ramp's), n_c,
 * n_d matrices (1: shared). smooth and held are n_delay x width zeros (width =
 * history_pad + n_samples); work holds n_u + 2 n_x + 2 n_delay doubles. states and
 * outputs receive n_samples rows. */
void dynamics_simulate_lpv(const double *phi, int64_t n_phi, const double *gamma,
                           const double *gamma_ramp, int64_t n_gamma, const double *c,
                           int64_t n_c, const double *d, int64_t n_d, const double *inputs,
                           int64_t n_samples, int64_t n_x, int64_t n_u, int64_t n_y,
                           const double *x0, const int64_t *delay_inputs,
                           const int64_t *delay_outputs, int64_t n_delay,
                           const double *delay_samples, int64_t history_pad,
                           const uint8_t *held_state, int64_t history_initial, double *smooth,
                           double *held, double *work, double *states, double *outputs)
{
    int64_t width = history_pad + n_samples;
    double *u = work;
    double *x = u + n_u;
    double *x_next = x + n_x;
    double *smooth_now = x_next + n_x;
    double *smooth_next = smooth_now + n_delay;
    for (int64_t r = 0; r < n_x; r++)
        x[r] = x0[r];
    for (int64_t i = 0; i < n_delay; i++) {
        smooth_now[i] = 0.0;
        smooth_next[i] = 0.0;
    }
    for (int64_t k = 0; k < n_samples; k++) {
        const double *phi_k = phi + (n_phi > 1 ? k : 0) * n_x * n_x;
        const double *gamma_k = gamma + (n_gamma > 1 ? k : 0) * n_x * n_u;
        const double *ramp_k = gamma_ramp + (n_gamma > 1 ? k : 0) * n_x * n_u;
        const double *c_k = c + (n_c > 1 ? k : 0) * n_y * n_x;
        const double *d_k = d + (n_d > 1 ? k : 0) * n_y * n_u;
        for (int64_t j = 0; j < n_u; j++)
            u[j] = inputs[k * n_u + j];
        int64_t newest = history_pad + k;
        for (int64_t r = 0; r < n_x; r++)
            states[k * n_x + r] = x[r];
        /* lpv_output_step */
        const double *delay_now = delay_samples + k * n_delay;
        int fill_past = k == 0 && history_initial;
        for (int64_t i = 0; i < n_delay; i++) {
            int64_t r = delay_outputs[i];
            double acc = 0.0;
            double held_value = 0.0;
            for (int64_t j = 0; j < n_x; j++) {
                if (held_state[j])
                    held_value += c_k[r * n_x + j] * x[j];
                else
                    acc += c_k[r * n_x + j] * x[j];
            }
            smooth[i * width + newest] = acc;
            for (int64_t j = 0; j < n_u; j++) {
                if (j != delay_inputs[i])
                    held_value += d_k[r * n_u + j] * u[j];
            }
            held[i * width + newest] = held_value;
            if (fill_past) {
                for (int64_t j = 0; j < newest; j++) {
                    smooth[i * width + j] = acc;
                    held[i * width + j] = held_value;
                }
                smooth_now[i] = acc;
            }
            double position = newest - delay_now[i];
            u[delay_inputs[i]] = smooth_now[i] + read_held(held + i * width, newest, position);
        }
        for (int64_t r = 0; r < n_y; r++) {
            double acc = 0.0;
            for (int64_t j = 0; j < n_x; j++)
                acc += c_k[r * n_x + j] * x[j];
            for (int64_t j = 0; j < n_u; j++)
                acc += d_k[r * n_u + j] * u[j];
            outputs[k * n_y + r] = acc;
        }
        if (k == n_samples - 1)
            break;
        /* lpv_state_step */
        const double *delay_next = delay_samples + (k + 1) * n_delay;
        for (int64_t i = 0; i < n_delay; i++) {
            double position = newest + 1.0 - delay_next[i];
            smooth_next[i] = read_smooth(smooth + i * width, newest, position);
        }
        for (int64_t r = 0; r < n_x; r++) {
            double acc = 0.0;
            for (int64_t j = 0; j < n_x; j++)
                acc += phi_k[r * n_x + j] * x[j];
            for (int64_t j = 0; j < n_u; j++)
                acc += gamma_k[r * n_u + j] * u[j];
            for (int64_t i = 0; i < n_delay; i++)
                acc += ramp_k[r * n_u + delay_inputs[i]] * (smooth_next[i] - smooth_now[i]);
            x_next[r] = acc;
        }
        for (int64_t r = 0; r < n_x; r++)
            x[r] = x_next[r];
        for (int64_t i = 0; i < n_delay; i++)
            smooth_now[i] = smooth_next[i];
    }
}
