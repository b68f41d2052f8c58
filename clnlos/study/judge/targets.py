"""Hidden targets of the legibility judge's twins beyond letters and charts (pure numpy): the
kinds of thing real NLOS targets are.

Every generator draws one target of a kind (:data:`TARGET_KINDS`) from a numpy Generator and
returns a :class:`Target`: the scene's ``[[objects]]`` tables (centred on the origin of the
target plane, the hidden side at ``translate_m[2]``), the files they name (masks as .npy
arrays, meshes as OBJ text; written beside the scene by the caller) and which objects are
the target's *content* (what its true front view is: :func:`clnlos.study.judge.twins.
true_footprint`). Sizes are in units of the target's side s (m), the largest extent of its
front view:

* ``glyph`` / ``chart``: the patterns of :mod:`clnlos.study.score.patterns` (their labels
  use the template rule, so they are drawn by the twins' plan, not here);
* ``sign``: a plate of aspect SIGN_ASPECT with a word (2-5 capitals of the stroke font) and
  or an arrow, *cut out* of the plate (one mask: the plate's material is the content) or
  *printed* on it (letters and arrow of albedo 1 on a plate of albedo SIGN_PLATE_ALBEDO:
  the letters and the arrow are the content, the plate a faint background);
* ``figure``: the silhouette of a person (:func:`person_mask`: head, torso, two arms and two
  legs in a random pose; a mannequin on a stand);
* ``object``: the silhouette of an object (:data:`OBJECTS`: a chair, a table, a lamp, a vase,
  a mug, a tree, a four-legged animal, a dragon, a bust on a plinth, a bicycle, a ladder);
* ``shape3d``: extended 3-D shapes: one to three spheres, a box or a cylinder (triangle
  meshes, turned), a figure or object in relief (its mask with a depth map bulging
  ``RELIEF_DEPTH`` s towards the wall, d = -RELIEF_DEPTH s sqrt(e / max e), e the
  distance to the silhouette's edge), two plates meeting at an angle (an open book);
* ``multi``: two or three of the above (a capital, a figure, an object, a sphere, a small
  sign) side by side at depths MULTI_DEPTH_STEP_M apart and more.

A silhouette mask is a boolean image [MASK_PIXELS, MASK_PIXELS] of its square of side s
(row 0 at the top, as :func:`clnlos.forward.geometry.read_mask` reads it), drawn as a union
of primitives in the square's coordinates u, v in [-1/2, 1/2] (v up): ellipses, capsules
(segments with round ends) and polygons. Signs, figures and objects may be turned by up to
MAX_TILT_DEG about x and y (a share TILTED of them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from clnlos.forward.geometry import letters_mask, text_extent

TARGET_KINDS = ("glyph", "chart", "sign", "figure", "object", "shape3d", "multi")
MASK_PIXELS = 128
SIGN_ASPECT = (1.4, 2.6)       # a sign's width over its height
SIGN_PLATE_ALBEDO = 0.2        # a printed sign's plate under letters of albedo 1
SIGN_WORDS = ("EXIT", "STOP", "OPEN", "EXIT", "NO", "UP", "GO", "WAY", "LAB", "HELP", "KEEP",
              "OUT", "FIRE", "ZONE", "MAX", "ON", "PARK", "BUS")
RELIEF_DEPTH = 0.25            # a relief's bulge towards the wall, in units of its side
MULTI_DEPTH_STEP_M = 0.15      # the least depth between the parts of a multi target ...
MULTI_DEPTH_SPAN_M = 0.5       # ... and the most between its nearest and farthest part
MAX_TILT_DEG = 35.0
TILTED = 0.35                  # the share of signs, figures and objects turned
OBJECTS = ("chair", "table", "lamp", "vase", "mug", "tree", "animal", "dragon", "bust",
           "bicycle", "ladder")
POSES = ("standing", "walking", "arms_up", "waving", "mannequin")


@dataclass
class Target:
    """One twin target: ``objects`` (scene tables, centred on the target plane's origin
    at depth 0: the caller adds the depth), ``files`` (name -> .npy array or OBJ text, named
    by the tables' ``path`` / ``depth_path``), ``content`` (per object: part of the true
    front view), ``name`` (what it is, e.g. "sign:EXIT cut"), ``side_m`` (its side s)."""

    kind: str
    name: str
    side_m: float
    objects: list[dict]
    content: list[bool]
    files: dict = field(default_factory=dict)


# ------------------------------------------------------------ primitives (u, v in [-1/2, 1/2])
def plane_grid(n: int = MASK_PIXELS) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates (u, v) [n, n] of a square of side 1 centred on 0, row 0 at
    the top (v = +1/2 - 1/(2n)), column 0 at the left."""
    c = (np.arange(n) + 0.5) / n - 0.5
    return np.meshgrid(c, c[::-1])


def ellipse(u, v, cx, cy, rx, ry, angle_deg: float = 0.0) -> np.ndarray:
    """((u' / rx)^2 + (v' / ry)^2 <= 1), (u', v') the point about (cx, cy) turned by -angle."""
    a = math.radians(angle_deg)
    du, dv = u - cx, v - cy
    x = du * math.cos(a) + dv * math.sin(a)
    y = -du * math.sin(a) + dv * math.cos(a)
    return (x / rx) ** 2 + (y / ry) ** 2 <= 1.0


def capsule(u, v, p, q, r) -> np.ndarray:
    """Points within r of the segment from p to q (a stroke with round ends)."""
    (x1, y1), (x2, y2) = p, q
    vx, vy = x2 - x1, y2 - y1
    L2 = vx * vx + vy * vy
    t = np.zeros_like(u) if L2 == 0 else np.clip(((u - x1) * vx + (v - y1) * vy) / L2, 0, 1)
    return np.hypot(u - x1 - t * vx, v - y1 - t * vy) <= r


def polygon(u, v, pts) -> np.ndarray:
    """Points inside the polygon ``pts`` [(u, v), ...] (even-odd ray casting)."""
    inside = np.zeros(u.shape, bool)
    p = np.asarray(pts, float)
    for (x1, y1), (x2, y2) in zip(p, np.roll(p, -1, axis=0), strict=True):
        crosses = (y1 > v) != (y2 > v)
        with np.errstate(divide="ignore", invalid="ignore"):
            xc = x1 + (v - y1) * (x2 - x1) / (y2 - y1)
        inside ^= crosses & (u < xc)
    return inside


def rect(u, v, cx, cy, w, h) -> np.ndarray:
    return (np.abs(u - cx) <= w / 2) & (np.abs(v - cy) <= h / 2)


def limb(u, v, start, angles_deg, lengths, r) -> tuple[np.ndarray, tuple[float, float]]:
    """A chain of capsules from ``start``, each segment at an absolute angle (deg, 0 =
    straight down, positive towards +u): (mask, the chain's end)."""
    m = np.zeros(u.shape, bool)
    p = start
    for a, L in zip(angles_deg, lengths, strict=True):
        q = (p[0] + L * math.sin(math.radians(a)), p[1] - L * math.cos(math.radians(a)))
        m |= capsule(u, v, p, q, r)
        p = q
    return m, p


# ------------------------------------------------------------------ silhouettes
def person_mask(rng: np.random.Generator, pose: str | None = None,
                n: int = MASK_PIXELS) -> tuple[np.ndarray, str]:
    """A person's silhouette (height 0.96 of the square: feet at v = -0.48), its pose one of
    POSES (random where None): (mask, pose)."""
    pose = pose or str(rng.choice(POSES))
    u, v = plane_grid(n)
    s = float(rng.uniform(0.9, 1.1))            # build: shoulders and hips
    m = ellipse(u, v, 0, 0.405, 0.055, 0.07)     # head
    m |= capsule(u, v, (0, 0.33), (0, 0.30), 0.03)                      # neck
    m |= polygon(u, v, [(-0.11 * s, 0.3), (0.11 * s, 0.3), (0.08 * s, 0.02),
                        (-0.08 * s, 0.02)])                             # torso
    arm = {"standing": ((8, 5), (-8, -5)), "walking": ((-20, -35), (20, 5)),
           "arms_up": ((150, 170), (-150, -170)), "waving": ((120, 160), (-10, -5)),
           "mannequin": ((12, 12), (-12, -12))}[pose]
    leg = {"standing": ((4, 2), (-4, -2)), "walking": ((22, 0), (-18, -35)),
           "arms_up": ((10, 5), (-10, -5)), "waving": ((6, 3), (-6, -3)),
           "mannequin": ((3, 3), (-3, -3))}[pose]
    jitter = rng.uniform(-8, 8, 8)
    for k, (side, a) in enumerate(((-1, arm[1]), (1, arm[0]))):
        am, _ = limb(u, v, (side * 0.105 * s, 0.28),
                     [a[0] + jitter[2 * k], a[1] + jitter[2 * k + 1]], [0.16, 0.15], 0.028)
        m |= am
    for k, (side, a) in enumerate(((-1, leg[1]), (1, leg[0]))):
        lm, _ = limb(u, v, (side * 0.05 * s, 0.03), [a[0] + jitter[4 + 2 * k] / 2,
                                                     a[1] + jitter[5 + 2 * k] / 2],
                     [0.25, 0.25], 0.04)
        m |= lm
    if pose == "mannequin":  # on a stand
        m |= rect(u, v, 0, -0.47, 0.22, 0.03)
    return m, pose


def object_mask(name: str, rng: np.random.Generator, n: int = MASK_PIXELS) -> np.ndarray:
    """The silhouette of one of OBJECTS, proportions drawn at random."""
    u, v = plane_grid(n)
    j = lambda a, b: float(rng.uniform(a, b))  # noqa: E731 - one draw, read inline
    if name == "chair":
        seat = j(-0.08, 0.02)
        m = rect(u, v, 0, seat, 0.6, 0.07) | rect(u, v, -0.27, (seat + 0.47) / 2, 0.07,
                                                  0.47 - seat)
        m |= rect(u, v, -0.27, (seat - 0.47) / 2, 0.06, 0.47 + seat)
        m |= rect(u, v, 0.27, (seat - 0.47) / 2, 0.06, 0.47 + seat)
        return m
    if name == "table":
        top = j(0.0, 0.2)
        m = rect(u, v, 0, top, 0.95, 0.08)
        for x in (-0.4, 0.4):
            m |= rect(u, v, x, (top - 0.48) / 2, 0.07, 0.48 + top)
        return m
    if name == "lamp":
        m = ellipse(u, v, 0, -0.45, 0.2, 0.04) | rect(u, v, 0, -0.1, 0.04, 0.7)
        return m | polygon(u, v, [(-0.3, 0.2), (0.3, 0.2), (0.15, 0.48), (-0.15, 0.48)])
    if name in ("vase", "mug"):
        if name == "mug":
            m = rect(u, v, -0.08, 0, 0.6, 0.8)
            return m | (ellipse(u, v, 0.25, 0.02, 0.22, 0.22)
                        & ~ellipse(u, v, 0.25, 0.02, 0.13, 0.13))
        y = np.linspace(-0.48, 0.48, 9)
        r = np.clip(0.2 + 0.15 * np.sin(np.pi * (y + 0.5) * j(0.8, 1.6) + j(0, 3))
                    + rng.uniform(-0.04, 0.04, 9), 0.06, 0.45)
        return polygon(u, v, list(zip(r, y, strict=True)) + list(zip(-r[::-1], y[::-1],
                                                                      strict=True)))
    if name == "tree":
        m = rect(u, v, 0, -0.3, 0.1, 0.4)
        for _ in range(3):
            m |= ellipse(u, v, j(-0.15, 0.15), j(0.05, 0.25), j(0.18, 0.3), j(0.15, 0.25))
        return m
    if name in ("animal", "dragon"):
        m = ellipse(u, v, 0, 0, 0.3, 0.13)                               # body
        m |= capsule(u, v, (0.22, 0.05), (0.33, 0.25), 0.06)              # neck
        m |= ellipse(u, v, 0.38, 0.28, 0.1, 0.06, -20)                    # head
        for x in (-0.2, -0.1, 0.12, 0.22):                                # legs
            m |= capsule(u, v, (x, -0.05), (x + j(-0.05, 0.05), -0.45), 0.035)
        m |= capsule(u, v, (-0.28, 0.02), (-0.46, j(-0.1, 0.2)), 0.03)    # tail
        if name == "dragon":                                              # wings
            m |= polygon(u, v, [(-0.12, 0.08), (0.1, 0.08), (j(-0.3, 0.1), 0.46)])
            m |= polygon(u, v, [(-0.05, 0.08), (0.16, 0.08), (j(0.0, 0.3), 0.4)])
        return m
    if name == "bust":
        m = ellipse(u, v, 0, 0.25, 0.13, 0.18) | capsule(u, v, (0, 0.1), (0, 0.0), 0.06)
        m |= ellipse(u, v, 0, -0.1, 0.3, 0.14) & (v > -0.15)
        return m | rect(u, v, 0, -0.32, 0.34, 0.34)
    if name == "bicycle":
        ring = lambda cx: (ellipse(u, v, cx, -0.15, 0.24, 0.24)  # noqa: E731
                           & ~ellipse(u, v, cx, -0.15, 0.19, 0.19))
        m = ring(-0.25) | ring(0.25)
        for p, q in (((-0.25, -0.15), (0.0, 0.15)), ((0.0, 0.15), (0.25, -0.15)),
                     ((-0.25, -0.15), (0.05, -0.15)), ((0.05, -0.15), (0.0, 0.15)),
                     ((0.0, 0.15), (-0.05, 0.25)), ((0.2, 0.2), (0.25, -0.15))):
            m |= capsule(u, v, p, q, 0.025)
        return m
    if name == "ladder":
        m = rect(u, v, -0.22, 0, 0.07, 1.0) | rect(u, v, 0.22, 0, 0.07, 1.0)
        for y in np.linspace(-0.38, 0.38, int(rng.integers(4, 7))):
            m |= rect(u, v, 0, y, 0.44, 0.06)
        return m
    raise ValueError(f"{name}: not an object ({', '.join(OBJECTS)})")


def word_mask(word: str, u, v, cx: float, cy: float, height: float) -> np.ndarray:
    """The word's letters (the stroke font, strokes a quarter of the height) of ``height``
    centred at (cx, cy), on the grid (u, v)."""
    xy = np.stack([u.ravel() - cx, v.ravel() - cy], axis=1)
    return letters_mask(word, height, height / 4, xy).reshape(u.shape)


def arrow_mask(u, v, cx, cy, length, direction: str) -> np.ndarray:
    """An arrow of ``length`` (a shaft of width length / 5, a head of width 3/4 of the length
    and a third of it long) pointing ``direction`` ("right", "up", "left", "down"), centred
    at (cx, cy)."""
    a = math.radians({"right": 0, "up": 90, "left": 180, "down": 270}[direction])
    du, dv = u - cx, v - cy
    x = du * math.cos(a) + dv * math.sin(a)      # along the arrow
    y = -du * math.sin(a) + dv * math.cos(a)
    L = length
    shaft = (x >= -L / 2) & (x <= L / 6) & (np.abs(y) <= L / 10)
    head = (x >= L / 6) & (x <= L / 2) & (np.abs(y) <= (L / 2 - x) * 9 / 8)
    return shaft | head


def relief_depth(mask: np.ndarray, side_m: float) -> np.ndarray:
    """Per-pixel offsets (m, along the normal: negative towards the wall) of a relief:
    -RELIEF_DEPTH side sqrt(e / max e), e the distance to the mask's edge (0 outside)."""
    e = ndimage.distance_transform_edt(mask)
    top = float(e.max())
    return np.where(mask, -RELIEF_DEPTH * side_m * np.sqrt(e / top if top > 0 else e), 0.0)


# ------------------------------------------------------------------ targets
def tilt(rng: np.random.Generator) -> list[float]:
    """A turn (deg, about x and y) for a share TILTED of the targets, else none."""
    if rng.random() >= TILTED:
        return [0.0, 0.0, 0.0]
    return [float(v) for v in rng.uniform(-MAX_TILT_DEG, MAX_TILT_DEG, 2)] + [0.0]


def mask_object(name: str, mask: np.ndarray, side_m: float, material, rotate=None,
                depth: np.ndarray | None = None, albedo: float = 1.0) -> tuple[dict, dict]:
    """(the scene table of a mask of side ``side_m`` named ``name``, its files)."""
    obj = {"shape": "mask", "path": f"{name}.npy", "size_m": [side_m, side_m],
           "material": material, "albedo": albedo, "translate_m": [0.0, 0.0, 0.0],
           "rotate_deg": list(rotate or [0.0, 0.0, 0.0])}
    files = {f"{name}.npy": mask.astype(np.uint8)}
    if depth is not None:
        obj["depth_path"] = f"{name}_depth.npy"
        files[f"{name}_depth.npy"] = depth
    return obj, files


def sign_target(rng: np.random.Generator, side_m: float, material) -> Target:
    """A plate with a word and / or an arrow, cut out or printed (module docstring)."""
    aspect = float(rng.uniform(*SIGN_ASPECT))
    w, h = 1.0, 1.0 / aspect                     # in units of the side (the plate's width)
    word = str(rng.choice(SIGN_WORDS))
    has_arrow = bool(rng.random() < 0.6)
    has_word = not has_arrow or bool(rng.random() < 0.7)
    u, v = plane_grid()
    arrow_len = min(0.3, 0.8 * h) if has_word else 0.8 * w
    room = 0.9 * w - (arrow_len + 0.05 if has_arrow and has_word else 0.0)
    content = np.zeros(u.shape, bool)
    if has_word:
        letter_h = h * float(rng.uniform(0.45, 0.65))
        half_w, _ = text_extent(word, letter_h, letter_h / 4)
        letter_h *= min(1.0, room / (2 * half_w))
        content |= word_mask(word, u, v, -(0.9 * w - room) / 2, 0.0, letter_h)
    if has_arrow:
        d = str(rng.choice(("left", "right", "up", "down")))
        cx = 0.45 * w - arrow_len / 2 if has_word else 0.0
        content |= arrow_mask(u, v, cx, 0.0, arrow_len, d)
    plate = rect(u, v, 0, 0, 0.98 * w, 0.98 * h)
    rot = tilt(rng)
    what = (word if has_word else "") + ("+arrow" if has_arrow else "")
    if rng.random() < 0.5:
        obj, files = mask_object("sign", plate & ~content, side_m, material, rot)
        return Target("sign", f"sign:{what} cut", side_m, [obj], [True], files)
    back, f1 = mask_object("plate", plate, side_m, material, rot, albedo=SIGN_PLATE_ALBEDO)
    front, f2 = mask_object("print", content & plate, side_m, material, rot)
    return Target("sign", f"sign:{what} printed", side_m, [back, front], [False, True],
                  {**f1, **f2})


def figure_target(rng: np.random.Generator, side_m: float, material) -> Target:
    m, pose = person_mask(rng)
    obj, files = mask_object("figure", m, side_m, material, tilt(rng))
    return Target("figure", f"figure:{pose}", side_m, [obj], [True], files)


def object_target(rng: np.random.Generator, side_m: float, material) -> Target:
    name = str(rng.choice(OBJECTS))
    obj, files = mask_object("object", object_mask(name, rng), side_m, material, tilt(rng))
    return Target("object", f"object:{name}", side_m, [obj], [True], files)


def box_obj(w: float, h: float, d: float) -> str:
    """An OBJ of a box w x h x d (m) centred on 0, faces wound outwards."""
    x, y, z = w / 2, h / 2, d / 2
    verts = [(-x, -y, -z), (x, -y, -z), (x, y, -z), (-x, y, -z),
             (-x, -y, z), (x, -y, z), (x, y, z), (-x, y, z)]
    quads = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7),
             (4, 1, 5, 8)]
    return "".join(f"v {a:.6g} {b:.6g} {c:.6g}\n" for a, b, c in verts) + "".join(
        f"f {a} {b} {c} {d}\n" for a, b, c, d in quads)


def cylinder_obj(r: float, h: float, n: int = 24) -> str:
    """An OBJ of a cylinder of radius r and height h (m) along y, centred on 0, capped."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = [(r * math.cos(t), y, r * math.sin(t)) for y in (-h / 2, h / 2) for t in a]
    verts = ring + [(0.0, -h / 2, 0.0), (0.0, h / 2, 0.0)]
    faces = []
    for k in range(n):
        k2 = (k + 1) % n
        faces.append((k + 1, k2 + 1, n + k2 + 1, n + k + 1))
        faces.append((2 * n + 1, k2 + 1, k + 1))
        faces.append((2 * n + 2, n + k + 1, n + k2 + 1))
    return "".join(f"v {x:.6g} {y:.6g} {z:.6g}\n" for x, y, z in verts) + "".join(
        "f " + " ".join(str(i) for i in f) + "\n" for f in faces)


def shape3d_target(rng: np.random.Generator, side_m: float, material) -> Target:
    """Spheres, a box or cylinder mesh, a relief or an open book (module docstring)."""
    form = str(rng.choice(("spheres", "box", "cylinder", "relief", "book")))
    base = {"material": material, "albedo": 1.0}
    if form == "spheres":
        k = int(rng.integers(1, 4))
        r = side_m / (2 * k) * rng.uniform(0.7, 1.0, k)
        xs = (np.arange(k) - (k - 1) / 2) * side_m / k
        objs = [{**base, "shape": "sphere", "radius_m": float(ri),
                 "translate_m": [float(x), float(rng.uniform(-0.15, 0.15) * side_m),
                                 float(ri)]} for x, ri in zip(xs, r, strict=True)]
        return Target("shape3d", f"shape3d:{k} spheres", side_m, objs, [True] * k)
    if form in ("box", "cylinder"):
        turn = [float(rng.uniform(-30, 30)), float(rng.uniform(-45, 45)), 0.0]
        if form == "box":
            dims = side_m * rng.uniform([0.35, 0.6, 0.2], [0.8, 0.9, 0.5])
            text = box_obj(*dims)
        else:
            text = cylinder_obj(side_m * float(rng.uniform(0.15, 0.3)),
                                side_m * float(rng.uniform(0.6, 0.9)))
        obj = {**base, "shape": "mesh", "path": f"{form}.obj", "rotate_deg": turn,
               "translate_m": [0.0, 0.0, 0.3 * side_m]}
        return Target("shape3d", f"shape3d:{form}", side_m, [obj], [True],
                      {f"{form}.obj": text})
    if form == "relief":
        m = (person_mask(rng)[0] if rng.random() < 0.5
             else object_mask(str(rng.choice(OBJECTS)), rng))
        obj, files = mask_object("relief", m, side_m, material, tilt(rng),
                                 relief_depth(m, side_m))
        return Target("shape3d", "shape3d:relief", side_m, [obj], [True], files)
    angle = float(rng.uniform(20, 50))   # an open book: two plates hinged on a vertical line
    w, h = side_m / 2 * math.cos(math.radians(angle)), side_m * float(rng.uniform(0.5, 0.9))
    objs = [{**base, "shape": "rectangle", "size_m": [side_m / 2, h],
             "rotate_deg": [0.0, sgn * angle, 0.0],
             "translate_m": [sgn * -w / 2, 0.0, side_m / 4 * math.sin(math.radians(angle))]}
            for sgn in (-1.0, 1.0)]
    return Target("shape3d", "shape3d:book", side_m, objs, [True, True])


def letter_target(rng: np.random.Generator, side_m: float, material) -> Target:
    """A capital of the stroke font (a part of a multi target)."""
    ch = chr(int(rng.integers(ord("A"), ord("Z") + 1)))
    obj = {"shape": "letters", "text": ch, "height_m": side_m, "stroke_m": side_m / 4,
           "material": material, "albedo": 1.0, "translate_m": [0.0, 0.0, 0.0]}
    return Target("glyph", f"letter:{ch}", side_m, [obj], [True])


PARTS = {"letter": letter_target, "figure": figure_target, "object": object_target,
         "sign": sign_target, "shape3d": shape3d_target}


def multi_target(rng: np.random.Generator, side_m: float, material) -> Target:
    """Two or three parts side by side (each up to side / k wide, k parts), each at its own
    depth: MULTI_DEPTH_STEP_M apart at least, within MULTI_DEPTH_SPAN_M."""
    k = int(rng.integers(2, 4))
    kinds = rng.choice(list(PARTS), size=k)
    depth = np.sort(rng.uniform(0, MULTI_DEPTH_SPAN_M - MULTI_DEPTH_STEP_M * (k - 1), k)) \
        + MULTI_DEPTH_STEP_M * np.arange(k)
    rng.shuffle(depth)
    objs, content, files, names = [], [], {}, []
    for i, kind in enumerate(kinds):
        part = PARTS[str(kind)](rng, side_m / k * 0.9, material)
        x = (i - (k - 1) / 2) * side_m / k
        y = float(rng.uniform(-0.15, 0.15)) * side_m
        for o, c in zip(part.objects, part.content, strict=True):
            o = dict(o)
            for key in ("path", "depth_path"):
                if key in o:
                    o[key] = f"p{i}_{o[key]}"
            t = o["translate_m"]
            o["translate_m"] = [t[0] + x, t[1] + y, t[2] + float(depth[i])]
            objs.append(o)
            content.append(c)
        files.update({f"p{i}_{k2}": v for k2, v in part.files.items()})
        names.append(part.name)
    return Target("multi", "multi:" + " + ".join(names), side_m, objs, content, files)


GENERATORS = {"sign": sign_target, "figure": figure_target, "object": object_target,
              "shape3d": shape3d_target, "multi": multi_target}


def draw_target(kind: str, rng: np.random.Generator, side_m: float, material) -> Target:
    """One target of ``kind`` (one of GENERATORS: the kinds beyond glyphs and charts) of side
    ``side_m`` in ``material``."""
    return GENERATORS[kind](rng, side_m, material)
