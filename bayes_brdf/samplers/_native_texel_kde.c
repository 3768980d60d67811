/* The proposal densities of the texel-local move (texel_moves.py); compiled on first use by render/native.py.
 * Every entry point runs eight texels at a time, one per SIMD lane (lane_blocks; bb_texel_propose in stages of TS
 * texels, propose_stage), through the same lane_widths
 * and lane_logq: the arithmetic of texel_moves._local_scale and texel_moves._log_q (the torch reference, which
 * runs where this does not: CUDA, no compiler), in the particles' precision (LR: float32 particles fill an AVX2
 * vector with the eight lanes; the log ratios within ~2e-6 nats of float64's), without the [T, a, b] temporaries.
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
 * drawn, both log densities, and the Metropolis decision, reading the particles' rows (no [G, T, b, k] copies: a stage's
 * columns of each row at most)
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
#define INLINE static inline __attribute__((always_inline))   /* for constant k where the caller has one */
#define BMAX 256
#define W 8      /* texels per pass, one per SIMD lane */
#define PF 64    /* texels ahead to prefetch (bb_texel_propose) */
/* The functions of a REAL (the lanes' arithmetic, LR below): with float particles glibc's float vector functions,
 * eight lanes to an AVX2 vector instead of four */
#define LABS(x) ((x) < 0 ? -(x) : (x))
#define RSQRT(x) _Generic((REAL)0, float: sqrtf, default: sqrt)(x)
/* e^x for x <= 0, its argument clamped at EXP_LO: e^-80 = 1.8e-35 is below the rounding of every sum it enters (each
 * has a term of at least 1); expf_neg's 2^n needs n >= -126, and glibc's vector exp (double particles) takes a scalar
 * path for a whole vector when one lane's argument is below about -87 (measured: a proposal half 2x slower with
 * narrow kernel widths) */
#define EXP_LO ((LR)-80)
#define REXP_NEG(x) _Generic((REAL)0, float: expf_neg, default: exp)((x) > EXP_LO ? (x) : EXP_LO)

/* e^x for float x in [EXP_LO, 0], inline: glibc's vector expf is a call, around which an `omp simd` loop's vectors are
 * spilled. x = n ln 2 + r with |r| <= ln 2 / 2 (ln 2 in two parts: n ln 2 exact in the first), e^r by Cephes' expf
 * polynomial (within 1 ulp of e^r), times 2^n made from its bits (n >= -116: a normal float) */
static inline float expf_neg(float x)
{
    const float n = __builtin_rintf(x * 1.44269504088896341f);
    const float r = (x - n * 0.693359375f) - n * -2.12194440e-4f;
    float p = 1.9875691500e-4f;
    p = p * r + 1.3981999507e-3f;
    p = p * r + 8.3334519073e-3f;
    p = p * r + 4.1665795894e-2f;
    p = p * r + 1.6666665459e-1f;
    p = p * r + 5.0000001201e-1f;
    p = p * (r * r) + r + 1;
    const int32_t bits = ((int32_t)n + 127) << 23;
    float s;
    memcpy(&s, &bits, sizeof s);
    return p * s;
}
#define RLOG(x) _Generic((REAL)0, float: logf, default: log)(x)
#define RLOG1P(x) _Generic((REAL)0, float: log1pf, default: log1p)(x)
#define RSIN(x) _Generic((REAL)0, float: sinf, default: sin)(x)
#define RCOS(x) _Generic((REAL)0, float: cosf, default: cos)(x)

/* Everything runs W texels at a time, one per SIMD lane: every loop ends in a loop over the W lanes (arrays
 * [..][W]), which the compiler turns into vector arithmetic and glibc's vector exp, log, sin and cos. A texel alone
 * is too small for that: its loops run over 10 particles and 4 coordinates. Lane is one value per coordinate and
 * lane; a texel's b centres are Lane [b] */
typedef REAL LR;   /* the lanes' arithmetic: the particles' precision (float32: eight lanes to an AVX2 vector) */
#define LR_MAX _Generic((LR)0, float: FLT_MAX, default: DBL_MAX)
typedef LR Lane[KMAX][W];

/* The lanes' texels: t0 + l, past the end the last texel again (its results are not written) */
static void lane_texels(int64_t t0, int64_t T, int64_t tl[W])
{
    for (int l = 0; l < W; l++)
        tl[l] = t0 + l < T ? t0 + l : T - 1;
}

/* dist [b] (the nearest other centre's |c_i - c_nn(i)| per coordinate, nn(i) the nearest by Euclidean distance,
 * the first on ties) for k coordinates: each centre's candidates in increasing index with its nearest so far in
 * registers. Each pair's distance is computed twice, once for each of its centres: fewer cycles than reading and
 * writing both centres' rows for every pair */
INLINE void lane_nearest(const Lane *C, int64_t b, int64_t k, Lane *dist)
{
    for (int64_t i = 0; i < b; i++) {
        LR best[W], di[KMAX][W];
#pragma omp simd
        for (int l = 0; l < W; l++)
            best[l] = LR_MAX;
        for (int64_t q = 0; q < k; q++)
#pragma omp simd
            for (int l = 0; l < W; l++)
                di[q][l] = 0;
        for (int64_t j = 0; j < b; j++) {
            if (j == i)
                continue;
            LR d2[W], ad[KMAX][W];
#pragma omp simd
            for (int l = 0; l < W; l++)
                d2[l] = 0;
            for (int64_t q = 0; q < k; q++)
#pragma omp simd
                for (int l = 0; l < W; l++) {
                    const LR d = C[i][q][l] - C[j][q][l];
                    d2[l] += d * d;
                    ad[q][l] = LABS(d);
                }
            for (int64_t q = 0; q < k; q++)
#pragma omp simd
                for (int l = 0; l < W; l++)
                    di[q][l] = d2[l] < best[l] ? ad[q][l] : di[q][l];
#pragma omp simd
            for (int l = 0; l < W; l++)
                best[l] = d2[l] < best[l] ? d2[l] : best[l];
        }
        for (int64_t q = 0; q < k; q++)
#pragma omp simd
            for (int l = 0; l < W; l++)
                dist[i][q][l] = di[q][l];
    }
}

/* H [k][W]: bw * the median over the b centres C of |c_i - c_nn(i)| per coordinate (lane_nearest), rounded to REAL,
 * at least hmin; the median of an even count is the lower middle value (torch.median's), found by rank (ties by
 * index). dist [b]: scratch */
INLINE void lane_widths(const Lane *C, int64_t b, int64_t k, LR bw, LR hmin, Lane *dist, LR H[KMAX][W])
{
    const int64_t mid = (b - 1) / 2;
    lane_nearest(C, b, k, dist);
    for (int64_t q = 0; q < k; q++) {
        LR med[W];
#pragma omp simd
        for (int l = 0; l < W; l++)
            med[l] = 0;
        for (int64_t i = 0; i < b; i++) {
            LR rank[W];          /* the values below dist_i, ties counted for the lower indices */
#pragma omp simd
            for (int l = 0; l < W; l++)
                rank[l] = 0;
            for (int64_t j = 0; j < i; j++)
#pragma omp simd
                for (int l = 0; l < W; l++)
                    rank[l] += dist[j][q][l] <= dist[i][q][l];
            for (int64_t j = i + 1; j < b; j++)
#pragma omp simd
                for (int l = 0; l < W; l++)
                    rank[l] += dist[j][q][l] < dist[i][q][l];
#pragma omp simd
            for (int l = 0; l < W; l++)
                med[l] = rank[l] == mid ? dist[i][q][l] : med[l];
        }
#pragma omp simd
        for (int l = 0; l < W; l++) {
            const REAL hq = (REAL)(med[l] * bw);
            H[q][l] = hq < (REAL)hmin ? (REAL)hmin : hq;
        }
    }
}

/* The kernel density of the lanes' texels, ready to score points: the centres in units of the widths cs [b], the
 * inverse widths and the log normaliser */
typedef struct { LR ih[KMAX][W], lognorm[W], l_kde, l_def; const Lane *cs; int64_t b, k; } LaneKde;

INLINE void lane_kde_init(LaneKde *K, const Lane *C, const LR H[KMAX][W], int64_t b, int64_t k, double defensive,
                          Lane *cs)
{
    K->b = b; K->k = k; K->cs = cs;
    K->l_kde = log1p(-defensive); K->l_def = log(defensive);
    const double lnb = log((double)b) + k * 0.5 * log(2 * M_PI);
#pragma omp simd
    for (int l = 0; l < W; l++)
        K->lognorm[l] = lnb;
    for (int64_t q = 0; q < k; q++)
#pragma omp simd
        for (int l = 0; l < W; l++) {
            K->lognorm[l] += RLOG(H[q][l]);
            K->ih[q][l] = 1 / H[q][l];
        }
    for (int64_t j = 0; j < b; j++)
        for (int64_t q = 0; q < k; q++)
#pragma omp simd
            for (int l = 0; l < W; l++)
                cs[j][q][l] = C[j][q][l] * K->ih[q][l];
}

/* all [W]: sum_q log logistic(x_q), the defensive density's log; jsum [W] (when not NULL): the same over the
 * coordinates with jac[q] != 0, the interval Jacobian's. log logistic(x) = -|x| - 2 log(1 + e^-|x|), and the logs of
 * a sum are the log of a product (each factor in (1, 2]): one log per point, not one per coordinate */
INLINE void lane_log_logistic(const LR X[KMAX][W], int64_t k, const int64_t *jac, LR all[W], LR jsum[W])
{
    LR sa[W], pa[W], sj[W], pj[W];
    int alljac = 1;
#pragma omp simd
    for (int l = 0; l < W; l++) { sa[l] = 0; pa[l] = 1; sj[l] = 0; pj[l] = 1; }
    for (int64_t q = 0; q < k; q++) {
        if (jsum && jac[q]) {
#pragma omp simd
            for (int l = 0; l < W; l++) {
                const LR ax = LABS(X[q][l]), f = 1 + REXP_NEG(-ax);
                sa[l] -= ax; pa[l] *= f; sj[l] -= ax; pj[l] *= f;
            }
        } else {
            alljac = 0;
#pragma omp simd
            for (int l = 0; l < W; l++) {
                const LR ax = LABS(X[q][l]);
                sa[l] -= ax; pa[l] *= 1 + REXP_NEG(-ax);
            }
        }
    }
#pragma omp simd
    for (int l = 0; l < W; l++)
        all[l] = sa[l] - 2 * RLOG(pa[l]);
    if (!jsum)
        return;
#pragma omp simd
    for (int l = 0; l < W; l++)
        jsum[l] = alljac ? all[l] : sj[l] - 2 * RLOG(pj[l]);
}

/* out [W]: log((1 - defensive) KDE(x) + defensive prod_k logistic(x_k)) at the point X [k][W] (ll: the log of that
 * product, lane_log_logistic's `all`), KDE the equal mixture of N(c_j, diag h^2); ex [b][W]: scratch */
INLINE void lane_logq(const LaneKde *K, const LR X[KMAX][W], const LR ll[W], LR (*ex)[W], LR out[W])
{
    const int64_t b = K->b, k = K->k;
    LR mm[W], wd[W], sum[W], xs[KMAX][W];
#pragma omp simd
    for (int l = 0; l < W; l++) { mm[l] = -LR_MAX; wd[l] = K->l_def; sum[l] = 0; }
    for (int64_t q = 0; q < k; q++)
#pragma omp simd
        for (int l = 0; l < W; l++)
            xs[q][l] = X[q][l] * K->ih[q][l];
    for (int64_t j = 0; j < b; j++) {
        LR e[W];          /* summed in a local array: a zeroed ex[j] reloaded whole stalls store forwarding */
#pragma omp simd
        for (int l = 0; l < W; l++)
            e[l] = 0;
        for (int64_t q = 0; q < k; q++)
#pragma omp simd
            for (int l = 0; l < W; l++) {
                const LR d = xs[q][l] - K->cs[j][q][l];
                e[l] -= (LR)0.5 * d * d;
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
            sum[l] += REXP_NEG(ex[j][l] - mm[l]);
#pragma omp simd
    for (int l = 0; l < W; l++)
        wd[l] += ll[l];
#pragma omp simd
    for (int l = 0; l < W; l++) {        /* logaddexp(kde, defensive) */
        const LR u = K->l_kde + mm[l] + RLOG(sum[l]) - K->lognorm[l];
        const LR hi = u > wd[l] ? u : wd[l], lo = u > wd[l] ? wd[l] : u;
        out[l] = hi + RLOG1P(REXP_NEG(lo - hi));
    }
}

/* The centres c [G, T, b, k] of group g's texels t0 + l into C [b] */
static void gather_centres(const REAL *c, int64_t g, int64_t T, int64_t b, int64_t k, const int64_t tl[W], Lane *C)
{
    for (int64_t j = 0; j < b; j++)
        for (int64_t q = 0; q < k; q++)
            for (int l = 0; l < W; l++)
                C[j][q][l] = (LR)c[((g * T + tl[l]) * b + j) * k + q];
}

/* One block of `step` texels of group g: t0 its first, nl of them real, tl its first W lanes' texels (lane_texels);
 * buf the thread's scratch; args the entry point's own */
typedef void (*LaneBlock)(const void *args, Lane *buf, int64_t g, int64_t t0, int64_t nl, const int64_t tl[W]);

/* body over every group g < G and block of `step` of the T texels (W: one per lane; bb_texel_propose: a stage of TS),
 * in parallel over the blocks (OpenMP, static), each thread with `scratch` zeroed bytes of its own; 0 on success, 1
 * when a thread's scratch could not be allocated */
static int lane_blocks(int64_t G, int64_t T, int64_t step, int64_t nthreads, size_t scratch, LaneBlock body,
                       const void *args)
{
    const int64_t nblk = (T + step - 1) / step;
    int failed = 0;
#pragma omp parallel num_threads(nthreads) reduction(| : failed)
    {
        Lane *buf = calloc(1, scratch);
        failed = !buf;
#pragma omp for schedule(static)
        for (int64_t gb = 0; gb < G * nblk; gb++) {
            if (!buf)
                continue;
            const int64_t g = gb / nblk, t0 = (gb % nblk) * step;
            int64_t tl[W];
            lane_texels(t0, T, tl);
            body(args, buf, g, t0, T - t0 < step ? T - t0 : step, tl);
        }
        free(buf);
    }
    return failed;
}

typedef struct { int64_t T, b, k; const REAL *c; double bw, hmin; REAL *h; } ScaleArgs;

/* scratch: the centres and their nearest-neighbour distances [b] */
static void scale_block(const void *args, Lane *buf, int64_t g, int64_t t0, int64_t nl, const int64_t tl[W])
{
    const ScaleArgs *q = args;
    const int64_t T = q->T, b = q->b, k = q->k;
    LR H[KMAX][W];
    gather_centres(q->c, g, T, b, k, tl, buf);
    lane_widths(buf, b, k, q->bw, q->hmin, buf + b, H);
    for (int l = 0; l < nl; l++)
        for (int64_t c = 0; c < k; c++)
            q->h[(g * T + t0 + l) * k + c] = (REAL)H[c][l];
}

/* h [G, T, k] from the centres c [G, T, b, k]; 0 on success, 1 when k or b exceed the kernel's bounds (the caller
 * then uses the torch reference) or out of memory */
int bb_texel_scale(int64_t G, int64_t T, int64_t b, int64_t k, int64_t nthreads, const REAL *c, double bw,
                   double hmin, REAL *h)
{
    if (k > KMAX || b > BMAX || b < 2)
        return 1;
    const ScaleArgs args = {T, b, k, c, bw, hmin, h};
    return lane_blocks(G, T, W, nthreads, 2 * b * sizeof(Lane), scale_block, &args);
}

typedef struct { int64_t T, a, b, k; const REAL *c, *x, *h; double defensive; REAL *logq; } LogqArgs;

/* scratch: the centres, their scaled copies [b] and the kernel's exponents [b][W] */
static void logq_block(const void *args, Lane *buf, int64_t g, int64_t t0, int64_t nl, const int64_t tl[W])
{
    const LogqArgs *q = args;
    const int64_t T = q->T, a = q->a, b = q->b, k = q->k;
    LR H[KMAX][W], X[KMAX][W], ll[W], out[W];
    LaneKde K;
    gather_centres(q->c, g, T, b, k, tl, buf);
    for (int64_t c = 0; c < k; c++)
        for (int l = 0; l < W; l++)
            H[c][l] = (LR)q->h[(g * T + tl[l]) * k + c];
    lane_kde_init(&K, buf, H, b, k, q->defensive, buf + b);
    for (int64_t p = 0; p < a; p++) {
        for (int64_t c = 0; c < k; c++)
            for (int l = 0; l < W; l++)
                X[c][l] = (LR)q->x[((g * T + tl[l]) * a + p) * k + c];
        lane_log_logistic(X, k, NULL, ll, NULL);
        lane_logq(&K, X, ll, (LR (*)[W])(buf + 2 * b), out);
        for (int l = 0; l < nl; l++)
            q->logq[(g * T + t0 + l) * a + p] = (REAL)out[l];
    }
}

/* logq [G, T, a] at x [G, T, a, k] for the centres c [G, T, b, k] and widths h [G, T, k]; 0 on success, 1 when k or
 * b exceed the kernel's bounds or out of memory */
int bb_texel_logq(int64_t G, int64_t T, int64_t a, int64_t b, int64_t k, int64_t nthreads, const REAL *c,
                  const REAL *x, const REAL *h, double defensive, REAL *logq)
{
    if (k > KMAX || b > BMAX)
        return 1;
    const LogqArgs args = {T, a, b, k, c, x, h, defensive, logq};
    return lane_blocks(G, T, W, nthreads, 2 * b * sizeof(Lane) + b * sizeof(LR[W]), logq_block, &args);
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

typedef uint64_t u64x4 __attribute__((vector_size(32)));
typedef double f64x4 __attribute__((vector_size(32)));

/* u [W]: uniform01(seed, s0 + l, idx) of the W lanes, the same bits, four lanes to a vector. The compiler leaves
 * uniform01 itself scalar: AVX2 has no conversion of 64-bit integers to double. Here the draw's 53 bits are converted
 * in two exact halves (each or'ed into the mantissa of 2^52, less 2^52), their sum is the integer exactly, and only
 * the add of 0.5 rounds, as in uniform01 (the empty asm keeps -ffast-math from reassociating it with the sum) */
static inline void lane_uniform01(uint64_t seed, uint64_t s0, uint64_t idx, double u[W])
{
#if defined(__x86_64__) || defined(__i386__)
    const u64x4 lane = {0, 1, 2, 3}, two52 = (u64x4){0} + 0x4330000000000000ULL;
    for (int h = 0; h < W; h += 4) {
        u64x4 x = seed + 0x9E3779B97F4A7C15ULL * ((s0 + (uint64_t)h + lane) * 64 + idx + 1);
        x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
        x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
        x ^= x >> 31;
        x >>= 11;
        f64x4 m = ((f64x4)((x >> 32) | two52) - 0x1p52) * 0x1p32 + ((f64x4)((x & 0xFFFFFFFFULL) | two52) - 0x1p52);
        __asm__("" : "+x"(m));
        m = (m + 0.5) * 0x1.0p-53;
        memcpy(u + h, &m, sizeof m);
    }
#else                                               /* the barrier names an x86 vector register: elsewhere, */
    for (int l = 0; l < W; l++)                     /* lane by lane */
        u[l] = uniform01(seed, s0 + (uint64_t)l, idx);
#endif
}

typedef struct {
    int64_t T, a, b, k, D;
    const REAL *z; const int64_t *layout, *jac, *A, *B;
    uint64_t seed; double bw, hmin, defensive;
    REAL *zp; double *dlq;
} ProposeArgs;

#define TS 256   /* texels per stage of the whole move (bb_texel_propose) */

/* Where propose_k reads the particles' values and writes the proposals: the rows of the other half (zb [b]), of the
 * movers (za [a]) and of their proposals (zo [a]), and where a texel's coordinates are in a row: the texels of a
 * stage are a run of columns for each coordinate (run: texel t0 + l at column c0[q] + l), or look-ups in layout */
typedef struct { const REAL *zb[BMAX], *za[BMAX]; REAL *zo[BMAX]; int64_t c0[KMAX]; int run; } Rows;

/* dst [W]: coordinate q of the lanes' texels tl (the first t0) in row zr, from the run of columns at c0 + off or one
 * look-up in layout [T, k] per lane */
INLINE void lane_load(const REAL *zr, const Rows *R, const int64_t *layout, int64_t k, int64_t q, int64_t off,
                      const int64_t tl[W], LR dst[W])
{
    if (R->run) {
#pragma omp simd
        for (int l = 0; l < W; l++)
            dst[l] = (LR)zr[R->c0[q] + off + l];
        return;
    }
    for (int l = 0; l < W; l++)
        dst[l] = (LR)zr[layout[tl[l] * k + q]];
}

/* One block of W texels (t0 its first, nl of them real, tl lane_texels') of group g, reading and writing through R
 * (off: t0 less its stage's first texel). scratch: the centres, their scaled copies and their nearest-neighbour
 * distances [b], the uniforms and normals [a], the points and their log-logistic terms [2 a]; and the kernel's
 * exponents [b][W] */
INLINE void propose_k(const ProposeArgs *pa, Lane *buf, int64_t g, int64_t t0, int64_t nl, const int64_t tl[W],
                      const int64_t k, const Rows *R, int64_t off)
{
    const int64_t T = pa->T, a = pa->a, b = pa->b, ke = k + (k & 1);
    const int64_t *layout = pa->layout, *jac = pa->jac;
    const uint64_t seed = pa->seed;
    const double bw = pa->bw, hmin = pa->hmin, defensive = pa->defensive, two_pi = 2 * M_PI;
    double *dlq = pa->dlq;
    Lane *C = buf, *cs = C + b, *dist = cs + b, *un = dist + b, *nrm = un + a, *X = nrm + a, *lg = X + 2 * a;
    LR (*ex)[W] = (LR (*)[W])(lg + 2 * a);
    int64_t pick[BMAX][W];
    LR wide[BMAX][W], H[KMAX][W];
    LaneKde K;
    if (!R->run) {
        /* the rows' values PF texels on, read and written by a later block of this thread: 3 k streams per particle
         * of the group, too many for the hardware prefetcher (measured on AVX2: a half 28.7 -> 22 ms on one thread) */
        const int64_t tp = t0 + PF < T ? t0 + PF : T - 1;
        for (int64_t q = 0; q < k; q++) {
            const int64_t col = layout[tp * k + q];
            for (int64_t j = 0; j < b; j++)
                __builtin_prefetch(R->zb[j] + col, 0, 3);
            for (int64_t i = 0; i < a; i++) {
                __builtin_prefetch(R->za[i] + col, 0, 3);
                __builtin_prefetch(R->zo[i] + col, 1, 3);
            }
        }
    }
    for (int64_t j = 0; j < b; j++)
        for (int64_t q = 0; q < k; q++)
            lane_load(R->zb[j], R, layout, k, q, off, tl, C[j][q]);
    lane_widths(C, b, k, bw, hmin, dist, H);
    lane_kde_init(&K, C, H, b, k, defensive, cs);
    /* the draws: 0 picks the defensive logistic, 1 the centre, 2.. the coordinates (pairs for Box-Muller) */
    for (int64_t i = 0; i < a; i++) {
        const uint64_t s0 = (uint64_t)((g * a + i) * T + t0);    /* lane l's stream: s0 + l */
        double u[W];
        lane_uniform01(seed, s0, 0, u);
#pragma omp simd
        for (int l = 0; l < W; l++)
            wide[i][l] = u[l] < defensive;
        lane_uniform01(seed, s0, 1, u);
#pragma omp simd
        for (int l = 0; l < W; l++) {
            const int64_t pk = (int64_t)(u[l] * b);
            pick[i][l] = pk < b ? pk : b - 1;
        }
        for (int64_t q = 0; q < ke; q++) {
            lane_uniform01(seed, s0, 2 + q, u);
#pragma omp simd
            for (int l = 0; l < W; l++)
                un[i][q][l] = u[l];
        }
    }
    /* Box-Muller; the cosines and sines in loops of their own, or the compiler fuses them into a scalar
     * sincos call */
    for (int64_t i = 0; i < a; i++)
        for (int64_t q = 0; q < ke; q += 2) {
            LR r[W];
#pragma omp simd
            for (int l = 0; l < W; l++)
                r[l] = RSQRT(-2 * RLOG((LR)un[i][q][l]));
#pragma omp simd
            for (int l = 0; l < W; l++)
                nrm[i][q][l] = r[l] * RCOS((REAL)(two_pi * un[i][q + 1][l]));
#pragma omp simd
            for (int l = 0; l < W; l++)
                nrm[i][q + 1][l] = r[l] * RSIN((REAL)(two_pi * un[i][q + 1][l]));
        }
    /* the points: the movers' current values (X[0..a)) and their proposals (X[a..2a)), rounded as the
     * particles are, scored as they will be */
    for (int64_t i = 0; i < a; i++) {
        for (int64_t q = 0; q < k; q++) {
            lane_load(R->za[i], R, layout, k, q, off, tl, X[i][q]);
            LR cp[W];
            for (int l = 0; l < W; l++)
                cp[l] = C[pick[i][l]][q][l];
#pragma omp simd
            for (int l = 0; l < W; l++) {
                const double v = un[i][q][l] < 1e-12 ? 1e-12 : (un[i][q][l] > 1 - 1e-12 ? 1 - 1e-12 : un[i][q][l]);
                const LR p = wide[i][l] != 0 ? RLOG((REAL)(v / (1 - v))) : cp[l] + H[q][l] * nrm[i][q][l];
                X[a + i][q][l] = p;
            }
        }
    }
    /* the log densities, current minus proposed, plus the Jacobian's difference */
    for (int64_t p = 0; p < 2 * a; p++)        /* lg[p]: [0] the defensive density's log, [1] the Jacobian's */
        lane_log_logistic(X[p], k, jac, lg[p][0], lg[p][1]);
    for (int64_t i = 0; i < a; i++) {
        LR out[2][W], dj[W];
        lane_logq(&K, X[i], lg[i][0], ex, out[0]);
        lane_logq(&K, X[a + i], lg[a + i][0], ex, out[1]);
#pragma omp simd
        for (int l = 0; l < W; l++)
            dj[l] = lg[a + i][1][l] - lg[i][1][l];
        double *dr = dlq + (g * a + i) * T + t0;
        for (int l = 0; l < nl; l++)
            dr[l] = (double)out[0][l] - out[1][l] + dj[l];
        if (R->run) {       /* into the stage (W lanes: its room is a whole number of blocks) */
            for (int64_t q = 0; q < k; q++)
#pragma omp simd
                for (int l = 0; l < W; l++)
                    R->zo[i][R->c0[q] + off + l] = (REAL)X[a + i][q][l];
            continue;
        }
        for (int l = 0; l < nl; l++)
            for (int64_t q = 0; q < k; q++)
                R->zo[i][layout[(t0 + l) * k + q]] = (REAL)X[a + i][q][l];
    }
}

/* propose_k's scratch (its Lanes and exponents), in bytes; the stage follows it in a thread's buffer */
static size_t propose_scratch(int64_t a, int64_t b)
{
    return (3 * b + 6 * a) * sizeof(Lane) + b * sizeof(LR[W]);
}

/* The n texels from tc of group g (a stage: at most TS): when each coordinate's columns are a run (texel_layout's
 * always are), the rows' runs are copied into the thread's stage (after propose_k's scratch in buf: the other half's,
 * then the movers', then the proposals' [k][TS] each; zeroed, for the lanes past a stage's end), so that the blocks
 * read and write it instead of 3 k (a + b) strided streams, and the proposals are copied out at the end; else the
 * blocks use the rows in place. propose_k inlined with k = 4 (three albedo channels and roughness: the common case)
 * for constant loop bounds */
static void propose_stage(const void *args, Lane *buf, int64_t g, int64_t tc, int64_t n, const int64_t tl0[W])
{
    (void)tl0;
    const ProposeArgs *pa = args;
    const int64_t T = pa->T, a = pa->a, b = pa->b, k = pa->k, D = pa->D, te = tc + n;
    const int64_t *layout = pa->layout;
    REAL *st = (REAL *)((char *)buf + propose_scratch(a, b));
    Rows R;
    R.run = 1;
    for (int64_t q = 0; q < k; q++) {
        R.c0[q] = layout[tc * k + q];
        for (int64_t t = tc + 1; t < te && R.run; t++)
            R.run = layout[t * k + q] == R.c0[q] + (t - tc);
    }
    for (int64_t j = 0; j < b; j++)
        R.zb[j] = pa->z + pa->B[g * b + j] * D;
    for (int64_t i = 0; i < a; i++) {
        R.za[i] = pa->z + pa->A[g * a + i] * D;
        R.zo[i] = pa->zp + (g * a + i) * D;
    }
    if (R.run) {
        for (int64_t j = 0; j < b + a; j++) {
            const REAL *src = j < b ? R.zb[j] : R.za[j - b];
            REAL *dst = st + j * k * TS;
            for (int64_t q = 0; q < k; q++)
                memcpy(dst + q * TS, src + R.c0[q], (size_t)n * sizeof(REAL));
            if (j < b) R.zb[j] = dst; else R.za[j - b] = dst;
        }
        for (int64_t i = 0; i < a; i++)
            R.zo[i] = st + (b + a + i) * k * TS;
        for (int64_t q = 0; q < k; q++)
            R.c0[q] = q * TS;
    }
    for (int64_t t0 = tc; t0 < te; t0 += W) {
        int64_t tl[W];
        lane_texels(t0, T, tl);
        const int64_t nl = te - t0 < W ? te - t0 : W;
        if (k == 4)
            propose_k(pa, buf, g, t0, nl, tl, 4, &R, t0 - tc);
        else
            propose_k(pa, buf, g, t0, nl, tl, k, &R, t0 - tc);
    }
    if (R.run)
        for (int64_t i = 0; i < a; i++)
            for (int64_t q = 0; q < k; q++)
                memcpy(pa->zp + (g * a + i) * D + layout[tc * k + q], R.zo[i] + q * TS, (size_t)n * sizeof(REAL));
}

/* For every mover i (rows A [G a] of z [N, D], the group g = i / a) and texel t (its coordinates layout [T, k]):
 * the proposal (a random centre of the other half, rows B [G, b], plus N(0, h^2) jitter, or with probability
 * `defensive` a standard logistic draw in every coordinate) written to zp [G a, D] at the texel's columns, and
 * dlq [G a, T] = log q(current) - log q(proposal) + J(proposal) - J(current), J the log-Jacobian of the interval
 * coordinates (jac [k] nonzero: log logistic(x_q), less a constant), which the caller's texel energies leave out.
 * The widths and densities are lane_widths' and lane_logq's, as bb_texel_scale's and bb_texel_logq's.
 * 0 on success, 1 outside the kernel's bounds (or out of memory) */
int bb_texel_propose(int64_t G, int64_t T, int64_t a, int64_t b, int64_t k, int64_t D, int64_t nthreads,
                     const REAL *z, const int64_t *layout, const int64_t *jac, const int64_t *A, const int64_t *B,
                     uint64_t seed, double bw, double hmin, double defensive, REAL *zp, double *dlq)
{
    if (k > KMAX || b > BMAX || a > BMAX || b < 2)     /* a mover's draws: 2 + k <= 10 of its stream's 64 */
        return 1;
    const ProposeArgs args = {T, a, b, k, D, z, layout, jac, A, B, seed, bw, hmin, defensive, zp, dlq};
    return lane_blocks(G, T, TS, nthreads, propose_scratch(a, b) + (size_t)((b + 2 * a) * k * TS) * sizeof(REAL),
                       propose_stage, &args);
}

/* the log of uniform01's smallest value, 2^-54 (-37.42995), rounded down: at or below it no draw accepts */
#define LOG_U_MIN (-37.43)

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
    const int64_t TB = 512, nblk = (T + TB - 1) / TB;     /* texel blocks, movers inside: rows read in order */
#pragma omp parallel for schedule(static) num_threads(nthreads) reduction(+ : accepted)
    for (int64_t tb = 0; tb < nblk; tb++) {
        const int64_t t1 = (tb + 1) * TB < T ? (tb + 1) * TB : T;
        for (int64_t i = 0; i < na; i++)
            for (int64_t t = tb * TB; t < t1; t++) {
                const double eprop = ep[i * T + t], ecur = e[A[i] * T + t];
                if (!finite_bits(eprop))
                    continue;                               /* an impossible proposal */
                if (!finite_bits(ecur)) {                   /* the current state impossible (+inf): any move is better; */
                    if (!is_plus_inf(ecur))                 /* -inf or NaN: refused, as torch's comparison does */
                        continue;
                } else {
                    /* log u < d, with log u in [LOG_U_MIN, 0] (u rounds to 1 at most): the draw decides only for d
                     * in (LOG_U_MIN, 0], so the logs of the others are not taken (the same decisions) */
                    const double d = ecur - eprop + dlq[i * T + t];
                    if (!(d > 0) && (d <= LOG_U_MIN || !(log(uniform01(seed, (uint64_t)(i * T + t), 0)) < d)))
                        continue;
                }
                for (int64_t q = 0; q < k; q++)
                    z[A[i] * D + layout[t * k + q]] = zp[i * D + layout[t * k + q]];
                accepted++;
            }
    }
    return accepted;
}
