/* The RBF kernel matrices of the samplers (samplers/kernels.py, rbf_matrix) in one pass over the particles:
 * compiled on first use by render/native.py (the package's one loader of C sources).
 *
 * For each group q of n particles z [G * n, D] (row-major):
 *   gram_ij = sum_d z_id z_jd                      (float products summed over chunks of CH coordinates, in double)
 *   d2_ij   = max(gram_ii + gram_jj - 2 gram_ij, 0),  d2_ii = 0
 *   M       = the lower median of sqrt(d2_ij), i < j (torch.median's choice for an even count)
 *   h       = M^2 / log n  (1 where M = 0: coincident particles)
 *   K_ij    = exp(-d2_ij / h)
 * as the torch ops of rbf_matrix do (tested against them), without the [G, n, n] intermediates between them. The
 * chunks are fixed (CH coordinates each, whatever the thread count) and their sums are added in chunk order, so the
 * result does not depend on the thread count. Inside a chunk, tiles of 2 x 4 particle pairs keep their eight
 * accumulators in registers: each row is read from L1 once per tile instead of once per pair (torch's matrix
 * product of a [n, D] by [D, n] with D >> n was 1 ms at 20 x 65536).
 */
#include <math.h>
#include <omp.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#define CH 512   /* coordinates per chunk (2 KB of a float row: a group's chunk in L1 for n up to 16, L2 beyond) */
#define VL 8     /* lanes of a tile's accumulators */

/* the chunk's lower-triangle Gram sums, rows padded to a multiple of 4 with zero rows: out[i * n + j], j <= i */
static void chunk_gram(const REAL *restrict x, int64_t n, int64_t D, int64_t m, const REAL *restrict zero,
                       double *restrict out)
{
    for (int64_t i0 = 0; i0 < n; i0 += 2) {
        const REAL *a0 = x + i0 * D, *a1 = i0 + 1 < n ? a0 + D : zero;
        for (int64_t j0 = 0; j0 <= i0 + 1 && j0 < n; j0 += 4) {
            const REAL *b[4];
            for (int t = 0; t < 4; t++) b[t] = j0 + t < n ? x + (j0 + t) * D : zero;
            REAL acc[2][4][VL];
            for (int s = 0; s < 2; s++)
                for (int t = 0; t < 4; t++)
                    for (int l = 0; l < VL; l++) acc[s][t][l] = 0;
            int64_t d = 0;
            for (; d + VL <= m; d += VL) {
#pragma omp simd
                for (int l = 0; l < VL; l++) {
                    const REAL u0 = a0[d + l], u1 = a1[d + l];
                    const REAL w0 = b[0][d + l], w1 = b[1][d + l], w2 = b[2][d + l], w3 = b[3][d + l];
                    acc[0][0][l] += u0 * w0; acc[0][1][l] += u0 * w1; acc[0][2][l] += u0 * w2; acc[0][3][l] += u0 * w3;
                    acc[1][0][l] += u1 * w0; acc[1][1][l] += u1 * w1; acc[1][2][l] += u1 * w2; acc[1][3][l] += u1 * w3;
                }
            }
            for (; d < m; d++) {      /* the last chunk's remainder, into lane 0 */
                for (int t = 0; t < 4; t++) { acc[0][t][0] += a0[d] * b[t][d]; acc[1][t][0] += a1[d] * b[t][d]; }
            }
            for (int s = 0; s < 2; s++)
                for (int t = 0; t < 4; t++) {
                    const int64_t i = i0 + s, j = j0 + t;
                    if (i >= n || j >= n || j > i) continue;
                    double sum = 0;
                    for (int l = 0; l < VL; l++) sum += (double)acc[s][t][l];
                    out[i * n + j] = sum;
                }
        }
    }
}

static int cmp_double(const void *a, const void *b)
{
    const double x = *(const double *)a, y = *(const double *)b;
    return (x > y) - (x < y);
}

/* K [G, n, n] and h [G] of particles z [G * n, D]; returns -1 when out of memory (nothing written) */
int bb_rbf_matrix(int64_t G, int64_t n, int64_t D, int64_t nt, const REAL *restrict z, REAL *restrict K,
                  REAL *restrict h)
{
    const int64_t nc = (D + CH - 1) / CH, nn = n * n;
    double *part = (double *)malloc(sizeof(double) * G * nc * nn);
    REAL *zero = (REAL *)calloc(CH, sizeof(REAL));
    double *d2 = (double *)malloc(sizeof(double) * nn), *dist = (double *)malloc(sizeof(double) * nn);
    if (!part || !zero || !d2 || !dist) {
        free(part); free(zero); free(d2); free(dist);
        return -1;
    }
#pragma omp parallel for num_threads(nt) schedule(static) collapse(2)
    for (int64_t q = 0; q < G; q++)
        for (int64_t c = 0; c < nc; c++) {
            const int64_t m = D - c * CH < CH ? D - c * CH : CH;
            chunk_gram(z + q * n * D + c * CH, n, D, m, zero, part + (q * nc + c) * nn);
        }
    for (int64_t q = 0; q < G; q++) {
        double *gram = part + q * nc * nn;       /* chunk 0's sums, the others added in chunk order */
        for (int64_t c = 1; c < nc; c++) {
            const double *pc = gram + c * nn;
            for (int64_t i = 0; i < n; i++)
                for (int64_t j = 0; j <= i; j++) gram[i * n + j] += pc[i * n + j];
        }
        int64_t k = 0;
        for (int64_t i = 0; i < n; i++) {
            d2[i * n + i] = 0;
            for (int64_t j = 0; j < i; j++) {
                double e = gram[i * n + i] + gram[j * n + j] - 2 * gram[i * n + j];
                e = e > 0 ? e : 0;
                d2[i * n + j] = d2[j * n + i] = e;
                dist[k++] = sqrt(e);
            }
        }
        qsort(dist, (size_t)k, sizeof(double), cmp_double);
        const double M = k > 0 ? dist[(k - 1) / 2] : 0, m2 = M * M;     /* (one particle: no pairs, h = 1) */
        const double hq = m2 > 0 ? m2 / log((double)n) : 1.0;
        h[q] = (REAL)hq;
        for (int64_t i = 0; i < nn; i++) K[q * nn + i] = (REAL)exp(-d2[i] / hq);
    }
    free(part); free(zero); free(d2); free(dist);
    return 0;
}
