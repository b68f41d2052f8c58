/* f-k migration (Lindell, Wetzstein & O'Toole, SIGGRAPH 2019) on a zero-padded grid of
 * shape (2M, 2Ny, 2Nx), spectra in FFT-native order (index i >= n/2 is frequency i - n).
 *
 *   fk_prepare: psi[t, y, x] = sqrt(max(w_t * tau[t, y, x], 0)), zero padded, real
 *               (w_t = (t/T)^p radiometric weight; the square root turns intensity into a
 *               wave amplitude)
 *   stolt:      PSI'(kz, ky, kx) = PSI(k(kz), ky, kx) * kz / k(kz) for 0 < kz <= kmax,
 *               k(kz) = sqrt(kz^2 + alpha_y ky^2 + alpha_x kx^2) in t-frequency index
 *               units, alpha_x = (M dz / (Nx dx))^2 (likewise y), linear interpolation
 *               along kz; PSI is the half spectrum of the real psi (kx >= 0), the other
 *               half from PSI(kt, ky, kx) = conj(PSI(-kt, -ky, -kx)). Launched on the rows
 *               kz = 1..kmax only; the caller zeroes the others.
 *   fk_finish:  vol[z, y, x] = |psi'[z, y, x]|^2 on the unpadded block
 */
#include "common.h"
#include "complex.h"

__kernel void fk_prepare(__global const real_t *restrict tau, __global const real_t *restrict w_t,
                         __global real_t *restrict psi, const int nt, const int ny, const int nx)
{
    const int x = get_global_id(0), y = get_global_id(1), t = get_global_id(2);
    const int py = 2 * ny, px = 2 * nx;
    if (x >= px || y >= py || t >= 2 * nt)
        return;
    /* two stores rather than a select: PoCL's vectoriser made the select form 15x slower */
    const size_t o = ((size_t)t * py + y) * px + x;
    if (t < nt && y < ny && x < nx)
        psi[o] = sqrt(fmax(w_t[t] * tau[((size_t)t * ny + y) * nx + x], (real_t)0));
    else
        psi[o] = (real_t)0;
}

inline int signed_freq(const int i, const int n) { return i < n / 2 ? i : i - n; }

__kernel void stolt(__global const cplx_t *restrict spec_h, __global cplx_t *restrict dst,
                    const int nt2, const int ny2, const int nx2, const real_t alpha_y,
                    const real_t alpha_x, const int x0, const int mirrored)
{
    /* columns x0 + gid(0); one launch for kx >= 0 (mirrored = 0, read as stored) and one for
     * kx < 0 (mirrored = 1, read through conjugate symmetry): uniform control flow in each */
    const int ix = get_global_id(0) + x0, iy = get_global_id(1), fz = get_global_id(2) + 1;
    const int kmax = nt2 / 2 - 1; /* highest positive t-frequency index below Nyquist */
    if (ix >= nx2 || iy >= ny2 || fz > kmax)
        return;
    const size_t o = ((size_t)fz * ny2 + iy) * nx2 + ix;
    const real_t fy = (real_t)signed_freq(iy, ny2), fx = (real_t)signed_freq(ix, nx2);
    const real_t k_raw = sqrt((real_t)fz * fz + alpha_y * fy * fy + alpha_x * fx * fx);
    const int inside = k_raw <= (real_t)kmax;
    /* no branch around the loads (PoCL vectorises straight-line code): outside the band
     * the row is clamped and the result multiplied by 0 */
    const real_t k = inside ? k_raw : (real_t)kmax;
    const int i0 = (int)k; /* k >= fz >= 1: truncation is floor (a libm call is 5x slower on
                            * PoCL here) */
    const real_t w = k - (real_t)i0;
    /* PSI(i, iy, ix) from the half spectrum (nt2, ny2, nh): stored for ix < nh, else
     * conj(PSI(-i, -iy, -ix)) with -i = nt2 - i (1 <= i < nt2) */
    const int nh = nx2 / 2 + 1;
    const size_t col = mirrored ? (size_t)(iy == 0 ? 0 : ny2 - iy) * nh + (size_t)(nx2 - ix)
                                : (size_t)iy * nh + (size_t)ix;
    const size_t plane = (size_t)ny2 * nh;
    const int r0 = mirrored ? nt2 - i0 : i0;
    const int step = mirrored ? -1 : 1; /* row of i0 + 1 */
    /* i0 + 1 <= kmax + 1 = nt2 / 2: both rows exist (the second has weight w, 0 at k = i0) */
    cplx_t v = CADD(CRMUL(spec_h[(size_t)r0 * plane + col], (real_t)1 - w),
                    CRMUL(spec_h[(size_t)(r0 + step) * plane + col], w));
    v.imag = mirrored ? -v.imag : v.imag;
    dst[o] = CRMUL(v, inside ? (real_t)fz / k : (real_t)0);
}

__kernel void fk_finish(__global const cplx_t *restrict psi, __global real_t *restrict vol, const int nt,
                        const int ny, const int nx)
{
    const int x = get_global_id(0), y = get_global_id(1), z = get_global_id(2);
    if (x >= nx || y >= ny || z >= nt)
        return;
    const cplx_t p = psi[((size_t)z * 2 * ny + y) * 2 * nx + x];
    vol[((size_t)z * ny + y) * nx + x] = p.real * p.real + p.imag * p.imag;
}
