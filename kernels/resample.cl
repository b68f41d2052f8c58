/* Resampling along axis 0 of [rows, y, x] volumes by a sparse (CSR) matrix:
 *
 *   out[r, y, x] = sum_{e = row_ptr[r]}^{row_ptr[r+1]-1} val[e] * in[col[e], y, x]
 *
 * for r < n_rows, y < ny, x < nx (the block), read at (in_y0, in_x0) of an input plane of
 * in_ny x in_nx and written at (out_y0, out_x0) of an output plane of out_ny x out_nx, so the
 * same kernel pads and crops at any offset, rebins in time
 * (mass-conserving bin overlaps), maps t -> t^2 for LCT and applies radiometric weights.
 * The adjoint is the same kernel with the transposed matrix.
 */
#include "common.h"

__kernel void csr_resample(__global const int *restrict row_ptr, __global const int *restrict col,
                           __global const real_t *restrict val,
                           __global const real_t *restrict in, const int in_ny, const int in_nx,
                           const int in_y0, const int in_x0,
                           __global real_t *restrict out, const int out_ny, const int out_nx,
                           const int out_y0, const int out_x0,
                           const int n_rows, const int ny, const int nx)
{
    const int x = get_global_id(0);
    const int y = get_global_id(1);
    const int r = get_global_id(2);
    if (x >= nx || y >= ny || r >= n_rows)
        return;
    const size_t in_plane = (size_t)in_ny * in_nx;
    const size_t off = (size_t)(y + in_y0) * in_nx + (size_t)(x + in_x0);
    real_t acc = 0;
    for (int e = row_ptr[r]; e < row_ptr[r + 1]; ++e)
        acc += val[e] * in[(size_t)col[e] * in_plane + off];
    out[(size_t)r * out_ny * out_nx + (size_t)(y + out_y0) * out_nx + (size_t)(x + out_x0)] = acc;
}

/* a[i] *= s: normalisation in place (one pass, in a program already built). */
__kernel void scale_inplace(__global real_t *restrict a, const real_t s, const long n)
{
    const long i = get_global_id(0);
    if (i < n)
        a[i] *= s;
}

/* out[i] = max(in[i], 0): the albedo volume is non-negative. */
__kernel void clamp_nonnegative(__global real_t *restrict a, const long n)
{
    const long i = get_global_id(0);
    if (i < n)
        a[i] = fmax(a[i], (real_t)0);
}

/* Zero padding in time, mirror padding laterally, into a (pt, 2 ny, 2 nx) FFT buffer:
 *   out[t, y, x] = in[t, m(y, ny), m(x, nx)] for t < nt, else 0,  m(j, n) = j < n ? j : 2n-1-j
 * Over the wrap-around half of a 2n grid this is the even (mirror) extension across both
 * edges at once, so a circular deconvolution sees no step at the scan border. */
__kernel void pad_mirror_xy(__global const real_t *restrict in, __global real_t *restrict out, const int nt,
                            const int ny, const int nx, const int pt)
{
    const int x = get_global_id(0), y = get_global_id(1), t = get_global_id(2);
    const int py = 2 * ny, px = 2 * nx;
    if (x >= px || y >= py || t >= pt)
        return;
    const int sy = y < ny ? y : py - 1 - y;
    const int sx = x < nx ? x : px - 1 - x;
    out[((size_t)t * py + y) * px + x] =
        t < nt ? in[((size_t)t * ny + sy) * nx + sx] : (real_t)0;
}
