/* f-k migration (Lindell, Wetzstein & O'Toole, SIGGRAPH 2019) on a zero-padded grid of
 * shape (2M, 2Ny, 2Nx), spectra in FFT-native order (index i >= n/2 is frequency i - n).
 *
 *   fk_prepare: psi[t, y, x] = sqrt(max(w_t * tau[t, y, x], 0)), zero padded
 *               (w_t = (t/T)^p radiometric weight; the square root turns intensity into a
 *               wave amplitude)
 *   stolt:      PSI'(kz, ky, kx) = PSI(k(kz), ky, kx) * kz / k(kz) for kz > 0, else 0,
 *               k(kz) = sqrt(kz^2 + alpha_y ky^2 + alpha_x kx^2) in t-frequency index
 *               units, alpha_x = (M dz / (Nx dx))^2 (likewise y), linear interpolation
 *               along kz
 *   fk_finish:  vol[z, y, x] = |psi'[z, y, x]|^2 on the unpadded block
 */
#include "common.h"
#include "complex.h"

__kernel void fk_prepare(__global const real_t *restrict tau, __global const real_t *restrict w_t,
                         __global cplx_t *restrict psi, const int nt, const int ny, const int nx)
{
    const int x = get_global_id(0), y = get_global_id(1), t = get_global_id(2);
    const int py = 2 * ny, px = 2 * nx;
    if (x >= px || y >= py || t >= 2 * nt)
        return;
    real_t v = 0;
    if (t < nt && y < ny && x < nx)
        v = sqrt(fmax(w_t[t] * tau[((size_t)t * ny + y) * nx + x], (real_t)0));
    psi[((size_t)t * py + y) * px + x] = CNEW(v, (real_t)0);
}

inline int signed_freq(const int i, const int n) { return i < n / 2 ? i : i - n; }

__kernel void stolt(__global const cplx_t *restrict src, __global cplx_t *restrict dst, const int nt2,
                    const int ny2, const int nx2, const real_t alpha_y, const real_t alpha_x)
{
    const int ix = get_global_id(0), iy = get_global_id(1), iz = get_global_id(2);
    if (ix >= nx2 || iy >= ny2 || iz >= nt2)
        return;
    const size_t plane = (size_t)ny2 * nx2;
    const size_t o = (size_t)iz * plane + (size_t)iy * nx2 + ix;
    const int fz = signed_freq(iz, nt2);
    const real_t fy = (real_t)signed_freq(iy, ny2), fx = (real_t)signed_freq(ix, nx2);
    const real_t k = sqrt((real_t)fz * fz + alpha_y * fy * fy + alpha_x * fx * fx);
    const int kmax = nt2 / 2 - 1; /* highest positive t-frequency index below Nyquist */
    if (fz <= 0 || k > (real_t)kmax) {
        dst[o] = CNEW((real_t)0, (real_t)0);
        return;
    }
    const int i0 = (int)floor(k);
    const real_t w = k - (real_t)i0;
    const size_t col = (size_t)iy * nx2 + ix;
    cplx_t v = CRMUL(src[(size_t)i0 * plane + col], (real_t)1 - w);
    if (w > 0)
        v = CADD(v, CRMUL(src[(size_t)(i0 + 1) * plane + col], w));
    dst[o] = CRMUL(v, (real_t)fz / fmax(k, (real_t)1e-6));
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
