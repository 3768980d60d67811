/* Per-pixel KDE entropy for bayes_brdf.guidance (compiled on first use by render/native.py's builder).
 *
 * x is [n, cols]: n particle renders of cols pixel values. For every column j:
 *   bandwidth (Eq. 20): bw = 0.9 n^(-1/5) min(sd, IQR / 1.34)   (sd alone when the IQR is 0),
 *                       bw^2 += noise_var (the KDE of R + render noise), bw >= min_bw;
 *   entropy of the 1-D Gaussian KDE p (Eq. 19):
 *     mode 0: single-sample Monte Carlo (Eq. 21): r = v[c] + bw e with c = floor(u n), h = -log p(r);
 *     mode 1: Gauss-Hermite quadrature of -(1/n) sum_c E_{N(v_c, bw^2)}[log p], nq nodes tq, weights wq
 *             (probabilists' nodes, weights summing to 1): deterministic.
 * Outputs h[j] (nats) and sd[j] (sample std, Bessel-corrected).
 *
 * Built with -ffast-math so that exp/log vectorise (glibc's libmvec); no value here is inf or NaN.
 * Columns are the SIMD lanes: a block of B columns is processed together (x is already laid out with
 * columns contiguous), and the quartiles come from branch-free ranks instead of a sort.
 */
#include <tgmath.h> /* floor, sqrt, log at the precision of REAL (float stays float) */
#include <stdint.h>
#include <string.h>

#ifndef REAL
#define REAL double
#endif
#define NMAX 128
#define B 64
/* exp's argument clamped at EXP_LO (<= 0 here): e^-80 is below the rounding of the sum it enters (which has a term
 * of 1), and glibc's vector exp takes a scalar path for the whole vector when one lane's argument is below about
 * -87 (float; -708 double): far renders under a narrow bandwidth */
#define EXP_LO ((REAL)-80)

int64_t bb_kde_nmax(void) { return NMAX; }

/* log p(r) for the B lanes, r given per lane */
static inline void log_kde(REAL (*restrict v)[B], int64_t n, const REAL *restrict r, const REAL *restrict inv2,
                           const REAL *restrict lognorm,
                           REAL *restrict out)
{
    REAL mn[B], s[B];
#pragma omp simd
    for (int jj = 0; jj < B; ++jj) { mn[jj] = (REAL)3e38; s[jj] = 0; }
    for (int64_t i = 0; i < n; ++i) {
#pragma omp simd
        for (int jj = 0; jj < B; ++jj) { REAL d = r[jj] - v[i][jj]; d *= d; mn[jj] = d < mn[jj] ? d : mn[jj]; }
    }
    for (int64_t i = 0; i < n; ++i) {
#pragma omp simd
        for (int jj = 0; jj < B; ++jj) {
            const REAL d = r[jj] - v[i][jj], a = -(d * d - mn[jj]) * inv2[jj];
            s[jj] += exp(a > EXP_LO ? a : EXP_LO);
        }
    }
#pragma omp simd
    for (int jj = 0; jj < B; ++jj) out[jj] = -mn[jj] * inv2[jj] + log(s[jj]) - lognorm[jj];
}

void bb_kde_entropy(int64_t mode, int64_t n, int64_t cols, int64_t nq, int64_t nthreads,
                    const REAL *x, const REAL *u, const REAL *e, const double *tq, const double *wq,
                    double noise_var, double min_bw, REAL *h, REAL *sd_out)
{
    const REAL LOG_SQRT_2PI = (REAL)0.91893853320467274178;
    const REAL fac = (REAL)(0.9 * pow((double)n, -0.2));
    const REAL nv = (REAL)noise_var, mb2 = (REAL)(min_bw * min_bw), logn = (REAL)log((double)n);
    /* quartile positions (linear interpolation, as numpy/torch quantile) */
    const double p25 = 0.25 * (double)(n - 1), p75 = 0.75 * (double)(n - 1);
    const int64_t l25 = (int64_t)p25, l75 = (int64_t)p75;
    const int64_t h25 = l25 + 1 < n ? l25 + 1 : n - 1, h75 = l75 + 1 < n ? l75 + 1 : n - 1;
    const REAL f25 = (REAL)(p25 - (double)l25), f75 = (REAL)(p75 - (double)l75);
    const int64_t nblocks = (cols + B - 1) / B;
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t b = 0; b < nblocks; ++b) {
        const int64_t j0 = b * B;
        const int m = (int)(cols - j0 < B ? cols - j0 : B);
        REAL v[NMAX][B];
        int rank[NMAX][B];
        REAL mean[B], sd[B], a25[B], b25[B], a75[B], b75[B], inv2[B], lognorm[B], bw[B], r[B], lp[B], acc[B];
        for (int64_t i = 0; i < n; ++i) {
            const REAL *row = x + i * cols + j0;
            for (int jj = 0; jj < B; ++jj) v[i][jj] = jj < m ? row[jj] : (REAL)0;
        }
#pragma omp simd
        for (int jj = 0; jj < B; ++jj) { mean[jj] = 0; sd[jj] = 0; a25[jj] = b25[jj] = a75[jj] = b75[jj] = 0; }
        for (int64_t i = 0; i < n; ++i) {
#pragma omp simd
            for (int jj = 0; jj < B; ++jj) mean[jj] += v[i][jj];
        }
#pragma omp simd
        for (int jj = 0; jj < B; ++jj) mean[jj] /= (REAL)n;
        for (int64_t i = 0; i < n; ++i) {  /* centre the values: keeps float precision when they agree */
#pragma omp simd
            for (int jj = 0; jj < B; ++jj) { REAL d = v[i][jj] - mean[jj]; v[i][jj] = d; sd[jj] += d * d; }
        }
        /* ranks (ties broken by index): value of rank k is the k-th order statistic */
        for (int64_t i = 0; i < n; ++i) {
#pragma omp simd
            for (int jj = 0; jj < B; ++jj) rank[i][jj] = 0;
            for (int64_t k = 0; k < n; ++k) {
                const int before = k < i;
#pragma omp simd
                for (int jj = 0; jj < B; ++jj)
                    rank[i][jj] += (v[k][jj] < v[i][jj]) | ((v[k][jj] == v[i][jj]) & before);
            }
#pragma omp simd
            for (int jj = 0; jj < B; ++jj) {
                const int rk = rank[i][jj];
                const REAL x_ = v[i][jj];
                a25[jj] += rk == l25 ? x_ : 0; b25[jj] += rk == h25 ? x_ : 0;
                a75[jj] += rk == l75 ? x_ : 0; b75[jj] += rk == h75 ? x_ : 0;
            }
        }
#pragma omp simd
        for (int jj = 0; jj < B; ++jj) {
            REAL s = n > 1 ? sqrt(sd[jj] / (REAL)(n - 1)) : 0;
            REAL iqr = (a75[jj] + f75 * (b75[jj] - a75[jj])) - (a25[jj] + f25 * (b25[jj] - a25[jj]));
            REAL q = iqr / (REAL)1.34;
            REAL a = (q > 0 && q < s) ? q : s;
            REAL bw2 = fac * a * fac * a + nv;
            bw2 = bw2 < mb2 ? mb2 : bw2;
            sd[jj] = s;
            bw[jj] = sqrt(bw2);
            inv2[jj] = (REAL)0.5 / bw2;
            lognorm[jj] = logn + log(bw[jj]) + LOG_SQRT_2PI;
            acc[jj] = 0;
        }
        if (mode == 0) {
            int c[B];
            for (int jj = 0; jj < B; ++jj) {
                int64_t ci = jj < m ? (int64_t)((double)u[j0 + jj] * (double)n) : 0;
                c[jj] = (int)(ci < 0 ? 0 : (ci >= n ? n - 1 : ci));
                r[jj] = jj < m ? bw[jj] * e[j0 + jj] : 0;
            }
            for (int64_t i = 0; i < n; ++i) {
#pragma omp simd
                for (int jj = 0; jj < B; ++jj) r[jj] += c[jj] == i ? v[i][jj] : 0;
            }
            log_kde(v, n, r, inv2, lognorm, lp);
#pragma omp simd
            for (int jj = 0; jj < B; ++jj) acc[jj] = -lp[jj];
        } else {
            for (int64_t ci = 0; ci < n; ++ci)
                for (int64_t q = 0; q < nq; ++q) {
                    const REAL t = (REAL)tq[q], w = (REAL)(wq[q] / (double)n);
#pragma omp simd
                    for (int jj = 0; jj < B; ++jj) r[jj] = v[ci][jj] + bw[jj] * t;
                    log_kde(v, n, r, inv2, lognorm, lp);
#pragma omp simd
                    for (int jj = 0; jj < B; ++jj) acc[jj] -= w * lp[jj];
                }
        }
        for (int jj = 0; jj < m; ++jj) {
            h[j0 + jj] = acc[jj];
            if (sd_out) sd_out[j0 + jj] = sd[jj];
        }
    }
}
