/* Proximal and vector-update kernels of the iterative solvers (clnlos/inverse/solvers.py).
 *
 * Volumes are [nz, ny, nx] arrays of n = nz * ny * nx values; the support is the depth rows
 * k >= row_min (plane = ny * nx values per row): outside it every update writes 0.
 *
 *   prox_step:    x1 = P(z - step * g - shift) with P = max(., 0) on the support, 0 off it
 *                 (the prox of step * (l1 * sum(x) + i(x >= 0)) when shift = step * l1);
 *                 the support is also restricted to the working set ``ws`` (uchar, 1 in it)
 *                 when has_ws; also r[i] = (z - x1)(x1 - x0), whose sum decides a gradient
 *                 restart
 *   gradient_step: v = z - step * g - shift;  restart_terms: r = (z - x1)(x1 - x0)
 *   fista_state:  one work item: the momentum sequence on the device, state = (t, beta,
 *                 restarts): a restart (sum of r > 0) sets t = 1, beta = 0, else
 *                 t' = (1 + sqrt(1 + 4 t^2)) / 2, beta = (t - 1) / t'
 *   momentum_state: z = x1 + state[1] (x1 - x0) (beta read on the device: no host sync)
 *   working_set:  ws = support and (x > 0 or g + shift < 0) (the variables a prox step may
 *                 move: nonzero, or at zero with a gradient that pushes them up), and
 *                 out[i] = 1 where the latter holds outside the old set ``old`` (a KKT
 *                 violation the last round could not see), else 0
 *   masked_copy:  out = ws ? x : 0 (the working set's restriction of a volume)
 *   tv_primal:    x = P(v - lam * div p)                         (FGP, Beck & Teboulle 2009)
 *   tv_dual:      p1 = Proj_{|p| <= 1}(q + grad(x) / (8 + 4 wz^2) / lam),
 *                 q = p1 + beta (p1 - p0)
 *   weighted_residual: r = w (a - y)       (w = 1 when w is not given)
 *
 * grad is the forward difference (0 at the far edge) along z (times wz), y and x; div is its
 * negative adjoint. p holds the three components as [3, nz, ny, nx]. Isotropic TV: the
 * per-voxel norm |p| = sqrt(pz^2 + py^2 + px^2).
 */
#include "common.h"

__kernel void prox_step(__global const real_t *restrict z, __global const real_t *restrict g,
                        __global const real_t *restrict x0, __global real_t *restrict x1,
                        __global real_t *restrict r, __global const uchar *restrict ws,
                        const int has_ws, const real_t step, const real_t shift,
                        const ulong row_min, const ulong plane, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    const int free_i = (i / plane >= row_min) && (!has_ws || ws[i]);
    const real_t v = free_i ? fmax(z[i] - step * g[i] - shift, (real_t)0) : (real_t)0;
    x1[i] = v;
    r[i] = (z[i] - v) * (v - x0[i]);
}

__kernel void gradient_step(__global const real_t *restrict z,
                            __global const real_t *restrict g, __global real_t *restrict v,
                            const real_t step, const real_t shift, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n)
        v[i] = z[i] - step * g[i] - shift;
}

__kernel void restart_terms(__global const real_t *restrict z, __global const real_t *restrict x1,
                            __global const real_t *restrict x0, __global real_t *restrict r,
                            const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n)
        r[i] = (z[i] - x1[i]) * (x1[i] - x0[i]);
}

__kernel void fista_state(__global real_t *restrict state,
                          __global const real_t *restrict restart_sum)
{
    if (get_global_id(0) != 0)
        return;
    const real_t t = state[0];
    if (restart_sum[0] > (real_t)0) {
        state[0] = (real_t)1;
        state[1] = (real_t)0;
        state[2] += (real_t)1;
    } else {
        const real_t t1 = ((real_t)1 + sqrt((real_t)1 + (real_t)4 * t * t)) / (real_t)2;
        state[0] = t1;
        state[1] = (t - (real_t)1) / t1;
    }
}

__kernel void momentum_state(__global const real_t *restrict x1,
                             __global const real_t *restrict x0, __global real_t *restrict z,
                             __global const real_t *restrict state, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    const real_t beta = state[1];
    z[i] = x1[i] + beta * (x1[i] - x0[i]);
}

__kernel void working_set(__global const real_t *restrict x, __global const real_t *restrict g,
                          __global const uchar *restrict old, __global uchar *restrict ws,
                          __global real_t *restrict out, const real_t shift,
                          const ulong row_min, const ulong plane, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    const int on = i / plane >= row_min;
    const int enters = on && x[i] <= (real_t)0 && g[i] + shift < (real_t)0;
    ws[i] = (uchar)(on && (x[i] > (real_t)0 || enters));
    out[i] = (enters && !old[i]) ? (real_t)1 : (real_t)0;
}

__kernel void masked_copy(__global const real_t *restrict x, __global const uchar *restrict ws,
                          __global real_t *restrict out, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i < n)
        out[i] = ws[i] ? x[i] : (real_t)0;
}

inline size_t idx3(const size_t k, const size_t j, const size_t i, const size_t ny,
                   const size_t nx)
{
    return (k * ny + j) * nx + i;
}

__kernel void tv_primal(__global const real_t *restrict v, __global const real_t *restrict p,
                        __global real_t *restrict x, const real_t lam, const real_t wz,
                        const ulong nz, const ulong ny, const ulong nx, const ulong row_min)
{
    const size_t i = get_global_id(0), j = get_global_id(1), k = get_global_id(2);
    if (i >= nx || j >= ny || k >= nz)
        return;
    const size_t n = nz * ny * nx;
    const size_t o = idx3(k, j, i, ny, nx);
    __global const real_t *pz = p, *py = p + n, *px = p + 2 * n;
    /* div p = -grad^T p (backward differences, boundary-aware) */
    real_t d = 0;
    if (k + 1 < nz) d += wz * pz[o];
    if (k > 0) d -= wz * pz[o - ny * nx];
    if (j + 1 < ny) d += py[o];
    if (j > 0) d -= py[o - nx];
    if (i + 1 < nx) d += px[o];
    if (i > 0) d -= px[o - 1];
    x[o] = (k >= row_min) ? fmax(v[o] + lam * d, (real_t)0) : (real_t)0;
}

__kernel void tv_dual(__global const real_t *restrict x, __global const real_t *restrict p0,
                      __global real_t *restrict p1, __global real_t *restrict q,
                      const real_t scale, const real_t beta, const real_t wz, const ulong nz,
                      const ulong ny, const ulong nx)
{
    const size_t i = get_global_id(0), j = get_global_id(1), k = get_global_id(2);
    if (i >= nx || j >= ny || k >= nz)
        return;
    const size_t n = nz * ny * nx;
    const size_t o = idx3(k, j, i, ny, nx);
    const real_t gz = (k + 1 < nz) ? wz * (x[o + ny * nx] - x[o]) : (real_t)0;
    const real_t gy = (j + 1 < ny) ? x[o + nx] - x[o] : (real_t)0;
    const real_t gx = (i + 1 < nx) ? x[o + 1] - x[o] : (real_t)0;
    real_t az = q[o] + scale * gz, ay = q[o + n] + scale * gy, ax = q[o + 2 * n] + scale * gx;
    const real_t nrm = fmax((real_t)1, sqrt(az * az + ay * ay + ax * ax));
    az /= nrm;
    ay /= nrm;
    ax /= nrm;
    q[o] = az + beta * (az - p0[o]);
    q[o + n] = ay + beta * (ay - p0[o + n]);
    q[o + 2 * n] = ax + beta * (ax - p0[o + 2 * n]);
    p1[o] = az;
    p1[o + n] = ay;
    p1[o + 2 * n] = ax;
}

__kernel void weighted_residual(__global const real_t *restrict a, __global const real_t *restrict y,
                                __global const real_t *restrict w, __global real_t *restrict r,
                                const int has_w, const ulong n)
{
    const size_t i = get_global_id(0);
    if (i >= n)
        return;
    const real_t d = a[i] - y[i];
    r[i] = has_w ? w[i] * d : d;
}
