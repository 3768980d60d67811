/* The proposal densities of the texel-local move (texel_moves.py), one texel at a time; compiled on first use by
 * render/native.py. The same arithmetic as texel_moves._local_scale and texel_moves._log_q (the torch reference,
 * which runs where this does not: CUDA, no compiler), in double inside, without the [T, a, b] temporaries.
 *
 * Per texel t of group g (inputs texel-major and contiguous: each texel's particles are adjacent):
 *   c [G, T, b, k]  the other half's values (the kernel density's centres)
 *   x [G, T, a, k]  the points to score
 *   h [G, T, k]     bb_texel_scale: bw * the median over the b centres of |c_i - c_nn(i)| per coordinate, nn(i) the
 *                   nearest other centre (Euclidean; the first on ties), at least hmin; the median of an even count
 *                   is the lower middle value (torch.median's)
 *   logq [G, T, a]  bb_texel_logq: log((1 - defensive) KDE(x) + defensive prod_k logistic(x_k)), KDE the equal
 *                   mixture of N(c_j, diag h^2)
 * Texels are independent: OpenMP over them, no reduction across threads, so the results do not depend on the
 * thread count.
 */
#include <float.h>
#include <math.h>
#include <omp.h>
#include <stdint.h>

#define KMAX 8
#define BMAX 256

/* h [G, T, k] from the centres c [G, T, b, k]; 0 on success, 1 when k or b exceed the kernel's bounds (the caller
 * then uses the torch reference) */
int bb_texel_scale(int64_t G, int64_t T, int64_t b, int64_t k, int64_t nthreads, const REAL *c, double bw,
                   double hmin, REAL *h)
{
    if (k > KMAX || b > BMAX || b < 2)
        return 1;
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t gt = 0; gt < G * T; gt++) {
        const REAL *C = c + gt * b * k;
        double dist[KMAX][BMAX];
        for (int64_t i = 0; i < b; i++) {
            int64_t nn = -1;
            double best = DBL_MAX;
            for (int64_t j = 0; j < b; j++) {
                if (j == i)
                    continue;
                double d2 = 0;
                for (int64_t q = 0; q < k; q++) {
                    const double d = (double)C[i * k + q] - (double)C[j * k + q];
                    d2 += d * d;
                }
                if (d2 < best) { best = d2; nn = j; }
            }
            for (int64_t q = 0; q < k; q++)
                dist[q][i] = (REAL)fabs((double)C[i * k + q] - (double)C[nn * k + q]);
        }
        for (int64_t q = 0; q < k; q++) {
            double *v = dist[q];
            for (int64_t i = 1; i < b; i++) {          /* insertion sort: b is half an ensemble */
                const double key = v[i];
                int64_t j = i - 1;
                while (j >= 0 && v[j] > key) { v[j + 1] = v[j]; j--; }
                v[j + 1] = key;
            }
            const REAL hq = (REAL)(v[(b - 1) / 2] * bw);
            h[gt * k + q] = hq < (REAL)hmin ? (REAL)hmin : hq;
        }
    }
    return 0;
}

/* logq [G, T, a] at x [G, T, a, k] for the centres c [G, T, b, k] and widths h [G, T, k]; 0 on success, 1 when k or
 * b exceed the kernel's bounds. Built with -ffast-math (native.py's flags for this file): the exponentials and
 * logarithms run as vector loops over a block of PB points (glibc's libmvec), not one call per value */
#define PB 16
int bb_texel_logq(int64_t G, int64_t T, int64_t a, int64_t b, int64_t k, int64_t nthreads, const REAL *c,
                  const REAL *x, const REAL *h, double defensive, REAL *logq)
{
    if (k > KMAX || b > BMAX)
        return 1;
    const double l_kde = log1p(-defensive), l_def = log(defensive), half_log2pi = 0.5 * log(2 * M_PI);
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t gt = 0; gt < G * T; gt++) {
        const REAL *C = c + gt * b * k, *X = x + gt * a * k, *H = h + gt * k;
        double lognorm = log((double)b) + k * half_log2pi, ih[KMAX], cs[KMAX][BMAX];
        for (int64_t q = 0; q < k; q++) {
            lognorm += log((double)H[q]);
            ih[q] = 1 / (double)H[q];
            for (int64_t j = 0; j < b; j++)
                cs[q][j] = (double)C[j * k + q] * ih[q];   /* the centres in units of the widths */
        }
        for (int64_t p0 = 0; p0 < a; p0 += PB) {
            const int64_t np = a - p0 < PB ? a - p0 : PB;
            double lp[PB * BMAX], m[PB], sum[PB], u[PB], v[PB], ax[PB * KMAX], ex[PB * KMAX];
            for (int64_t i = 0; i < np * k; i++)
                ax[i] = fabs((double)X[p0 * k + i]);
#pragma omp simd
            for (int64_t i = 0; i < np * k; i++)
                ex[i] = log1p(exp(-ax[i]));               /* log logistic(u) = -|u| - 2 log(1 + e^-|u|) */
            for (int64_t p = 0; p < np; p++) {
                const REAL *xp = X + (p0 + p) * k;
                double *l = lp + p * b, wide = 0;
                for (int64_t j = 0; j < b; j++)
                    l[j] = 0;
                for (int64_t q = 0; q < k; q++) {
                    const double xq = (double)xp[q] * ih[q];
#pragma omp simd
                    for (int64_t j = 0; j < b; j++) {
                        const double d = xq - cs[q][j];
                        l[j] -= 0.5 * d * d;
                    }
                    wide -= ax[p * k + q] + 2 * ex[p * k + q];
                }
                double mm = -DBL_MAX;
                for (int64_t j = 0; j < b; j++)
                    mm = l[j] > mm ? l[j] : mm;
                m[p] = mm;
                v[p] = l_def + wide;
                for (int64_t j = 0; j < b; j++)
                    l[j] -= mm;
            }
#pragma omp simd
            for (int64_t i = 0; i < np * b; i++)         /* the block's exponentials in one vector loop */
                lp[i] = exp(lp[i]);
            for (int64_t p = 0; p < np; p++) {
                double s = 0;
                for (int64_t j = 0; j < b; j++)
                    s += lp[p * b + j];
                sum[p] = s;
            }
#pragma omp simd
            for (int64_t p = 0; p < np; p++)
                u[p] = l_kde + m[p] + log(sum[p]) - lognorm;
#pragma omp simd
            for (int64_t p = 0; p < np; p++) {         /* logaddexp(u, v) */
                const double hi = u[p] > v[p] ? u[p] : v[p], lo = u[p] > v[p] ? v[p] : u[p];
                logq[gt * a + p0 + p] = (REAL)(hi + log1p(exp(lo - hi)));
            }
        }
    }
    return 0;
}
