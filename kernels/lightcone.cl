/* BRDF-weighted confocal light-cone accumulation (transient rendering of surface elements).
 *
 * For each scan point r = (sx, sy, 0) on the relay / slab exit plane (normal +z) and each
 * surface element x with normal n, area dA, albedo a and material m:
 *
 *   I(t, r) += a f_m(theta) cos^2(theta_relay) cos^2(theta_obj) / |x - r|^4 dA
 *
 * at t = 2 |x - r| / c (round trip), cos(theta_relay) = (x - r).z / |x - r|,
 * cos(theta_obj) = n . (r - x) / |x - r| = cos(theta), the confocal retro-reflection angle
 * (incoming = outgoing direction). Back faces (cos_obj <= 0) and points behind the relay
 * (cos_relay <= 0) are skipped. Units: I in 1/(m^2 sr) per bin, summed over the bin.
 *
 * Time binning: bin k covers [start + k dt, start + (k+1) dt). SPLAT_ORDER 0 deposits into
 * that bin; SPLAT_ORDER 1 splits linearly between the two bins whose centres bracket t
 * (sub-bin accuracy, no aliasing of the hyperbolae).
 *
 * BRDF: without RETRO_TABLE, f = 1/pi (Lambertian; albedo separate). With RETRO_TABLE,
 * f_m(theta) is interpolated linearly in a table of N_THETA samples per material over
 * theta in [0, pi/2] (the confocal slice f(w, w) of any BRDF model or measurement).
 * With RETRO_CONE as well, a retroreflector's cone averaged over the scanned spot is added
 * (clnlos.physics.retroreflector, Eq. 3):
 *
 *   f_eff = f_m(theta) + f0_m(theta) S(c_m / r^2),   S(x) = (1 - exp(-x)) / x,
 *
 * f0_m the cone's peak slice (a second table, zero for other materials) and c_m = a^2 /
 * (2 sigma^2) the material's spot constant (m^2: a the spot's radius, sigma the cone's rms
 * angle): 1 / r^4 where the cone is wider than the spot (S = 1), 1 / r^2 where the spot holds
 * all of it (S = c_m^-1 r^2).
 *
 * lightcone_accumulate: one work item per scan point; it owns its histogram column, so no
 * atomics are needed (right for CPUs). lightcone_accumulate_group (built with
 * -DGROUP_VARIANT): one work-group per scan point with a local-memory histogram (GPUs).
 * Output layout [t, y, x] with scan index p = y * nx + x.
 */
#include "common.h"
#if defined(USE_FP64) && defined(GROUP_VARIANT)
#pragma OPENCL EXTENSION cl_khr_int64_base_atomics : enable
#endif

#ifndef SPLAT_ORDER
#define SPLAT_ORDER 1
#endif

#ifndef C0_LIGHT
#error "C0_LIGHT (m/s) comes from clnlos.runtime.physical_defines (clnlos.C0)"
#endif
#define INV_PI ((real_t)0.31830988618379067154)

inline void deposit(__global real_t *out, const size_t col, const int n_scan, const int nt,
                    const real_t b, const real_t w)
{
#if SPLAT_ORDER == 0
    const real_t fb = floor(b);
    if (fb >= 0 && fb < (real_t)nt)
        out[(size_t)fb * n_scan + col] += w;
#else
    const real_t c = b - (real_t)0.5; /* position relative to bin centres */
    const real_t fc = floor(c);
    const real_t f = c - fc;
    if (fc >= 0 && fc < (real_t)nt)
        out[(size_t)fc * n_scan + col] += w * ((real_t)1 - f);
    if (fc + 1 >= 0 && fc + 1 < (real_t)nt)
        out[(size_t)(fc + 1) * n_scan + col] += w * f;
#endif
}

/* The contribution of element e to scan point (sx, sy): returns its weight (0 when the
 * element is a back face, behind the relay or at the scan point) and its fractional bin. */
inline real_t element_term(__global const real_t *restrict pos, __global const real_t *restrict nrm,
                           __global const real_t *restrict area,
                           __global const real_t *restrict albedo,
                           __global const int *restrict material,
                           __global const real_t *restrict retro,
                           __global const real_t *restrict cone,
                           __global const real_t *restrict spot, const size_t e,
                           const real_t sx, const real_t sy, const real_t to_bin,
                           const real_t b0, real_t *bin)
{
    const real_t dx = pos[3 * e] - sx, dy = pos[3 * e + 1] - sy, dz = pos[3 * e + 2];
    const real_t r2 = dx * dx + dy * dy + dz * dz;
    if (!(r2 > 0))
        return 0;
    const real_t r = sqrt(r2);
    const real_t cos_relay = dz / r;
    const real_t cos_obj = -(nrm[3 * e] * dx + nrm[3 * e + 1] * dy + nrm[3 * e + 2] * dz) / r;
    if (cos_obj <= 0 || cos_relay <= 0)
        return 0;
#ifdef RETRO_TABLE
    const real_t th = acos(fmin(cos_obj, (real_t)1)) * ((real_t)(N_THETA - 1) / (PI_R / 2));
    const int i0 = min((int)th, N_THETA - 2);
    const real_t ft = th - (real_t)i0;
    __global const real_t *tab = retro + (size_t)material[e] * N_THETA;
    real_t fr = tab[i0] * ((real_t)1 - ft) + tab[i0 + 1] * ft;
#ifdef RETRO_CONE
    const real_t c = spot[material[e]];
    if (c > 0) {
        __global const real_t *cn = cone + (size_t)material[e] * N_THETA;
        const real_t x = c / r2;
        const real_t s = x < (real_t)1e-4 ? (real_t)1 - (real_t)0.5 * x
                                          : -expm1(-x) / x;
        fr += (cn[i0] * ((real_t)1 - ft) + cn[i0 + 1] * ft) * s;
    }
#endif
#else
    const real_t fr = INV_PI;
#endif
    *bin = r * to_bin - b0;
    return albedo[e] * fr * cos_relay * cos_relay * cos_obj * cos_obj / (r2 * r2) * area[e];
}

__kernel void lightcone_accumulate(
    __global const real_t *restrict pos,     /* [n_el, 3] element centres (m) */
    __global const real_t *restrict nrm,     /* [n_el, 3] unit normals */
    __global const real_t *restrict area,    /* [n_el] element areas (m^2) */
    __global const real_t *restrict albedo,  /* [n_el] */
    __global const int *restrict material,   /* [n_el] material index into the retro table */
    __global const real_t *restrict retro,   /* [n_materials, N_THETA] f(theta) (1/sr) */
    __global const real_t *restrict cone,    /* [n_materials, N_THETA] f0(theta) (1/sr) */
    __global const real_t *restrict spot,    /* [n_materials] spot constants c (m^2) */
    const int n_el,
    const int nx, const int ny, const real_t scan_x0, const real_t scan_y0, const real_t pitch,
    const int nt, const real_t start_s, const real_t bin_width_s,
    __global real_t *restrict out)           /* [nt, ny, nx], zeroed */
{
    const size_t ix = get_global_id(0);
    const size_t iy = get_global_id(1);
    if (ix >= (size_t)nx || iy >= (size_t)ny)
        return;
    const int n_scan = nx * ny;
    const size_t col = iy * (size_t)nx + ix;
    const real_t sx = scan_x0 + (real_t)ix * pitch;
    const real_t sy = scan_y0 + (real_t)iy * pitch;
    const real_t to_bin = (real_t)2 / ((real_t)C0_LIGHT * bin_width_s);
    const real_t b0 = start_s / bin_width_s;

    for (size_t e = 0; e < (size_t)n_el; ++e) {
        real_t b;
        const real_t w = element_term(pos, nrm, area, albedo, material, retro, cone, spot, e, sx, sy,
                                      to_bin, b0, &b);
        if (w != 0)
            deposit(out, col, n_scan, nt, b, w);
    }
}

#ifdef GROUP_VARIANT
/* GPU-shaped variant: one work-group per scan point. The group's work-items stride over the
 * elements and accumulate into a histogram of nt bins in local memory (float adds by
 * compare-and-swap, 64-bit for double, which needs cl_khr_int64_base_atomics), then write
 * the column out. Same sums as lightcone_accumulate up to the order of the additions. */
inline void local_add(volatile __local real_t *p, const real_t v)
{
#ifdef USE_FP64
    union { double f; ulong i; } old_v, new_v;
    do {
        old_v.f = *p;
        new_v.f = old_v.f + v;
    } while (atom_cmpxchg((volatile __local ulong *)p, old_v.i, new_v.i) != old_v.i);
#else
    union { float f; uint i; } old_v, new_v;
    do {
        old_v.f = *p;
        new_v.f = old_v.f + v;
    } while (atomic_cmpxchg((volatile __local uint *)p, old_v.i, new_v.i) != old_v.i);
#endif
}

inline void deposit_local(volatile __local real_t *hist, const int nt, const real_t b,
                          const real_t w)
{
#if SPLAT_ORDER == 0
    const real_t fb = floor(b);
    if (fb >= 0 && fb < (real_t)nt)
        local_add(hist + (size_t)fb, w);
#else
    const real_t c = b - (real_t)0.5;
    const real_t fc = floor(c);
    const real_t f = c - fc;
    if (fc >= 0 && fc < (real_t)nt)
        local_add(hist + (size_t)fc, w * ((real_t)1 - f));
    if (fc + 1 >= 0 && fc + 1 < (real_t)nt)
        local_add(hist + (size_t)(fc + 1), w * f);
#endif
}

__kernel void lightcone_accumulate_group(
    __global const real_t *restrict pos, __global const real_t *restrict nrm,
    __global const real_t *restrict area, __global const real_t *restrict albedo,
    __global const int *restrict material, __global const real_t *restrict retro,
    __global const real_t *restrict cone, __global const real_t *restrict spot,
    const int n_el,
    const int nx, const int ny, const real_t scan_x0, const real_t scan_y0, const real_t pitch,
    const int nt, const real_t start_s, const real_t bin_width_s,
    __global real_t *restrict out,           /* [nt, ny, nx] */
    volatile __local real_t *hist)           /* [nt] */
{
    const size_t col = get_group_id(0);      /* scan point y * nx + x */
    const size_t lid = get_local_id(0), lsz = get_local_size(0);
    const size_t n_scan = (size_t)nx * (size_t)ny;
    if (col >= n_scan)
        return;                              /* whole groups only: no barrier is skipped */
    for (size_t k = lid; k < (size_t)nt; k += lsz)
        hist[k] = 0;
    barrier(CLK_LOCAL_MEM_FENCE);
    const real_t sx = scan_x0 + (real_t)(col % (size_t)nx) * pitch;
    const real_t sy = scan_y0 + (real_t)(col / (size_t)nx) * pitch;
    const real_t to_bin = (real_t)2 / ((real_t)C0_LIGHT * bin_width_s);
    const real_t b0 = start_s / bin_width_s;
    for (size_t e = lid; e < (size_t)n_el; e += lsz) {
        real_t b;
        const real_t w = element_term(pos, nrm, area, albedo, material, retro, cone, spot, e, sx, sy,
                                      to_bin, b0, &b);
        if (w != 0)
            deposit_local(hist, nt, b, w);
    }
    barrier(CLK_LOCAL_MEM_FENCE);
    for (size_t k = lid; k < (size_t)nt; k += lsz)
        out[k * n_scan + col] = hist[k];
}
#endif /* GROUP_VARIANT */
