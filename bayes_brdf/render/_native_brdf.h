/* The BRDF terms both native shading kernels share (see fused.py for the formulas and their gradients).
 *
 * Macros over expressions, so that one text serves the pixel kernel (REAL scalars inside `omp simd`
 * loops, _native_kernels.c) and the texel kernel (GCC vector-extension lanes of particles,
 * _native_texels.c); a scalar operand broadcasts against a vector one. Notation: rr the roughness,
 * a = rr^2, a2 = a^2, k = a / 2, nh2 = (n.h)^2, nl = n.l, nv = n.v, w the Fresnel weight,
 * A = scale * (n.l), kf = 1 when the diffuse term carries (1 - ks).
 */
#ifndef BB_NATIVE_BRDF_H
#define BB_NATIVE_BRDF_H

#ifndef REAL
#define REAL float
#endif

#define BB_INV_PI ((REAL)0.318309886183790671538)

/* S = D G / (4 (n.l)(n.v)) into S, and S * d ln S / dr into SD (one division for three reciprocals) */
#define BB_SPEC(rr, a, a2, k, nh2, nl, nv, S, SD, WITH_GRAD) do { \
        const __typeof__(a) den_ = (nh2) * ((a2) - 1) + 1, gl_ = (nl) * (1 - (k)) + (k), gv_ = (nv) * (1 - (k)) + (k); \
        const __typeof__(a) inv_ = 1 / (den_ * gl_ * gv_); \
        const __typeof__(a) cst_ = (REAL)0.25 * BB_INV_PI * inv_ * inv_ * gl_ * gv_;  /* 1 / (4 pi den^2 gl gv) */ \
        (S) = (a2) * cst_; \
        if (WITH_GRAD) { \
            const __typeof__(a) iden_ = gl_ * gv_ * inv_, igl_ = den_ * gv_ * inv_, igv_ = den_ * gl_ * inv_; \
            (SD) = 4 * (rr) * (a) * cst_ - (S) * (8 * (rr) * (a) * (nh2) * iden_ + \
                                                (rr) * ((1 - (nl)) * igl_ + (1 - (nv)) * igv_)); \
        } \
    } while (0)

/* radiance of one light in one channel: A (kd (1 - kf ks) / pi + S (ks (1 - w) + w)) */
#define BB_RADIANCE(A, kd, ks, S, w, kf) ((A) * ((kd) * (1 - (kf) * (ks)) * BB_INV_PI + (S) * ((ks) * (1 - (w)) + (w))))

/* gradient of one light in one channel given g = d loss / d radiance: into akd, aks, and gF (to multiply by SD) */
#define BB_GRAD(g, A, kd, ks, S, w, kf, akd, aks, gF) do { \
        const __typeof__(g) gA_ = (g) * (A); \
        (akd) += gA_ * (1 - (kf) * (ks)) * BB_INV_PI; \
        (aks) += gA_ * ((S) * (1 - (w)) - (kf) * (kd) * BB_INV_PI); \
        (gF) += gA_ * ((ks) * (1 - (w)) + (w)); \
    } while (0)

#endif
