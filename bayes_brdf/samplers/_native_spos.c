/* One SPOS update (samplers/spos.py, Eqs. 4-6 with the Adam preconditioner and the ensemble-scaled step) fused
 * into one pass over the coordinates: compiled on first use by render/native.py (the package's one loader).
 *
 * Given the particles z, their energy gradients g and the noise xi ([G * n, D], row-major), the RBF kernel
 * matrix K [G, n, n], its row sums ks [G, n] and c = 2 / h [G] of each group, for each coordinate d:
 *   rep_i   = c (z_i ks_i - sum_j K_ij z_j)                          (sum_j grad_{x_j} k(x_j, x_i))
 *   drift_i = (rep_i - gam sum_j K_ij g_j) / n - gam g_i / beta
 *   v'      = b2 v + (1 - b2) mean_i drift_i^2     (per particle: drift_i^2),  G = 1 / (sqrt(v' / bc) + eps)
 *   and, while annealing (noise_pc): the same from the un-annealed drift (gam = 1) into vn', G1, Gn = min(G, G1)
 *   spread: s = max(std_i z_i, floor), lam = step s, corr_i = (z_i - m) / (max(var, floor^2) (n - 1))
 *   M = Gn lam / beta,  z_i' = z_i + xi_i sqrt(2 M) + M corr_i + G lam drift_i
 * exactly the torch update of spos.py (the plain reference it is tested against), in one read of z, g, xi, v
 * and one write of z', v'. Parallel over blocks of coordinates; every output element is computed by one
 * thread in a fixed order, so the result does not depend on the thread count.
 */
#include <tgmath.h> /* sqrt of REAL */
#include <omp.h>
#include <stdint.h>

#define B 256    /* coordinates per block: 1 KB of each particle's row per array (fewer, longer streams; measured 1.6x faster than 32 on AVX2) */
#define NMAX 64  /* particles per group (the caller checks) */
#define IT 4     /* particles i per pass of the kernel sums */
#if defined(__AVX512F__)
#define V (64 / (int)sizeof(REAL))   /* coordinates per SIMD vector */
#else
#define V (32 / (int)sizeof(REAL))
#endif

static const REAL zrow[NMAX] = {0};   /* a kernel row of zeros: the padding of the last pass */

/* the update's arguments and derived constants, shared by every block */
typedef struct {
    int64_t n, D, adam, per_particle, noise_pc, spread;
    const REAL *z, *g, *xi, *K, *ks, *c2h, *v, *vn;
    REAL *zo, *vo, *vno;
    REAL rg, ibeta, gb, in, reps, rb2, r1b2, ibc, ibcn, rstep, rfloor, ff;
} upd;

/* one Adam second moment over m coordinates: v' = b2 v + (1 - b2) w s (s the block's sums of squared drifts, w
 * one over their count) written to vo, and the preconditioner 1 / (sqrt(v' ibc) + eps) to G */
static inline __attribute__((always_inline)) void moment(const REAL *restrict vr, REAL *restrict vor,
                                                          const REAL *restrict s, const REAL w, const REAL ibc,
                                                          const upd *restrict a, REAL *restrict G, const int64_t m)
{
    const REAL rb2 = a->rb2, r1b2 = a->r1b2, reps = a->reps;
    for (int64_t b = 0; b < m; b++) {
        const REAL nv = rb2 * vr[b] + r1b2 * (s[b] * w);
        vor[b] = nv;
        G[b] = (REAL)1 / (sqrt(nv * ibc) + reps);
    }
}

/* one block of B coordinates of group q: m (<= B) of them are real; inlined twice, with m = B (the loops then
 * have constant bounds and vectorise) and with the last block's remainder */
static inline __attribute__((always_inline)) void block(const upd *restrict a, const int64_t q, const int64_t k,
                                                         const int64_t m)
{
    const int64_t n = a->n, D = a->D, adam = a->adam, per_particle = a->per_particle, noise_pc = a->noise_pc,
                  spread = a->spread, d0 = k * B;
    const REAL *restrict z = a->z, *restrict g = a->g, *restrict xi = a->xi, *restrict K = a->K,
               *restrict ks = a->ks, *restrict c2h = a->c2h, *restrict v = a->v, *restrict vn = a->vn;
    REAL *restrict zo = a->zo, *restrict vo = a->vo, *restrict vno = a->vno;
    const REAL rg = a->rg, ibeta = a->ibeta, gb = a->gb, in = a->in, ibc = a->ibc, ibcn = a->ibcn,
               rstep = a->rstep, rfloor = a->rfloor, ff = a->ff;
    REAL zc[n][B], gc[n][B], dr[n][B], d1[n][B];   /* n <= NMAX rows: 4 n B values on the stack */
    REAL lam[B], corrs[B], mean[B], Gs[B], G1[B];
    const REAL *restrict Kq = K + q * n * n, *restrict ksq = ks + q * n;
    const REAL c = c2h[q];
    for (int64_t j = 0; j < n; j++) {
        const REAL *restrict zr = z + (q * n + j) * D + d0, *restrict gr = g + (q * n + j) * D + d0;
        for (int64_t b = 0; b < m; b++) { zc[j][b] = zr[b]; gc[j][b] = gr[b]; }
        for (int64_t b = m; b < B; b++) { zc[j][b] = 0; gc[j][b] = 0; }
    }
    /* sum_j K_ij z_j and sum_j K_ij g_j, four particles i at a time (each row j read once per four) and one SIMD
     * vector of coordinates at a time: the 2 IT accumulators stay in registers (16 on AVX2) */
    for (int64_t i0 = 0; i0 < n; i0 += IT) {
        const int64_t ni = n - i0 < IT ? n - i0 : IT;
        /* rows past the last particle read zeros (their sums are not used) */
        const REAL *K0 = Kq + i0 * n, *K1 = ni > 1 ? K0 + n : zrow, *K2 = ni > 2 ? K0 + 2 * n : zrow,
                   *K3 = ni > 3 ? K0 + 3 * n : zrow;
        for (int64_t b0 = 0; b0 < B; b0 += V) {
            REAL kz[IT][V], kg[IT][V];
            for (int64_t t = 0; t < IT; t++)
#pragma omp simd
                for (int64_t b = 0; b < V; b++) { kz[t][b] = 0; kg[t][b] = 0; }
            for (int64_t j = 0; j < n; j++) {
                const REAL k0 = K0[j], k1 = K1[j], k2 = K2[j], k3 = K3[j];
                const REAL *restrict zj = zc[j] + b0, *restrict gj = gc[j] + b0;
#pragma omp simd
                for (int64_t b = 0; b < V; b++) {
                    kz[0][b] += k0 * zj[b]; kg[0][b] += k0 * gj[b];
                    kz[1][b] += k1 * zj[b]; kg[1][b] += k1 * gj[b];
                    kz[2][b] += k2 * zj[b]; kg[2][b] += k2 * gj[b];
                    kz[3][b] += k3 * zj[b]; kg[3][b] += k3 * gj[b];
                }
            }
            for (int64_t t = 0; t < ni; t++) {
                const int64_t i = i0 + t;
                const REAL ksi = ksq[i];
#pragma omp simd
                for (int64_t b = 0; b < V; b++) {
                    const REAL rep = c * (zc[i][b0 + b] * ksi - kz[t][b]);
                    dr[i][b0 + b] = (rep - rg * kg[t][b]) * in - gb * gc[i][b0 + b];
                    d1[i][b0 + b] = (rep - kg[t][b]) * in - ibeta * gc[i][b0 + b];
                }
            }
        }
    }
    /* the ensemble-scaled step */
    if (spread && n >= 2) {
#pragma omp simd
        for (int64_t b = 0; b < B; b++) mean[b] = 0;
        for (int64_t j = 0; j < n; j++)
#pragma omp simd
            for (int64_t b = 0; b < B; b++) mean[b] += zc[j][b];
#pragma omp simd
        for (int64_t b = 0; b < B; b++) { mean[b] *= in; corrs[b] = 0; }
        for (int64_t j = 0; j < n; j++)
#pragma omp simd
            for (int64_t b = 0; b < B; b++) { const REAL e = zc[j][b] - mean[b]; corrs[b] += e * e; }
#pragma omp simd
        for (int64_t b = 0; b < B; b++) {
            const REAL var = corrs[b] / (REAL)(n - 1), s = sqrt(var);
            lam[b] = rstep * (s > rfloor ? s : rfloor);
            corrs[b] = (REAL)1 / ((var > ff ? var : ff) * (REAL)(n - 1));   /* corr_i = (z_i - m) corrs */
        }
    } else {
#pragma omp simd
        for (int64_t b = 0; b < B; b++) { lam[b] = rstep; corrs[b] = 0; mean[b] = 0; }
    }
    const int64_t with_corr = spread && n >= 2;
    /* the preconditioner(s): one second moment per group, or per particle */
    const int64_t np = per_particle ? n : 1;
    for (int64_t p = 0; p < np; p++) {
        const int64_t row = per_particle ? q * n + p : q;
        const int64_t i0 = per_particle ? p : 0, i1 = per_particle ? p + 1 : n;
        const REAL w = (REAL)1 / (REAL)(i1 - i0);
        if (adam) {
            REAL s2[B], s1[B];
#pragma omp simd
            for (int64_t b = 0; b < B; b++) { s2[b] = 0; s1[b] = 0; }
            for (int64_t i = i0; i < i1; i++)
#pragma omp simd
                for (int64_t b = 0; b < B; b++) { s2[b] += dr[i][b] * dr[i][b]; s1[b] += d1[i][b] * d1[i][b]; }
            moment(v + row * D + d0, vo + row * D + d0, s2, w, ibc, a, Gs, m);
            if (noise_pc)   /* vn, vno: only read and written while annealing */
                moment(vn + row * D + d0, vno + row * D + d0, s1, w, ibcn, a, G1, m);
            else
                for (int64_t b = 0; b < m; b++) G1[b] = Gs[b];
        } else {
            for (int64_t b = 0; b < m; b++) { Gs[b] = 1; G1[b] = 1; }
        }
        REAL sq[B], gl[B], mc[B];   /* per coordinate, the same for every particle */
        for (int64_t b = 0; b < m; b++) {
            const REAL gn = G1[b] < Gs[b] ? G1[b] : Gs[b];
            const REAL M = gn * lam[b] * ibeta;
            sq[b] = sqrt((REAL)2 * M);
            gl[b] = Gs[b] * lam[b];
            mc[b] = M;
        }
        for (int64_t i = i0; i < i1; i++) {
            const int64_t r = (q * n + i) * D + d0;
            const REAL *restrict xr = xi + r;
            REAL *restrict out = zo + r;
            for (int64_t b = 0; b < m; b++) {
                REAL zz = xr[b] * sq[b] + gl[b] * dr[i][b];
                if (with_corr) zz += mc[b] * (zc[i][b] - mean[b]) * corrs[b];
                out[b] = zz + zc[i][b];
            }
        }
    }
}

void bb_spos_update(int64_t G, int64_t n, int64_t D, int64_t nt, const REAL *restrict z, const REAL *restrict g,
                    const REAL *restrict xi, const REAL *restrict K, const REAL *restrict ks,
                    const REAL *restrict c2h, const REAL *restrict v, const REAL *restrict vn, REAL *restrict zo,
                    REAL *restrict vo, REAL *restrict vno, int64_t adam, int64_t per_particle, int64_t noise_pc,
                    int64_t spread, double gam, double beta, double eps, double b2, double bc, double bcn,
                    double step, double floor)
{
    const int64_t nblk = (D + B - 1) / B;
    const upd a = {n, D, adam, per_particle, noise_pc, spread, z, g, xi, K, ks, c2h, v, vn, zo, vo, vno,
                   (REAL)gam, (REAL)(1.0 / beta), (REAL)(gam / beta), (REAL)(1.0 / n), (REAL)eps, (REAL)b2,
                   (REAL)(1.0 - b2), (REAL)(1.0 / bc), (REAL)(1.0 / bcn), (REAL)step, (REAL)floor,
                   (REAL)(floor * floor)};
#pragma omp parallel for num_threads(nt) schedule(static) collapse(2)
    for (int64_t q = 0; q < G; q++) {
        for (int64_t k = 0; k < nblk; k++) {
            const int64_t m = D - k * B < B ? D - k * B : B;
            if (m == B) block(&a, q, k, B);
            else block(&a, q, k, m);
        }
    }
}
