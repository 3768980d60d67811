/* The saturated pixels' censored Laplace terms (models/likelihood.py, _CensoredSum; models/texel_energy.py) in one
 * pass, with their derivatives: compiled on first use by render/native.py (the package's one loader).
 *
 * For particle i and saturated value m (pixel k = m / C, channel c), with t = (level_m - r_im) / (s_i g_k):
 *   log S = log P(noise / scale >= t) = -t - log 2 (t >= 0), log(1 - e^t / 2) (t < 0)
 *   d log S / dt = -1 (t >= 0), 1 - 1 / S (t < 0)
 * total [i] = sum_m w_k log S,  dsig [i] = d total / d s_i = -sum_m w_k (d log S / dt) t / s_i,
 * terms [i, k] = sum_c w_k log S (optional, double), grad [i, m] = d total / d r_im = -w_k (d log S / dt) / (s_i g_k)
 * (optional). In double inside whatever REAL is; each particle is one thread's, in a fixed order, so the sums do
 * not depend on the thread count. Built with -ffast-math for glibc's vector exp and log1p: the inputs are finite
 * renders and levels, and both branches are computed with e^min(t, 0), so nothing overflows.
 */
#include <math.h>
#include <omp.h>
#include <stdint.h>

#include <stdlib.h>

/* Particle i's values: the sums into *tot and *dt, and grad and terms where asked. Inlined with WITHG, WITHGRAD and
 * WITHPER constant (bb_censored_laplace's eight cases), so that the vector loop has no test of a null pointer: with
 * one, GCC loads g[m] (or stores) under a mask that is all false, from address 0 + m, and on AMD's cores such a
 * masked access of an unmapped page takes a microcode assist (measured: 70 % of the kernel's time, 2.5 ms for 20
 * particles x 5174 saturated pixels on 2 cores) */
static inline __attribute__((always_inline)) void particle(const int WITHG, const int WITHGRAD, const int WITHPER,
                                                           int64_t M, const REAL *restrict ri,
                                                           const REAL *restrict level, double si,
                                                           const REAL *restrict g, const REAL *restrict w,
                                                           REAL *restrict gi, double *restrict per, double *out_tot,
                                                           double *out_dt)
{
    const double ln2 = log(2.0), is = 1 / si;
    double tot = 0, dt = 0;
#pragma omp simd reduction(+ : tot, dt)
    for (int64_t m = 0; m < M; m++) {
        const double isc = WITHG ? is / (double)g[m] : is, wm = (double)w[m];
        const double t = ((double)level[m] - (double)ri[m]) * isc;
        const double e = exp(t < 0 ? t : 0), S = 1 - 0.5 * e;
        const double ls = t >= 0 ? -t - ln2 : log1p(-0.5 * e);
        const double d = t >= 0 ? -1.0 : 1 - 1 / S;
        tot += wm * ls;
        dt += wm * d * t;
        if (WITHGRAD)
            gi[m] = (REAL)(-wm * d * isc);
        if (WITHPER)
            per[m] = wm * ls;
    }
    *out_tot = tot;
    *out_dt = dt;
}

/* w [K C] and g [K C] (or NULL) per value, repeated over each pixel's channels: one flat vector loop. 0 on
 * success, 1 when out of memory */
int bb_censored_laplace(int64_t n, int64_t K, int64_t C, int64_t nthreads, const REAL *restrict r,
                        const REAL *restrict level, const double *restrict s, const REAL *restrict g,
                        const REAL *restrict w, double *restrict total, double *restrict dsig,
                        double *restrict terms, REAL *restrict grad)
{
    const int64_t M = K * C;
    const int cases = (g != 0) * 4 + (grad != 0) * 2 + (terms != 0);
    int failed = 0;
#pragma omp parallel for schedule(static) num_threads(nthreads) reduction(| : failed)
    for (int64_t i = 0; i < n; i++) {
        const REAL *restrict ri = r + i * M;
        REAL *restrict gi = grad ? grad + i * M : NULL;
        double *restrict per = terms ? malloc(M * sizeof(double)) : NULL;
        if (terms && !per) {
            failed = 1;
            continue;
        }
        double tot, dt;
#define BB_PARTICLE(G_, GRAD_, PER_) particle(G_, GRAD_, PER_, M, ri, level, s[i], g, w, gi, per, &tot, &dt)
        switch (cases) {
        case 0: BB_PARTICLE(0, 0, 0); break;
        case 1: BB_PARTICLE(0, 0, 1); break;
        case 2: BB_PARTICLE(0, 1, 0); break;
        case 3: BB_PARTICLE(0, 1, 1); break;
        case 4: BB_PARTICLE(1, 0, 0); break;
        case 5: BB_PARTICLE(1, 0, 1); break;
        case 6: BB_PARTICLE(1, 1, 0); break;
        default: BB_PARTICLE(1, 1, 1); break;
        }
#undef BB_PARTICLE
        if (per) {
            for (int64_t k = 0; k < K; k++) {
                double lt = 0;
                for (int64_t c = 0; c < C; c++)
                    lt += per[k * C + c];
                terms[i * K + k] = lt;
            }
            free(per);
        }
        total[i] = tot;
        dsig[i] = -dt * (1 / s[i]);
    }
    return failed;
}
