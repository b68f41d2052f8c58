/* Time-resolved diffuse transmittance of a homogeneous slab (pencil beam, flux form).
 *
 *   T(rho,t) = (4 pi D v)^(-3/2) t^(-5/2) exp(-mu_a v t - rho^2/(4 D v t))
 *              * 1/2 sum_{m=-M..M} [ z1_m exp(-z1_m^2/(4Dvt)) - z2_m exp(-z2_m^2/(4Dvt)) ]
 *   z1_m = (1-2m) d - 4m ze - z0,   z2_m = (1-2m) d - (4m-2) ze + z0          [1/(m^2 s)]
 *
 * Evaluated in log space: the largest Gaussian exp(-zmin^2/a) is factored out of the sum
 * and folded into the log prefactor, so t -> 0, huge rho and long times neither overflow nor
 * give NaN (exact 0 where the value underflows). Each image pair is summed in the
 * cancellation-free form
 *   z1 e^{-z1^2/a} - z2 e^{-z2^2/a} = e^{-z1^2/a} [ (z1 - z2) - z2 expm1(-delta) ],
 *   z1 - z2 = -2 (ze + z0),  delta = (z2^2 - z1^2)/a = 2 (ze + z0)(z1 + z2)/a.
 *
 * n_dipoles >= 0: exactly that M (the accuracy knob; truncation makes late times too small,
 * clamped at 0). n_dipoles < 0 ("auto"): per sample, with x = D v t / L^2 and L = d + 2 ze,
 * the image series is used for x < X_SWITCH with M = ceil(sqrt(x ln(1/tol))) + 1, and the
 * equivalent eigenmode series (Poisson dual, converges fast at late times)
 *   T = D v (4 pi D v t)^-1 e^{-rho^2/a - mu_a v t} (2 pi / L^2)
 *       sum_n n (-1)^(n+1) sin(n pi (z0+ze)/L) cos(n pi ze/L) e^{-n^2 pi^2 x}
 * for x >= X_SWITCH with N = ceil(sqrt(1 + ln(1/tol)/(pi^2 x))) + 1 terms.
 */
#include "common.h"

#define X_SWITCH ((real_t)0.25)

/* Depths of the m-th image pair (the header's z1_m, z2_m), stated once. */
inline void image_depths(const int m, const real_t d, const real_t z0, const real_t ze,
                         real_t *z1, real_t *z2)
{
    *z1 = (real_t)(1 - 2 * m) * d - (real_t)(4 * m) * ze - z0;
    *z2 = (real_t)(1 - 2 * m) * d - (real_t)(4 * m - 2) * ze + z0;
}

inline real_t image_pair(const int m, const real_t d, const real_t z0, const real_t ze,
                         const real_t a, const real_t zmin2)
{
    real_t z1, z2;
    image_depths(m, d, z0, ze, &z1, &z2);
    const real_t h = ze + z0;
    const real_t delta = (real_t)2 * h * (z1 + z2) / a;
    /* expm1 of huge arguments is not reliable on every OpenCL library (PoCL returns -inf
     * for double); beyond |delta| = 64 it is -1 to working precision anyway. */
    const real_t em = fabs(delta) > (real_t)64 ? (real_t)-1 : expm1(-fabs(delta));
    /* fmax: with FMA contraction z*z - zmin2 can come out slightly negative for the
     * smallest term, and divided by a tiny a that would overflow. */
    if (delta >= 0)
        return exp(-fmax(z1 * z1 - zmin2, (real_t)0) / a) * ((real_t)-2 * h - z2 * em);
    return exp(-fmax(z2 * z2 - zmin2, (real_t)0) / a) * ((real_t)-2 * h + z1 * em);
}

/* log of T(0, t) exp(+mu_a v t ... ) -- everything but the lateral Gaussian:
 * T(rho, t) = exp(slab_log_T0(t) - rho^2 / (4 D v t)). -INFINITY where T is 0. */
inline real_t slab_log_T0(const real_t t, const real_t Dv, const real_t muav, const real_t d,
                          const real_t z0, const real_t ze, const int n_dipoles,
                          const real_t ln_tol)
{
    if (!(t > 0))
        return -INFINITY;
    const real_t a = (real_t)4 * Dv * t;
    const real_t L = d + (real_t)2 * ze;
    const real_t x = Dv * t / (L * L);

    if (n_dipoles >= 0 || x < X_SWITCH) {
        const int M = n_dipoles >= 0 ? n_dipoles : (int)ceil(sqrt(x * ln_tol)) + 1;
        real_t zmin2 = INFINITY;
        for (int m = -M; m <= M; ++m) {
            real_t z1, z2;
            image_depths(m, d, z0, ze, &z1, &z2);
            zmin2 = fmin(zmin2, fmin(z1 * z1, z2 * z2));
        }
        real_t s = 0;
        for (int m = -M; m <= M; ++m)
            s += image_pair(m, d, z0, ze, a, zmin2);
        if (!(s > 0))
            return -INFINITY;
        return (real_t)-1.5 * log((real_t)4 * PI_R * Dv) - (real_t)2.5 * log(t) - muav * t
               - zmin2 / a + log((real_t)0.5 * s);
    }
    const int N = (int)ceil(sqrt((real_t)1 + ln_tol / (PI_R * PI_R * x))) + 1;
    const real_t k1 = PI_R * PI_R * x;
    real_t s = 0;
    for (int n = 1; n <= N; ++n) {
        const real_t sg = (n & 1) ? (real_t)1 : (real_t)-1;
        s += sg * (real_t)n * sin((real_t)n * PI_R * (z0 + ze) / L)
             * cos((real_t)n * PI_R * ze / L) * exp(-k1 * (real_t)(n * n - 1));
    }
    if (!(s > 0))
        return -INFINITY;
    return log(Dv) - log((real_t)4 * PI_R * Dv * t) - muav * t - k1
           + log((real_t)2 * PI_R / (L * L)) + log(s);
}

inline real_t slab_T(const real_t rho, const real_t t, const real_t Dv, const real_t muav,
                     const real_t d, const real_t z0, const real_t ze, const int n_dipoles,
                     const real_t ln_tol)
{
    const real_t lf = slab_log_T0(t, Dv, muav, d, z0, ze, n_dipoles, ln_tol);
    if (lf == -INFINITY)
        return 0;
    return exp(lf - rho * rho / ((real_t)4 * Dv * t));
}

/* out[i] = T(rho[i], t[i]) for n samples. */
__kernel void transmittance_pairs(__global const real_t *restrict rho,
                                  __global const real_t *restrict t,
                                  __global real_t *restrict out, const int n,
                                  const real_t Dv, const real_t muav, const real_t d,
                                  const real_t z0, const real_t ze, const int n_dipoles,
                                  const real_t ln_tol)
{
    const size_t i = get_global_id(0);
    if (i >= (size_t)n)
        return;
    out[i] = slab_T(rho[i], t[i], Dv, muav, d, z0, ze, n_dipoles, ln_tol);
}

/* log_t0[it] = slab_log_T0(t[it]): the series, once per time sample. */
__kernel void log_series(__global const real_t *restrict t, __global real_t *restrict log_t0, const int n_t,
                         const real_t Dv, const real_t muav, const real_t d, const real_t z0,
                         const real_t ze, const int n_dipoles, const real_t ln_tol)
{
    const int it = get_global_id(0);
    if (it >= n_t)
        return;
    log_t0[it] = slab_log_T0(t[it], Dv, muav, d, z0, ze, n_dipoles, ln_tol);
}

/* out[it * n_rho + ir] = scale * T(rho[ir], t[it]) from the per-time series log_t0: the
 * (t, rho) table used for PSF grids; the series is not recomputed per radius. */
__kernel void transmittance_outer(__global const real_t *restrict rho, __global const real_t *restrict t,
                                  __global const real_t *restrict log_t0, __global real_t *restrict out,
                                  const int n_rho, const int n_t, const real_t Dv,
                                  const real_t scale)
{
    const int ir = get_global_id(0);
    const int it = get_global_id(1);
    if (ir >= n_rho || it >= n_t)
        return;
    const real_t lf = log_t0[it];
    const real_t r = rho[ir];
    out[(size_t)it * n_rho + ir] =
        lf == -INFINITY ? (real_t)0 : scale * exp(lf - r * r / ((real_t)4 * Dv * t[it]));
}

/* out[it * n_rho + ir] = scale * sum_k w[k] T(rho[ir], t[it * n_nodes + k]): the bin-averaged
 * table of diffusion_psf (Gauss-Legendre nodes k within bin it), summed in registers so the
 * table is written once (a pass per node plus an accumulation pass cost 5x the memory
 * traffic). log_t0 has the layout of t. */
__kernel void transmittance_outer_avg(__global const real_t *restrict rho,
                                      __global const real_t *restrict t,
                                      __global const real_t *restrict log_t0,
                                      __constant real_t *w, __global real_t *restrict out,
                                      const int n_rho, const int n_t, const int n_nodes,
                                      const real_t Dv, const real_t scale)
{
    const size_t ir = get_global_id(0);
    const size_t it = get_global_id(1);
    if (ir >= (size_t)n_rho || it >= (size_t)n_t)
        return;
    const real_t r2 = rho[ir] * rho[ir];
    real_t acc = 0;
    for (int k = 0; k < n_nodes; ++k) {
        const size_t j = it * (size_t)n_nodes + (size_t)k;
        const real_t lf = log_t0[j];
        if (lf != -INFINITY)
            acc += w[k] * exp(lf - r2 / ((real_t)4 * Dv * t[j]));
    }
    out[it * (size_t)n_rho + ir] = scale * acc;
}
