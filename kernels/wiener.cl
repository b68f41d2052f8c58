/* Element-wise spectral operations on complex half or full spectra (pyopencl-complex.h).
 *
 *   wiener_apply:      X <- conj(G) / (|G|^2 + inv_snr) * X      (adjoint: G / (...) * X)
 *   spectral_multiply: X <- G * X (convolution) or conj(G) * X (correlation = adjoint)
 *
 * with G = h_scale * H: the normalisation (unit DC gain) is applied on the fly, so a
 * spectrum is never rescaled in a pass of its own (270 MB at 128 x 128 x 512).
 *
 * 1/SNR is added to the real denominator |H|^2 only (the published CDT code also adds it
 * to the imaginary part, which biases the phase).
 */
#include "common.h"
#include "complex.h"

__kernel void wiener_apply(__global const cplx_t *restrict H, __global cplx_t *restrict X,
                           const real_t h_scale, const real_t inv_snr, const int adjoint,
                           const long n)
{
    const long i = get_global_id(0);
    if (i >= n)
        return;
    const cplx_t h = CRMUL(H[i], h_scale);
    const real_t den = CABS2(h) + inv_snr;
    /* den == 0 only where H == 0 and 1/SNR == 0: the inverse filter has no information
     * there, so the output is 0 rather than NaN. */
    const real_t g = den > 0 ? (real_t)1 / den : (real_t)0;
    const cplx_t w = CRMUL(adjoint ? h : CCONJ(h), g);
    X[i] = CMUL(w, X[i]);
}

__kernel void spectral_multiply(__global const cplx_t *restrict H, __global cplx_t *restrict X,
                                const real_t h_scale, const int conjugate, const long n)
{
    const long i = get_global_id(0);
    if (i >= n)
        return;
    const cplx_t h = CRMUL(H[i], h_scale);
    X[i] = CMUL(conjugate ? CCONJ(h) : h, X[i]);
}
