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
 *
 * One work item per scan point: it owns its histogram column, so no atomics are needed.
 * Output layout [t, y, x] with scan index p = y * nx + x.
 */
#include "common.h"

#ifndef SPLAT_ORDER
#define SPLAT_ORDER 1
#endif

#define C0_LIGHT ((real_t)299792458.0)
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

__kernel void lightcone_accumulate(
    __global const real_t *pos,     /* [n_el, 3] element centres (m) */
    __global const real_t *nrm,     /* [n_el, 3] unit normals */
    __global const real_t *area,    /* [n_el] element areas (m^2) */
    __global const real_t *albedo,  /* [n_el] */
    __global const int *material,   /* [n_el] material index into the retro table */
    __global const real_t *retro,   /* [n_materials, N_THETA] f(theta) (1/sr), or unused */
    const int n_el,
    const int nx, const int ny, const real_t scan_x0, const real_t scan_y0, const real_t pitch,
    const int nt, const real_t start_s, const real_t bin_width_s,
    __global real_t *out)           /* [nt, ny, nx], zeroed */
{
    const int ix = get_global_id(0);
    const int iy = get_global_id(1);
    if (ix >= nx || iy >= ny)
        return;
    const int n_scan = nx * ny;
    const size_t col = (size_t)iy * nx + ix;
    const real_t sx = scan_x0 + (real_t)ix * pitch;
    const real_t sy = scan_y0 + (real_t)iy * pitch;
    const real_t to_bin = (real_t)2 / (C0_LIGHT * bin_width_s);
    const real_t b0 = start_s / bin_width_s;

    for (int e = 0; e < n_el; ++e) {
        const real_t dx = pos[3 * e] - sx, dy = pos[3 * e + 1] - sy, dz = pos[3 * e + 2];
        const real_t r2 = dx * dx + dy * dy + dz * dz;
        if (!(r2 > 0))
            continue;
        const real_t r = sqrt(r2);
        const real_t cos_relay = dz / r;
        const real_t cos_obj = -(nrm[3 * e] * dx + nrm[3 * e + 1] * dy + nrm[3 * e + 2] * dz) / r;
        if (cos_obj <= 0 || cos_relay <= 0)
            continue;
#ifdef RETRO_TABLE
        const real_t th = acos(fmin(cos_obj, (real_t)1)) * ((real_t)(N_THETA - 1) / (PI_R / 2));
        const int i0 = min((int)th, N_THETA - 2);
        const real_t ft = th - (real_t)i0;
        __global const real_t *tab = retro + (size_t)material[e] * N_THETA;
        const real_t fr = tab[i0] * ((real_t)1 - ft) + tab[i0 + 1] * ft;
#else
        const real_t fr = INV_PI;
#endif
        const real_t w = albedo[e] * fr * cos_relay * cos_relay * cos_obj * cos_obj
                         / (r2 * r2) * area[e];
        deposit(out, col, n_scan, nt, r * to_bin - b0, w);
    }
}
