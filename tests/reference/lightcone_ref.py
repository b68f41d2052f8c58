"""Float64 numpy reference of the confocal light-cone accumulation (kernels/lightcone.cl)."""

import numpy as np

C0 = 299_792_458.0


def lightcone_ref(pos, nrm, area, albedo, material, tables, *, points, width, bins,
                  bin_width, start, splat_order=1):
    out = np.zeros((bins, points, points))
    c = (np.arange(points) + 0.5) * width / points - width / 2
    for iy, sy in enumerate(c):
        for ix, sx in enumerate(c):
            d = pos - np.array([sx, sy, 0.0])
            r = np.linalg.norm(d, axis=1)
            cos_relay = d[:, 2] / r
            cos_obj = -(nrm * d).sum(1) / r
            ok = (cos_obj > 0) & (cos_relay > 0)
            if tables is None:
                fr = np.full(len(r), 1 / np.pi)
            else:
                th = np.arccos(np.clip(cos_obj, -1, 1))
                grid = np.linspace(0, np.pi / 2, tables.shape[1])
                fr = np.array([np.interp(t, grid, tables[m]) for t, m in zip(th, material,
                                                                           strict=True)])
            w = albedo * fr * cos_relay**2 * cos_obj**2 / r**4 * area
            b = (2 * r / C0 - start) / bin_width
            for bi, wi, oki in zip(b, w, ok, strict=True):
                if not oki:
                    continue
                if splat_order == 0:
                    k = int(np.floor(bi))
                    if 0 <= k < bins:
                        out[k, iy, ix] += wi
                else:
                    cc = bi - 0.5
                    k = int(np.floor(cc))
                    f = cc - k
                    if 0 <= k < bins:
                        out[k, iy, ix] += wi * (1 - f)
                    if 0 <= k + 1 < bins:
                        out[k + 1, iy, ix] += wi * f
    return out
