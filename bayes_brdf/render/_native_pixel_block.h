/* What the two kernels over pixel blocks share (_native_kernels.c: cosines shared by the particles;
 * _native_normal_maps.c: a normal map per particle): the block size, a block's map pointers, and the write-out of
 * a (block, particle)'s energy and map gradients.
 *
 * Maps: kd, ks [n, 3, P], r [n, P]; flags bit k (kd 1, r 2, ks 4): map k is constant, one value per particle and
 * channel; bit 3 + k: its gradient is not wanted.
 */
#ifndef BB_NATIVE_PIXEL_BLOCK_H
#define BB_NATIVE_PIXEL_BLOCK_H

#include <stdint.h>

#define BLK 128
#define LMAX 4 /* lights per view (the caller checks) */

/* The L1 loss's terms: |d|, and wg sign(d) for a pixel weight wg >= 0 (the weights are masks and inverse noise
 * scales): wg with d's sign bit, 0 where d is 0. A mask and a copy of the sign bit instead of compares, blends and
 * an integer conversion: the pixel kernel about 5 % faster. (wg * copysign(1, d) stops GCC vectorising the
 * one-light loop: 5x slower.) */
#define ABS(x) _Generic((x), float: __builtin_fabsf, default: __builtin_fabs)(x)
#define WSIGN(wg, d) ((d) != 0 ? _Generic((d), float: __builtin_copysignf, default: __builtin_copysign)((wg), (d)) : (REAL)0)

/* Declares KD0..KD2, KS0..KS2 and R: the block's map values for particle i (a constant map's values repeated over
 * the block in ckd, cks, cr, so the loops stay one shape) */
#define BB_BLOCK_MAPS(kd_, r_, ks_, i, P, p0, flags) \
    REAL ckd[3][BLK], cks[3][BLK], cr[BLK]; \
    if ((flags) & 1) \
        for (int c = 0; c < 3; c++) for (int64_t j = 0; j < BLK; j++) ckd[c][j] = (kd_)[(i) * 3 + c]; \
    if ((flags) & 2) \
        for (int64_t j = 0; j < BLK; j++) cr[j] = (r_)[i]; \
    if ((flags) & 4) \
        for (int c = 0; c < 3; c++) for (int64_t j = 0; j < BLK; j++) cks[c][j] = (ks_)[(i) * 3 + c]; \
    const REAL *restrict KD0 = ((flags) & 1) ? ckd[0] : (kd_) + (i) * 3 * (P) + (p0); \
    const REAL *restrict KD1 = ((flags) & 1) ? ckd[1] : KD0 + (P), *restrict KD2 = ((flags) & 1) ? ckd[2] : KD0 + 2 * (P); \
    const REAL *restrict KS0 = ((flags) & 4) ? cks[0] : (ks_) + (i) * 3 * (P) + (p0); \
    const REAL *restrict KS1 = ((flags) & 4) ? cks[1] : KS0 + (P), *restrict KS2 = ((flags) & 4) ? cks[2] : KS0 + 2 * (P); \
    const REAL *restrict R = ((flags) & 2) ? cr : (r_) + (i) * (P) + (p0)

/* Runs BLOCK(q, i, b, m) for every particle i of block b (m of its pixels real): BLOCK is an always-inline function,
 * called with m the constant BLK for a full block (its loops then have a constant trip count: 4-10 % faster) and
 * with the remainder for the last one */
#define BB_EACH_PARTICLE(BLOCK, q, n, b, P) do { \
        const int64_t m_ = (P) - (b) * BLK < BLK ? (P) - (b) * BLK : BLK; \
        if (m_ == BLK) \
            for (int64_t i_ = 0; i_ < (n); i_++) BLOCK(q, i_, b, BLK); \
        else \
            for (int64_t i_ = 0; i_ < (n); i_++) BLOCK(q, i_, b, m_); \
    } while (0)

/* A (block b, particle i)'s outputs over its m pixels from p0: with epart, the sum of its energies e into
 * epart[i, b]; with grad, its map gradients acc = {kd x3, r, ks x3} into dst = {gkd, gr, gks}: a full map's into
 * [n, c, P], a constant map's as this block's partial sum into [n, c, nb] (the caller sums them: no thread writes
 * another's), an unwanted one not at all */
static inline void bb_store_block(double *epart, const REAL *e, int64_t grad, const REAL *const acc[7],
                                  REAL *const dst[3], int64_t flags, int64_t i, int64_t b, int64_t nb, int64_t P,
                                  int64_t p0, int64_t m)
{
    if (epart) {
        double sum = 0;
        for (int64_t j = 0; j < m; j++) sum += e[j];
        epart[i * nb + b] = sum;
    }
    if (!grad) return;
    for (int k = 0, a = 0; k < 3; k++) {
        const int c = k == 1 ? 1 : 3;
        if (flags & (8 << k)) { a += c; continue; }          /* not wanted */
        for (int ch = 0; ch < c; ch++, a++) {
            if (flags & (1 << k)) {                          /* constant: this block's partial sum */
                REAL sum = 0;
                for (int64_t j = 0; j < m; j++) sum += acc[a][j];
                dst[k][(i * c + ch) * nb + b] = sum;
            } else {
                REAL *G = dst[k] + (i * c + ch) * P + p0;
                for (int64_t j = 0; j < m; j++) G[j] = acc[a][j];
            }
        }
    }
}

#endif
