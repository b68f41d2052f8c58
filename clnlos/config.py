"""Typed, validated configuration loaded from TOML (every error names field, value and range).

Reconstruction parameters (``clnlos reconstruct --config PARAMS.toml``)::

    [capture]                    # geometry not stored in the capture file (CDT .mat)
    scan_width_m = 0.7           # side of the scanned square
    bin_width_s = 16e-12         # optional: overrides the file
    start_s = 0.0                # optional: time of the start of bin 0
    [preprocess]
    max_path_m = 2.0             # keep round-trip path lengths c t below this
    bins = 128                   # rebin the kept window to this many bins (mass-conserving)
    normalize = "max"            # "max", "sum" or "none"
    [slab]                       # optional: absent = plain NLOS (no deconvolution)
    thickness_m = 0.0254
    mu_a = 0.53
    mu_s_prime = 262.0
    n = 1.12
    ze_m = 0.0036                # optional
    n_dipoles = 20               # optional (default: auto)
    [deconvolution]
    snr = 1e4                    # Wiener SNR of the slab deconvolution
    guard_fraction = 0.25        # deconvolve this much more of the capture past max_path_m
                                 # (where it has it), then drop it: keeps edge effects out
    lateral_pad = "mirror"       # "mirror" (even extension across the scan border) or "zero"
    [inversion]
    method = "lct"               # "lct" or "fk"
    snr = 100.0                  # Wiener SNR of the LCT light-cone filter
    falloff = 4.0                # radiometric exponent p (LCT default 4, f-k default 2)
"""

from __future__ import annotations

import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

from .checks import choice, integer, positive
from .diffusion import Slab
from .errors import InputFileError, ParameterError


def check_keys(section: str, table: dict, allowed: set[str]) -> None:
    extra = sorted(set(table) - allowed)
    if extra:
        raise ParameterError(f"{section}.{extra[0]}" if section else extra[0], table[extra[0]],
                             "one of the known keys: " + ", ".join(sorted(allowed)))


def load_toml(path) -> dict:
    p = Path(path)
    if not p.is_file():
        raise InputFileError(f"{p}: no such file")
    try:
        return tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{p}: invalid TOML ({exc})") from None


def slab_from_table(t: dict, section: str = "slab") -> tuple[Slab, int | None]:
    check_keys(section, t, {"thickness_m", "mu_a", "mu_s_prime", "n", "ze_m", "n_dipoles"})
    missing = [k for k in ("thickness_m", "mu_a", "mu_s_prime", "n") if k not in t]
    if missing:
        raise ParameterError(f"{section}.{missing[0]}", None, "required when a slab is given")
    nd = t.get("n_dipoles")
    if nd is not None:
        nd = integer(f"{section}.n_dipoles", nd, 0, 10000)
    try:
        slab = Slab(thickness_m=t["thickness_m"], mu_a=t["mu_a"], mu_s_prime=t["mu_s_prime"],
                    n=t["n"], ze_m=t.get("ze_m"))
    except ParameterError as exc:
        raise ParameterError(f"{section}.{exc.name}", exc.value, exc.allowed) from None
    return slab, nd


@dataclass
class ReconstructionConfig:
    scan_width_m: float | None = None
    bin_width_s: float | None = None
    start_s: float | None = None
    max_path_m: float | None = None
    bins: int | None = None
    normalize: str = "max"
    slab: Slab | None = None
    n_dipoles: int | None = None
    snr: float = 1e4
    guard_fraction: float = 0.25
    lateral_pad: str = "mirror"
    method: str = "lct"
    inversion_snr: float = 1e2
    falloff: float | None = None
    extra: dict = field(default_factory=dict)

    def validate(self) -> ReconstructionConfig:
        if self.scan_width_m is not None:
            self.scan_width_m = positive("capture.scan_width_m", self.scan_width_m, upper=1e3)
        if self.bin_width_s is not None:
            self.bin_width_s = positive("capture.bin_width_s", self.bin_width_s, upper=1e-6)
        if self.start_s is not None:
            s = float(self.start_s)
            if not math.isfinite(s) or abs(s) > 1e-3:
                raise ParameterError("capture.start_s", self.start_s, "finite, |start_s| <= 1e-3")
            self.start_s = s
        if self.max_path_m is not None:
            self.max_path_m = positive("preprocess.max_path_m", self.max_path_m, upper=1e4)
        if self.bins is not None:
            self.bins = integer("preprocess.bins", self.bins, 1, 1 << 16)
        self.normalize = choice("preprocess.normalize", self.normalize, ("max", "sum", "none"))
        self.snr = positive("deconvolution.snr", self.snr, upper=1e30)
        self.guard_fraction = positive("deconvolution.guard_fraction", self.guard_fraction,
                                       allow_zero=True, upper=4.0)
        self.lateral_pad = choice("deconvolution.lateral_pad", self.lateral_pad,
                                  ("mirror", "zero"))
        self.method = choice("inversion.method", self.method, ("lct", "fk"))
        self.inversion_snr = positive("inversion.snr", self.inversion_snr, upper=1e30)
        if self.falloff is not None:
            f = float(self.falloff)
            if not (math.isfinite(f) and 0 <= f <= 8):
                raise ParameterError("inversion.falloff", self.falloff, "0 to 8")
            self.falloff = f
        return self

    @classmethod
    def from_toml(cls, path) -> ReconstructionConfig:
        return cls.from_dict(load_toml(path))

    @classmethod
    def from_dict(cls, d: dict) -> ReconstructionConfig:
        check_keys("", d, {"capture", "preprocess", "slab", "deconvolution", "inversion"})
        cap = d.get("capture", {})
        check_keys("capture", cap, {"scan_width_m", "bin_width_s", "start_s"})
        pre = d.get("preprocess", {})
        check_keys("preprocess", pre, {"max_path_m", "bins", "normalize"})
        dec = d.get("deconvolution", {})
        check_keys("deconvolution", dec, {"snr", "guard_fraction", "lateral_pad"})
        inv = d.get("inversion", {})
        check_keys("inversion", inv, {"method", "snr", "falloff"})
        slab, nd = slab_from_table(d["slab"]) if "slab" in d else (None, None)
        return cls(scan_width_m=cap.get("scan_width_m"), bin_width_s=cap.get("bin_width_s"),
                   start_s=cap.get("start_s"), max_path_m=pre.get("max_path_m"),
                   bins=pre.get("bins"), normalize=pre.get("normalize", "max"), slab=slab,
                   n_dipoles=nd, snr=dec.get("snr", 1e4),
                   guard_fraction=dec.get("guard_fraction", 0.25),
                   lateral_pad=dec.get("lateral_pad", "mirror"), method=inv.get("method", "lct"),
                   inversion_snr=inv.get("snr", 1e2), falloff=inv.get("falloff")).validate()

    def as_attrs(self) -> dict:
        d = asdict(self)
        d.pop("extra", None)
        d["slab"] = None if self.slab is None else {**asdict(self.slab), "ze_used_m":
                                                    self.slab.ze}
        return d
