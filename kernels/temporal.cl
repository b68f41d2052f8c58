/* Temporal convolution of transients [t, p] (p = flattened scan index) with a short kernel:
 *
 *   out[t, p] = sum_{k=-K..K} taps[k + K] * in[t - k, p]      (zero outside 0..nt-1)
 *
 * used for the laser pulse (Gaussian taps, bin-integrated, summing to 1).
 */
#include "common.h"

__kernel void time_convolve(__global const real_t *restrict in, __global real_t *restrict out,
                            __global const real_t *restrict taps, const int K, const int nt,
                            const int n_scan)
{
    const int p = get_global_id(0);
    const int t = get_global_id(1);
    if (p >= n_scan || t >= nt)
        return;
    real_t acc = 0;
    for (int k = -K; k <= K; ++k) {
        const int s = t - k;
        if (s >= 0 && s < nt)
            acc += taps[k + K] * in[(size_t)s * n_scan + p];
    }
    out[(size_t)t * n_scan + p] = acc;
}
