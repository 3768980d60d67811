/* Fused CPU shading kernels for bayes_brdf (compiled on first use by native.py).
 *
 * One loop nest serves three jobs, chosen by `mode`:
 *   MODE_IMAGE_FWD  out[i, v, c, p]  = sum_l A (kd q + S F)
 *   MODE_IMAGE_BWD  d/d(kd, r, ks) of sum(gout * out)
 *   MODE_LOSS       e[i] = sum wgt * |out - y|  (or (out - y)^2), and its gradient when need_grad
 * with A = scale * (n.l), q = (1 - ks) / pi (or 1 / pi), F = ks (1 - w) + w,
 * S = D G / (4 (n.l)(n.v)), w the Fresnel weight (precomputed per view and light).
 *
 * Layout (contiguous, channel-first, P = H * W pixels = texels):
 *   kd, ks [n, 3, P]; r [n, P]
 *   nl, nh2 = (n.h)^2, w [V, L, P]; nv [V, P]; A = scale * (n.l) [V, L, 3, P]
 *   y, gout-per-view [.., 3, P]; wgt [V, P]
 * Parallel over blocks of pixels, particles inside (the block's geometry stays in
 * cache); each (block, particle) owns its outputs, so the
 * results do not depend on the thread schedule. Views and lights are the inner
 * loops, so the maps are read once and the gradients stay in registers/L1.
 */
#include <math.h>
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

void bb_shade(int64_t mode, int64_t n, int64_t V, int64_t L, int64_t P, int64_t ks_factor, int64_t l2,
              int64_t need_grad, int64_t nthreads,
              const REAL *restrict kd, const REAL *restrict r, const REAL *restrict ks,
              const REAL *restrict nl, const REAL *restrict nv, const REAL *restrict nh2,
              const REAL *restrict w, const REAL *restrict amp,
              const REAL *restrict y, const REAL *restrict wgt, const REAL *restrict gout,
              REAL *restrict out, double *restrict epart, REAL *restrict gkd, REAL *restrict gr, REAL *restrict gks)
{
    const int64_t nb = (P + BLK - 1) / BLK;
    const int grad = (mode == MODE_IMAGE_BWD) || (mode == MODE_LOSS && need_grad);
    const REAL kf = ks_factor ? (REAL)1 : (REAL)0;  /* q = (1 - kf ks) / pi */
    /* blocks outside, particles inside: a block's geometry (all views) stays in cache across particles */
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t b = 0; b < nb; b++) {
        for (int64_t i = 0; i < n; i++) {
            const int64_t p0 = b * BLK;
            const int64_t m = (P - p0) < BLK ? (P - p0) : BLK;
            const REAL *KD0 = kd + i * 3 * P + p0, *KD1 = KD0 + P, *KD2 = KD0 + 2 * P;
            const REAL *KS0 = ks + i * 3 * P + p0, *KS1 = KS0 + P, *KS2 = KS0 + 2 * P;
            const REAL *R = r + i * P + p0;
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
                    REAL *OUT = out + ((i * V + v) * 3) * P + p0;
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
                epart[i * nb + b] = sum;
            }
            if (grad) {
                REAL *GKD = gkd + i * 3 * P + p0, *GKS = gks + i * 3 * P + p0, *GR = gr + i * P + p0;
                for (int64_t j = 0; j < m; j++) {
                    GKD[j] = akd0[j]; GKD[P + j] = akd1[j]; GKD[2 * P + j] = akd2[j];
                    GKS[j] = aks0[j]; GKS[P + j] = aks1[j]; GKS[2 * P + j] = aks2[j];
                    GR[j] = ar[j];
                }
            }
        }
    }
}
