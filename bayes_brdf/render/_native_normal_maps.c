/* The per-particle loss of views whose pixels are the texels when every particle has its own normal map (a
 * decoded or sampled normal map), with its gradient w.r.t. the maps and the normals (compiled on first use by
 * native.py). The pixel kernel (_native_kernels.c) takes cosines shared by all particles; here they are made
 * per particle, pixel, view and light from the normal map, as shade.geometry_terms does:
 *
 *   n_w = normalize(T n_x + B n_y + N n_z)                  (|.|^2 floored at 1e-30)
 *   n.l = max(n_w . l, eps), n.v = max(n_w . v, eps), n.h = max(n_w . h, eps)
 *   e[i] = sum wgt |R - y|  (or (R - y)^2),  R_c = sum_l A_c (kd_c q_c + S F_c),  A_c = scale_c (n.l)
 *
 * with h = normalize(l + v) and the Fresnel weight w(v.h) particle independent (inputs). The gradient w.r.t. the
 * cosines, with g_c = d e / d R_c, gF = sum_c g_c A_c F_c (so d e / d ln S = gF S), and alpha, k, gl, gv, den as
 * in fused.py's docstring:
 *
 *   d e / d(n.l) = sum_c g_c scale_c (kd_c q_c + S F_c) - gF S (1 - k) / gl
 *   d e / d(n.v) = - gF S (1 - k) / gv,     d e / d(n.h) = - gF S 4 (n.h) (alpha^2 - 1) / den
 *
 * each zero where its clamp is active (torch's clamp_min passes the gradient where x >= eps); then back through
 * the normalisation, (g - n_w (n_w . g)) / |raw|, and the frame, to the tangent-space normal.
 *
 * Layout (contiguous, P = H * W pixels): kd, ks [n, 3, P], r [n, P] (flags as the pixel kernel: bit k a
 * constant map k, one value per particle, its gradient as per-block partial sums [n, c, blocks]; bit 3 + k its
 * gradient not wanted; bit 6 the normals' gradient not wanted); nt [n, 3, P] the tangent-space normals;
 * frame [V, 9, P] (T, B, N, each x y z); vd [V, 3, P]; ld, hd [V, L, 3, P]; w [V, L, P]; scale [V, L, 3, P];
 * y [V, 3, P]; wgt [V, P]. Parallel over blocks of pixels, particles inside; each (block, particle) owns its
 * outputs, so the results do not depend on the thread schedule.
 */
#include <math.h>
#include <omp.h>
#include <stdint.h>

#include "_native_brdf.h"
#include "_native_pixel_block.h"

#define NORM_FLOOR ((REAL)1e-30)

#define SQRT(x) _Generic((x), float: sqrtf, default: sqrt)(x)

/* Declares view-and-light vl's rows over the block: the light's direction LX..LZ, the half vector HX..HZ, the
 * Fresnel weight W, the light's scale per channel C0..C2 */
#define LIGHT_ROWS(vl) \
    const REAL *restrict LX = q->ld + (vl) * 3 * P + p0, *restrict LY = LX + P, *restrict LZ = LX + 2 * P; \
    const REAL *restrict HX = q->hd + (vl) * 3 * P + p0, *restrict HY = HX + P, *restrict HZ = HX + 2 * P; \
    const REAL *restrict W = q->w + (vl) * P + p0; \
    const REAL *restrict C0 = q->scale + (vl) * 3 * P + p0, *restrict C1 = C0 + P, *restrict C2 = C0 + 2 * P

struct nargs {
    int64_t n, V, L, P, l2, grad, nb, flags;
    REAL kf, eps;
    const REAL *kd, *r, *ks, *nt, *frame, *vd, *ld, *hd, *w, *scale, *y, *wgt;
    double *epart;
    REAL *gkd, *gr, *gks, *gn;
};

/* Particle i over block b's m pixels (inlined twice by BB_EACH_PARTICLE: a full block's trip count a constant) */
static inline __attribute__((always_inline)) void nblock(const struct nargs *restrict q, const int64_t i,
                                                        const int64_t b, const int64_t m)
{
    const int64_t V = q->V, L = q->L, P = q->P, l2 = q->l2, grad = q->grad, flags = q->flags;
    const REAL kf = q->kf, eps = q->eps;
    const int64_t p0 = b * BLK;
    BB_BLOCK_MAPS(q->kd, q->r, q->ks, i, P, p0, flags);
    const REAL *restrict NX = q->nt + i * 3 * P + p0, *restrict NY = NX + P, *restrict NZ = NX + 2 * P;

    REAL akd0[BLK] = {0}, akd1[BLK] = {0}, akd2[BLK] = {0}, aks0[BLK] = {0}, aks1[BLK] = {0},
         aks2[BLK] = {0}, ar[BLK] = {0}, e[BLK] = {0}, gtx[BLK] = {0}, gty[BLK] = {0}, gtz[BLK] = {0};
    REAL wx[BLK], wy[BLK], wz[BLK], rs[BLK], kn[BLK];   /* the world normal, 1 / |raw|, 1 unless floored */
    REAL nv[BLK], mv[BLK];                              /* clamped n.v and its clamp's mask */
    REAL o0[BLK], o1[BLK], o2[BLK], h0[BLK], h1[BLK], h2[BLK];
    REAL sS[LMAX][BLK], sD[LMAX][BLK], cl[LMAX][BLK], ch[LMAX][BLK], ml[LMAX][BLK], mh[LMAX][BLK];
    for (int64_t v = 0; v < V; v++) {
        const REAL *restrict F = q->frame + v * 9 * P + p0;
        const REAL *restrict VX = q->vd + v * 3 * P + p0, *restrict VY = VX + P, *restrict VZ = VX + 2 * P;
#pragma omp simd
        for (int64_t j = 0; j < m; j++) {
            const REAL x = F[j] * NX[j] + F[3 * P + j] * NY[j] + F[6 * P + j] * NZ[j];
            const REAL y = F[P + j] * NX[j] + F[4 * P + j] * NY[j] + F[7 * P + j] * NZ[j];
            const REAL z = F[2 * P + j] * NX[j] + F[5 * P + j] * NY[j] + F[8 * P + j] * NZ[j];
            const REAL s2 = x * x + y * y + z * z;
            const REAL len = SQRT(s2 < NORM_FLOOR ? NORM_FLOOR : s2);
            wx[j] = x / len; wy[j] = y / len; wz[j] = z / len;
            rs[j] = 1 / len;
            kn[j] = s2 < NORM_FLOOR ? 0 : 1;
            const REAL dv = wx[j] * VX[j] + wy[j] * VY[j] + wz[j] * VZ[j];
            nv[j] = dv >= eps ? dv : eps;
            mv[j] = dv >= eps ? 1 : 0;
        }
        for (int64_t j = 0; j < BLK; j++) o0[j] = o1[j] = o2[j] = 0;
        for (int64_t l = 0; l < L; l++) {
            LIGHT_ROWS(v * L + l);
            REAL *restrict SS = sS[l], *restrict SD = sD[l], *restrict CL = cl[l], *restrict CH = ch[l],
                 *restrict ML = ml[l], *restrict MH = mh[l];
#pragma omp simd
            for (int64_t j = 0; j < m; j++) {
                const REAL dl = wx[j] * LX[j] + wy[j] * LY[j] + wz[j] * LZ[j];
                const REAL dh = wx[j] * HX[j] + wy[j] * HY[j] + wz[j] * HZ[j];
                const REAL nl = dl >= eps ? dl : eps, nh = dh >= eps ? dh : eps;
                const REAL rr = R[j], a = rr * rr, a2 = a * a, k = (REAL)0.5 * a, wj = W[j];
                REAL s, sd = 0;
                BB_SPEC(rr, a, a2, k, nh * nh, nl, nv[j], s, sd, 1);
                o0[j] += BB_RADIANCE(C0[j] * nl, KD0[j], KS0[j], s, wj, kf);
                o1[j] += BB_RADIANCE(C1[j] * nl, KD1[j], KS1[j], s, wj, kf);
                o2[j] += BB_RADIANCE(C2[j] * nl, KD2[j], KS2[j], s, wj, kf);
                SS[j] = s; SD[j] = sd; CL[j] = nl; CH[j] = nh;
                ML[j] = dl >= eps ? 1 : 0; MH[j] = dh >= eps ? 1 : 0;
            }
        }
        {
            const REAL *restrict Y0 = q->y + v * 3 * P + p0, *restrict Y1 = Y0 + P, *restrict Y2 = Y0 + 2 * P;
            const REAL *restrict WG = q->wgt + v * P + p0;
#pragma omp simd
            for (int64_t j = 0; j < m; j++) {
                const REAL d0 = o0[j] - Y0[j], d1 = o1[j] - Y1[j], d2 = o2[j] - Y2[j], wg = WG[j];
                if (l2) {
                    e[j] += wg * (d0 * d0 + d1 * d1 + d2 * d2);
                    h0[j] = 2 * wg * d0; h1[j] = 2 * wg * d1; h2[j] = 2 * wg * d2;
                } else {
                    e[j] += wg * (ABS(d0) + ABS(d1) + ABS(d2));
                    h0[j] = WSIGN(wg, d0); h1[j] = WSIGN(wg, d1); h2[j] = WSIGN(wg, d2);
                }
            }
        }
        if (!grad) continue;
        REAL gwx[BLK] = {0}, gwy[BLK] = {0}, gwz[BLK] = {0}, gnv[BLK] = {0};   /* d e / d n_w, d e / d(n.v) */
        for (int64_t l = 0; l < L; l++) {
            LIGHT_ROWS(v * L + l);
            const REAL *restrict SS = sS[l], *restrict SD = sD[l], *restrict CL = cl[l], *restrict CH = ch[l],
                       *restrict ML = ml[l], *restrict MH = mh[l];
#pragma omp simd
            for (int64_t j = 0; j < m; j++) {
                const REAL s = SS[j], wj = W[j], nl = CL[j], nh = CH[j];
                const REAL A0 = C0[j] * nl, A1 = C1[j] * nl, A2 = C2[j] * nl;
                REAL gF = 0;
                BB_GRAD(h0[j], A0, KD0[j], KS0[j], s, wj, kf, akd0[j], aks0[j], gF);
                BB_GRAD(h1[j], A1, KD1[j], KS1[j], s, wj, kf, akd1[j], aks1[j], gF);
                BB_GRAD(h2[j], A2, KD2[j], KS2[j], s, wj, kf, akd2[j], aks2[j], gF);
                ar[j] += gF * SD[j];
                /* d e / d A_c times scale_c: the radiance per unit n.l */
                const REAL gA = h0[j] * C0[j] * BB_RADIANCE((REAL)1, KD0[j], KS0[j], s, wj, kf) +
                                h1[j] * C1[j] * BB_RADIANCE((REAL)1, KD1[j], KS1[j], s, wj, kf) +
                                h2[j] * C2[j] * BB_RADIANCE((REAL)1, KD2[j], KS2[j], s, wj, kf);
                const REAL gS = gF * s;
                const REAL rr = R[j], a = rr * rr, a2 = a * a, k = (REAL)0.5 * a;
                const REAL gl = nl * (1 - k) + k, gv = nv[j] * (1 - k) + k, den = nh * nh * (a2 - 1) + 1;
                const REAL gnl = ML[j] * (gA - gS * (1 - k) / gl);
                const REAL gnh = MH[j] * (-gS * 4 * nh * (a2 - 1) / den);
                gnv[j] -= gS * (1 - k) / gv;
                gwx[j] += gnl * LX[j] + gnh * HX[j];
                gwy[j] += gnl * LY[j] + gnh * HY[j];
                gwz[j] += gnl * LZ[j] + gnh * HZ[j];
            }
        }
#pragma omp simd
        for (int64_t j = 0; j < m; j++) {
            const REAL gv_ = gnv[j] * mv[j];
            const REAL gx = gwx[j] + gv_ * VX[j], gy = gwy[j] + gv_ * VY[j], gz = gwz[j] + gv_ * VZ[j];
            const REAL dot = kn[j] * (wx[j] * gx + wy[j] * gy + wz[j] * gz);   /* floored: x / c, no projection */
            const REAL rx = rs[j] * (gx - wx[j] * dot), ry = rs[j] * (gy - wy[j] * dot),
                       rz = rs[j] * (gz - wz[j] * dot);
            gtx[j] += F[j] * rx + F[P + j] * ry + F[2 * P + j] * rz;
            gty[j] += F[3 * P + j] * rx + F[4 * P + j] * ry + F[5 * P + j] * rz;
            gtz[j] += F[6 * P + j] * rx + F[7 * P + j] * ry + F[8 * P + j] * rz;
        }
    }
    const REAL *const acc[7] = {akd0, akd1, akd2, ar, aks0, aks1, aks2};
    REAL *const dst[3] = {q->gkd, q->gr, q->gks};
    bb_store_block(q->epart, e, grad, acc, dst, flags, i, b, q->nb, P, p0, m);
    if (!grad) return;
    if (!(flags & 64)) {
        REAL *G = q->gn + i * 3 * P + p0;
        for (int64_t j = 0; j < m; j++) { G[j] = gtx[j]; G[P + j] = gty[j]; G[2 * P + j] = gtz[j]; }
    }
}

void bb_shade_normal_maps(int64_t n, int64_t V, int64_t L, int64_t P, int64_t ks_factor, int64_t l2,
                          int64_t need_grad, int64_t nthreads, int64_t flags, double eps,
                          const REAL *kd, const REAL *r, const REAL *ks, const REAL *nt,
                          const REAL *frame, const REAL *vd, const REAL *ld, const REAL *hd,
                          const REAL *w, const REAL *scale, const REAL *y, const REAL *wgt,
                          double *epart, REAL *gkd, REAL *gr, REAL *gks, REAL *gn)
{
    struct nargs q = {n, V, L, P, l2, need_grad, (P + BLK - 1) / BLK, flags, ks_factor ? (REAL)1 : (REAL)0,
                      (REAL)eps, kd, r, ks, nt, frame, vd, ld, hd, w, scale, y, wgt, epart, gkd, gr, gks, gn};
    const int64_t nb = q.nb;
#pragma omp parallel for schedule(static) num_threads(nthreads)
    for (int64_t b = 0; b < nb; b++) BB_EACH_PARTICLE(nblock, &q, n, b, P);
}
