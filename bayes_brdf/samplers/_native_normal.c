/* Standard normal draws from a counter-based generator (compiled on first use by render/native.py).
 *
 * Philox4x32-10 (Salmon et al. 2011, "Parallel random numbers: as easy as 1, 2, 3"; the generator of cuRAND
 * and of torch's CUDA draws) keyed by a 64-bit seed: block k of four 32-bit words is Philox(counter = k, key =
 * seed), and its words make two Box-Muller pairs, i.e. the normals 4k .. 4k + 3. Every element depends only on
 * (seed, its index), so the draws are the same for any thread count and any split of the work, and cost one
 * pass over the output (the samplers' noise: 1.3M normals per SPOS step at 128^2, 3 ms with torch.randn).
 */
#include <omp.h>
#include <stdint.h>
#include <tgmath.h>

#define PHILOX_M0 0xD2511F53u
#define PHILOX_M1 0xCD9E8D57u
#define PHILOX_W0 0x9E3779B9u
#define PHILOX_W1 0xBB67AE85u
#define TWO_PI 6.283185307179586476925

#define CH 64   /* Philox blocks per chunk: SIMD over the chunk's blocks */

#if defined(__AVX2__) && !defined(__AVX512F__)   /* AVX-512 has 64-bit products: the compiler's loop */
#include <immintrin.h>

/* hi and lo 32 bits of the eight products c * m (m < 2^32 in every lane): the even lanes' 64-bit products and
 * the odd lanes' (shifted down), their halves blended back into place */
static inline void mul_hilo(__m256i c, __m256i m, __m256i *hi, __m256i *lo)
{
    const __m256i pe = _mm256_mul_epu32(c, m), po = _mm256_mul_epu32(_mm256_srli_epi64(c, 32), m);
    *hi = _mm256_blend_epi32(_mm256_srli_epi64(pe, 32), po, 0xAA);
    *lo = _mm256_blend_epi32(pe, _mm256_slli_epi64(po, 32), 0xAA);
}

/* The loop below with the rounds in AVX2 registers, eight blocks at a time: the compiler's own vectorisation of
 * the 32 x 32 -> 64-bit products spends most of its time shuffling (measured: 60 % of bb_normal). The same words */
static void philox_avx2(int64_t q, uint32_t key0, uint32_t key1, uint32_t *c0, uint32_t *c1, uint32_t *c2,
                        uint32_t *c3)
{
    const __m256i m0 = _mm256_set1_epi32((int)PHILOX_M0), m1 = _mm256_set1_epi32((int)PHILOX_M1);
    const __m256i step = _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7);
    for (int j = 0; j < CH; j += 8) {
        const uint64_t b0 = (uint64_t)(q * CH + j);
        /* the counters b0 .. b0 + 7: low words; high words (b >> 32) the same in all eight unless they straddle */
        __m256i x0 = _mm256_add_epi32(_mm256_set1_epi32((int)(uint32_t)b0), step);
        __m256i x1 = _mm256_setr_epi32((int)(uint32_t)(b0 >> 32), (int)(uint32_t)((b0 + 1) >> 32),
                                       (int)(uint32_t)((b0 + 2) >> 32), (int)(uint32_t)((b0 + 3) >> 32),
                                       (int)(uint32_t)((b0 + 4) >> 32), (int)(uint32_t)((b0 + 5) >> 32),
                                       (int)(uint32_t)((b0 + 6) >> 32), (int)(uint32_t)((b0 + 7) >> 32));
        __m256i x2 = _mm256_setzero_si256(), x3 = _mm256_setzero_si256();
        uint32_t k0 = key0, k1 = key1;
        for (int r = 0; r < 10; r++) {
            __m256i h0, l0, h1, l1;
            mul_hilo(x0, m0, &h0, &l0);
            mul_hilo(x2, m1, &h1, &l1);
            const __m256i n0 = _mm256_xor_si256(_mm256_xor_si256(h1, x1), _mm256_set1_epi32((int)k0));
            const __m256i n2 = _mm256_xor_si256(_mm256_xor_si256(h0, x3), _mm256_set1_epi32((int)k1));
            x1 = l1; x3 = l0; x0 = n0; x2 = n2;
            k0 += PHILOX_W0; k1 += PHILOX_W1;
        }
        _mm256_storeu_si256((__m256i *)(c0 + j), x0);
        _mm256_storeu_si256((__m256i *)(c1 + j), x1);
        _mm256_storeu_si256((__m256i *)(c2 + j), x2);
        _mm256_storeu_si256((__m256i *)(c3 + j), x3);
    }
}
#endif

void bb_normal(uint64_t seed, int64_t count, int64_t nt, REAL *restrict out)
{
    const uint32_t key0 = (uint32_t)seed, key1 = (uint32_t)(seed >> 32);
    const int64_t blocks = (count + 3) / 4, chunks = (blocks + CH - 1) / CH;
#pragma omp parallel for num_threads(nt) schedule(static)
    for (int64_t q = 0; q < chunks; q++) {
        uint32_t c0[CH], c1[CH], c2[CH], c3[CH];
        REAL z[4][CH];
#if defined(__AVX2__) && !defined(__AVX512F__)   /* AVX-512 has 64-bit products: the compiler's loop */
        philox_avx2(q, key0, key1, c0, c1, c2, c3);
#else
#pragma omp simd
        for (int j = 0; j < CH; j++) {
            const uint64_t b = (uint64_t)(q * CH + j);
            c0[j] = (uint32_t)b; c1[j] = (uint32_t)(b >> 32); c2[j] = 0u; c3[j] = 0u;
        }
        uint32_t k0 = key0, k1 = key1;
        for (int r = 0; r < 10; r++) {      /* Philox4x32 rounds, all lanes at once */
#pragma omp simd
            for (int j = 0; j < CH; j++) {
                const uint64_t p0 = (uint64_t)PHILOX_M0 * c0[j], p1 = (uint64_t)PHILOX_M1 * c2[j];
                const uint32_t n0 = (uint32_t)(p1 >> 32) ^ c1[j] ^ k0, n2 = (uint32_t)(p0 >> 32) ^ c3[j] ^ k1;
                c1[j] = (uint32_t)p1; c3[j] = (uint32_t)p0; c0[j] = n0; c2[j] = n2;
            }
            k0 += PHILOX_W0; k1 += PHILOX_W1;
        }
#endif
        /* Box-Muller on (c0, c1) and (c2, c3): uniforms in (0, 1], never 0 (the log) */
#pragma omp simd
        for (int j = 0; j < CH; j++) {
            const REAL u1 = ((REAL)c0[j] + (REAL)0.5) * (REAL)2.3283064365386963e-10;
            const REAL u2 = ((REAL)c1[j] + (REAL)0.5) * (REAL)2.3283064365386963e-10;
            const REAL u3 = ((REAL)c2[j] + (REAL)0.5) * (REAL)2.3283064365386963e-10;
            const REAL u4 = ((REAL)c3[j] + (REAL)0.5) * (REAL)2.3283064365386963e-10;
            const REAL ra = sqrt((REAL)-2 * log(u1)), rb = sqrt((REAL)-2 * log(u3));
            const REAL aa = (REAL)TWO_PI * u2, ab = (REAL)TWO_PI * u4;
            /* cos(a) as sin(pi/2 - a): sin and cos of one argument would become a scalar sincos call */
            z[0][j] = ra * sin((REAL)(TWO_PI / 4) - aa); z[1][j] = ra * sin(aa);
            z[2][j] = rb * sin((REAL)(TWO_PI / 4) - ab); z[3][j] = rb * sin(ab);
        }
        const int64_t i0 = 4 * q * CH;
        if (i0 + 4 * CH <= count) {
            for (int j = 0; j < CH; j++)
                for (int h = 0; h < 4; h++) out[i0 + 4 * j + h] = z[h][j];
        } else {
            for (int j = 0; j < CH; j++)
                for (int h = 0; h < 4; h++)
                    if (i0 + 4 * j + h < count) out[i0 + 4 * j + h] = z[h][j];
        }
    }
}
