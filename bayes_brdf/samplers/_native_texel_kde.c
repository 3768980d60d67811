/* The proposal densities of the texel-local move (texel_moves.py); compiled on first use by render/native.py.
 * bb_texel_scale and bb_texel_logq go one texel at a time, bb_texel_propose eight at a time (one per SIMD lane). The same arithmetic as texel_moves._local_scale and texel_moves._log_q (the torch reference,
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
 * bb_texel_propose and bb_texel_accept are the whole move of one half (texel_moves._half_native): the proposal
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
#include <stdlib.h>
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

/* The whole move runs W texels at a time, one per SIMD lane: every loop below ends in a loop over the W lanes
 * (arrays [..][W]), which the compiler turns into vector arithmetic and glibc's vector exp, log and sincos. A texel
 * alone (texel_scale, kde_logq above) is too small for that: its loops run over 10 particles and 4 coordinates */
#define W 8

/* For every mover i (rows A [G a] of z [N, D], the group g = i / a) and texel t (its coordinates layout [T, k]):
 * the proposal (a random centre of the other half, rows B [G, b], plus N(0, h^2) jitter, or with probability
 * `defensive` a standard logistic draw in every coordinate) written to zp [G a, D] at the texel's columns, and
 * dlq [G a, T] = log q(current) - log q(proposal) + J(proposal) - J(current), J the log-Jacobian of the interval
 * coordinates (jac [k] nonzero: log logistic(x_q), less a constant), which the caller's texel energies leave out.
 * The widths and densities are texel_scale's and kde_logq's, lane by lane, in the same order of operations.
 * 0 on success, 1 outside the kernel's bounds (or out of memory) */
int bb_texel_propose(int64_t G, int64_t T, int64_t a, int64_t b, int64_t k, int64_t D, int64_t nthreads,
                     const REAL *z, const int64_t *layout, const int64_t *jac, const int64_t *A, const int64_t *B,
                     uint64_t seed, double bw, double hmin, double defensive, REAL *zp, double *dlq)
{
    if (k > KMAX || b > BMAX || a > BMAX || b < 2)     /* a mover's draws: 2 + k <= 10 of its stream's 64 */
        return 1;
    const int64_t nblk = (T + W - 1) / W, ke = k + (k & 1), mid = (b - 1) / 2;
    const double l_kde = log1p(-defensive), l_def = log(defensive), two_pi = 2 * M_PI;
    const double lnb = log((double)b) + k * 0.5 * log(2 * M_PI);
    /* per thread, each in frames of [KMAX][W]: the centres, their scaled copies and their nearest-neighbour
     * distances [b], the uniforms and normals [a], the points and their log-logistic terms [2 a]; and the kernel's
     * exponents [b][W] */
    const size_t per = (size_t)W * ((3 * b + 6 * a) * KMAX + b);
    int failed = 0;
#pragma omp parallel num_threads(nthreads) reduction(| : failed)
    {
        double *buf = malloc(per * sizeof(double));
        if (!buf)
            failed = 1;
#pragma omp for schedule(static)
        for (int64_t gb = 0; gb < G * nblk; gb++) {
            if (!buf)
                continue;
            double (*C)[KMAX][W] = (double (*)[KMAX][W])buf;             /* only [b][k] of each used */
            double (*cs)[KMAX][W] = C + b, (*dist)[KMAX][W] = cs + b;
            double (*un)[KMAX][W] = dist + b, (*nrm)[KMAX][W] = un + a;
            double (*X)[KMAX][W] = nrm + a, (*lg)[KMAX][W] = X + 2 * a;
            double (*ex)[W] = (double (*)[W])(lg + 2 * a);
            const int64_t g = gb / nblk, t0 = (gb % nblk) * W;
            int64_t tl[W], pick[BMAX][W];
            double wide[BMAX][W];
            double H[KMAX][W], ih[KMAX][W], lognorm[W];
            for (int l = 0; l < W; l++)
                tl[l] = t0 + l < T ? t0 + l : T - 1;                /* lanes past the end repeat the last texel */
            for (int64_t j = 0; j < b; j++) {
                const REAL *zr = z + B[g * b + j] * D;
                for (int64_t q = 0; q < k; q++)
                    for (int l = 0; l < W; l++)
                        C[j][q][l] = (double)zr[layout[tl[l] * k + q]];
            }
            /* the widths (texel_scale): each centre's nearest other centre, first on ties */
            for (int64_t i = 0; i < b; i++) {
                double best[W];
                for (int l = 0; l < W; l++)
                    best[l] = DBL_MAX;
                for (int64_t j = 0; j < b; j++) {
                    if (j == i)
                        continue;
                    double d2[W];
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        d2[l] = 0;
                    for (int64_t q = 0; q < k; q++)
#pragma omp simd
                        for (int l = 0; l < W; l++) {
                            const double d = C[i][q][l] - C[j][q][l];
                            d2[l] += d * d;
                        }
                    for (int64_t q = 0; q < k; q++)
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            dist[i][q][l] = d2[l] < best[l] ? (double)(REAL)fabs(C[i][q][l] - C[j][q][l])
                                                            : dist[i][q][l];
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        best[l] = d2[l] < best[l] ? d2[l] : best[l];
                }
            }
            /* the median of an even count is the lower middle value: the one of rank (b - 1) / 2, ties by index */
            for (int64_t q = 0; q < k; q++) {
                double med[W];
#pragma omp simd
                for (int l = 0; l < W; l++)
                    med[l] = 0;
                for (int64_t i = 0; i < b; i++) {
                    int64_t rank[W];
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        rank[l] = 0;
                    for (int64_t j = 0; j < b; j++)
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            rank[l] += dist[j][q][l] < dist[i][q][l] || (dist[j][q][l] == dist[i][q][l] && j < i);
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        med[l] = rank[l] == mid ? dist[i][q][l] : med[l];
                }
#pragma omp simd
                for (int l = 0; l < W; l++) {
                    const REAL hq = (REAL)(med[l] * bw);
                    H[q][l] = hq < (REAL)hmin ? (REAL)hmin : hq;
                    ih[q][l] = 1 / H[q][l];
                }
            }
            /* the kernel density (kde_init) */
#pragma omp simd
            for (int l = 0; l < W; l++)
                lognorm[l] = lnb;
            for (int64_t q = 0; q < k; q++)
#pragma omp simd
                for (int l = 0; l < W; l++)
                    lognorm[l] += log(H[q][l]);
            for (int64_t j = 0; j < b; j++)
                for (int64_t q = 0; q < k; q++)
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        cs[j][q][l] = C[j][q][l] * ih[q][l];
            /* the draws: 0 picks the defensive logistic, 1 the centre, 2.. the coordinates (pairs for Box-Muller) */
            for (int64_t i = 0; i < a; i++) {
                const uint64_t s0 = (uint64_t)((g * a + i) * T + t0);    /* lane l's stream: s0 + l */
#pragma omp simd
                for (int l = 0; l < W; l++)
                    wide[i][l] = uniform01(seed, s0 + (uint64_t)l, 0) < defensive;
#pragma omp simd
                for (int l = 0; l < W; l++) {
                    const int64_t pk = (int64_t)(uniform01(seed, s0 + (uint64_t)l, 1) * b);
                    pick[i][l] = pk < b ? pk : b - 1;
                }
                for (int64_t q = 0; q < ke; q++)
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        un[i][q][l] = uniform01(seed, s0 + (uint64_t)l, 2 + q);
            }
            /* Box-Muller; the cosines and sines in loops of their own, or the compiler fuses them into a scalar
             * sincos call */
            for (int64_t i = 0; i < a; i++)
                for (int64_t q = 0; q < ke; q += 2) {
                    double r[W];
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        r[l] = sqrt(-2 * log(un[i][q][l]));
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        nrm[i][q][l] = r[l] * cos(two_pi * un[i][q + 1][l]);
#pragma omp simd
                    for (int l = 0; l < W; l++)
                        nrm[i][q + 1][l] = r[l] * sin(two_pi * un[i][q + 1][l]);
                }
            /* the points: the movers' current values (X[0..a)) and their proposals (X[a..2a)), rounded as the
             * particles are, scored as they will be */
            for (int64_t i = 0; i < a; i++) {
                const REAL *zr = z + A[g * a + i] * D;
                for (int64_t q = 0; q < k; q++) {
                    for (int l = 0; l < W; l++)
                        X[i][q][l] = (double)zr[layout[tl[l] * k + q]];
                    double cp[W];
                    for (int l = 0; l < W; l++)
                        cp[l] = C[pick[i][l]][q][l];
#pragma omp simd
                    for (int l = 0; l < W; l++) {
                        const double v = un[i][q][l] < 1e-12 ? 1e-12 : (un[i][q][l] > 1 - 1e-12 ? 1 - 1e-12 : un[i][q][l]);
                        const double p = wide[i][l] != 0 ? log(v) - log1p(-v) : cp[l] + H[q][l] * nrm[i][q][l];
                        X[a + i][q][l] = (double)(REAL)p;
                    }
                }
            }
            /* log logistic of every coordinate: the defensive density's terms and the Jacobian's */
            for (int64_t p = 0; p < 2 * a; p++)
                for (int64_t q = 0; q < k; q++)
#pragma omp simd
                    for (int l = 0; l < W; l++) {
                        const double ax = fabs(X[p][q][l]);
                        lg[p][q][l] = -ax - 2 * log1p(exp(-ax));
                    }
            /* the log densities (kde_logq), current minus proposed, plus the Jacobian's difference */
            double out[2][W];
            for (int64_t i = 0; i < a; i++) {
                for (int s = 0; s < 2; s++) {
                    const int64_t p = s * a + i;
                    double mm[W], wd[W], sum[W];
#pragma omp simd
                    for (int l = 0; l < W; l++) { mm[l] = -DBL_MAX; wd[l] = l_def; sum[l] = 0; }
                    double xs[KMAX][W];
                    for (int64_t q = 0; q < k; q++)
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            xs[q][l] = X[p][q][l] * ih[q][l];
                    for (int64_t j = 0; j < b; j++) {
                        double e[W];          /* summed in a local array: a zeroed ex[j] reloaded whole stalls */
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            e[l] = 0;
                        for (int64_t q = 0; q < k; q++)
#pragma omp simd
                            for (int l = 0; l < W; l++) {
                                const double d = xs[q][l] - cs[j][q][l];
                                e[l] -= 0.5 * d * d;
                            }
#pragma omp simd
                        for (int l = 0; l < W; l++) {
                            ex[j][l] = e[l];
                            mm[l] = e[l] > mm[l] ? e[l] : mm[l];
                        }
                    }
                    for (int64_t j = 0; j < b; j++)
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            sum[l] += exp(ex[j][l] - mm[l]);
                    for (int64_t q = 0; q < k; q++)
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            wd[l] += lg[p][q][l];
#pragma omp simd
                    for (int l = 0; l < W; l++) {        /* logaddexp(kde, defensive) */
                        const double u = l_kde + mm[l] + log(sum[l]) - lognorm[l];
                        const double hi = u > wd[l] ? u : wd[l], lo = u > wd[l] ? wd[l] : u;
                        out[s][l] = hi + log1p(exp(lo - hi));
                    }
                }
                double dj[W];
#pragma omp simd
                for (int l = 0; l < W; l++)
                    dj[l] = 0;
                for (int64_t q = 0; q < k; q++)
                    if (jac[q])
#pragma omp simd
                        for (int l = 0; l < W; l++)
                            dj[l] += lg[a + i][q][l] - lg[i][q][l];
                const int64_t row = g * a + i, nl = T - t0 < W ? T - t0 : W;
                for (int l = 0; l < nl; l++) {
                    dlq[row * T + t0 + l] = out[0][l] - out[1][l] + dj[l];
                    for (int64_t q = 0; q < k; q++)
                        zp[row * D + layout[(t0 + l) * k + q]] = (REAL)X[a + i][q][l];
                }
            }
        }
        free(buf);
    }
    return failed;
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
