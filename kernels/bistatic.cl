/* Bistatic BRDF transport through the slab (the seed's Eq. 8), two stages.
 *
 * Light leaves the slab's hidden face (plane z = 0, normal +z) at r1 = r0 + o_1, reflects
 * off a surface element x (normal n, area dA, albedo a, material m) with the full BRDF
 * f(x; w1, w2) and re-enters the face at r2 = r0 + o_2:
 *
 *   I(r1, r2, t) += a f cos(th_r1) cos(th_x1) cos(th_x2) cos(th_r2) / (|x-r1|^2 |x-r2|^2) dA
 *
 * at t = (|x - r1| + |x - r2|) / c, and tau(r0, t) = sum_{o1, o2} m(o1) (x)_t m(o2) (x)_t I.
 * At r1 = r2 the term is the confocal light-cone term of kernels/lightcone.cl.
 *
 * Face samples (clnlos.bistatic.FaceQuadrature): N_RINGS rings of N_PHI points each, the
 * same offsets for every scan point, ring-major (sample k = ring * N_PHI + angle). Every
 * sample of ring i carries the same slab time series m_i(t), so the pairs of rings (i, j),
 * i <= j ("classes"), share one kernel m_i (x) m_j: stage 1 histograms each class,
 * stage 2 convolves the class histograms with their kernels and sums them.
 *
 * bistatic_pairs: one work-item per (class, scan point, element slice); it owns its
 * histogram row H[slice, p, class, :] (no atomics). For a class (i, j) with i != j it adds
 * both orders (r1 on ring i and r2 on ring j, and the reverse): the geometry and delay are
 * symmetric, the BRDF is looked up both ways (no reciprocity assumed).
 * bistatic_convolve: one work-item per (bin, scan point): sum over slices, classes and lags.
 *
 * BRDF: without LAMBERTIAN, f is read from a stack of isotropic textures
 * tex[m, theta_i, theta_s, delta_phi] (clnlos.brdf.texture's grid: theta on [0, pi/2],
 * delta_phi on [0, pi], trilinear), theta the zenith angles at x, delta_phi the angle
 * between the projections of w1 and w2 on the tangent plane. LAMBERTIAN: f = 1/pi.
 * Time binning: bin k covers [start + k dt, start + (k+1) dt); SPLAT_ORDER as in
 * lightcone.cl. Units: H and tau in 1/(m^2 sr) per bin (the slab kernels are
 * dimensionless probabilities per bin).
 */
#include "common.h"

#ifndef SPLAT_ORDER
#define SPLAT_ORDER 1
#endif
#ifndef N_PHI
#error "N_PHI (points per face ring) comes from clnlos.bistatic"
#endif
#ifndef C0_LIGHT
#error "C0_LIGHT (m/s) comes from clnlos.runtime.physical_defines (clnlos.C0)"
#endif
#define INV_PI ((real_t)0.31830988618379067154)

inline void hist_add(__global real_t *row, const int nt, const real_t b, const real_t w)
{
#if SPLAT_ORDER == 0
    const real_t fb = floor(b);
    if (fb >= 0 && fb < (real_t)nt)
        row[(size_t)fb] += w;
#else
    const real_t c = b - (real_t)0.5;
    const real_t fc = floor(c);
    const real_t f = c - fc;
    if (fc >= 0 && fc < (real_t)nt)
        row[(size_t)fc] += w * ((real_t)1 - f);
    if (fc + 1 >= 0 && fc + 1 < (real_t)nt)
        row[(size_t)(fc + 1)] += w * f;
#endif
}

#ifndef LAMBERTIAN
inline real_t tex_lookup(__global const real_t *restrict tex, const int n_ti, const int n_ts,
                         const int n_dp, const real_t th_i, const real_t th_s, const real_t dp)
{
    const real_t u = clamp(th_i, (real_t)0, PI_R / 2) / (PI_R / 2) * (real_t)(n_ti - 1);
    const real_t v = clamp(th_s, (real_t)0, PI_R / 2) / (PI_R / 2) * (real_t)(n_ts - 1);
    const real_t w = clamp(dp, (real_t)0, PI_R) / PI_R * (real_t)(n_dp - 1);
    const int i0 = min((int)u, n_ti - 2), j0 = min((int)v, n_ts - 2), k0 = min((int)w, n_dp - 2);
    const real_t fu = u - i0, fv = v - j0, fw = w - k0;
    real_t acc = 0;
    for (int di = 0; di < 2; ++di)
        for (int dj = 0; dj < 2; ++dj) {
            __global const real_t *r = tex + ((size_t)(i0 + di) * n_ts + (j0 + dj)) * n_dp + k0;
            const real_t wt = (di ? fu : 1 - fu) * (dj ? fv : 1 - fv);
            acc += wt * (r[0] * (1 - fw) + r[1] * fw);
        }
    return acc;
}
#endif

/* One leg x -> face point (fx, fy, 0): distance, relay cosines over d^2 (0 for a back face
 * or a point behind the face), zenith angle at x and the unit projection of the direction
 * on the tangent plane (zero at normal incidence). */
inline void leg(const real_t px, const real_t py, const real_t pz, const real_t nx_,
                const real_t ny_, const real_t nz_, const real_t fx, const real_t fy,
                real_t *d, real_t *g, real_t *th, real_t *ux, real_t *uy, real_t *uz)
{
    const real_t dx = fx - px, dy = fy - py, dz = -pz;   /* x -> face */
    const real_t r2 = dx * dx + dy * dy + dz * dz;
    const real_t r = sqrt(r2);
    *d = r;
    const real_t cos_relay = pz / r;
    const real_t cos_x = (nx_ * dx + ny_ * dy + nz_ * dz) / r;
    *g = (cos_relay > 0 && cos_x > 0 && r2 > 0) ? cos_relay * cos_x / r2 : (real_t)0;
    *th = acos(fmin(fmax(cos_x, (real_t)0), (real_t)1));
    real_t tx = dx / r - cos_x * nx_, ty = dy / r - cos_x * ny_, tz = dz / r - cos_x * nz_;
    const real_t tn = sqrt(tx * tx + ty * ty + tz * tz);
    const real_t inv = tn > (real_t)1e-12 ? (real_t)1 / tn : (real_t)0;
    *ux = tx * inv;
    *uy = ty * inv;
    *uz = tz * inv;
}

__kernel void bistatic_pairs(
    __global const real_t *restrict pos,      /* [n_el, 3] element centres (m) */
    __global const real_t *restrict nrm,      /* [n_el, 3] unit normals */
    __global const real_t *restrict area,     /* [n_el] (m^2) */
    __global const real_t *restrict albedo,   /* [n_el] */
    __global const int *restrict material,    /* [n_el] texture index */
    __global const real_t *restrict tex,      /* [n_mat, n_ti, n_ts, n_dp] (1/sr) */
    const int n_ti, const int n_ts, const int n_dp,
    __global const real_t *restrict face,     /* [N_RINGS * N_PHI, 2] offsets (m) */
    __global const int *restrict classes,     /* [n_cls, 2] ring pairs i <= j */
    const int n_cls, const int n_el, const int n_slices,
    const int nx, const real_t scan_x0, const real_t scan_y0, const real_t pitch,
    const int p_first, const int n_p,
    const int nt, const real_t start_s, const real_t bin_width_s,
    __global real_t *restrict hist)           /* [n_slices, n_p, n_cls, nt], zeroed */
{
    const size_t gid = get_global_id(0);
    const size_t c = gid % (size_t)n_cls;
    const size_t rest = gid / (size_t)n_cls;
    const size_t p = rest % (size_t)n_p;
    const size_t s = rest / (size_t)n_p;
    if (s >= (size_t)n_slices)
        return;
    const size_t col = (size_t)p_first + p;
    const real_t sx = scan_x0 + (real_t)(col % (size_t)nx) * pitch;
    const real_t sy = scan_y0 + (real_t)(col / (size_t)nx) * pitch;
    const int ri = classes[2 * c], rj = classes[2 * c + 1];
    const real_t to_bin = (real_t)1 / ((real_t)C0_LIGHT * bin_width_s);
    const real_t b0 = start_s / bin_width_s;
    __global real_t *row = hist + ((s * (size_t)n_p + p) * (size_t)n_cls + c) * (size_t)nt;
    const size_t per = ((size_t)n_el + (size_t)n_slices - 1) / (size_t)n_slices;
    const size_t e0 = s * per;
    const size_t e1 = min((size_t)n_el, e0 + per);

    real_t dA[N_PHI], gA[N_PHI], tA[N_PHI], xA[N_PHI], yA[N_PHI], zA[N_PHI];
    real_t dB[N_PHI], gB[N_PHI], tB[N_PHI], xB[N_PHI], yB[N_PHI], zB[N_PHI];
    for (size_t e = e0; e < e1; ++e) {
        const real_t px = pos[3 * e], py = pos[3 * e + 1], pz = pos[3 * e + 2];
        const real_t nx_ = nrm[3 * e], ny_ = nrm[3 * e + 1], nz_ = nrm[3 * e + 2];
        const real_t aw = albedo[e] * area[e];
        if (!(pz > 0) || aw == 0)
            continue;
        bool any = false;
        for (int a = 0; a < N_PHI; ++a) {
            const size_t ka = (size_t)ri * N_PHI + a, kb = (size_t)rj * N_PHI + a;
            leg(px, py, pz, nx_, ny_, nz_, sx + face[2 * ka], sy + face[2 * ka + 1],
                &dA[a], &gA[a], &tA[a], &xA[a], &yA[a], &zA[a]);
            leg(px, py, pz, nx_, ny_, nz_, sx + face[2 * kb], sy + face[2 * kb + 1],
                &dB[a], &gB[a], &tB[a], &xB[a], &yB[a], &zB[a]);
            any = any || gA[a] > 0 || gB[a] > 0;
        }
        if (!any)
            continue;
#ifndef LAMBERTIAN
        __global const real_t *t_m = tex + (size_t)material[e] * n_ti * n_ts * n_dp;
#endif
        for (int a = 0; a < N_PHI; ++a) {
            if (gA[a] == 0)
                continue;
            for (int b = 0; b < N_PHI; ++b) {
                if (gB[b] == 0)
                    continue;
#ifdef LAMBERTIAN
                const real_t f = (ri == rj ? (real_t)1 : (real_t)2) * INV_PI;
#else
                const real_t cd = xA[a] * xB[b] + yA[a] * yB[b] + zA[a] * zB[b];
                const real_t dp = acos(clamp(cd, (real_t)-1, (real_t)1));
                real_t f = tex_lookup(t_m, n_ti, n_ts, n_dp, tA[a], tB[b], dp);
                if (ri != rj)
                    f += tex_lookup(t_m, n_ti, n_ts, n_dp, tB[b], tA[a], dp);
#endif
                const real_t w = aw * gA[a] * gB[b] * f;
                if (w != 0)
                    hist_add(row, nt, (dA[a] + dB[b]) * to_bin - b0, w);
            }
        }
    }
}

__kernel void bistatic_convolve(
    __global const real_t *restrict hist,     /* [n_slices, n_p, n_cls, nt] */
    __global const real_t *restrict kern,     /* [n_cls, n_lag] slab kernels m_i (x) m_j */
    const int n_cls, const int n_lag, const int n_slices, const int p_first, const int n_p,
    const int n_scan, const int nt,
    __global real_t *restrict out)            /* [nt, n_scan] */
{
    const size_t k = get_global_id(0);
    const size_t p = get_global_id(1);
    if (k >= (size_t)nt || p >= (size_t)n_p)
        return;
    const size_t l_end = min((size_t)n_lag, k + 1);
    real_t acc = 0;
    for (size_t s = 0; s < (size_t)n_slices; ++s)
        for (size_t c = 0; c < (size_t)n_cls; ++c) {
            __global const real_t *h = hist + ((s * (size_t)n_p + p) * (size_t)n_cls + c)
                                               * (size_t)nt;
            __global const real_t *kc = kern + c * (size_t)n_lag;
            for (size_t l = 0; l < l_end; ++l)
                acc += kc[l] * h[k - l];
        }
    out[k * (size_t)n_scan + (size_t)p_first + p] = acc;
}
