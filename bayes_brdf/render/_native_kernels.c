/* Fused CPU shading kernels for bayes_brdf (compiled on first use by native.py).
 *
 * One loop nest serves three jobs, chosen by `mode`:
 *   MODE_IMAGE_FWD  out[i, v, c, p]  = sum_l A (kd q + S F)
 *   MODE_IMAGE_BWD  d/d(kd, r, ks) of sum(gout * out)
 *   MODE_LOSS       e[i] = sum wgt * |out - y|  (or (out - y)^2), and its gradient when need_grad
 * with A = scale * (n.l), q = (1 - ks) / pi (or 1 / pi), F = ks (1 - w) + w,
 * S = D G / (4 (n.l)(n.v)), w the Fresnel weight (precomputed per view and light).
 *
 * Layout (contiguous, channel-first, P = H * W pixels):
 *   kd, ks [n, 3, P]; r [n, P]    -- pixels are texels (rectified views), or, with taps (tidx != NULL):
 *   kd, ks [n, 3, T]; r [n, T]    -- texel maps read bilinearly: pixel p is sum_k tw[p, k] map[tidx[p, k]]
 *                                    (tidx int32 [P, 4], tw [P, 4]); gradients scatter back the same way;
 *                                    tex_flags bits 0-2: kd, r, ks is one constant texel ([n, 3, 1]),
 *                                    bits 3-5: kd, r, ks needs no gradient (not scattered)
 *   nl, nh2 = (n.h)^2, w [V, L, P]; nv [V, P]; A = scale * (n.l) [V, L, 3, P]
 *   y, gout-per-view [.., 3, P]; wgt [V, P]
 * Parallel over blocks of pixels, particles inside (the block's geometry stays in
 * cache); each (block, particle) owns its outputs, so the
 * results do not depend on the thread schedule. With taps, gradients scatter into
 * texels that many pixels share: then parallel over particles, blocks inside, each
 * particle's gradient maps owned by one thread (deterministic, no atomics). Views and lights are the inner
 * loops, so the maps are read once and the gradients stay in registers/L1.
 */
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <string.h>

#ifndef REAL
#define REAL float
#endif
#define BLK 64
#define LMAX 4 /* lights per view (the caller checks) */
#define MODE_IMAGE_FWD 0
#define MODE_IMAGE_BWD 1
#define MODE_LOSS 2

#define ABS(x) ((x) < 0 ? -(x) : (x))
#define SIGN(x) ((REAL)(((x) > 0) - ((x) < 0)))

static const REAL INV_PI = (REAL)0.318309886183790671538;

/* Radiance of one view and light over a block; with WITH_GRAD also keep S and S dlnS/dr.
 * A macro so that both variants are straight-line SIMD loops. */
#define SPEC_LOOP(WITH_GRAD) \
    _Pragma("omp simd") \
    for (int64_t j = 0; j < m; j++) { \
        const REAL rr = R[j], a = rr * rr, a2 = a * a, k = (REAL)0.5 * a, nh2 = NH2[j]; \
        const REAL nlj = NL[j], nvj = NV[j], wj = W[j]; \
        const REAL den = nh2 * (a2 - 1) + 1, gl = nlj * (1 - k) + k, gv = nvj * (1 - k) + k; \
        const REAL inv = 1 / (den * gl * gv);                      /* one division for three reciprocals */ \
        const REAL cst = (REAL)0.25 * INV_PI * inv * inv * gl * gv;  /* 1 / (4 pi den^2 gl gv) */ \
        const REAL s = a2 * cst; \
        if (WITH_GRAD) { \
            const REAL iden = gl * gv * inv, igl = den * gv * inv, igv = den * gl * inv; \
            sS[l][j] = s;  /* and s * d ln S / dr, written without 1/r */ \
            sD[l][j] = 4 * rr * a * cst - s * (8 * rr * a * nh2 * iden + rr * ((1 - nlj) * igl + (1 - nvj) * igv)); \
        } \
        o0[j] += A0[j] * (KD0[j] * (1 - kf * KS0[j]) * INV_PI + s * (KS0[j] * (1 - wj) + wj)); \
        o1[j] += A1[j] * (KD1[j] * (1 - kf * KS1[j]) * INV_PI + s * (KS1[j] * (1 - wj) + wj)); \
        o2[j] += A2[j] * (KD2[j] * (1 - kf * KS2[j]) * INV_PI + s * (KS2[j] * (1 - wj) + wj)); \
    }

struct args {
    int64_t mode, n, V, L, P, T, l2, grad, nb, flags;
    REAL kf;
    const int32_t *tidx; const REAL *tw;
    const REAL *kd, *r, *ks, *nl, *nv, *nh2, *w, *amp, *y, *wgt, *gout;
    REAL *out; double *epart; REAL *gkd, *gr, *gks;
};

static inline void block(const struct args *restrict q, const int64_t i, const int64_t b)
{
    const int64_t mode = q->mode, V = q->V, L = q->L, P = q->P, T = q->T, l2 = q->l2, grad = q->grad;
    const REAL kf = q->kf;
    const REAL *restrict nl = q->nl, *restrict nv = q->nv, *restrict nh2 = q->nh2, *restrict w = q->w,
               *restrict amp = q->amp, *restrict y = q->y, *restrict wgt = q->wgt, *restrict gout = q->gout;
    const int64_t p0 = b * BLK;
    const int64_t m = (P - p0) < BLK ? (P - p0) : BLK;
    const REAL *restrict KD0, *restrict KD1, *restrict KD2, *restrict KS0, *restrict KS1, *restrict KS2, *restrict R;
    REAL tkd0[BLK], tkd1[BLK], tkd2[BLK], tks0[BLK], tks1[BLK], tks2[BLK], tr[BLK];
    if (q->tidx) {  /* gather the block's maps from the texels (a constant map: its one value) */
        const int64_t fl = q->flags, Tkd = fl & 1 ? 1 : T, Tr = fl & 2 ? 1 : T, Tks = fl & 4 ? 1 : T;
        const REAL *kd = q->kd + i * 3 * Tkd, *ks = q->ks + i * 3 * Tks, *r = q->r + i * Tr;
        for (int64_t j = 0; j < m; j++) {
            const int32_t *ti = q->tidx + (p0 + j) * 4;
            const REAL *tw = q->tw + (p0 + j) * 4;
            REAL a0 = 0, a1 = 0, a2 = 0, s0 = 0, s1 = 0, s2 = 0, rr = 0;
            for (int k = 0; k < 4; k++) {
                const int64_t t = ti[k];
                const REAL wk = tw[k];
                if (!(fl & 1)) { a0 += wk * kd[t]; a1 += wk * kd[T + t]; a2 += wk * kd[2 * T + t]; }
                if (!(fl & 4)) { s0 += wk * ks[t]; s1 += wk * ks[T + t]; s2 += wk * ks[2 * T + t]; }
                if (!(fl & 2)) rr += wk * r[t];
            }
            if (fl & 1) { a0 = kd[0]; a1 = kd[1]; a2 = kd[2]; }
            if (fl & 4) { s0 = ks[0]; s1 = ks[1]; s2 = ks[2]; }
            if (fl & 2) rr = r[0];
            tkd0[j] = a0; tkd1[j] = a1; tkd2[j] = a2; tks0[j] = s0; tks1[j] = s1; tks2[j] = s2; tr[j] = rr;
        }
        KD0 = tkd0; KD1 = tkd1; KD2 = tkd2; KS0 = tks0; KS1 = tks1; KS2 = tks2; R = tr;
    } else {
        KD0 = q->kd + i * 3 * P + p0; KD1 = KD0 + P; KD2 = KD0 + 2 * P;
        KS0 = q->ks + i * 3 * P + p0; KS1 = KS0 + P; KS2 = KS0 + 2 * P;
        R = q->r + i * P + p0;
    }
    REAL akd0[BLK] = {0}, akd1[BLK] = {0}, akd2[BLK] = {0}, aks0[BLK] = {0}, aks1[BLK] = {0},
         aks2[BLK] = {0}, ar[BLK] = {0}, e[BLK] = {0};
    REAL o0[BLK], o1[BLK], o2[BLK], g0[BLK], g1[BLK], g2[BLK];
    REAL sS[LMAX][BLK], sD[LMAX][BLK];  /* S and S * dlnS/dr per light, kept for the gradient pass */
    for (int64_t v = 0; v < V; v++) {
        const REAL *NV = nv + v * P + p0;
        {  /* radiance of this view, and the specular terms the gradient pass reuses */
            for (int64_t j = 0; j < BLK; j++) o0[j] = o1[j] = o2[j] = 0;
            for (int64_t l = 0; l < L; l++) {
                const int64_t vl = v * L + l;
                const REAL *NL = nl + vl * P + p0, *NH2 = nh2 + vl * P + p0, *W = w + vl * P + p0;
                const REAL *A0 = amp + vl * 3 * P + p0, *A1 = A0 + P, *A2 = A0 + 2 * P;
                if (grad) { SPEC_LOOP(1) } else { SPEC_LOOP(0) }
            }
        }
        if (mode == MODE_IMAGE_FWD) {
            REAL *OUT = q->out + ((i * V + v) * 3) * P + p0;
            for (int64_t j = 0; j < m; j++) { OUT[j] = o0[j]; OUT[P + j] = o1[j]; OUT[2 * P + j] = o2[j]; }
            continue;
        }
        if (mode == MODE_LOSS) {
            const REAL *Y0 = y + v * 3 * P + p0, *Y1 = Y0 + P, *Y2 = Y0 + 2 * P, *WG = wgt + v * P + p0;
            if (l2) {
#pragma omp simd
                for (int64_t j = 0; j < m; j++) {
                    const REAL d0 = o0[j] - Y0[j], d1 = o1[j] - Y1[j], d2 = o2[j] - Y2[j];
                    e[j] += WG[j] * (d0 * d0 + d1 * d1 + d2 * d2);
                    g0[j] = 2 * WG[j] * d0; g1[j] = 2 * WG[j] * d1; g2[j] = 2 * WG[j] * d2;
                }
            } else {
#pragma omp simd
                for (int64_t j = 0; j < m; j++) {
                    const REAL d0 = o0[j] - Y0[j], d1 = o1[j] - Y1[j], d2 = o2[j] - Y2[j];
                    e[j] += WG[j] * (ABS(d0) + ABS(d1) + ABS(d2));
                    g0[j] = WG[j] * SIGN(d0); g1[j] = WG[j] * SIGN(d1); g2[j] = WG[j] * SIGN(d2);
                }
            }
        } else {
            const REAL *GO = gout + ((i * V + v) * 3) * P + p0;
            for (int64_t j = 0; j < m; j++) { g0[j] = GO[j]; g1[j] = GO[P + j]; g2[j] = GO[2 * P + j]; }
        }
        if (!grad) continue;
        for (int64_t l = 0; l < L; l++) {
            const int64_t vl = v * L + l;
            const REAL *NL = nl + vl * P + p0, *NH2 = nh2 + vl * P + p0, *W = w + vl * P + p0;
            const REAL *A0 = amp + vl * 3 * P + p0, *A1 = A0 + P, *A2 = A0 + 2 * P;
            (void)NL; (void)NH2;
#pragma omp simd
            for (int64_t j = 0; j < m; j++) {
                const REAL s = sS[l][j], sd = sD[l][j], wj = W[j];
                REAL gF = 0;
#define GRAD(c) { const REAL gA = g##c[j] * A##c[j]; \
                  akd##c[j] += gA * (1 - kf * KS##c[j]) * INV_PI; \
                  aks##c[j] += gA * (s * (1 - wj) - kf * KD##c[j] * INV_PI); \
                  gF += gA * (KS##c[j] * (1 - wj) + wj); }
                GRAD(0) GRAD(1) GRAD(2)
#undef GRAD
                ar[j] += gF * sd;
            }
        }
    }
    if (mode == MODE_LOSS) {
        double sum = 0;
        for (int64_t j = 0; j < m; j++) sum += e[j];
        q->epart[i * q->nb + b] = sum;
    }
    if (!grad) return;
    if (q->tidx) {  /* scatter to the texels (this particle's maps belong to this thread) */
        const int64_t fl = q->flags, Tkd = fl & 1 ? 1 : T, Tr = fl & 2 ? 1 : T, Tks = fl & 4 ? 1 : T;
        REAL *GKD = q->gkd + i * 3 * Tkd, *GKS = q->gks + i * 3 * Tks, *GR = q->gr + i * Tr;
        REAL c0 = 0, c1 = 0, c2 = 0, c3 = 0, c4 = 0, c5 = 0, c6 = 0;   /* sums for constant maps */
        for (int64_t j = 0; j < m; j++) {
            const int32_t *ti = q->tidx + (p0 + j) * 4;
            const REAL *tw = q->tw + (p0 + j) * 4;
            if (!(fl & 8)) {
                if (fl & 1) { c0 += akd0[j]; c1 += akd1[j]; c2 += akd2[j]; }
                else for (int k = 0; k < 4; k++) {
                    const int64_t t = ti[k];
                    const REAL wk = tw[k];
                    GKD[t] += wk * akd0[j]; GKD[T + t] += wk * akd1[j]; GKD[2 * T + t] += wk * akd2[j];
                }
            }
            if (!(fl & 16)) {
                if (fl & 2) c3 += ar[j];
                else for (int k = 0; k < 4; k++) GR[ti[k]] += tw[k] * ar[j];
            }
            if (!(fl & 32)) {
                if (fl & 4) { c4 += aks0[j]; c5 += aks1[j]; c6 += aks2[j]; }
                else for (int k = 0; k < 4; k++) {
                    const int64_t t = ti[k];
                    const REAL wk = tw[k];
                    GKS[t] += wk * aks0[j]; GKS[T + t] += wk * aks1[j]; GKS[2 * T + t] += wk * aks2[j];
                }
            }
        }
        if ((fl & 1) && !(fl & 8)) { GKD[0] += c0; GKD[1] += c1; GKD[2] += c2; }
        if ((fl & 2) && !(fl & 16)) GR[0] += c3;
        if ((fl & 4) && !(fl & 32)) { GKS[0] += c4; GKS[1] += c5; GKS[2] += c6; }
    } else {
        REAL *GKD = q->gkd + i * 3 * P + p0, *GKS = q->gks + i * 3 * P + p0, *GR = q->gr + i * P + p0;
        for (int64_t j = 0; j < m; j++) {
            GKD[j] = akd0[j]; GKD[P + j] = akd1[j]; GKD[2 * P + j] = akd2[j];
            GKS[j] = aks0[j]; GKS[P + j] = aks1[j]; GKS[2 * P + j] = aks2[j];
            GR[j] = ar[j];
        }
    }
}

void bb_shade(int64_t mode, int64_t n, int64_t V, int64_t L, int64_t P, int64_t ks_factor, int64_t l2,
              int64_t need_grad, int64_t nthreads, int64_t T, int64_t tex_flags, const int32_t *tidx, const REAL *tw,
              const REAL *kd, const REAL *r, const REAL *ks,
              const REAL *nl, const REAL *nv, const REAL *nh2,
              const REAL *w, const REAL *amp,
              const REAL *y, const REAL *wgt, const REAL *gout,
              REAL *out, double *epart, REAL *gkd, REAL *gr, REAL *gks)
{
    struct args q = {mode, n, V, L, P, T, l2, (mode == MODE_IMAGE_BWD) || (mode == MODE_LOSS && need_grad),
                     (P + BLK - 1) / BLK, tex_flags, ks_factor ? (REAL)1 : (REAL)0,  /* q = (1 - kf ks) / pi */
                     tidx, tw, kd, r, ks, nl, nv, nh2, w, amp, y, wgt, gout, out, epart, gkd, gr, gks};
    const int64_t nb = q.nb;
    if (tidx) {
        /* each particle belongs to one thread (i mod threads), which walks the blocks in order: its
         * gradient maps have one writer and a fixed summation order; a block's geometry stays in cache
         * across the thread's particles */
#pragma omp parallel num_threads(nthreads)
        {
            const int64_t t = omp_get_thread_num(), nt = omp_get_num_threads();
            for (int64_t b = 0; b < nb; b++)
                for (int64_t i = t; i < n; i += nt) block(&q, i, b);
        }
    } else {
        /* blocks outside, particles inside: a block's geometry (all views) stays in cache across particles */
#pragma omp parallel for schedule(static) num_threads(nthreads)
        for (int64_t b = 0; b < nb; b++)
            for (int64_t i = 0; i < n; i++) block(&q, i, b);
    }
}
