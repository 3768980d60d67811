/* The interval bijection x = lo + w sigmoid(u) with its log-Jacobian, forward and backward in one pass each
 * (compiled on first use by render/native.py, the package's one loader of C sources; used by potential.py).
 *
 * Forward, for particles i and their m coordinates u[i, :]:
 *     s = sigmoid(u),  x = lo + w s,  ladj[i] = sum_j log(w s (1 - s))
 * with log s (1 - s) = -|u| - 2 log1p(exp(-|u|)), stable at saturation; s is kept for the backward. The log1p
 * terms are summed as the log of their product over runs of 8 coordinates a lane (each factor 1 + exp(-|u|) is in
 * (1, 2], so the product is finite): one log per 8 coordinates instead of a log1p each (2x faster; the sum
 * within float32 rounding of the per-term one).
 * bb_interval_map: x alone, the same values.
 * Backward, given dL/dx (gx) and dL/dladj (gl[i]):
 *     du = gx w s (1 - s) + gl[i] (1 - 2 s)
 * written with a row stride, so that each site's gradient goes straight into its columns of dL/dz.
 * Parallel over particles, one particle's sum in one thread in a fixed order (the result does not depend on
 * the thread count); SIMD inside.
 */
#include <tgmath.h> /* exp, log1p of REAL (float: expf, log1pf) */
#include <omp.h>
#include <stdint.h>

/* sigmoid(u), and t = e^-|u| (which the log-Jacobian reuses): the one expression of the forward and the map */
static inline REAL sigmoid_t(REAL u, REAL *t)
{
    const REAL a = u < 0 ? -u : u;
    *t = exp(-a);
    const REAL inv = (REAL)1 / ((REAL)1 + *t);
    return u >= 0 ? inv : *t * inv;
}

void bb_interval_fwd(int64_t n, int64_t m, int64_t us, double lo, double w, int64_t nt, const REAL *restrict u,
                     REAL *restrict x, REAL *restrict s, double *restrict ladj)
{
    const REAL rlo = (REAL)lo, rw = (REAL)w;
    const double logw = log(w) * (double)m;   /* w: double, so log is double */
#pragma omp parallel for num_threads(nt) schedule(static)
    for (int64_t i = 0; i < n; i++) {
        const REAL *restrict ui = u + i * us;   /* us: u's row stride (a slice of z) */
        REAL *restrict xi = x + i * m, *restrict si = s + i * m;
        double acc = 0.0;
        /* blocks of 4096: a float sum per block, a double sum over blocks; inside, runs of 64 (8 lanes x 8) */
        for (int64_t b = 0; b < m; b += 4096) {
            const int64_t e = b + 4096 < m ? b + 4096 : m;
            REAL part = 0;
            int64_t j = b;
            for (; j + 64 <= e; j += 64) {
                REAL prod[8] = {1, 1, 1, 1, 1, 1, 1, 1}, sa[8] = {0};
                for (int64_t k = 0; k < 64; k += 8) {
#pragma omp simd
                    for (int l = 0; l < 8; l++) {
                        const REAL uj = ui[j + k + l];
                        REAL t;
                        const REAL sj = sigmoid_t(uj, &t);
                        si[j + k + l] = sj;
                        xi[j + k + l] = rlo + rw * sj;
                        prod[l] *= (REAL)1 + t;
                        sa[l] += uj < 0 ? -uj : uj;
                    }
                }
#pragma omp simd reduction(+ : part)
                for (int l = 0; l < 8; l++) part += -sa[l] - (REAL)2 * log(prod[l]);
            }
            for (; j < e; j++) {
                REAL t;
                const REAL sj = sigmoid_t(ui[j], &t);
                si[j] = sj;
                xi[j] = rlo + rw * sj;
                part += -(ui[j] < 0 ? -ui[j] : ui[j]) - (REAL)2 * log1p(t);
            }
            acc += (double)part;
        }
        ladj[i] = acc + logw;
    }
}

/* x = lo + w sigmoid(u) alone, by bb_interval_fwd's expression (sigmoid_t): for values that need no gradient
 * and no log-Jacobian (IntervalBijection.__call__ without a graph: a texel sweep's renders, the outputs' maps).
 * In one thread below torch's grain size (32768 values), as torch.sigmoid, which it replaces, ran there: a small
 * fit's sweep calls it six times a step, and waking the other thread costs more than the work (and much more when
 * another process holds the cores) */
void bb_interval_map(int64_t n, int64_t m, int64_t us, double lo, double w, int64_t nt, const REAL *restrict u,
                     REAL *restrict x)
{
    const REAL rlo = (REAL)lo, rw = (REAL)w;
#pragma omp parallel for num_threads(nt) schedule(static) if (n * m >= 32768)
    for (int64_t i = 0; i < n; i++) {
        const REAL *restrict ui = u + i * us;
        REAL *restrict xi = x + i * m;
#pragma omp simd
        for (int64_t j = 0; j < m; j++) {
            REAL t;
            xi[j] = rlo + rw * sigmoid_t(ui[j], &t);
        }
    }
}

void bb_interval_bwd(int64_t n, int64_t m, int64_t gs, double w, int64_t nt, const REAL *restrict s,
                     const REAL *restrict gx, const REAL *restrict gl, REAL *restrict gu)
{
    const REAL rw = (REAL)w;
#pragma omp parallel for num_threads(nt) schedule(static)
    for (int64_t i = 0; i < n; i++) {
        const REAL *restrict si = s + i * m;
        REAL *restrict gi = gu + i * gs;   /* gs: gu's row stride (the site's columns of the whole gradient) */
        const REAL gli = gl ? gl[i] : (REAL)0;
        if (gx) {
            const REAL *restrict gxi = gx + i * m;
#pragma omp simd
            for (int64_t j = 0; j < m; j++)
                gi[j] = gxi[j] * (rw * si[j] * ((REAL)1 - si[j])) + gli * ((REAL)1 - (REAL)2 * si[j]);
        } else {
#pragma omp simd
            for (int64_t j = 0; j < m; j++)
                gi[j] = gli * ((REAL)1 - (REAL)2 * si[j]);
        }
    }
}
