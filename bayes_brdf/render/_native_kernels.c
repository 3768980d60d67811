/* Fused CPU shading kernel for views whose pixels are the texels (compiled on first use by native.py).
 *
 * One loop nest serves three jobs, chosen by `mode`:
 *   MODE_IMAGE_FWD  out[i, v, c, p]  = sum_l A (kd q + S F)
 *   MODE_IMAGE_BWD  d/d(kd, r, ks) of sum(gout * out)
 *   MODE_LOSS       e[i] = sum wgt * |out - y|  (or (out - y)^2), and its gradient when need_grad
 *   MODE_PIXEL_LOSS out[i, c, p] = sum_v wgt * |out - y|  (or squared): the loss per pixel and channel, summed
 *                   over the views only (a texel's share of the energy when the pixels are the texels; no gradient)
 * with A = scale * (n.l), q = (1 - ks) / pi (or 1 / pi), F = ks (1 - w) + w,
 * S = D G / (4 (n.l)(n.v)), w the Fresnel weight (precomputed per view and light); the terms are
 * the macros of _native_brdf.h, shared with the texel kernel (_native_texels.c: pixels that read
 * texel maps through bilinear taps, e.g. a mesh's).
 *
 * Layout (contiguous, channel-first, P = H * W pixels):
 *   kd, ks [n, 3, P]; r [n, P]; a map flagged constant (flags bit k: kd 1, r 2, ks 4) is one value per particle
 *   and channel instead, kd, ks [n, 3], r [n], and its gradient comes as per-block partial sums
 *   [n, c, blocks] (the caller sums them: no thread writes another's); flags bit 3 + k: map k's gradient is
 *   not wanted (not written, its pointer may be null)
 *   nl, nh2 = (n.h)^2, w [V, L, P]; nv [V, P]; A = scale * (n.l) [V, L, 3, P]
 *   y, gout-per-view [.., 3, P]; wgt [V, P]
 * Parallel over blocks of pixels, particles inside (the block's geometry stays in
 * cache); each (block, particle) owns its outputs, so the results do not depend on
 * the thread schedule. Views and lights are the inner loops, so the maps are read
 * once and the gradients stay in registers/L1.
 */
#include <omp.h>
#include <stdint.h>

#include "_native_brdf.h"
#include "_native_pixel_block.h"

#define MODE_IMAGE_FWD 0
#define MODE_IMAGE_BWD 1
#define MODE_LOSS 2
#define MODE_PIXEL_LOSS 3


/* Radiance of one view and light over a block; with WITH_GRAD also keep S and S dlnS/dr.
 * A macro so that both variants are straight-line SIMD loops. */
#define SPEC_LOOP(WITH_GRAD) \
    _Pragma("omp simd") \
    for (int64_t j = 0; j < m; j++) { \
        const REAL rr = R[j], a = rr * rr, a2 = a * a, k = (REAL)0.5 * a, wj = W[j]; \
        REAL s, sd = 0; \
        BB_SPEC(rr, a, a2, k, NH2[j], NL[j], NV[j], s, sd, WITH_GRAD); \
        if (WITH_GRAD) { sS[l][j] = s; sD[l][j] = sd; } \
        o0[j] += BB_RADIANCE(A0[j], KD0[j], KS0[j], s, wj, kf); \
        o1[j] += BB_RADIANCE(A1[j], KD1[j], KS1[j], s, wj, kf); \
        o2[j] += BB_RADIANCE(A2[j], KD2[j], KS2[j], s, wj, kf); \
    }

/* One pixel's loss terms from its residuals d = R - y: the weighted loss into E and its gradient
 * d loss / d R into H (L2: squared, else L1) */
#define LOSS_TERMS(L2, wg, d0, d1, d2, E, H0, H1, H2) do { \
        if (L2) { \
            (E) += (wg) * ((d0) * (d0) + (d1) * (d1) + (d2) * (d2)); \
            (H0) = 2 * (wg) * (d0); (H1) = 2 * (wg) * (d1); (H2) = 2 * (wg) * (d2); \
        } else { \
            (E) += (wg) * (ABS(d0) + ABS(d1) + ABS(d2)); \
            (H0) = WSIGN(wg, d0); (H1) = WSIGN(wg, d1); (H2) = WSIGN(wg, d2); \
        } \
    } while (0)

/* The loss and its gradient for one light, every term in registers (no per-view arrays): the same
 * expressions as SPEC_LOOP, the loss loops and the gradient loop below, in one pass. KS(c) is channel c's
 * specular value of pixel j, AKS(c) where its gradient goes: the map's, or (constant specular whose gradient
 * is not wanted: the per-texel models) one value per particle and channel and a dead store the compiler drops,
 * fewer streams and instructions in the hottest loop. */
#define ONE_LIGHT_LOOP(L2, KS, AKS) \
    _Pragma("omp simd") \
    for (int64_t j = 0; j < m; j++) { \
        const REAL rr = R[j], a = rr * rr, a2 = a * a, k = (REAL)0.5 * a, wj = W[j], wg = WG[j]; \
        REAL s, sd = 0; \
        BB_SPEC(rr, a, a2, k, NH2[j], NL[j], NV[j], s, sd, 1); \
        const REAL d0 = BB_RADIANCE(A0[j], KD0[j], KS(0), s, wj, kf) - Y0[j]; \
        const REAL d1 = BB_RADIANCE(A1[j], KD1[j], KS(1), s, wj, kf) - Y1[j]; \
        const REAL d2 = BB_RADIANCE(A2[j], KD2[j], KS(2), s, wj, kf) - Y2[j]; \
        REAL h0, h1, h2, gF = 0, dead_ = 0; \
        LOSS_TERMS(L2, wg, d0, d1, d2, e[j], h0, h1, h2); \
        BB_GRAD(h0, A0[j], KD0[j], KS(0), s, wj, kf, akd0[j], AKS(0), gF); \
        BB_GRAD(h1, A1[j], KD1[j], KS(1), s, wj, kf, akd1[j], AKS(1), gF); \
        BB_GRAD(h2, A2[j], KD2[j], KS(2), s, wj, kf, akd2[j], AKS(2), gF); \
        ar[j] += gF * sd; \
        (void)dead_; \
    }
#define KS_MAP(c) KS##c[j]
#define AKS_MAP(c) aks##c[j]
#define KS_CONST(c) ks##c
#define AKS_DEAD(c) dead_

/* Pixel j's weighted loss per channel from its residuals d = R - y, added into px0..px2 */
#define PIXEL_TERMS(L2, j, d0, d1, d2) do { \
        if (L2) { px0[j] += WG[j] * (d0) * (d0); px1[j] += WG[j] * (d1) * (d1); px2[j] += WG[j] * (d2) * (d2); } \
        else { px0[j] += WG[j] * ABS(d0); px1[j] += WG[j] * ABS(d1); px2[j] += WG[j] * ABS(d2); } \
    } while (0)

/* A view's loss per pixel and channel from the radiance arrays o, added into px0..px2 */
#define PIXEL_LOOP(L2) \
    _Pragma("omp simd") \
    for (int64_t j = 0; j < m; j++) { \
        const REAL d0 = o0[j] - Y0[j], d1 = o1[j] - Y1[j], d2 = o2[j] - Y2[j]; \
        PIXEL_TERMS(L2, j, d0, d1, d2); \
    }

/* One light: a view's radiance and its loss per pixel and channel in one loop, in registers (PIXEL_LOOP's
 * expressions on SPEC_LOOP's radiance); KS as in ONE_LIGHT_LOOP */
#define ONE_LIGHT_PIXEL_LOOP(L2, KS) \
    _Pragma("omp simd") \
    for (int64_t j = 0; j < m; j++) { \
        const REAL rr = R[j], a = rr * rr, a2 = a * a, k = (REAL)0.5 * a, wj = W[j]; \
        REAL s, sd = 0; \
        BB_SPEC(rr, a, a2, k, NH2[j], NL[j], NV[j], s, sd, 0); \
        const REAL d0 = BB_RADIANCE(A0[j], KD0[j], KS(0), s, wj, kf) - Y0[j]; \
        const REAL d1 = BB_RADIANCE(A1[j], KD1[j], KS(1), s, wj, kf) - Y1[j]; \
        const REAL d2 = BB_RADIANCE(A2[j], KD2[j], KS(2), s, wj, kf) - Y2[j]; \
        PIXEL_TERMS(L2, j, d0, d1, d2); \
    }

/* The loss terms of a view from the radiance arrays o (several lights) */
#define RESIDUAL_LOOP(L2) \
    _Pragma("omp simd") \
    for (int64_t j = 0; j < m; j++) { \
        const REAL d0 = o0[j] - Y0[j], d1 = o1[j] - Y1[j], d2 = o2[j] - Y2[j]; \
        LOSS_TERMS(L2, WG[j], d0, d1, d2, e[j], g0[j], g1[j], g2[j]); \
    }

struct args {
    int64_t mode, n, V, L, P, l2, grad, nb, flags;
    REAL kf;
    const REAL *kd, *r, *ks, *nl, *nv, *nh2, *w, *amp, *y, *wgt, *gout;
    REAL *out; double *epart; REAL *gkd, *gr, *gks;
};

/* Particle i over block b's m pixels (inlined twice by BB_EACH_PARTICLE: a full block's trip count a constant) */
static inline __attribute__((always_inline)) void block(const struct args *restrict q, const int64_t i, const int64_t b,
                                                       const int64_t m)
{
    const int64_t mode = q->mode, V = q->V, L = q->L, P = q->P, l2 = q->l2, grad = q->grad;
    const REAL kf = q->kf;
    const REAL *restrict nl = q->nl, *restrict nv = q->nv, *restrict nh2 = q->nh2, *restrict w = q->w,
               *restrict amp = q->amp, *restrict y = q->y, *restrict wgt = q->wgt, *restrict gout = q->gout;
    const int64_t p0 = b * BLK;
    const int64_t flags = q->flags;
    BB_BLOCK_MAPS(q->kd, q->r, q->ks, i, P, p0, flags);
    /* constant specular: its three values as scalars (the one-light loops); cks_dead: and its gradient unwanted */
    const REAL ks0 = (flags & 4) ? q->ks[i * 3] : 0, ks1 = (flags & 4) ? q->ks[i * 3 + 1] : 0,
               ks2 = (flags & 4) ? q->ks[i * 3 + 2] : 0;
    const int cks_dead = (flags & 36) == 36;
    REAL akd0[BLK] = {0}, akd1[BLK] = {0}, akd2[BLK] = {0}, aks0[BLK] = {0}, aks1[BLK] = {0},
         aks2[BLK] = {0}, ar[BLK] = {0}, e[BLK] = {0};
    REAL o0[BLK], o1[BLK], o2[BLK], g0[BLK], g1[BLK], g2[BLK];
    REAL px0[BLK] = {0}, px1[BLK] = {0}, px2[BLK] = {0};   /* MODE_PIXEL_LOSS: the block's per-pixel sums */
    REAL sS[LMAX][BLK], sD[LMAX][BLK];  /* S and S * dlnS/dr per light, kept for the gradient pass */
    for (int64_t v = 0; v < V; v++) {
        const REAL *NV = nv + v * P + p0;
        if (mode == MODE_LOSS && grad && L == 1) {  /* one light (a flash): radiance, loss and gradient in one loop */
            const REAL *NL = nl + v * P + p0, *NH2 = nh2 + v * P + p0, *W = w + v * P + p0;
            const REAL *A0 = amp + v * 3 * P + p0, *A1 = A0 + P, *A2 = A0 + 2 * P;
            const REAL *Y0 = y + v * 3 * P + p0, *Y1 = Y0 + P, *Y2 = Y0 + 2 * P, *WG = wgt + v * P + p0;
            if (cks_dead) {
                if (l2) { ONE_LIGHT_LOOP(1, KS_CONST, AKS_DEAD) } else { ONE_LIGHT_LOOP(0, KS_CONST, AKS_DEAD) }
            } else {
                if (l2) { ONE_LIGHT_LOOP(1, KS_MAP, AKS_MAP) } else { ONE_LIGHT_LOOP(0, KS_MAP, AKS_MAP) }
            }
            continue;
        }
        if (mode == MODE_PIXEL_LOSS && L == 1) {      /* one light: radiance and per-pixel loss in one loop */
            const REAL *NL = nl + v * P + p0, *NH2 = nh2 + v * P + p0, *W = w + v * P + p0;
            const REAL *A0 = amp + v * 3 * P + p0, *A1 = A0 + P, *A2 = A0 + 2 * P;
            const REAL *Y0 = y + v * 3 * P + p0, *Y1 = Y0 + P, *Y2 = Y0 + 2 * P, *WG = wgt + v * P + p0;
            if (flags & 4) {
                if (l2) { ONE_LIGHT_PIXEL_LOOP(1, KS_CONST) } else { ONE_LIGHT_PIXEL_LOOP(0, KS_CONST) }
            } else {
                if (l2) { ONE_LIGHT_PIXEL_LOOP(1, KS_MAP) } else { ONE_LIGHT_PIXEL_LOOP(0, KS_MAP) }
            }
            continue;
        }
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
        if (mode == MODE_PIXEL_LOSS) {
            const REAL *Y0 = y + v * 3 * P + p0, *Y1 = Y0 + P, *Y2 = Y0 + 2 * P, *WG = wgt + v * P + p0;
            if (l2) { PIXEL_LOOP(1) } else { PIXEL_LOOP(0) }
            continue;
        }
        if (mode == MODE_LOSS) {
            const REAL *Y0 = y + v * 3 * P + p0, *Y1 = Y0 + P, *Y2 = Y0 + 2 * P, *WG = wgt + v * P + p0;
            if (l2) { RESIDUAL_LOOP(1) } else { RESIDUAL_LOOP(0) }
        } else {
            const REAL *GO = gout + ((i * V + v) * 3) * P + p0;
            for (int64_t j = 0; j < m; j++) { g0[j] = GO[j]; g1[j] = GO[P + j]; g2[j] = GO[2 * P + j]; }
        }
        if (!grad) continue;
        for (int64_t l = 0; l < L; l++) {
            const int64_t vl = v * L + l;
            const REAL *W = w + vl * P + p0, *A0 = amp + vl * 3 * P + p0, *A1 = A0 + P, *A2 = A0 + 2 * P;
#pragma omp simd
            for (int64_t j = 0; j < m; j++) {
                const REAL s = sS[l][j], wj = W[j];
                REAL gF = 0;
                BB_GRAD(g0[j], A0[j], KD0[j], KS0[j], s, wj, kf, akd0[j], aks0[j], gF);
                BB_GRAD(g1[j], A1[j], KD1[j], KS1[j], s, wj, kf, akd1[j], aks1[j], gF);
                BB_GRAD(g2[j], A2[j], KD2[j], KS2[j], s, wj, kf, akd2[j], aks2[j], gF);
                ar[j] += gF * sD[l][j];
            }
        }
    }
    if (mode == MODE_PIXEL_LOSS) {
        REAL *OUT = q->out + i * 3 * P + p0;
        for (int64_t j = 0; j < m; j++) { OUT[j] = px0[j]; OUT[P + j] = px1[j]; OUT[2 * P + j] = px2[j]; }
        return;
    }
    const REAL *const acc[7] = {akd0, akd1, akd2, ar, aks0, aks1, aks2};
    REAL *const dst[3] = {q->gkd, q->gr, q->gks};
    bb_store_block(mode == MODE_LOSS ? q->epart : 0, e, grad, acc, dst, flags, i, b, q->nb, P, p0, m);
}

void bb_shade(int64_t mode, int64_t n, int64_t V, int64_t L, int64_t P, int64_t ks_factor, int64_t l2,
              int64_t need_grad, int64_t nthreads, int64_t flags,
              const REAL *kd, const REAL *r, const REAL *ks,
              const REAL *nl, const REAL *nv, const REAL *nh2,
              const REAL *w, const REAL *amp,
              const REAL *y, const REAL *wgt, const REAL *gout,
              REAL *out, double *epart, REAL *gkd, REAL *gr, REAL *gks)
{
    struct args q = {mode, n, V, L, P, l2, (mode == MODE_IMAGE_BWD) || (mode == MODE_LOSS && need_grad),
                     (P + BLK - 1) / BLK, flags, ks_factor ? (REAL)1 : (REAL)0,  /* q = (1 - kf ks) / pi */
                     kd, r, ks, nl, nv, nh2, w, amp, y, wgt, gout, out, epart, gkd, gr, gks};
    const int64_t nb = q.nb;
    /* blocks outside, particles inside: a block's geometry (all views) stays in cache across particles */
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t b = 0; b < nb; b++) BB_EACH_PARTICLE(block, &q, n, b, P);
}

/* BLK, for the caller's per-block buffers */
int64_t bb_pixel_block(void) { return BLK; }
