/* Tabulated isotropic BRDF lookup with trilinear interpolation.
 *
 * Texture f[i, j, k] at theta_i = i * pi/2 / (n_ti - 1), theta_s = j * pi/2 / (n_ts - 1),
 * delta_phi = k * pi / (n_dp - 1), delta_phi = |phi_s - phi_i| wrapped to [0, pi] (isotropy
 * and bilateral symmetry). Queries angles[q] = (theta_i, phi_i, theta_s, phi_s) in radians;
 * zenith angles are clamped to [0, pi/2]. Angles are finite (checked on the host,
 * clnlos.brdf.texture.TextureLookup): a NaN would reach an (int) conversion.
 *
 * brdf_lookup_buffer: any precision, manual trilinear interpolation from a buffer.
 * brdf_lookup_image (built with -DUSE_IMAGE, float only): a 3D image with a linear sampler
 * (hardware filtering where the device has it; GPUs filter with ~8-bit weights).
 */
#include "common.h"

inline real_t wrap_dphi(const real_t pi_, const real_t ps)
{
    real_t d = fabs(ps - pi_);
    d = fmod(d, (real_t)2 * PI_R);
    return d > PI_R ? (real_t)2 * PI_R - d : d;
}

inline real_t grid_pos(const real_t a, const real_t amax, const int n)
{
    return clamp(a, (real_t)0, amax) / amax * (real_t)(n - 1);
}

/* Fractional grid positions (theta_i, theta_s, delta_phi) of query q. */
inline void query_grid_pos(__global const real_t *restrict angles, const size_t q,
                           const int n_ti,
                           const int n_ts, const int n_dp, real_t *u, real_t *v, real_t *w)
{
    *u = grid_pos(angles[4 * q], PI_R / 2, n_ti);
    *v = grid_pos(angles[4 * q + 2], PI_R / 2, n_ts);
    *w = grid_pos(wrap_dphi(angles[4 * q + 1], angles[4 * q + 3]), PI_R, n_dp);
}

__kernel void brdf_lookup_buffer(__global const real_t *restrict tex, const int n_ti,
                                 const int n_ts, const int n_dp,
                                 __global const real_t *restrict angles,
                                 __global real_t *restrict out, const ulong n)
{
    const size_t q = get_global_id(0);
    if (q >= n)
        return;
    real_t u, v, w;
    query_grid_pos(angles, q, n_ti, n_ts, n_dp, &u, &v, &w);
    const int i0 = min((int)u, n_ti - 2), j0 = min((int)v, n_ts - 2), k0 = min((int)w, n_dp - 2);
    const real_t fu = u - i0, fv = v - j0, fw = w - k0;
    real_t acc = 0;
    for (int di = 0; di < 2; ++di)
        for (int dj = 0; dj < 2; ++dj)
            for (int dk = 0; dk < 2; ++dk) {
                const real_t wt = (di ? fu : 1 - fu) * (dj ? fv : 1 - fv) * (dk ? fw : 1 - fw);
                acc += wt * tex[((size_t)(i0 + di) * n_ts + (j0 + dj)) * n_dp + (k0 + dk)];
            }
    out[q] = acc;
}

#ifdef USE_IMAGE
__constant sampler_t LINEAR = CLK_NORMALIZED_COORDS_FALSE | CLK_ADDRESS_CLAMP_TO_EDGE |
                              CLK_FILTER_LINEAR;

__kernel void brdf_lookup_image(__read_only image3d_t tex, const int n_ti, const int n_ts,
                                const int n_dp, __global const real_t *restrict angles,
                                __global real_t *restrict out, const ulong n)
{
    const size_t q = get_global_id(0);
    if (q >= n)
        return;
    real_t u, v, w;
    query_grid_pos(angles, q, n_ti, n_ts, n_dp, &u, &v, &w);
    /* image axes: x = delta_phi (fastest), y = theta_s, z = theta_i; texel centres at +0.5 */
    out[q] = read_imagef(tex, LINEAR, (float4)(w + 0.5f, v + 0.5f, u + 0.5f, 0.0f)).x;
}
#endif
