"""Hidden-object geometry sampled into surface elements (position, normal, area).

Coordinates: the scan (relay wall / slab exit) plane is z = 0, hidden objects lie at z > 0;
x to the right, y up, as in the reconstructions. Planar shapes are built in their local x-y
plane facing the scan plane (normal -z), then rotated by ``rotate_deg`` = (rx, ry, rz) as
R = Rz(rz) Ry(ry) Rx(rx) about their own origin and translated by ``translate_m``.

Sampling density is elements per square metre: a planar shape is cut into square cells of
side h = density^-1/2 (element at the cell centre, area h^2 inside the shape), a sphere into
a Fibonacci lattice of equal areas, a mesh triangle into barycentric sub-triangles.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from PIL import Image

from clnlos.checks import input_file
from clnlos.errors import InputFileError, ParameterError

# Stroke font: each glyph is a list of polylines in a box of width 0.6 and height 1
# (origin bottom-left). Strokes are drawn with round caps of the requested stroke width.
_ARC_N = 12


def _arc(cx, cy, rx, ry, a0, a1, n=_ARC_N):
    a = np.radians(np.linspace(a0, a1, n))
    return list(zip(cx + rx * np.cos(a), cy + ry * np.sin(a), strict=True))


GLYPHS: dict[str, list[list[tuple[float, float]]]] = {
    "A": [[(0, 0), (0.3, 1), (0.6, 0)], [(0.12, 0.4), (0.48, 0.4)]],
    "B": [[(0, 0), (0, 1), (0.4, 1)] + _arc(0.4, 0.75, 0.2, 0.25, 90, -90) + [(0, 0.5)],
          [(0, 0.5), (0.4, 0.5)] + _arc(0.4, 0.25, 0.2, 0.25, 90, -90) + [(0, 0)]],
    "C": [_arc(0.3, 0.5, 0.3, 0.5, 45, 315)],
    "D": [[(0, 0), (0, 1), (0.25, 1)] + _arc(0.25, 0.5, 0.35, 0.5, 90, -90) + [(0, 0)]],
    "E": [[(0.6, 0), (0, 0), (0, 1), (0.6, 1)], [(0, 0.5), (0.45, 0.5)]],
    "F": [[(0, 0), (0, 1), (0.6, 1)], [(0, 0.5), (0.45, 0.5)]],
    "G": [_arc(0.3, 0.5, 0.3, 0.5, 45, 360) + [(0.6, 0.5), (0.35, 0.5)]],
    "H": [[(0, 0), (0, 1)], [(0.6, 0), (0.6, 1)], [(0, 0.5), (0.6, 0.5)]],
    "I": [[(0.3, 0), (0.3, 1)], [(0.1, 0), (0.5, 0)], [(0.1, 1), (0.5, 1)]],
    "J": [[(0.6, 1), (0.6, 0.3)] + _arc(0.3, 0.3, 0.3, 0.3, 0, -180)],
    "K": [[(0, 0), (0, 1)], [(0.6, 1), (0, 0.4)], [(0.2, 0.6), (0.6, 0)]],
    "L": [[(0, 1), (0, 0), (0.6, 0)]],
    "M": [[(0, 0), (0, 1), (0.3, 0.5), (0.6, 1), (0.6, 0)]],
    "N": [[(0, 0), (0, 1), (0.6, 0), (0.6, 1)]],
    "O": [_arc(0.3, 0.5, 0.3, 0.5, 0, 360, 24)],
    "P": [[(0, 0), (0, 1), (0.35, 1)] + _arc(0.35, 0.75, 0.25, 0.25, 90, -90) + [(0, 0.5)]],
    "Q": [_arc(0.3, 0.5, 0.3, 0.5, 0, 360, 24), [(0.35, 0.25), (0.6, 0)]],
    "R": [[(0, 0), (0, 1), (0.35, 1)] + _arc(0.35, 0.75, 0.25, 0.25, 90, -90) + [(0, 0.5)],
          [(0.25, 0.5), (0.6, 0)]],
    "S": [_arc(0.3, 0.75, 0.28, 0.25, 20, 270) + _arc(0.3, 0.25, 0.28, 0.25, 90, -160)],
    "T": [[(0, 1), (0.6, 1)], [(0.3, 1), (0.3, 0)]],
    "U": [[(0, 1), (0, 0.3)] + _arc(0.3, 0.3, 0.3, 0.3, 180, 360) + [(0.6, 1)]],
    "V": [[(0, 1), (0.3, 0), (0.6, 1)]],
    "W": [[(0, 1), (0.15, 0), (0.3, 0.6), (0.45, 0), (0.6, 1)]],
    "X": [[(0, 0), (0.6, 1)], [(0, 1), (0.6, 0)]],
    "Y": [[(0, 1), (0.3, 0.5), (0.6, 1)], [(0.3, 0.5), (0.3, 0)]],
    "Z": [[(0, 1), (0.6, 1), (0, 0), (0.6, 0)]],
    " ": [],
}
GLYPH_WIDTH = 0.6
GLYPH_GAP = 0.35  # advance between glyph boxes, in letter heights


def _segments(text: str, height: float, stroke: float) -> np.ndarray:
    """Stroke segments (N, 4) of the text centred at the origin, letters of ``height``.

    Glyph coordinates are scaled so the outer edge of the strokes spans ``height``.
    """
    segs = []
    inner = height - stroke
    x0 = 0.0
    for ch in text.upper():
        if ch not in GLYPHS:
            raise ParameterError("objects.text", text,
                                 "letters A-Z and spaces (stroke font of clnlos.forward.geometry)")
        for line in GLYPHS[ch]:
            p = np.asarray(line, float) * inner + [x0, 0.0]
            segs.extend(np.hstack([p[:-1], p[1:]]))
        x0 += (GLYPH_WIDTH + GLYPH_GAP) * inner
    s = np.asarray(segs).reshape(-1, 4)
    width = x0 - GLYPH_GAP * inner
    s[:, [0, 2]] -= width / 2
    s[:, [1, 3]] -= inner / 2
    return s


def glyph_boxes(text: str, height_m: float, stroke_m: float) -> list[tuple[float, float,
                                                                            float, float]]:
    """(x0, x1, y0, y1) of each character's box in the text's local frame (m, centred as
    :func:`letters_mask` draws it): the glyph box of width GLYPH_WIDTH and height 1 in
    letter units, with the strokes' caps."""
    inner = height_m - stroke_m
    n = len(text)
    width = (n * (GLYPH_WIDTH + GLYPH_GAP) - GLYPH_GAP) * inner
    out = []
    for i in range(n):
        x0 = i * (GLYPH_WIDTH + GLYPH_GAP) * inner - width / 2
        out.append((x0 - stroke_m / 2, x0 + GLYPH_WIDTH * inner + stroke_m / 2,
                    -height_m / 2, height_m / 2))
    return out


def _distance_to_segments(pts: np.ndarray, segs: np.ndarray) -> np.ndarray:
    d = np.full(len(pts), np.inf)
    for x1, y1, x2, y2 in segs:
        vx, vy = x2 - x1, y2 - y1
        L2 = vx * vx + vy * vy
        t = np.zeros(len(pts)) if L2 == 0 else np.clip(
            ((pts[:, 0] - x1) * vx + (pts[:, 1] - y1) * vy) / L2, 0, 1)
        d = np.minimum(d, np.hypot(pts[:, 0] - x1 - t * vx, pts[:, 1] - y1 - t * vy))
    return d


def letters_mask(text: str, height_m: float, stroke_m: float, xy: np.ndarray) -> np.ndarray:
    """True where local points xy (N, 2) lie inside the stroked text."""
    if not (0 < stroke_m < height_m):
        raise ParameterError("objects.stroke_m", stroke_m, f"> 0 and < height_m = {height_m}")
    return _distance_to_segments(xy, _segments(text, height_m, stroke_m)) <= stroke_m / 2


def text_extent(text: str, height_m: float, stroke_m: float) -> tuple[float, float]:
    s = _segments(text, height_m, stroke_m)
    return (float(np.abs(s[:, [0, 2]]).max() + stroke_m / 2),
            float(np.abs(s[:, [1, 3]]).max() + stroke_m / 2))


@dataclass
class Elements:
    """Surface elements: positions (N, 3) m, unit normals (N, 3), areas (N,) m^2."""

    pos: np.ndarray
    normal: np.ndarray
    area: np.ndarray

    def __len__(self):
        return len(self.area)

    @staticmethod
    def concat(parts: list[Elements]) -> Elements:
        if not parts:
            return Elements(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))
        return Elements(np.concatenate([p.pos for p in parts]),
                        np.concatenate([p.normal for p in parts]),
                        np.concatenate([p.area for p in parts]))


def rotation_matrix(rotate_deg) -> np.ndarray:
    rx, ry, rz = np.radians(np.asarray(rotate_deg, float))
    cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                              math.cos(rz), math.sin(rz))
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def transform(el: Elements, rotate_deg, translate_m) -> Elements:
    R = rotation_matrix(rotate_deg)
    return Elements(el.pos @ R.T + np.asarray(translate_m, float), el.normal @ R.T, el.area)


def planar_cells(half_w: float, half_h: float, density: float) -> tuple[int, int]:
    """(nx, ny): the cells of side density^-1/2 that cover a planar shape's box."""
    h = 1.0 / math.sqrt(density)
    return max(1, int(math.ceil(2 * half_w / h))), max(1, int(math.ceil(2 * half_h / h)))


def text_extent_bound(text: str, height_m: float, stroke_m: float) -> tuple[float, float]:
    """An upper bound of :func:`text_extent` from the text's length alone (no strokes
    built): every glyph box (GLYPH_WIDTH, 1) and gap, plus the stroke's caps."""
    inner = height_m - stroke_m
    n = max(1, len(text))
    width = (n * GLYPH_WIDTH + (n - 1) * GLYPH_GAP) * inner
    return width / 2 + stroke_m / 2, inner / 2 + stroke_m / 2


def _planar_grid(half_w: float, half_h: float, density: float, inside) -> Elements:
    nx, ny = planar_cells(half_w, half_h, density)
    xs = (np.arange(nx) + 0.5) * (2 * half_w / nx) - half_w
    ys = (np.arange(ny) + 0.5) * (2 * half_h / ny) - half_h
    X, Y = np.meshgrid(xs, ys, indexing="xy")
    xy = np.column_stack([X.ravel(), Y.ravel()])
    keep = inside(xy)
    xy = xy[keep]
    n = len(xy)
    pos = np.column_stack([xy, np.zeros(n)])
    normal = np.tile([0.0, 0.0, -1.0], (n, 1))
    return Elements(pos, normal, np.full(n, (2 * half_w / nx) * (2 * half_h / ny)))


def sample_letters(text: str, height_m: float, stroke_m: float, density: float) -> Elements:
    hw, hh = text_extent(text, height_m, stroke_m)
    return _planar_grid(hw, hh, density,
                        lambda xy: letters_mask(text, height_m, stroke_m, xy))


def sample_rectangle(width_m: float, height_m: float, density: float) -> Elements:
    return _planar_grid(width_m / 2, height_m / 2, density, lambda xy: np.ones(len(xy), bool))


def sample_sphere(radius_m: float, density: float) -> Elements:
    n = max(4, int(round(4 * math.pi * radius_m**2 * density)))
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    phi = i * math.pi * (3 - math.sqrt(5))
    r = np.sqrt(1 - z * z)
    nrm = np.column_stack([r * np.cos(phi), r * np.sin(phi), z])
    return Elements(nrm * radius_m, nrm, np.full(n, 4 * math.pi * radius_m**2 / n))


MASK_FORMATS = (".png", ".npy")


def read_mask(path) -> np.ndarray:
    """A target mask [y, x] (row 0 at the top, as the image shows it) from a PNG (its
    brightness, or its alpha where it has one) or a 2-D .npy: True where the value exceeds
    half the maximum; an InputFileError where it cannot be read or holds no shape."""
    p = input_file(path, "mask ")
    if p.suffix.lower() not in MASK_FORMATS:
        raise InputFileError(f"{p}: a mask is a PNG or a .npy, not {p.suffix or 'no suffix'}")
    try:
        if p.suffix.lower() == ".npy":
            a = np.load(p, allow_pickle=False)
        else:
            with Image.open(p) as im:
                a = np.asarray(im.getchannel("A") if "A" in im.getbands()
                               else im.convert("L"), dtype=np.float64)
    except (OSError, ValueError, SyntaxError) as exc:
        raise InputFileError(f"{p}: unreadable as a mask ({type(exc).__name__}: "
                             f"{' '.join(str(exc).split())})") from None
    a = np.asarray(a, dtype=np.float64)
    if a.ndim != 2 or min(a.shape) < 2 or not np.all(np.isfinite(a)):
        raise InputFileError(f"{p}: a mask must be a 2-D image of finite values, got shape "
                             f"{list(a.shape)}")
    top = float(a.max())
    m = a > top / 2 if top > 0 else np.zeros(a.shape, bool)
    if not m.any() or m.all():
        raise InputFileError(f"{p}: the mask holds no shape (every pixel "
                             f"{'on' if m.all() else 'off'}); the target is its bright part")
    return m


def read_depth_map(path, shape: tuple[int, int]) -> np.ndarray:
    """Per-pixel depth offsets [y, x] (m, along the object's normal; finite) of a mask, from a
    .npy of the mask's shape."""
    p = input_file(path, "depth map ")
    try:
        a = np.asarray(np.load(p, allow_pickle=False), dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{p}: unreadable as a depth map ({exc})") from None
    if a.shape != tuple(shape) or not np.all(np.isfinite(a)):
        raise InputFileError(f"{p}: a depth map of the mask's shape {list(shape)} with finite "
                             f"values (m) expected, got shape {list(a.shape)}")
    return a


def mask_lookup(mask: np.ndarray, width_m: float, height_m: float, xy: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """(row, column) of the mask pixel under each local point xy (N, 2) (m, from the mask's
    centre, y up; row 0 is the top of the image)."""
    ny, nx = mask.shape
    col = np.clip(((xy[:, 0] / width_m + 0.5) * nx).astype(int), 0, nx - 1)
    row = np.clip(((0.5 - xy[:, 1] / height_m) * ny).astype(int), 0, ny - 1)
    return row, col


def sample_mask(mask: np.ndarray, width_m: float, height_m: float, density: float,
                depth: np.ndarray | None = None) -> Elements:
    """A flat shape cut out of a plane of ``width_m`` x ``height_m`` where ``mask`` is True,
    each element moved along the normal by its pixel's ``depth`` offset (m) where given."""
    def inside(xy):
        r, c = mask_lookup(mask, width_m, height_m, xy)
        return mask[r, c]

    el = _planar_grid(width_m / 2, height_m / 2, density, inside)
    if depth is not None and len(el):
        r, c = mask_lookup(mask, width_m, height_m, el.pos[:, :2])
        el.pos[:, 2] = depth[r, c]
    return el


def mask_albedo(values: np.ndarray, width_m: float, height_m: float, el: Elements
                ) -> np.ndarray:
    """Each element's albedo factor: the pixel of ``values`` [y, x] under it (elements of
    :func:`sample_mask` before they are moved into the scene)."""
    r, c = mask_lookup(values, width_m, height_m, el.pos[:, :2])
    return np.asarray(values, np.float64)[r, c]


def read_albedo_map(path, shape: tuple[int, int]) -> np.ndarray:
    """Per-pixel albedo factors [y, x] (finite, >= 0) of a mask, from a .npy of its shape."""
    p = input_file(path, "albedo map ")
    try:
        a = np.asarray(np.load(p, allow_pickle=False), dtype=np.float64)
    except (OSError, ValueError) as exc:
        raise InputFileError(f"{p}: unreadable as an albedo map ({exc})") from None
    if a.shape != tuple(shape) or not np.all(np.isfinite(a)) or np.any(a < 0):
        raise InputFileError(f"{p}: an albedo map of the mask's shape {list(shape)} with "
                             f"finite values >= 0 expected, got shape {list(a.shape)}")
    return a


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V, 3) and triangles (F, 3) of an ASCII OBJ or PLY file (polygons fanned)."""
    p = input_file(path, "mesh ")
    try:
        lines = p.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError:
        raise InputFileError(f"{p}: only ASCII OBJ/PLY meshes are supported") from None
    verts, faces = [], []
    try:
        if p.suffix.lower() == ".obj":
            for ln in lines:
                tok = ln.split()
                if not tok:
                    continue
                if tok[0] == "v":
                    verts.append([float(v) for v in tok[1:4]])
                elif tok[0] == "f":
                    idx = [int(t.split("/")[0]) for t in tok[1:]]
                    idx = [i - 1 if i > 0 else len(verts) + i for i in idx]
                    faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1))
        elif p.suffix.lower() == ".ply":
            if not lines or lines[0].strip() != "ply" or "ascii" not in lines[1]:
                raise InputFileError(f"{p}: only ASCII PLY is supported")
            nv = nf = 0
            k = 0
            for k, ln in enumerate(lines):  # noqa: B007 (k is the header length, used below)
                if ln.startswith("element vertex"):
                    nv = int(ln.split()[2])
                elif ln.startswith("element face"):
                    nf = int(ln.split()[2])
                elif ln.strip() == "end_header":
                    break
            body = lines[k + 1:]
            verts = [[float(v) for v in body[i].split()[:3]] for i in range(nv)]
            for i in range(nv, nv + nf):
                tok = [int(v) for v in body[i].split()]
                idx = tok[1:1 + tok[0]]
                faces.extend([idx[0], idx[j], idx[j + 1]] for j in range(1, len(idx) - 1))
        else:
            raise InputFileError(f"{p}: mesh must be .obj or .ply")
    except (ValueError, IndexError):
        raise InputFileError(f"{p}: malformed mesh file") from None
    V, F = np.asarray(verts, float).reshape(-1, 3), np.asarray(faces, int).reshape(-1, 3)
    if len(F) == 0 or F.min(initial=0) < 0 or F.max(initial=0) >= len(V):
        raise InputFileError(f"{p}: mesh has no valid triangles")
    if not np.all(np.isfinite(V)):
        raise InputFileError(f"{p}: mesh has non-finite vertices")
    return V, F


def sample_mesh(V: np.ndarray, F: np.ndarray, density: float) -> Elements:
    """Each triangle cut into k^2 congruent sub-triangles, k from its area and the density.

    Normals follow the vertex winding (counter-clockwise seen from the front side).
    """
    parts = []
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    cr = np.cross(b - a, c - a)
    area = 0.5 * np.linalg.norm(cr, axis=1)
    ok = area > 0
    a, b, c, cr, area = a[ok], b[ok], c[ok], cr[ok], area[ok]
    nrm = cr / (2 * area[:, None])
    k = np.maximum(1, np.ceil(np.sqrt(area * density))).astype(int)
    for kk in np.unique(k):
        sel = k == kk
        # centroids of the kk^2 sub-triangles in barycentric coordinates
        bary = []
        for i in range(kk):
            for j in range(kk - i):
                bary.append(((i + 1 / 3) / kk, (j + 1 / 3) / kk))
                if i + j < kk - 1:
                    bary.append(((i + 2 / 3) / kk, (j + 2 / 3) / kk))
        u, v = np.asarray(bary).T
        A, B, C = a[sel], b[sel], c[sel]
        pos = (A[:, None] + (B - A)[:, None] * u[None, :, None]
               + (C - A)[:, None] * v[None, :, None]).reshape(-1, 3)
        parts.append(Elements(pos, np.repeat(nrm[sel], len(u), axis=0),
                              np.repeat(area[sel] / kk**2, len(u))))
    return Elements.concat(parts)
