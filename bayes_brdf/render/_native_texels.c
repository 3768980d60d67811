/* Fused CPU shading kernel for pixels that read texel maps through bilinear taps (a mesh's pixels, a
 * perspective view of the plane), compiled on first use by native.py.
 *
 * The same three jobs as _native_kernels.c (MODE_IMAGE_FWD, MODE_IMAGE_BWD, MODE_LOSS) and the same
 * BRDF terms (_native_brdf.h), but the particles are the SIMD lanes: every particle reads the same
 * four texels at a pixel, so with the maps copied texel-major ([T][channel][particle]) a pixel's taps
 * are contiguous vector loads, and its gradients contiguous vector adds, whatever texels it reads.
 * The pixel kernel's lanes are pixels: there a pixel's taps were scalar gathers and scatters, which
 * cost 4-5x the shading itself on a mesh. LANES particles make a vector: 8, or 16 (built with -DLANES=16;
 * native.texel_lanes picks it for float32 where vectors are 64 bytes and it takes fewer passes).
 *
 * Determinism: the pixels come in fixed chunks (the caller's plan, independent of the thread count).
 * A chunk adds its gradients into rows of its own, one per texel it touches (`lidx`: each tap's row),
 * and then each texel sums its rows in chunk order (`rptr`, `rsrc`); energies are summed per chunk in
 * pixel order. So results do not depend on the number of threads or their schedule.
 *
 * Layout (contiguous; P pixels, T texels, n particles):
 *   kd, ks [n, 3, T] and r [n, T], or one constant texel ([n, 3, 1], [n, 1]; flags bits 0-2: kd, r, ks);
 *   flags bits 3-5: kd, r, ks need no gradient (not written; their pointers may be null)
 *   nl, nh2, w [V, L, P]; nv [V, P]; A = scale * (n.l) [V, L, 3, P]; y, gout-per-view [.., 3, P]; wgt [V, P]
 *   tidx int32 [P, 4] texel indices, tw [P, 4] bilinear weights
 *   plan: cstart [nchunk + 1] pixel offsets of the chunks; uoff [nchunk + 1] offsets of their texel rows;
 *         lidx int32 [P, 4] the row (within its chunk) of each tap; rptr [T + 1], rsrc int32 [rows]:
 *         the rows of texel t are rsrc[rptr[t] .. rptr[t + 1]), in chunk order
 *   out [n, V, 3, P] (images), epart [n, nchunk] (energies), gkd, gr, gks shaped like kd, r, ks
 *   env [V, P, 3 + 6 (nodes + 2) + 2] (rows padded by 2, so a slot's 6 values load as one vector) or NULL: an environment light's precomputed terms (transfer.py): E, then per
 *       roughness slot a, b (a ghost slot at each end), read by Catmull-Rom in log r (nodes at t0 + k dt)
 * Returns 0, or 1 when its scratch memory could not be allocated.
 */
#include <omp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "_native_brdf.h"

#ifndef LANES
#define LANES 8 /* particles per vector: 8 (an AVX2 register of floats), or 16 (-DLANES=16: AVX-512's) */
#endif
#if LANES != 8 && LANES != 16
#error "LANES must be 8 or 16"
#endif
#define LMAX 4  /* lights per view (the caller checks) */
#define TILE 128 /* texels per step of the layout passes (long enough runs of each map row for the prefetcher) */
#define MODE_IMAGE_FWD 0
#define MODE_IMAGE_BWD 1
#define MODE_LOSS 2

typedef REAL vec __attribute__((vector_size(LANES * sizeof(REAL))));
typedef REAL vecu __attribute__((vector_size(LANES * sizeof(REAL)), aligned(sizeof(REAL))));
/* Energies are summed in double as two halves of LANES / 2 lanes, each as wide as a vec of floats (32 bytes for 8
 * lanes). One vector of 8 doubles is 64 bytes, which GCC lowers on AVX2 through the stack and general registers, with
 * a failed store-to-load forwarding on every pixel: on the bunny, one block of particles took 4.4 ms that way and
 * 3.7 ms in halves. */
typedef double dhalf __attribute__((vector_size(LANES / 2 * sizeof(double))));
typedef REAL hvec __attribute__((vector_size(LANES / 2 * sizeof(REAL))));
struct esum { dhalf lo, hi; };
static inline void esum_add(struct esum *s, vec e)
{
    hvec lo, hi;
    memcpy(&lo, &e, sizeof lo);
    memcpy(&hi, (const char *)&e + sizeof lo, sizeof hi);
    s->lo += __builtin_convertvector(lo, dhalf);
    s->hi += __builtin_convertvector(hi, dhalf);
}
#define LD(p) ((vec)(*(const vecu *)(p)))
#define ST(p, x) (*(vecu *)(p) = (x))

#define VSIGN(d) __builtin_convertvector(((d) < 0) - ((d) > 0), vec)

/* channels: 0-2 kd, 3 r, 4-6 ks */
static inline int map_of(int ch) { return ch < 3 ? 0 : ch == 3 ? 1 : 2; }

struct targs {
    int64_t mode, n, V, L, P, T, l2, grad, flags, np, nch, row, nchunk;
    REAL kf;
    const int32_t *tidx, *lidx; const REAL *tw;
    const int64_t *cstart, *uoff;
    const REAL *nl, *nv, *nh2, *w, *amp, *y, *wgt, *gout;
    REAL *out;
    const REAL *M;     /* maps texel-major [T][nch][np] */
    const REAL *C;     /* constant channels [7][np] */
    REAL *G;           /* gradient rows [rows][nch][np] */
    REAL *GC;          /* constant channels' gradient sums per chunk [nchunk][7][np] */
    double *ES;        /* energies per chunk [nchunk][np] */
    const REAL *env;   /* environment terms per pixel [V][P][ech] (E rgb, then slots of a rgb, b rgb) or 0 */
    int64_t nodes, ech;
    double t0, dt;     /* roughness node k at log r = t0 + k dt */
};

#define BB_CAT_(a, b) a##b
#define BB_CAT(a, b) BB_CAT_(a, b)
#define BB_IS_DOUBLE_double 1
#define BB_IS_DOUBLE_float 0
#if BB_CAT(BB_IS_DOUBLE_, REAL)
typedef int64_t ireal;   /* an integer as wide as REAL */
#define MANT 52
#define EBIAS 1023
#else
typedef int32_t ireal;
#define MANT 23
#define EBIAS 127
#endif
typedef ireal ivec __attribute__((vector_size(LANES * sizeof(ireal))));   /* a comparison's mask of vecs */
typedef REAL vrow __attribute__((vector_size(8 * sizeof(REAL))));          /* a table slot: 6 values, 2 pads */
typedef REAL vrowu __attribute__((vector_size(8 * sizeof(REAL)), aligned(sizeof(REAL))));
typedef ireal irow __attribute__((vector_size(8 * sizeof(ireal))));
#define LDR(p) ((vrow)(*(const vrowu *)(p)))

static inline vec vsel(ivec m, vec a, vec b) { return (vec)((m & (ivec)a) | (~m & (ivec)b)); }

/* log(x) of every lane, for normal x > 0, branch-free: x = m 2^e with m in [sqrt(1/2), sqrt(2)),
 * log m = 2 atanh(s), s = (m - 1) / (m + 1), |s| < 0.172, summed to s^21 (below double's rounding).
 * Within 3 ulp of libm's log / logf. */
static inline vec vlog(vec x)
{
    ivec bits = (ivec)x;
    ivec e = (bits >> MANT) - EBIAS;
    vec m = (vec)((bits & (((ireal)1 << MANT) - 1)) | ((ireal)EBIAS << MANT));
    const ivec big = m > (REAL)1.4142135623730951;
    m = vsel(big, m * (REAL)0.5, m);
    e -= big;   /* a true mask is -1 */
    const vec s = (m - 1) / (m + 1), s2 = s * s;
    vec p = s2 * (REAL)(1.0 / 21) + (REAL)(1.0 / 19);
    p = p * s2 + (REAL)(1.0 / 17); p = p * s2 + (REAL)(1.0 / 15); p = p * s2 + (REAL)(1.0 / 13);
    p = p * s2 + (REAL)(1.0 / 11); p = p * s2 + (REAL)(1.0 / 9); p = p * s2 + (REAL)(1.0 / 7);
    p = p * s2 + (REAL)(1.0 / 5); p = p * s2 + (REAL)(1.0 / 3); p = p * s2 + 1;
    return __builtin_convertvector(e, vec) * (REAL)0.6931471805599453 + 2 * s * p;
}

/* The rows r[0..7] of an 8 x 8 block become its columns (three rounds of two-vector shuffles) */
#if defined(__clang__)
#define SHUF(a, b, ...) __builtin_shufflevector(a, b, __VA_ARGS__)
#else
#define SHUF(a, b, ...) __builtin_shuffle(a, b, (irow){__VA_ARGS__})
#endif
static inline void transpose8(vrow r[8])
{
    vrow a[8], b[8];
    for (int i = 0; i < 8; i += 2) {
        a[i] = SHUF(r[i], r[i + 1], 0, 8, 2, 10, 4, 12, 6, 14);
        a[i + 1] = SHUF(r[i], r[i + 1], 1, 9, 3, 11, 5, 13, 7, 15);
    }
    for (int i = 0; i < 8; i += 4)
        for (int j = i; j < i + 2; j++) {
            b[j] = SHUF(a[j], a[j + 2], 0, 1, 8, 9, 4, 5, 12, 13);
            b[j + 2] = SHUF(a[j], a[j + 2], 2, 3, 10, 11, 6, 7, 14, 15);
        }
    for (int j = 0; j < 4; j++) {
        r[j] = SHUF(b[j], b[j + 4], 0, 1, 2, 3, 8, 9, 10, 11);
        r[j + 4] = SHUF(b[j], b[j + 4], 4, 5, 6, 7, 12, 13, 14, 15);
    }
}

#define STR(p, x) (*(vrowu *)(p) = (x))

/* Texels t0..t1 of one channel of the maps, particle-major (particle i at src + i * stride), into texel-major
 * rows (texel t's n particles at m + t * row, padded to np lanes with a harmless 0.5): 8 particles x 8 texels
 * at a time as 8 vector loads, a transpose and 8 vector stores. Texels that no pixel reads (no gradient rows:
 * rptr[t + 1] == rptr[t], e.g. a texture atlas's gaps) are left unwritten, 8 at a time. */
static void to_texel_major(REAL *restrict m, int64_t row, const REAL *restrict src, int64_t stride, int64_t n,
                           int64_t np, const int64_t *rptr, int64_t t0, int64_t t1)
{
    const vrow half = (vrow){0} + (REAL)0.5;
    for (int64_t i0 = 0; i0 < np; i0 += 8) {
        int64_t t = t0;
        for (; t + 8 <= t1; t += 8) {
            if (rptr[t + 8] == rptr[t]) continue;
            vrow r[8];
            for (int k = 0; k < 8; k++) r[k] = i0 + k < n ? LDR(src + (i0 + k) * stride + t) : half;
            transpose8(r);
            for (int j = 0; j < 8; j++) STR(m + (t + j) * row + i0, r[j]);
        }
        for (; t < t1; t++)
            for (int k = 0; k < 8; k++) m[t * row + i0 + k] = i0 + k < n ? src[(i0 + k) * stride + t] : (REAL)0.5;
    }
}

/* The inverse for the gradients: texel-major rows of texels t0..t1 (texel t's particles at rp[t - t0] + off)
 * into the n particles' maps (particle i at dst + i * stride). */
static void from_texel_major(REAL *restrict dst, int64_t stride, const REAL *const *rp, int64_t off, int64_t n,
                             int64_t t0, int64_t t1)
{
    for (int64_t i0 = 0; i0 < n; i0 += 8) {
        int64_t t = t0;
        for (; t + 8 <= t1; t += 8) {
            vrow r[8];
            for (int j = 0; j < 8; j++) r[j] = LDR(rp[t - t0 + j] + off + i0);
            transpose8(r);
            for (int k = 0; k < 8 && i0 + k < n; k++) STR(dst + (i0 + k) * stride + t, r[k]);
        }
        for (; t < t1; t++)
            for (int k = 0; k < 8 && i0 + k < n; k++) dst[(i0 + k) * stride + t] = rp[t - t0][off + i0 + k];
    }
}

/* Catmull-Rom in log r of the environment's tables at the lanes' roughness: values and d/dr of a, b.
 * The lanes' nodes and weights are computed as vectors without branches; each lane's 4 slots load as 4 rows (a
 * slot's 6 values as one vector, rows padded by 2), a transpose per slot and 8 lanes turns them into vectors over
 * the lanes, and the slots are weighted as vectors (weighting each lane's rows by its weights before one transpose
 * took a broadcast of each of its 8 weights: on the bunny, the kernel 16.1-17.0 against 14.1 ms, the same bits). */
static inline void env_lookup(const struct targs *restrict q, const REAL *restrict ep, const vec rr,
                              vec va[6], vec vd[6])
{
    const ireal N = (ireal)q->nodes;
    const REAL t0 = (REAL)q->t0, idt = (REAL)(1.0 / q->dt), top = (REAL)(N - 1);
    const vec zero = {0}, r = vsel(rr > (REAL)1e-30, rr, zero + (REAL)1e-30);
    const vec tr = (vlog(r) - t0) * idt;
    const ivec lo = tr <= 0, hi = tr >= top;
    const vec t = vsel(lo, zero, vsel(hi, zero + top, tr)), ds = vsel(lo | hi, zero, idt / r);
    ivec k = __builtin_convertvector(t, ivec);
    const ivec top_k = k - k + (N - 2);
    const ivec over = k > top_k;
    k = (over & top_k) | (~over & k);
    const vec x = t - __builtin_convertvector(k, vec), x2 = x * x, x3 = x2 * x;
    const vec w0 = (REAL)0.5 * (-x + 2 * x2 - x3), w1 = (REAL)0.5 * (2 - 5 * x2 + 3 * x3),
              w2 = (REAL)0.5 * (x + 4 * x2 - 3 * x3), w3 = (REAL)0.5 * (x3 - x2);
    const vec d0 = (REAL)0.5 * (-1 + 4 * x - 3 * x2) * ds, d1 = (REAL)0.5 * (-10 * x + 9 * x2) * ds,
              d2 = (REAL)0.5 * (1 + 8 * x - 9 * x2) * ds, d3 = (REAL)0.5 * (3 * x2 - 2 * x) * ds;
#if LANES == 16
    /* 16 lanes: the table is value-major (env_layout), so value c's slots are one 32-entry table held in two
     * vectors, and each tap of all 16 lanes is one two-vector permute by the lanes' slot indices */
    const int64_t sl = q->nodes + 2;
    for (int c = 0; c < 6; c++) {
        const REAL *tb = ep + 3 + c * sl;
        const vec lo16 = LD(tb), hi16 = LD(tb + 16);
        const vec f0 = __builtin_shuffle(lo16, hi16, k), f1 = __builtin_shuffle(lo16, hi16, k + 1),
                  f2 = __builtin_shuffle(lo16, hi16, k + 2), f3 = __builtin_shuffle(lo16, hi16, k + 3);
        va[c] = w0 * f0 + w1 * f1 + w2 * f2 + w3 * f3;
        vd[c] = d0 * f0 + d1 * f1 + d2 * f2 + d3 * f3;
    }
#else
    for (int g = 0; g < LANES; g += 8) {
        vrow F[4][8];   /* tap m's slot of each of 8 lanes (6 values), transposed into vectors over the lanes */
        for (int i = 0; i < 8; i++) {
            const REAL *tb = ep + 3 + k[g + i] * 6;
            for (int m = 0; m < 4; m++) F[m][i] = LDR(tb + 6 * m);
        }
        for (int m = 0; m < 4; m++) transpose8(F[m]);
        vrow W[4], D[4];   /* the 8 lanes' weights of each slot (one by one: from an array, 8 % slower) */
        memcpy(W, (const REAL *)&w0 + g, sizeof W[0]); memcpy(W + 1, (const REAL *)&w1 + g, sizeof W[0]);
        memcpy(W + 2, (const REAL *)&w2 + g, sizeof W[0]); memcpy(W + 3, (const REAL *)&w3 + g, sizeof W[0]);
        memcpy(D, (const REAL *)&d0 + g, sizeof D[0]); memcpy(D + 1, (const REAL *)&d1 + g, sizeof D[0]);
        memcpy(D + 2, (const REAL *)&d2 + g, sizeof D[0]); memcpy(D + 3, (const REAL *)&d3 + g, sizeof D[0]);
        for (int c = 0; c < 6; c++) {
            const vrow a = W[0] * F[0][c] + W[1] * F[1][c] + W[2] * F[2][c] + W[3] * F[3][c];
            const vrow d = D[0] * F[0][c] + D[1] * F[1][c] + D[2] * F[2][c] + D[3] * F[3][c];
            memcpy((REAL *)&va[c] + g, &a, sizeof a);
            memcpy((REAL *)&vd[c] + g, &d, sizeof d);
        }
    }
#endif
}

/* channel ch's place in a texel row under `flags`, or -1 for a constant map: the maps' channels that are not
 * constant, in order (a constant expression where flags is one, so a specialised chunk_body has no look-ups) */
static inline int slot_of(int ch, int64_t flags)
{
    if ((flags >> map_of(ch)) & 1) return -1;
    int s = 0;
    for (int j = 0; j < ch; j++) s += !((flags >> map_of(j)) & 1);
    return s;
}

/* What one pixel gives a block of particles: its energy and the gradients of its 7 channels */
struct pres { vec e, acc[7]; };

/* One pixel p for the block of particles at lane b: its radiance (written out in MODE_IMAGE_FWD), energy and
 * channel gradients. It writes no gradient: the caller deposits them (deposit), after every block's pixel. */
static inline __attribute__((always_inline)) void pixel(const struct targs *restrict q, const int64_t p,
                                                        const int64_t b, const int64_t mode, const int64_t L,
                                                        const int64_t Vc, const int envp, const int64_t l2,
                                                        const int64_t flags, struct pres *restrict res)
{
    const int64_t V = Vc ? Vc : q->V, P = q->P, np = q->np, row = q->row, grad = q->grad;
    const REAL kf = q->kf;
    const int32_t *ti = q->tidx + p * 4;
    const REAL *tw = q->tw + p * 4;
    const REAL w0 = tw[0], w1 = tw[1], w2 = tw[2], w3 = tw[3];
    const REAL *M0 = q->M + ti[0] * row, *M1 = q->M + ti[1] * row, *M2 = q->M + ti[2] * row, *M3 = q->M + ti[3] * row;
    vec val[7];
#pragma GCC unroll 7   /* see deposit */
    for (int ch = 0; ch < 7; ch++) {
        const int64_t o = slot_of(ch, flags) * np + b;
        val[ch] = slot_of(ch, flags) < 0 ? LD(q->C + ch * np + b)
                                         : w0 * LD(M0 + o) + w1 * LD(M1 + o) + w2 * LD(M2 + o) + w3 * LD(M3 + o);
    }
    const vec kd0 = val[0], kd1 = val[1], kd2 = val[2], rr = val[3], ks0 = val[4], ks1 = val[5], ks2 = val[6];
    const vec a = rr * rr, a2 = a * a, k = (REAL)0.5 * a;
    vec akd0 = {0}, akd1 = {0}, akd2 = {0}, aks0 = {0}, aks1 = {0}, aks2 = {0}, ar = {0}, e = {0};
    for (int64_t v = 0; v < V; v++) {
        const REAL nv = q->nv[v * P + p];
        vec o0 = {0}, o1 = {0}, o2 = {0}, g0 = {0}, g1 = {0}, g2 = {0}, sS[LMAX], sD[LMAX];
        vec ea[6], ed[6];
        REAL E0 = 0, E1 = 0, E2 = 0;
        if (envp) {   /* the environment: kd (1 - kf ks) / pi E + ks a(r) + b(r) */
            const REAL *ep = q->env + (v * P + p) * q->ech;
            E0 = ep[0] * BB_INV_PI; E1 = ep[1] * BB_INV_PI; E2 = ep[2] * BB_INV_PI;
            env_lookup(q, ep, rr, ea, ed);
            o0 += kd0 * (1 - kf * ks0) * E0 + ks0 * ea[0] + ea[3];
            o1 += kd1 * (1 - kf * ks1) * E1 + ks1 * ea[1] + ea[4];
            o2 += kd2 * (1 - kf * ks2) * E2 + ks2 * ea[2] + ea[5];
        }
        for (int64_t l = 0; l < L; l++) {
            const int64_t vl = v * L + l;
            const REAL nl = q->nl[vl * P + p], nh2 = q->nh2[vl * P + p], wj = q->w[vl * P + p];
            const REAL *A = q->amp + vl * 3 * P + p;
            vec s, sd = {0};
            BB_SPEC(rr, a, a2, k, nh2, nl, nv, s, sd, grad);
            sS[l] = s; sD[l] = sd;
            o0 += BB_RADIANCE(A[0], kd0, ks0, s, wj, kf);
            o1 += BB_RADIANCE(A[P], kd1, ks1, s, wj, kf);
            o2 += BB_RADIANCE(A[2 * P], kd2, ks2, s, wj, kf);
        }
        if (mode == MODE_IMAGE_FWD) {
            for (int64_t i = b; i < b + LANES && i < q->n; i++) {
                REAL *out = q->out + ((i * V + v) * 3) * P + p;
                out[0] = o0[i - b]; out[P] = o1[i - b]; out[2 * P] = o2[i - b];
            }
            continue;
        }
        if (mode == MODE_LOSS) {
            const REAL *Y = q->y + v * 3 * P + p, wg = q->wgt[v * P + p];
            const vec d0 = o0 - Y[0], d1 = o1 - Y[P], d2 = o2 - Y[2 * P];
            if (l2) {
                e += wg * (d0 * d0 + d1 * d1 + d2 * d2);
                g0 = 2 * wg * d0; g1 = 2 * wg * d1; g2 = 2 * wg * d2;
            } else {
                const vec s0 = VSIGN(d0), s1 = VSIGN(d1), s2 = VSIGN(d2);
                e += wg * (s0 * d0 + s1 * d1 + s2 * d2);
                g0 = wg * s0; g1 = wg * s1; g2 = wg * s2;
            }
        } else {
            for (int64_t i = b; i < b + LANES && i < q->n; i++) {
                const REAL *go = q->gout + ((i * V + v) * 3) * P + p;
                g0[i - b] = go[0]; g1[i - b] = go[P]; g2[i - b] = go[2 * P];
            }
        }
        if (!grad) continue;
        if (envp) {
            akd0 += g0 * (1 - kf * ks0) * E0; akd1 += g1 * (1 - kf * ks1) * E1; akd2 += g2 * (1 - kf * ks2) * E2;
            aks0 += g0 * (ea[0] - kf * kd0 * E0); aks1 += g1 * (ea[1] - kf * kd1 * E1);
            aks2 += g2 * (ea[2] - kf * kd2 * E2);
            ar += g0 * (ks0 * ed[0] + ed[3]) + g1 * (ks1 * ed[1] + ed[4]) + g2 * (ks2 * ed[2] + ed[5]);
        }
        for (int64_t l = 0; l < L; l++) {
            const int64_t vl = v * L + l;
            const REAL wj = q->w[vl * P + p], *A = q->amp + vl * 3 * P + p;
            vec gF = {0};
            BB_GRAD(g0, A[0], kd0, ks0, sS[l], wj, kf, akd0, aks0, gF);
            BB_GRAD(g1, A[P], kd1, ks1, sS[l], wj, kf, akd1, aks1, gF);
            BB_GRAD(g2, A[2 * P], kd2, ks2, sS[l], wj, kf, akd2, aks2, gF);
            ar += gF * sD[l];
        }
    }
    res->e = e;
    res->acc[0] = akd0; res->acc[1] = akd1; res->acc[2] = akd2; res->acc[3] = ar;
    res->acc[4] = aks0; res->acc[5] = aks1; res->acc[6] = aks2;
}

/* Pixel p's results into the block's sums: its energy, its constant maps' gradients, and its texel maps'
 * gradients into the chunk's rows of its four taps */
static inline __attribute__((always_inline)) void deposit(const struct targs *restrict q, REAL *restrict G,
                                                          const int64_t p, const int64_t b, const int64_t mode,
                                                          const int64_t flags, const struct pres *restrict res,
                                                          struct esum *es, vec gcs[7])
{
    const int64_t np = q->np, row = q->row;
    if (mode == MODE_LOSS) esum_add(es, res->e);
    if (!q->grad) return;
    const int32_t *li = q->lidx + p * 4;
    const REAL *tw = q->tw + p * 4;
    const REAL w0 = tw[0], w1 = tw[1], w2 = tw[2], w3 = tw[3];
    REAL *G0 = G + li[0] * row, *G1 = G + li[1] * row, *G2 = G + li[2] * row, *G3 = G + li[3] * row;
#pragma GCC unroll 7   /* unrolled, slot_of(ch, flags) is a constant (else a loop of its own every time) */
    for (int ch = 0; ch < 7; ch++) {
        if (flags & (8 << map_of(ch))) continue;
        const vec g = res->acc[ch];
        if (slot_of(ch, flags) < 0) {
            gcs[ch] += g;
        } else {
            const int64_t o = slot_of(ch, flags) * np + b;
            ST(G0 + o, LD(G0 + o) + w0 * g); ST(G1 + o, LD(G1 + o) + w1 * g);
            ST(G2 + o, LD(G2 + o) + w2 * g); ST(G3 + o, LD(G3 + o) + w3 * g);
        }
    }
}

/* nb (1-3) blocks of particles from lane b over the chunk's pixels p0..p1: each pixel is shaded for every block,
 * then deposited block by block, so a block's sums are in pixel order as with one block at a time. A pixel's
 * scalar work (its taps, weights and geometry) is shared by the blocks, and their chains of dependent operations
 * are in flight together: 20 particles on 16 lanes, whose second block holds 4, cost 0.8 of two passes. */
static inline __attribute__((always_inline)) void blocks(const struct targs *restrict q, REAL *restrict G,
                                                         REAL *restrict GC, double *restrict ES, const int64_t b,
                                                         const int nb, const int64_t p0, const int64_t p1,
                                                         const int64_t mode, const int64_t L, const int64_t Vc,
                                                         const int envp, const int64_t l2, const int64_t flags)
{
    const int64_t np = q->np;
    struct esum es[3] = {{{0}}};   /* the blocks' energies and constant maps' gradients, summed in pixel order */
    vec gcs[3][7] = {{{0}}};
    for (int64_t p = p0; p < p1; p++) {
        struct pres r[3];
        for (int j = 0; j < nb; j++) pixel(q, p, b + j * LANES, mode, L, Vc, envp, l2, flags, &r[j]);
        for (int j = 0; j < nb; j++) deposit(q, G, p, b + j * LANES, mode, flags, &r[j], &es[j], gcs[j]);
    }
    for (int j = 0; j < nb; j++) {
        memcpy(ES + b + j * LANES, &es[j], sizeof es[j]);   /* lo, then hi: the block's lanes in order */
        for (int ch = 0; ch < 7; ch++) ST(GC + ch * np + b + j * LANES, gcs[j][ch]);
    }
}

/* One chunk of pixels. Written once for every case; chunk() calls it with the common cases' mode, lights, views
 * (Vc; 0: q->V), environment, loss and flags as constants, so that the compiler drops the branches, the views' loop
 * and the per-light arrays and keeps more of the blocks' terms in registers. */
static inline __attribute__((always_inline)) void chunk_body(const struct targs *restrict q, const int64_t c,
                                                             const int64_t mode, const int64_t L, const int64_t Vc,
                                                             const int envp, const int64_t l2, const int64_t flags)
{
    const int64_t np = q->np, row = q->row;
    REAL *restrict G = q->G + q->uoff[c] * row, *restrict GC = q->GC + c * 7 * np;
    double *restrict ES = q->ES + c * np;
    const int64_t p0 = q->cstart[c], p1 = q->cstart[c + 1];
    if (q->grad) memset(G, 0, (size_t)((q->uoff[c + 1] - q->uoff[c]) * row) * sizeof(REAL));
    for (int64_t b = 0; b < np;) {   /* the particles in groups of up to 3 blocks */
        const int64_t nb = (np - b) / LANES;
        if (nb >= 3) { blocks(q, G, GC, ES, b, 3, p0, p1, mode, L, Vc, envp, l2, flags); b += 3 * LANES; }
        else if (nb == 2) { blocks(q, G, GC, ES, b, 2, p0, p1, mode, L, Vc, envp, l2, flags); b += 2 * LANES; }
        else { blocks(q, G, GC, ES, b, 1, p0, p1, mode, L, Vc, envp, l2, flags); b += LANES; }
    }
}

static void chunk(const struct targs *restrict q, const int64_t c)
{
    /* the fits' cases with constants: one view (a fit's pixels come compacted into one row: shade.shade_loss), one
     * light (a flash) or none (an environment alone), L1 loss, and the maps all per texel or the specular constant
     * (without its gradient) */
    const int64_t f = q->flags;
    if (q->mode == MODE_LOSS && q->V == 1 && !q->l2 && (f == 0 || f == (4 | 32))) {
        if (q->L == 1 && !q->env) {
            if (f == 0) chunk_body(q, c, MODE_LOSS, 1, 1, 0, 0, 0);
            else chunk_body(q, c, MODE_LOSS, 1, 1, 0, 0, 4 | 32);
            return;
        }
        if (q->L == 0 && q->env) {
            if (f == 0) chunk_body(q, c, MODE_LOSS, 0, 1, 1, 0, 0);
            else chunk_body(q, c, MODE_LOSS, 0, 1, 1, 0, 4 | 32);
            return;
        }
    }
    chunk_body(q, c, q->mode, q->L, 0, q->env != 0, q->l2, f);
}

/* The widest vector the compiler was allowed (-march): 64 bytes with AVX-512, else 32 */
int64_t bb_texel_vector_bytes(void)
{
#if defined(__AVX512F__)
    return 64;
#else
    return 32;
#endif
}

static void *amalloc(size_t n) { return aligned_alloc(64, (n + 63) / 64 * 64); }

int bb_shade_texels(int64_t mode, int64_t n, int64_t V, int64_t L, int64_t P, int64_t ks_factor, int64_t l2,
                    int64_t need_grad, int64_t nthreads, int64_t T, int64_t flags, int64_t nchunk,
                    const int32_t *tidx, const REAL *tw, const int64_t *cstart, const int64_t *uoff,
                    const int32_t *lidx, const int64_t *rptr, const int32_t *rsrc,
                    const REAL *kd, const REAL *r, const REAL *ks,
                    const REAL *nl, const REAL *nv, const REAL *nh2, const REAL *w, const REAL *amp,
                    const REAL *y, const REAL *wgt, const REAL *gout,
                    REAL *out, double *epart, REAL *gkd, REAL *gr, REAL *gks,
                    const REAL *env, int64_t nodes, double t0, double dt)
{
    const int64_t np = (n + LANES - 1) / LANES * LANES;
    struct targs q = {mode, n, V, L, P, T, l2, (mode == MODE_IMAGE_BWD) || (mode == MODE_LOSS && need_grad),
                      flags, np, 0, 0, nchunk, ks_factor ? (REAL)1 : (REAL)0, tidx, lidx, tw, cstart, uoff,
                      nl, nv, nh2, w, amp, y, wgt, gout, out, 0, 0, 0, 0, 0,
                      env, nodes, 3 + 6 * (nodes + 2) + (LANES == 16 ? 14 : 2), t0, dt};
    const REAL *src[7];    /* channel ch of particle i: src[ch][i * stride[ch] + t] */
    int64_t stride[7];
    REAL *dst[7];
    for (int ch = 0; ch < 7; ch++) {
        const int mi = map_of(ch), c3 = ch < 3 ? ch : ch - 4, cons = (flags >> mi) & 1;
        const int64_t Tm = cons ? 1 : T;
        src[ch] = mi == 0 ? kd + c3 * Tm : mi == 1 ? r : ks + c3 * Tm;
        dst[ch] = (flags & (8 << mi)) ? 0 : mi == 0 ? gkd + c3 * Tm : mi == 1 ? gr : gks + c3 * Tm;  /* unwanted: null */
        stride[ch] = mi == 1 ? Tm : 3 * Tm;
        q.nch += !cons;
    }
    const int64_t nch = q.nch, row = nch * np, rows = uoff[nchunk];
    q.row = row;
    REAL *M = amalloc((size_t)(T * row + 1) * sizeof(REAL)), *C = amalloc((size_t)(7 * np) * sizeof(REAL));
    REAL *Gb = q.grad ? amalloc((size_t)(rows * row + 1) * sizeof(REAL)) : 0;
    REAL *GC = amalloc((size_t)(nchunk * 7 * np + 1) * sizeof(REAL));
    REAL *B = q.grad ? amalloc((size_t)(nthreads * TILE * row + 1) * sizeof(REAL)) : 0;
    REAL *Z = amalloc(((size_t)row + 8) * sizeof(REAL));   /* the gradient row of a texel that no pixel reads */
    if (Z) memset(Z, 0, ((size_t)row + 8) * sizeof(REAL));
    double *ES = malloc((size_t)(nchunk * np + 1) * sizeof(double));
    if (!M || !C || !GC || !ES || !Z || (q.grad && (!Gb || !B))) {
        free(M); free(C); free(Gb); free(GC); free(B); free(ES); free(Z);
        return 1;
    }
    q.M = M; q.C = C; q.G = Gb; q.GC = GC; q.ES = ES;
    /* lanes past n hold a harmless material (0.5 everywhere) and are never read out */
    for (int ch = 0; ch < 7; ch++)
        for (int64_t i = 0; i < np; i++) C[ch * np + i] = slot_of(ch, flags) < 0 && i < n ? src[ch][i * stride[ch]] : (REAL)0.5;
#pragma omp parallel num_threads(nthreads)
    {
#pragma omp for schedule(static)
        for (int64_t t0 = 0; t0 < T; t0 += TILE) {   /* the maps, texel-major: 8 x 8 blocks transposed */
            const int64_t t1 = t0 + TILE < T ? t0 + TILE : T;
            for (int ch = 0; ch < 7; ch++)
                if (slot_of(ch, flags) >= 0) to_texel_major(M + slot_of(ch, flags) * np, row, src[ch], stride[ch], n, np, rptr, t0, t1);
        }
#pragma omp for schedule(dynamic, 1)
        for (int64_t c = 0; c < nchunk; c++) chunk(&q, c);
        if (q.grad) {
            REAL *buf = B + omp_get_thread_num() * TILE * row;
            const REAL *rp[TILE];
#pragma omp for schedule(static)
            for (int64_t t0 = 0; t0 < T; t0 += TILE) {   /* each texel sums its chunks' rows, in chunk order */
                const int64_t t1 = t0 + TILE < T ? t0 + TILE : T;
                for (int64_t t = t0; t < t1; t++) {
                    const int64_t e0 = rptr[t], e1 = rptr[t + 1];
                    if (e1 - e0 <= 1) {   /* no rows: zeros; one row: itself */
                        rp[t - t0] = e1 == e0 ? Z : Gb + rsrc[e0] * row;
                        continue;
                    }
                    REAL *bt = buf + (t - t0) * row;
                    memcpy(bt, Gb + rsrc[e0] * row, (size_t)row * sizeof(REAL));
                    for (int64_t e = e0 + 1; e < e1; e++) {
                        const REAL *g = Gb + rsrc[e] * row;
                        for (int64_t k = 0; k < row; k++) bt[k] += g[k];
                    }
                    rp[t - t0] = bt;
                }
                for (int ch = 0; ch < 7; ch++)
                    if (slot_of(ch, flags) >= 0 && !(flags & (8 << map_of(ch))))
                        from_texel_major(dst[ch], stride[ch], rp, slot_of(ch, flags) * np, n, t0, t1);
            }
        }
    }
    for (int64_t i = 0; i < n; i++) {
        if (mode == MODE_LOSS)
            for (int64_t c = 0; c < nchunk; c++) epart[i * nchunk + c] = ES[c * np + i];
        if (!q.grad) continue;
        for (int ch = 0; ch < 7; ch++) {   /* constant maps: the chunks' sums, in chunk order */
            if (slot_of(ch, flags) >= 0 || (flags & (8 << map_of(ch)))) continue;
            REAL s = 0;
            for (int64_t c = 0; c < nchunk; c++) s += GC[(c * 7 + ch) * np + i];
            dst[ch][i * stride[ch]] = s;
        }
    }
    free(M); free(C); free(Gb); free(GC); free(B); free(ES); free(Z);
    return 0;
}
