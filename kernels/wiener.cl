/* Element-wise spectral operations on complex half or full spectra (pyopencl-complex.h).
 *
 *   wiener_apply:      X <- conj(H) / (|H|^2 + inv_snr) * X      (adjoint: H / (...) * X)
 *   spectral_multiply: X <- H * X (convolution) or conj(H) * X (correlation = adjoint)
 *   spectral_square:   H <- H * H (confocal: the blur crossed twice)
 *
 * 1/SNR is added to the real denominator |H|^2 only (the published CDT code also adds it
 * to the imaginary part, which biases the phase).
 */
#include "common.h"
#include "complex.h"

__kernel void wiener_apply(__global const cplx_t *restrict H, __global cplx_t *restrict X, const real_t inv_snr,
                           const int adjoint, const long n)
{
    const long i = get_global_id(0);
    if (i >= n)
        return;
    const cplx_t h = H[i];
    const real_t den = CABS2(h) + inv_snr;
    /* den == 0 only where H == 0 and 1/SNR == 0: the inverse filter has no information
     * there, so the output is 0 rather than NaN. */
    const real_t g = den > 0 ? (real_t)1 / den : (real_t)0;
    const cplx_t w = CRMUL(adjoint ? h : CCONJ(h), g);
    X[i] = CMUL(w, X[i]);
}

__kernel void spectral_multiply(__global const cplx_t *restrict H, __global cplx_t *restrict X, const int conjugate,
                                const long n)
{
    const long i = get_global_id(0);
    if (i >= n)
        return;
    const cplx_t h = H[i];
    X[i] = CMUL(conjugate ? CCONJ(h) : h, X[i]);
}

__kernel void spectral_square(__global cplx_t *restrict H, const long n)
{
    const long i = get_global_id(0);
    if (i >= n)
        return;
    H[i] = CMUL(H[i], H[i]);
}
