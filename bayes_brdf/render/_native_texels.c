/* Fused CPU shading kernel for pixels that read texel maps through bilinear taps (a mesh's pixels, a
 * perspective view of the plane), compiled on first use by native.py.
 *
 * The same three jobs as _native_kernels.c (MODE_IMAGE_FWD, MODE_IMAGE_BWD, MODE_LOSS) and the same
 * BRDF terms (_native_brdf.h), but the particles are the SIMD lanes: every particle reads the same
 * four texels at a pixel, so with the maps copied texel-major ([T][channel][particle]) a pixel's taps
 * are contiguous vector loads, and its gradients contiguous vector adds, whatever texels it reads.
 * The pixel kernel's lanes are pixels: there a pixel's taps were scalar gathers and scatters, which
 * cost 4-5x the shading itself on a mesh.
 *
 * Determinism: the pixels come in fixed chunks (the caller's plan, independent of the thread count).
 * A chunk adds its gradients into rows of its own, one per texel it touches (`lidx`: each tap's row),
 * and then each texel sums its rows in chunk order (`rptr`, `rsrc`); energies are summed per chunk in
 * pixel order. So results do not depend on the number of threads or their schedule.
 *
 * Layout (contiguous; P pixels, T texels, n particles):
 *   kd, ks [n, 3, T] and r [n, T], or one constant texel ([n, 3, 1], [n, 1]; flags bits 0-2: kd, r, ks);
 *   flags bits 3-5: kd, r, ks need no gradient
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
#include <math.h>

#include "_native_brdf.h"

#define LOG(x) (sizeof(REAL) == sizeof(float) ? logf((float)(x)) : log((double)(x)))
#define LANES 8 /* particles per vector (AVX2 floats; doubles take two registers) */
#define LMAX 4  /* lights per view (the caller checks) */
#define TILE 16 /* texels per step of the layout passes */
#define MODE_IMAGE_FWD 0
#define MODE_IMAGE_BWD 1
#define MODE_LOSS 2

typedef REAL vec __attribute__((vector_size(LANES * sizeof(REAL))));
typedef REAL vecu __attribute__((vector_size(LANES * sizeof(REAL)), aligned(sizeof(REAL))));
typedef double dvecu __attribute__((vector_size(LANES * sizeof(double)), aligned(sizeof(double))));
typedef double dvec __attribute__((vector_size(LANES * sizeof(double))));
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
    int slot[7];       /* channel -> its place in a texel row, or -1 (a constant map) */
    const REAL *M;     /* maps texel-major [T][nch][np] */
    const REAL *C;     /* constant channels [7][np] */
    REAL *G;           /* gradient rows [rows][nch][np] */
    REAL *GC;          /* constant channels' gradient sums per chunk [nchunk][7][np] */
    double *ES;        /* energies per chunk [nchunk][np] */
    const REAL *env;   /* environment terms per pixel [V][P][ech] (E rgb, then slots of a rgb, b rgb) or 0 */
    int64_t nodes, ech;
    double t0, dt;     /* roughness node k at log r = t0 + k dt */
};

/* Catmull-Rom in log r of the environment's tables at the lanes' roughness: values and d/dr of a, b */
static inline void env_lookup(const struct targs *restrict q, const REAL *restrict ep, const vec rr,
                              vec va[6], vec vd[6])
{
    const int64_t N = q->nodes;
    REAL xa[6][LANES], xd[6][LANES], tt[LANES], dd[LANES];
    const REAL t0 = (REAL)q->t0, idt = (REAL)(1.0 / q->dt), top = (REAL)(N - 1);
#pragma omp simd
    for (int i = 0; i < LANES; i++) {   /* node coordinate of every lane at once (a vector log) */
        const REAL r = rr[i] > (REAL)1e-30 ? rr[i] : (REAL)1e-30;
        const REAL t = (LOG(r) - t0) * idt;
        tt[i] = t <= 0 ? 0 : (t >= top ? top : t);
        dd[i] = (t <= 0 || t >= top) ? 0 : idt / r;
    }
    for (int i = 0; i < LANES; i++) {   /* one lane: its 4 slots as vectors over the 6 values (rows padded by 2) */
        const REAL t = tt[i], ds = dd[i];
        int64_t k = (int64_t)t;
        if (k > N - 2) k = N - 2;
        const REAL x = t - (REAL)k, x2 = x * x, x3 = x2 * x;
        const REAL w0 = (REAL)0.5 * (-x + 2 * x2 - x3), w1 = (REAL)0.5 * (2 - 5 * x2 + 3 * x3),
                   w2 = (REAL)0.5 * (x + 4 * x2 - 3 * x3), w3 = (REAL)0.5 * (x3 - x2);
        const REAL d0 = (REAL)0.5 * (-1 + 4 * x - 3 * x2) * ds, d1 = (REAL)0.5 * (-10 * x + 9 * x2) * ds,
                   d2 = (REAL)0.5 * (1 + 8 * x - 9 * x2) * ds, d3 = (REAL)0.5 * (3 * x2 - 2 * x) * ds;
        const REAL *tb = ep + 3 + k * 6;
        const vec f0 = LD(tb), f1 = LD(tb + 6), f2 = LD(tb + 12), f3 = LD(tb + 18);
        const vec val = w0 * f0 + w1 * f1 + w2 * f2 + w3 * f3, der = d0 * f0 + d1 * f1 + d2 * f2 + d3 * f3;
        for (int c = 0; c < 6; c++) { xa[c][i] = val[c]; xd[c][i] = der[c]; }
    }
    for (int c = 0; c < 6; c++) { va[c] = LD(xa[c]); vd[c] = LD(xd[c]); }
}

static void chunk(const struct targs *restrict q, const int64_t c)
{
    const int64_t V = q->V, L = q->L, P = q->P, np = q->np, row = q->row, mode = q->mode, grad = q->grad;
    const REAL kf = q->kf;
    REAL *restrict G = q->G + q->uoff[c] * row, *restrict GC = q->GC + c * 7 * np;
    double *restrict ES = q->ES + c * np;
    if (grad) {
        memset(G, 0, (size_t)((q->uoff[c + 1] - q->uoff[c]) * row) * sizeof(REAL));
        memset(GC, 0, (size_t)(7 * np) * sizeof(REAL));
    }
    memset(ES, 0, (size_t)np * sizeof(double));
    for (int64_t p = q->cstart[c]; p < q->cstart[c + 1]; p++) {
        const int32_t *ti = q->tidx + p * 4, *li = q->lidx + p * 4;
        const REAL *tw = q->tw + p * 4;
        const REAL w0 = tw[0], w1 = tw[1], w2 = tw[2], w3 = tw[3];
        const REAL *M0 = q->M + ti[0] * row, *M1 = q->M + ti[1] * row, *M2 = q->M + ti[2] * row,
                   *M3 = q->M + ti[3] * row;
        REAL *G0 = G + li[0] * row, *G1 = G + li[1] * row, *G2 = G + li[2] * row, *G3 = G + li[3] * row;
        for (int64_t b = 0; b < np; b += LANES) {
            vec val[7];
            for (int ch = 0; ch < 7; ch++) {
                const int64_t o = q->slot[ch] * np + b;
                val[ch] = q->slot[ch] < 0 ? LD(q->C + ch * np + b)
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
                if (q->env) {   /* the environment: kd (1 - kf ks) / pi E + ks a(r) + b(r) */
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
                    if (q->l2) {
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
                if (q->env) {
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
            if (mode == MODE_LOSS)
                *(dvecu *)(ES + b) = (dvec)(*(dvecu *)(ES + b)) + __builtin_convertvector(e, dvec);
            if (!grad) continue;
            const vec acc[7] = {akd0, akd1, akd2, ar, aks0, aks1, aks2};
            for (int ch = 0; ch < 7; ch++) {
                if (q->flags & (8 << map_of(ch))) continue;
                const vec g = acc[ch];
                if (q->slot[ch] < 0) {
                    REAL *gc = GC + ch * np + b;
                    ST(gc, LD(gc) + g);
                } else {
                    const int64_t o = q->slot[ch] * np + b;
                    ST(G0 + o, LD(G0 + o) + w0 * g); ST(G1 + o, LD(G1 + o) + w1 * g);
                    ST(G2 + o, LD(G2 + o) + w2 * g); ST(G3 + o, LD(G3 + o) + w3 * g);
                }
            }
        }
    }
}

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
                      nl, nv, nh2, w, amp, y, wgt, gout, out, {0}, 0, 0, 0, 0, 0,
                      env, nodes, 3 + 6 * (nodes + 2) + 2, t0, dt};
    const REAL *src[7];    /* channel ch of particle i: src[ch][i * stride[ch] + t] */
    int64_t stride[7];
    REAL *dst[7];
    for (int ch = 0; ch < 7; ch++) {
        const int mi = map_of(ch), c3 = ch < 3 ? ch : ch - 4, cons = (flags >> mi) & 1;
        const int64_t Tm = cons ? 1 : T;
        src[ch] = mi == 0 ? kd + c3 * Tm : mi == 1 ? r : ks + c3 * Tm;
        dst[ch] = mi == 0 ? gkd + c3 * Tm : mi == 1 ? gr : gks + c3 * Tm;
        stride[ch] = mi == 1 ? Tm : 3 * Tm;
        q.slot[ch] = cons ? -1 : (int)q.nch++;
    }
    const int64_t nch = q.nch, row = nch * np, rows = uoff[nchunk];
    q.row = row;
    REAL *M = malloc((size_t)(T * row + 1) * sizeof(REAL)), *C = malloc((size_t)(7 * np) * sizeof(REAL));
    REAL *Gb = q.grad ? malloc((size_t)(rows * row + 1) * sizeof(REAL)) : 0;
    REAL *GC = malloc((size_t)(nchunk * 7 * np + 1) * sizeof(REAL));
    REAL *B = q.grad ? malloc((size_t)(nthreads * TILE * row + 1) * sizeof(REAL)) : 0;
    double *ES = malloc((size_t)(nchunk * np + 1) * sizeof(double));
    if (!M || !C || !GC || !ES || (q.grad && (!Gb || !B))) {
        free(M); free(C); free(Gb); free(GC); free(B); free(ES);
        return 1;
    }
    q.M = M; q.C = C; q.G = Gb; q.GC = GC; q.ES = ES;
    /* lanes past n hold a harmless material (0.5 everywhere) and are never read out */
    for (int ch = 0; ch < 7; ch++)
        for (int64_t i = 0; i < np; i++) C[ch * np + i] = q.slot[ch] < 0 && i < n ? src[ch][i * stride[ch]] : (REAL)0.5;
#pragma omp parallel num_threads(nthreads)
    {
#pragma omp for schedule(static)
        for (int64_t t0 = 0; t0 < T; t0 += TILE) {   /* the maps, texel-major */
            const int64_t t1 = t0 + TILE < T ? t0 + TILE : T;
            for (int ch = 0; ch < 7; ch++) {
                if (q.slot[ch] < 0) continue;
                for (int64_t i = 0; i < np; i++) {
                    REAL *m = M + q.slot[ch] * np + i;
                    if (i < n) {
                        const REAL *s = src[ch] + i * stride[ch];
                        for (int64_t t = t0; t < t1; t++) m[t * row] = s[t];
                    } else {
                        for (int64_t t = t0; t < t1; t++) m[t * row] = (REAL)0.5;
                    }
                }
            }
        }
#pragma omp for schedule(dynamic, 1)
        for (int64_t c = 0; c < nchunk; c++) chunk(&q, c);
        if (q.grad) {
            REAL *buf = B + omp_get_thread_num() * TILE * row;
#pragma omp for schedule(static)
            for (int64_t t0 = 0; t0 < T; t0 += TILE) {   /* each texel sums its chunks' rows, in chunk order */
                const int64_t t1 = t0 + TILE < T ? t0 + TILE : T;
                for (int64_t t = t0; t < t1; t++) {
                    REAL *bt = buf + (t - t0) * row;
                    memset(bt, 0, (size_t)row * sizeof(REAL));
                    for (int64_t e = rptr[t]; e < rptr[t + 1]; e++) {
                        const REAL *g = Gb + rsrc[e] * row;
                        for (int64_t k = 0; k < row; k++) bt[k] += g[k];
                    }
                }
                for (int ch = 0; ch < 7; ch++) {
                    if (q.slot[ch] < 0 || (flags & (8 << map_of(ch)))) continue;
                    for (int64_t i = 0; i < n; i++) {
                        const REAL *bi = buf + q.slot[ch] * np + i;
                        REAL *d = dst[ch] + i * stride[ch];
                        for (int64_t t = t0; t < t1; t++) d[t] = bi[(t - t0) * row];
                    }
                }
            }
        }
    }
    for (int64_t i = 0; i < n; i++) {
        if (mode == MODE_LOSS)
            for (int64_t c = 0; c < nchunk; c++) epart[i * nchunk + c] = ES[c * np + i];
        if (!q.grad) continue;
        for (int ch = 0; ch < 7; ch++) {   /* constant maps: the chunks' sums, in chunk order */
            if (q.slot[ch] >= 0 || (flags & (8 << map_of(ch)))) continue;
            REAL s = 0;
            for (int64_t c = 0; c < nchunk; c++) s += GC[(c * 7 + ch) * np + i];
            dst[ch][i * stride[ch]] = s;
        }
    }
    free(M); free(C); free(Gb); free(GC); free(B); free(ES);
    return 0;
}
