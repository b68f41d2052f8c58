/* Element-wise spectral operations on complex half spectra (pyopencl-complex.h), launched on
 * the spectrum's grid (kx, ky, w) = (gid 0, 1, 2) of shape (n0, n1, n2h):
 *
 *   wiener_apply:      X <- conj(G) / (|G|^2 + inv_snr) * X      (adjoint: G / (...) * X)
 *   spectral_multiply: X <- G * X (convolution) or conj(G) * X (correlation = adjoint)
 *   spectral_multiply_into: Y <- G * X (or conj(G) * X), accumulated into Y when
 *                      accumulate = 1 (Y += ...): sums of convolutions share one inverse FFT
 *   scale_rows:        Y[w] <- s[w] X[w] (or Y[w] += s[w] X[w]) for the rows w < n0, and
 *                      Y[w] <- 0 for n0 <= w < n_out: a real weight per row of a spectrum
 *                      transformed along y and x only (a depth weight commutes with the
 *                      lateral transform), into a grid zero-padded along w
 *
 * with G = h_scale * H: the normalisation (unit DC gain) is applied on the fly, so a
 * spectrum is never rescaled in a pass of its own (270 MB at 128 x 128 x 512).
 *
 * H is stored whole (folded = 0) or folded (folded = 1): for a PSF that is real and even in
 * y and x (the slab's, the light cone's), H(w, ky, kx) = H(w, -ky, kx) and H(-w, ky, kx) = conj(H(w, ky, kx)), so
 * only w <= n0 / 2 and ky <= n1 / 2 are stored, (n0 / 2 + 1, n1 / 2 + 1, n2h): a quarter.
 *
 * 1/SNR is added to the real denominator |H|^2 only (the published CDT code also adds it
 * to the imaginary part, which biases the phase).
 */
#include "common.h"
#include "complex.h"

/* h_scale * H at (w, ky, kx) of the (n0, n1, n2h) spectrum, from H stored whole or folded */
inline cplx_t spectrum_at(__global const cplx_t *restrict H, const size_t w, const size_t ky,
                          const size_t kx, const size_t n0, const size_t n1, const size_t n2h,
                          const int folded, const real_t h_scale)
{
    if (!folded)
        return CRMUL(H[(w * n1 + ky) * n2h + kx], h_scale);
    const int upper = w > n0 / 2;
    const size_t wf = upper ? n0 - w : w;
    const size_t kyf = ky > n1 / 2 ? n1 - ky : ky;
    cplx_t h = CRMUL(H[(wf * (n1 / 2 + 1) + kyf) * n2h + kx], h_scale);
    h.imag = upper ? -h.imag : h.imag;
    return h;
}

__kernel void wiener_apply(__global const cplx_t *restrict H, __global cplx_t *restrict X,
                           const real_t h_scale, const real_t inv_snr, const int adjoint,
                           const int folded, const int n0, const int n1, const int n2h)
{
    const size_t kx = get_global_id(0), ky = get_global_id(1), w = get_global_id(2);
    if (kx >= (size_t)n2h || ky >= (size_t)n1 || w >= (size_t)n0)
        return;
    const size_t i = (w * n1 + ky) * n2h + kx;
    const cplx_t h = spectrum_at(H, w, ky, kx, n0, n1, n2h, folded, h_scale);
    const real_t den = CABS2(h) + inv_snr;
    /* den == 0 only where H == 0 and 1/SNR == 0: the inverse filter has no information
     * there, so the output is 0 rather than NaN. */
    const real_t g = den > 0 ? (real_t)1 / den : (real_t)0;
    const cplx_t f = CRMUL(adjoint ? h : CCONJ(h), g);
    X[i] = CMUL(f, X[i]);
}

__kernel void spectral_multiply(__global const cplx_t *restrict H, __global cplx_t *restrict X,
                                const real_t h_scale, const int conjugate, const int folded,
                                const int n0, const int n1, const int n2h)
{
    const size_t kx = get_global_id(0), ky = get_global_id(1), w = get_global_id(2);
    if (kx >= (size_t)n2h || ky >= (size_t)n1 || w >= (size_t)n0)
        return;
    const size_t i = (w * n1 + ky) * n2h + kx;
    const cplx_t h = spectrum_at(H, w, ky, kx, n0, n1, n2h, folded, h_scale);
    X[i] = CMUL(conjugate ? CCONJ(h) : h, X[i]);
}

__kernel void spectral_multiply_into(__global const cplx_t *restrict H,
                                     __global const cplx_t *restrict X,
                                     __global cplx_t *restrict Y, const real_t h_scale,
                                     const int conjugate, const int accumulate,
                                     const int folded, const int n0, const int n1,
                                     const int n2h)
{
    const size_t kx = get_global_id(0), ky = get_global_id(1), w = get_global_id(2);
    if (kx >= (size_t)n2h || ky >= (size_t)n1 || w >= (size_t)n0)
        return;
    const size_t i = (w * n1 + ky) * n2h + kx;
    const cplx_t h = spectrum_at(H, w, ky, kx, n0, n1, n2h, folded, h_scale);
    const cplx_t p = CMUL(conjugate ? CCONJ(h) : h, X[i]);
    Y[i] = accumulate ? CADD(Y[i], p) : p;
}

__kernel void scale_rows(__global const cplx_t *restrict X, __global cplx_t *restrict Y,
                         __global const real_t *restrict s, const int accumulate,
                         const int n0, const int n_out, const int n1, const int n2h)
{
    const size_t kx = get_global_id(0), ky = get_global_id(1), w = get_global_id(2);
    if (kx >= (size_t)n2h || ky >= (size_t)n1 || w >= (size_t)n_out)
        return;
    const size_t i = (w * n1 + ky) * n2h + kx;
    if (w >= (size_t)n0) {  /* the zero padding past the weighted rows (never accumulated) */
        Y[i] = (cplx_t){(real_t)0, (real_t)0};
        return;
    }
    const cplx_t p = CRMUL(X[i], s[w]);
    Y[i] = accumulate ? CADD(Y[i], p) : p;
}
