/* Light-cone transform: the light cone h on the padded (pv, py, px) v-grid (clnlos/inverse/lct.py).
 *
 * Lateral cell (y, x) in wrap order has offset (dy, dx) cells, d = j < (n + 1) / 2 ? j : j - n;
 * its response sits at the v-shift s = (dy^2 + dx^2) * shift_per_cell2 bins
 * (shift_per_cell2 = pitch^2 / R^2 * nt), split linearly between bins k0 = floor(s) and k0 + 1:
 *
 *   psf[k0, y, x] = (1 - f) * scale,   psf[k0 + 1, y, x] = f * scale,   f = s - k0,
 *
 * where those bins lie below pv (``scale`` = 1 / the sum of the kept weights, from the host).
 * One work-item per column writes only its own column: no atomics. psf must be zeroed. */
#include "common.h"

__kernel void lightcone_psf(__global real_t *restrict psf, const int pv, const int py,
                            const int px, const real_t shift_per_cell2, const real_t scale)
{
    const int x = get_global_id(0), y = get_global_id(1);
    if (x >= px || y >= py)
        return;
    const long dy = y < (py + 1) / 2 ? y : y - py;
    const long dx = x < (px + 1) / 2 ? x : x - px;
    const real_t s = (real_t)(dy * dy + dx * dx) * shift_per_cell2;
    if (!(s < (real_t)pv))
        return;
    const long k0 = (long)floor(s);
    const real_t f = s - (real_t)k0;
    const size_t plane = (size_t)py * (size_t)px;
    const size_t col = (size_t)y * (size_t)px + (size_t)x;
    psf[(size_t)k0 * plane + col] = ((real_t)1 - f) * scale;
    if (k0 + 1 < pv)
        psf[(size_t)(k0 + 1) * plane + col] = f * scale;
}
