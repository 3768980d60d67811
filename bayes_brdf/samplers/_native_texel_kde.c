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
 * bb_texel_propose and bb_texel_accept are the whole move of one half (texel_moves._move_native): the proposal
 * drawn, both log densities, and the Metropolis decision, reading the particles in place (no [G, T, b, k] copies)
 * and drawing from a counter-based generator (one seed per call from torch's; each draw a hash of the seed and its
 * particle, texel and index), so they need no torch random tensors either.
 * Texels are independent: OpenMP over them, no reduction across threads but integer counts, so the results do not
 * depend on the thread count.
 */
#include <float.h>
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <string.h>

#define KMAX 8
#define BMAX 256
#define PB 16

/* h [k] for one texel: bw * the median over its b centres C [b, k] of |c_i - c_nn(i)| per coordinate, at least hmin */
static void texel_scale(const double *C, int64_t b, int64_t k, double bw, double hmin, double *h)
{
    double dist[KMAX][BMAX];
    for (int64_t i = 0; i < b; i++) {
        int64_t nn = -1;
        double best = DBL_MAX;
        for (int64_t j = 0; j < b; j++) {
            if (j == i)
                continue;
            double d2 = 0;
            for (int64_t q = 0; q < k; q++) {
                const double d = C[i * k + q] - C[j * k + q];
                d2 += d * d;
            }
            if (d2 < best) { best = d2; nn = j; }
        }
        for (int64_t q = 0; q < k; q++)
            dist[q][i] = (REAL)fabs(C[i * k + q] - C[nn * k + q]);
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
        h[q] = hq < (REAL)hmin ? (REAL)hmin : hq;
    }
}

/* The kernel density of one texel, ready to score points: centres in units of the widths, the inverse widths and
 * the log normaliser */
typedef struct { double cs[KMAX][BMAX], ih[KMAX], lognorm; int64_t b, k; } Kde;

static void kde_init(Kde *K, const double *C, const double *h, int64_t b, int64_t k)
{
    K->b = b; K->k = k;
    K->lognorm = log((double)b) + k * 0.5 * log(2 * M_PI);
    for (int64_t q = 0; q < k; q++) {
        K->lognorm += log(h[q]);
        K->ih[q] = 1 / h[q];
        for (int64_t j = 0; j < b; j++)
            K->cs[q][j] = C[j * k + q] * K->ih[q];
    }
}

/* logq [n] at the points X [n, k]: log((1 - defensive) KDE(x) + defensive prod_k logistic(x_k)). Built with
 * -ffast-math (native.py's flags for this file): the exponentials and logarithms run as vector loops over a block
 * of PB points (glibc's libmvec), not one call per value */
static void kde_logq(const Kde *K, const double *X, int64_t n, double defensive, double *logq)
{
    const int64_t b = K->b, k = K->k;
    const double l_kde = log1p(-defensive), l_def = log(defensive);
    for (int64_t p0 = 0; p0 < n; p0 += PB) {
        const int64_t np = n - p0 < PB ? n - p0 : PB;
        double lp[PB * BMAX], m[PB], sum[PB], u[PB], v[PB], ax[PB * KMAX], ex[PB * KMAX];
        for (int64_t i = 0; i < np * k; i++)
            ax[i] = fabs(X[p0 * k + i]);
#pragma omp simd
        for (int64_t i = 0; i < np * k; i++)
            ex[i] = log1p(exp(-ax[i]));               /* log logistic(u) = -|u| - 2 log(1 + e^-|u|) */
        for (int64_t p = 0; p < np; p++) {
            const double *xp = X + (p0 + p) * k;
            double *l = lp + p * b, wide = 0;
            for (int64_t j = 0; j < b; j++)
                l[j] = 0;
            for (int64_t q = 0; q < k; q++) {
                const double xq = xp[q] * K->ih[q];
#pragma omp simd
                for (int64_t j = 0; j < b; j++) {
                    const double d = xq - K->cs[q][j];
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
            u[p] = l_kde + m[p] + log(sum[p]) - K->lognorm;
#pragma omp simd
        for (int64_t p = 0; p < np; p++) {         /* logaddexp(u, v) */
            const double hi = u[p] > v[p] ? u[p] : v[p], lo = u[p] > v[p] ? v[p] : u[p];
            logq[p0 + p] = hi + log1p(exp(lo - hi));
        }
    }
}

/* h [G, T, k] from the centres c [G, T, b, k]; 0 on success, 1 when k or b exceed the kernel's bounds (the caller
 * then uses the torch reference) */
int bb_texel_scale(int64_t G, int64_t T, int64_t b, int64_t k, int64_t nthreads, const REAL *c, double bw,
                   double hmin, REAL *h)
{
    if (k > KMAX || b > BMAX || b < 2)
        return 1;
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t gt = 0; gt < G * T; gt++) {
        double C[BMAX * KMAX], H[KMAX];
        for (int64_t i = 0; i < b * k; i++)
            C[i] = (double)c[gt * b * k + i];
        texel_scale(C, b, k, bw, hmin, H);
        for (int64_t q = 0; q < k; q++)
            h[gt * k + q] = (REAL)H[q];
    }
    return 0;
}

/* logq [G, T, a] at x [G, T, a, k] for the centres c [G, T, b, k] and widths h [G, T, k]; 0 on success, 1 when k or
 * b exceed the kernel's bounds */
int bb_texel_logq(int64_t G, int64_t T, int64_t a, int64_t b, int64_t k, int64_t nthreads, const REAL *c,
                  const REAL *x, const REAL *h, double defensive, REAL *logq)
{
    if (k > KMAX || b > BMAX)
        return 1;
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t gt = 0; gt < G * T; gt++) {
        Kde K;
        double C[BMAX * KMAX], H[KMAX], X[PB * KMAX], out[PB];
        for (int64_t i = 0; i < b * k; i++)
            C[i] = (double)c[gt * b * k + i];
        for (int64_t q = 0; q < k; q++)
            H[q] = (double)h[gt * k + q];
        kde_init(&K, C, H, b, k);
        for (int64_t p0 = 0; p0 < a; p0 += PB) {
            const int64_t np = a - p0 < PB ? a - p0 : PB;
            for (int64_t i = 0; i < np * k; i++)
                X[i] = (double)x[(gt * a + p0) * k + i];
            kde_logq(&K, X, np, defensive, out);
            for (int64_t p = 0; p < np; p++)
                logq[gt * a + p0 + p] = (REAL)out[p];
        }
    }
    return 0;
}

/* ---------------------------------------------------------------------------------------------- the whole move */

/* A uniform draw in (0, 1) for draw `idx` of the stream `stream` under `seed` (splitmix64's finaliser of their
 * combination: a bijection of the 64-bit counter, so distinct draws are distinct hashes) */
static inline double uniform01(uint64_t seed, uint64_t stream, uint64_t idx)
{
    uint64_t x = seed + 0x9E3779B97F4A7C15ULL * (stream * 64 + idx + 1);
    x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
    x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
    x ^= x >> 31;
    return ((double)(x >> 11) + 0.5) * 0x1.0p-53;
}

/* For every mover i (rows A [G a] of z [N, D], the group g = i / a) and texel t (its coordinates layout [T, k]):
 * the proposal (a random centre of the other half, rows B [G, b], plus N(0, h^2) jitter, or with probability
 * `defensive` a standard logistic draw in every coordinate) written to zp [G a, D] at the texel's columns, and
 * dlq [G a, T] = log q(current) - log q(proposal) + J(proposal) - J(current), J the log-Jacobian of the interval
 * coordinates (jac [k] nonzero: log logistic(x_q), less a constant), which the caller's texel energies leave out.
 * 0 on success, 1 outside the kernel's bounds */
int bb_texel_propose(int64_t G, int64_t T, int64_t a, int64_t b, int64_t k, int64_t D, int64_t nthreads,
                     const REAL *z, const int64_t *layout, const int64_t *jac, const int64_t *A, const int64_t *B,
                     uint64_t seed, double bw, double hmin, double defensive, REAL *zp, double *dlq)
{
    if (k > KMAX || b > BMAX || a > BMAX || b < 2)     /* a mover's draws: 2 + k <= 10 of its stream's 64 */
        return 1;
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t gt = 0; gt < G * T; gt++) {
        const int64_t g = gt / T, t = gt % T;
        const int64_t *col = layout + t * k;
        Kde K;
        double C[BMAX * KMAX], H[KMAX], X[2 * BMAX * KMAX], lq[2 * BMAX], lg[2 * BMAX * KMAX];
        double un[BMAX * KMAX], nrm[BMAX * KMAX], lgt[BMAX * KMAX];
        int64_t pick[BMAX], wide[BMAX];
        for (int64_t j = 0; j < b; j++)
            for (int64_t q = 0; q < k; q++)
                C[j * k + q] = (double)z[B[g * b + j] * D + col[q]];
        texel_scale(C, b, k, bw, hmin, H);
        kde_init(&K, C, H, b, k);
        /* every mover's draws first, then their functions in loops of their own: draw 0 picks the defensive
         * logistic, 1 the centre, 2.. the coordinates (as pairs for Box-Muller) */
        const int64_t ke = k + (k & 1);
        for (int64_t i = 0; i < a; i++) {
            const uint64_t stream = (uint64_t)((g * a + i) * T + t);
            wide[i] = uniform01(seed, stream, 0) < defensive;
            pick[i] = (int64_t)(uniform01(seed, stream, 1) * b);
            pick[i] = pick[i] < b ? pick[i] : b - 1;
            for (int64_t q = 0; q < ke; q++)
                un[i * ke + q] = uniform01(seed, stream, 2 + q);
        }
#pragma omp simd
        for (int64_t m = 0; m < a * ke; m += 2) {      /* Box-Muller: two normals per pair of draws */
            const double r = sqrt(-2 * log(un[m])), w = 2 * M_PI * un[m + 1];
            nrm[m] = r * cos(w);
            nrm[m + 1] = r * sin(w);
        }
#pragma omp simd
        for (int64_t m = 0; m < a * ke; m++) {          /* the standard logistic's quantile */
            const double v = un[m] < 1e-12 ? 1e-12 : (un[m] > 1 - 1e-12 ? 1 - 1e-12 : un[m]);
            lgt[m] = log(v) - log1p(-v);
        }
        for (int64_t i = 0; i < a; i++) {
            const int64_t row = A[g * a + i];
            double *cur = X + i * k, *prop = X + (a + i) * k;
            for (int64_t q = 0; q < k; q++) {
                cur[q] = (double)z[row * D + col[q]];
                const double p = wide[i] ? lgt[i * ke + q] : C[pick[i] * k + q] + H[q] * nrm[i * ke + q];
                prop[q] = (double)(REAL)p;             /* rounded as the particles are, scored as they will be */
            }
        }
        kde_logq(&K, X, 2 * a, defensive, lq);
#pragma omp simd
        for (int64_t j = 0; j < 2 * a * k; j++)
            lg[j] = -fabs(X[j]) - 2 * log1p(exp(-fabs(X[j])));
        for (int64_t i = 0; i < a; i++) {
            double dj = 0;
            for (int64_t q = 0; q < k; q++) {
                zp[(g * a + i) * D + col[q]] = (REAL)X[(a + i) * k + q];
                if (jac[q])
                    dj += lg[(a + i) * k + q] - lg[i * k + q];
            }
            dlq[(g * a + i) * T + t] = lq[i] - lq[a + i] + dj;
        }
    }
    return 0;
}

/* Whether x is finite, from its bits: -ffast-math lets the compiler assume isfinite() and NaN comparisons away */
static inline int finite_bits(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return ((u >> 52) & 0x7FF) != 0x7FF;
}

static inline int is_plus_inf(double x)
{
    uint64_t u;
    memcpy(&u, &x, sizeof u);
    return u == 0x7FF0000000000000ULL;
}

/* The Metropolis decision of every mover i and texel t: accepted when log u < e[A_i, t] - ep[i, t] + dlq[i, t] and
 * ep is finite, u uniform under `seed`; an accepted texel's coordinates copied from zp [G a, D] into z's row A_i.
 * Returns the number accepted */
int64_t bb_texel_accept(int64_t na, int64_t T, int64_t k, int64_t D, int64_t nthreads, REAL *z, const int64_t *layout,
                        const int64_t *A, const REAL *zp, const double *e, const double *ep, const double *dlq,
                        uint64_t seed)
{
    int64_t accepted = 0;
#pragma omp parallel for schedule(static) num_threads(nthreads) reduction(+ : accepted)
    for (int64_t t = 0; t < T; t++) {
        for (int64_t i = 0; i < na; i++) {
            const double eprop = ep[i * T + t], ecur = e[A[i] * T + t];
            if (!finite_bits(eprop))
                continue;                               /* an impossible proposal */
            if (!finite_bits(ecur)) {                   /* the current state impossible (+inf): any move is better; */
                if (!is_plus_inf(ecur))                 /* -inf or NaN: refused, as torch's comparison does */
                    continue;
            } else if (!(log(uniform01(seed, (uint64_t)(i * T + t), 0)) < ecur - eprop + dlq[i * T + t]))
                continue;
            for (int64_t q = 0; q < k; q++)
                z[A[i] * D + layout[t * k + q]] = zp[i * D + layout[t * k + q]];
            accepted++;
        }
    }
    return accepted;
}
