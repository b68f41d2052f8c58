"""Validation of user-given parameters: each failure names the field, its value and the range.

Types are strict: a number must be an int or float (not a string such as "0.3", not a
boolean), a count must be an int (not 3.0).
"""

from __future__ import annotations

import difflib
import math
import numbers
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from clnlos.errors import InputFileError, ParameterError


def _is_real(v: Any) -> bool:
    return isinstance(v, numbers.Real) and not isinstance(v, bool)


def positive(name: str, v: Any, *, allow_zero: bool = False, upper: float | None = None
             ) -> float:
    """A finite real number > 0 (>= 0 with ``allow_zero``), at most ``upper``."""
    rng = (">= 0" if allow_zero else "> 0") + (f" and <= {upper:g}" if upper else "")
    if not _is_real(v):
        raise ParameterError(name, v, f"a number {rng}")
    x = float(v)
    lo_ok = x >= 0 if allow_zero else x > 0
    if not (math.isfinite(x) and lo_ok and (upper is None or x <= upper)):
        raise ParameterError(name, v, rng + " (finite)")
    return x


def real(name: str, v: Any, lo: float, hi: float) -> float:
    """A finite real number in [lo, hi]."""
    if not _is_real(v) or not math.isfinite(float(v)) or not lo <= float(v) <= hi:
        raise ParameterError(name, v, f"a number from {lo:g} to {hi:g}")
    return float(v)


def integer(name: str, v: Any, lo: int, hi: int) -> int:
    """An int (not a float, not a boolean) in [lo, hi]."""
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or not lo <= v <= hi:
        raise ParameterError(name, v, f"an integer from {lo} to {hi}")
    return int(v)


def choice(name: str, v: Any, allowed: tuple[str, ...]) -> str:
    if v not in allowed:
        raise ParameterError(name, v, " or ".join(repr(a) for a in allowed)
                             + did_you_mean(v, allowed))
    return v


def auto_or_positive(name: str, v: Any, *, upper: float) -> float | str:
    """The string "auto" or a number > 0 (at most ``upper``)."""
    if v == "auto":
        return "auto"
    if isinstance(v, str):
        raise ParameterError(name, v, f"\"auto\" or a number > 0 and <= {upper:g}"
                             + did_you_mean(v, ("auto",)))
    return positive(name, v, upper=upper)


def did_you_mean(v: Any, options) -> str:
    """' (did you mean 'x'?)' for the closest option to a string, else ''."""
    if not isinstance(v, str):
        return ""
    hits = difflib.get_close_matches(v.lower(), [str(o).lower() for o in options], n=1,
                                     cutoff=0.6)
    if not hits:
        return ""
    original = next(o for o in options if str(o).lower() == hits[0])
    return f" (did you mean {original!r}?)"


def input_file(path: str | os.PathLike, what: str = "") -> Path:
    """``path`` as a Path when it is an existing regular file, else an InputFileError naming
    it and what it is instead ("no such file", "is a directory", "not a regular file");
    ``what`` ("mesh ", ...) says which kind of file was expected."""
    p = Path(path)
    if p.is_file():
        return p
    if p.is_dir():
        raise InputFileError(f"{p}: is a directory, not a {what}file")
    if p.exists():
        raise InputFileError(f"{p}: not a regular {what}file")
    raise InputFileError(f"{p}: no such {what}file")


# The one range table of the capture geometry (SI units): (low, high, low allowed). The flags,
# the [capture] table and the values read from capture files are all checked against it.
GEOMETRY_LIMITS: dict[str, tuple[float, float, bool]] = {
    "scan_width_m": (0.0, 1e3, False),   # side of the scanned area along x (m), > 0
    "bin_width_s": (0.0, 1e-6, False),   # histogram bin (s), > 0
    "start_s": (-1e-3, 1e-3, True),      # start of bin 0, round trip (s)
}


@dataclass(frozen=True)
class Plausible:
    """What a lab NLOS capture can have of one quantity (SI units). Inside ``usual``
    nothing is said; outside it but inside ``possible``, one warning line (unusual); outside
    ``possible`` no NLOS capture has it -- most likely a unit slip, ``slip_high`` /
    ``slip_low`` name the likely one -- and it is an error unless the user accepts it
    (``allow_implausible``). Why each bound: docs/reference/files.md, "Values that cannot
    be"."""

    unit: str  # "m" or "s": how values are shown
    usual: tuple[float, float]
    possible: tuple[float, float]
    slip_high: str
    slip_low: str
    slip_factor: float | None = None  # a value too high times this: what was likely meant


# The one plausibility rule of every reader, flag, config key and scene (a reconstruction:
# clnlos.config.plausibility_warnings; a simulation: clnlos.api.simulate). Kinds: the side of
# the scanned area; a time resolution (a histogram bin, a laser pulse's FWHM); a depth behind
# the scan plane (where a time window ends, c (start + n dt) / 2; where it starts; max_path / 2;
# depth_min).
PLAUSIBLE: dict[str, Plausible] = {
    "scan_width_m": Plausible("m", (1e-2, 10.0), (1e-4, 20.0), "a length in cm typed as m",
                              "a length in km", 1e-2),
    "time_step_s": Plausible("s", (1e-13, 1e-9), (1e-15, 1e-8), "a time in ns typed for ps",
                             "a time in fs typed for ps", 1e-3),
    "depth_m": Plausible("m", (-100.0, 100.0), (-1e3, 1e3), "a time in ns typed for ps (or "
                         "us for ns)", "a time in ns typed for ps (or us for ns)"),
}
ALLOW_IMPLAUSIBLE = "--allow-implausible"  # the option that accepts an impossible value


def shown_quantity(value: float, unit: str) -> str:
    """A value for a message: lengths in m, times in ps below 1 ns, else in ns."""
    if unit == "m":
        return f"{value:.4g} m"
    return f"{value * 1e12:.4g} ps" if abs(value) < 1e-9 else f"{value * 1e9:.4g} ns"


def plausibility(kind: str, value: float) -> tuple[str, str]:
    """("usual" | "unusual" | "impossible", the clause saying why) of ``value`` of the
    quantity ``kind`` of :data:`PLAUSIBLE`."""
    p = PLAUSIBLE[kind]
    lo, hi = p.usual
    if lo <= value <= hi:
        return "usual", ""
    high = value > hi
    slip = p.slip_high if high else p.slip_low
    if high and p.slip_factor:
        slip += f": {shown_quantity(value * p.slip_factor, p.unit)}"
    plo, phi = p.possible
    if plo <= value <= phi:
        bound = shown_quantity(hi if high else lo, p.unit)
        return "unusual", (f"{'more' if high else 'less'} than the {bound} usual for an NLOS "
                           f"capture ({slip}?)")
    bound = shown_quantity(phi if high else plo, p.unit)
    return "impossible", (f"{'beyond' if high else 'below'} the {bound} any NLOS capture can "
                          f"have ({slip}?)")


def check_keys(section: str, table: dict, allowed) -> None:
    """Unknown keys are an error that names the key and suggests the closest known one."""
    allowed = sorted(allowed)
    extra = sorted(set(table) - set(allowed))
    if extra:
        raise ParameterError(f"{section}.{extra[0]}" if section else extra[0], table[extra[0]],
                             "one of the known keys: " + ", ".join(allowed)
                             + did_you_mean(extra[0], allowed))


def check_geometry(field: str, value, name: str | None = None) -> float:
    """A capture geometry value (``field`` of :data:`GEOMETRY_LIMITS`) checked against the
    one range table; the ParameterError names ``name`` (default: the field)."""
    lo, hi, lo_allowed = GEOMETRY_LIMITS[field]
    if lo_allowed:
        return real(name or field, value, lo, hi)
    return positive(name or field, value, upper=hi)


def parse_toml(text: str) -> dict:
    """TOML text to a dict; nesting too deep for the parser is a ValueError like bad syntax."""
    try:
        return tomllib.loads(text)
    except RecursionError:
        raise ValueError("nested too deeply") from None
