"""The one in-memory capture contract every reader returns (:mod:`clnlos.io.formats`, one
module per file format, chosen by content): transient [t, y, x], bin width, start of bin 0
(round trip from the scan plane), scan width, and the file's attributes (a clnlos simulation
records its scene and slab there)."""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass, field

import numpy as np

from clnlos.checks import check_geometry, parse_toml
from clnlos.errors import ClnlosError, InputFileError, ParameterError
from clnlos.io.layout import parse_axes
from clnlos.physics.constants import C0
from clnlos.physics.slab import slab_from_table

CAPTURE_FORMAT = "clnlos-capture-1"  # the format attribute of the clnlos capture files

# how a capture format names the geometry it stores, when not by the Capture field's name
# (error messages name what the file holds)
GEOMETRY_SOURCES = {
    "y-tal": {"bin_width_s": "delta_t / c", "start_s": "t_start / c",
              "scan_width_m": "the scan grid's pitch x points"},
    "lct-mat": {"bin_width_s": "variable 'bin_resolution'", "scan_width_m": "2 x variable "
                "'width'"},
}


@dataclass
class Capture:
    """A confocal transient [t, y, x] with its time and scan geometry (SI units).

    The geometry is checked on construction against the one range table the flags use
    (``clnlos.config.GEOMETRY_LIMITS``): a value out of range is an InputFileError that
    names the source, what in it gave the value, and the allowed range."""

    transient: np.ndarray
    bin_width_s: float | None
    start_s: float
    scan_width_m: float | None
    source: str = ""
    attrs: dict = field(default_factory=dict)
    # [y, x]: how far (in bins) a reader moved each column earlier to align the scan points
    # (y-tal's first and last bounces, an f-k tofgrid); None when it did not. Fractional
    # parts interpolate, which the reconstruction counts as a model error
    # (clnlos.inverse.pipeline.ReconstructionPipeline.resampling_snr).
    time_shift_bins: np.ndarray | None = None
    # (x, y) of the scan grid's centre on the relay plane (m): the volume's lateral extents
    # are centred there (a y-tal grid need not be centred on the origin)
    scan_center_m: tuple[float, float] = (0.0, 0.0)
    # the scan's side along y (m) when the file says it (a non-square scan); else the pitch
    # scan_width_m / columns times the rows
    scan_height_m: float | None = None

    def __post_init__(self):
        fmt = self.attrs.get("format") if isinstance(self.attrs, dict) else None
        labels = GEOMETRY_SOURCES.get(fmt, {})
        for f in ("bin_width_s", "start_s", "scan_width_m"):
            v = getattr(self, f)
            if v is None:
                continue
            what = f"{labels[f]} gives {f}" if f in labels else f"attribute {f!r}"
            try:
                setattr(self, f, check_geometry(f, v, f))
            except ParameterError as exc:
                raise InputFileError(f"{self.source or 'capture'}: {what} = {v!r}: allowed "
                                     f"{exc.allowed}") from None

    def recorded_scene(self) -> dict | None:
        """The scene a clnlos simulation recorded in the file (parsed TOML), else None; a
        recorded scene that is not valid TOML is an InputFileError."""
        text = self.attrs.get("scene")
        if not isinstance(text, str) or not text.strip():
            return None
        try:
            return parse_toml(text)
        except ValueError as exc:
            raise InputFileError(f"{self.source or 'capture'}: attribute 'scene' is not a "
                                 f"valid TOML scene ({exc})") from None

    def recorded_slab(self):
        """(Slab, n_dipoles) of the slab a clnlos simulation recorded (attribute ``slab``, a
        JSON [slab] table, or the [slab] of the recorded scene), else None. A recorded slab
        that is not a table or does not validate is an InputFileError naming the attribute
        (never silently "no slab")."""
        src = self.source or "capture"
        raw = self.attrs.get("slab")
        if raw is not None and not (isinstance(raw, str) and raw.strip().lower()
                                    in NO_SLAB_ATTRS):
            where, shown = "attribute 'slab'", raw
            try:
                table = json.loads(raw) if isinstance(raw, str) else raw
            except (json.JSONDecodeError, RecursionError):
                table = None
        else:
            scene = self.recorded_scene()
            if not scene or "slab" not in scene:
                return None
            where, table = "the [slab] of attribute 'scene'", scene["slab"]
            shown = table
        if not isinstance(table, dict):
            raise InputFileError(f"{src}: {where} = {_short(shown)}"
                                 " is not a [slab] table (JSON object with thickness_m, "
                                 "mu_a, mu_s_prime, n)")
        try:
            return slab_from_table(table, section="slab")
        except ClnlosError as exc:
            raise InputFileError(f"{src}: {where}: {exc}") from None


# the geometry a reader may take from its layout's published code: (field, attribute naming
# where from, label, how the user overrides it)
SUPPLIED = (("bin_width_s", "bin_width_source", "bin width", "--bin-width"),
            ("scan_width_m", "scan_width_source", "scan width", "--scan-width"),
            ("start_s", "start_source", "start", "[capture] start_s"))


def _value(field: str, v: float) -> str:
    if field == "scan_width_m":
        return f"{v:g} m"
    return f"{v * 1e12:.4g} ps"


def reader_notes(capture: Capture, *, bin_width_s: float | None = None,
                 start_s: float | None = None, scan_width_m: float | None = None
                 ) -> list[str]:
    """One note line each for what a reader supplied and the user did not override (the
    keyword arguments: the user's values, None where not given): the layout it read an array
    with that the file does not record (attribute ``axes``, unless the user gave it), and the
    geometry taken from the layout's published code (:data:`SUPPLIED`)."""
    src = capture.source or "the capture"
    notes = []
    axes, why = capture.attrs.get("axes"), capture.attrs.get("axes_source")
    if axes and why and why != "given":
        shape = capture.attrs.get("axes_stored_shape") or ()
        described = parse_axes(axes).describe(shape) if len(shape) == 3 else ""
        notes.append(f"{src}: {capture.attrs.get('axes_array', 'the array')} read as axes "
                     f"{axes} ({why}): {described}; if the front view is turned or mirrored, "
                     "give the stored order with --axes (e.g. t,x,y or -y,x,t)")
    given = {"bin_width_s": bin_width_s, "start_s": start_s, "scan_width_m": scan_width_m}
    parts, flags = [], []
    for name, attr, label, flag in SUPPLIED:
        why = capture.attrs.get(attr)
        value = getattr(capture, name)
        if why and value is not None and given[name] is None:
            parts.append(f"{label} {_value(name, value)}: {why}")
            flags.append(flag)
    if parts:
        notes.append(f"{src}: " + "; ".join(parts) + f" (the file does not store "
                     f"{'it' if len(parts) == 1 else 'them'}; override with "
                     f"{', '.join(flags)})")
    return notes


def without_direct(capture: Capture, cut_s: float | None = None, *,
                   bin_width_s: float | None = None, start_s: float | None = None,
                   scan_width_m: float | None = None) -> tuple[Capture, list[str]]:
    """(capture, notes): the capture with its window zeroed before ``cut_s`` (round trip, s;
    None: the direct reflection the reader recorded, attribute ``direct_end_s``; 0: nothing),
    the bins the direct reflection off the relay wall fills, and one note line per thing a
    reader supplied (:func:`reader_notes`; the cut). ``bin_width_s``, ``start_s`` and
    ``scan_width_m``: the geometry the reconstruction uses where the user overrides the
    file's (default: the capture's). Bins are zeroed, not dropped: the time axis (and t = 0
    at the wall) stays."""
    notes = reader_notes(capture, bin_width_s=bin_width_s, start_s=start_s,
                         scan_width_m=scan_width_m)
    recorded = capture.attrs.get("direct_end_s")
    cut = float(recorded or 0.0) if cut_s is None else float(cut_s)
    bw = capture.bin_width_s if bin_width_s is None else float(bin_width_s)
    start = capture.start_s if start_s is None else float(start_s)
    if not cut > 0 or bw is None:
        return capture, notes
    k = int(min(capture.transient.shape[0], max(0, math.ceil((cut - start) / bw - 1e-9))))
    if k == 0:
        return capture, notes
    t = np.array(capture.transient, copy=True)
    removed = float(np.sum(t[:k], dtype=np.float64))
    t[:k] = 0
    kept = float(np.sum(t, dtype=np.float64))
    why = ("the direct reflection off the wall, as the published code" if cut_s is None
           else "as asked")
    notes.append(f"the first {k} bins ({cut * 1e9:.3g} ns, paths below {C0 * cut:.3g} m) "
                 f"zeroed: {why} ({removed:.4g} of {removed + kept:.4g} counts; change with "
                 "--direct-cut, 0 keeps them)")
    return dataclasses.replace(capture, transient=t), notes


NO_SLAB_ATTRS = ("", "none")  # a ``slab`` attribute that records "no slab" (None is written so)


def _short(v, n: int = 60) -> str:
    """repr of ``v`` cut to ``n`` characters, for error messages."""
    r = repr(v)
    return r if len(r) <= n else r[:n - 3] + "..."


def plain_attr(v):
    """An HDF5 attribute as a plain Python value."""
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v
