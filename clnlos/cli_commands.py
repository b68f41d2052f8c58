"""Sub-commands of the clnlos CLI beyond ``devices`` (each one thin over a pipeline)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

DTYPES = {"float32": np.float32, "float64": np.float64}


def _add_precision(p) -> None:
    p.add_argument("--dtype", choices=sorted(DTYPES), default="float32",
                   help="kernel precision (default float32)")


def cmd_reconstruct(args) -> int:
    from .config import ReconstructionConfig, slab_from_table
    from .io import read_capture, save_figure, write_h5
    from .reconstruct import reconstruct, volume_figure
    from .runtime import get_queue

    cfg = ReconstructionConfig.from_toml(args.config) if args.config else ReconstructionConfig()
    for flag, attr in (("scan_width", "scan_width_m"), ("bin_width", "bin_width_s"),
                       ("snr", "snr"), ("max_path", "max_path_m"), ("bins", "bins"),
                       ("method", "method"), ("inversion_snr", "inversion_snr"),
                       ("falloff", "falloff")):
        v = getattr(args, flag)
        if v is not None:
            setattr(cfg, attr, v)
    slab_flags = {"thickness_m": args.slab_thickness, "mu_a": args.mu_a,
                  "mu_s_prime": args.mu_s_prime, "n": args.n}
    if args.no_slab:
        cfg.slab = None
    elif any(v is not None for v in slab_flags.values()):
        base = {} if cfg.slab is None else {"thickness_m": cfg.slab.thickness_m,
                                            "mu_a": cfg.slab.mu_a,
                                            "mu_s_prime": cfg.slab.mu_s_prime, "n": cfg.slab.n,
                                            "ze_m": cfg.slab.ze_m}
        base.update({k: v for k, v in slab_flags.items() if v is not None})
        base = {k: v for k, v in base.items() if v is not None}
        cfg.slab, nd = slab_from_table(base)
    cfg.validate()
    capture = read_capture(args.capture)
    queue = get_queue(args.device)
    rec = reconstruct(capture, cfg, dtype=DTYPES[args.dtype], device=queue)
    out = Path(args.output)
    attrs = {**rec.extents, "bin_width_s": rec.bin_width_s, "scan_width_m": rec.scan_width_m,
             "stages": json.dumps(rec.stages), "timings_s": json.dumps(rec.timings_s),
             "params": json.dumps(rec.params), "capture": str(args.capture),
             "dtype": args.dtype, "device": queue.device.name.strip(),
             "axes": "volume[z, y, x]; +x with column index, +y with row index",
             "format": "clnlos-volume-1"}
    write_h5(out, {"volume": rec.volume.astype(np.float32)}, attrs)
    png = out.with_suffix(".png")
    save_figure(volume_figure(rec, title=f"{Path(args.capture).name} ({cfg.method})"), png)
    total = sum(rec.timings_s.values())
    print(f"wrote {out} volume {rec.volume.shape} [z, y, x], depth 0-"
          f"{rec.extents['depth_max_m']:.3f} m; stages {', '.join(rec.stages)}; "
          f"{total:.3f} s on {queue.device.name.strip()}")
    print(f"wrote {png}")
    return 0


def register(sub, add_device) -> None:
    """Add the pipeline sub-commands to the parser ``sub``."""
    r = sub.add_parser("reconstruct", help="reconstruct a hidden volume from a capture")
    r.add_argument("capture", help="clnlos HDF5 capture or CDT .mat file")
    r.add_argument("-o", "--output", required=True, help="output HDF5 (a PNG is written beside)")
    r.add_argument("--config", help="reconstruction parameters (TOML)")
    r.add_argument("--method", choices=["lct", "fk"], default=None)
    r.add_argument("--scan-width", type=float, help="side of the scanned square (m)")
    r.add_argument("--bin-width", type=float, help="histogram bin width (s)")
    r.add_argument("--snr", type=float, help="Wiener SNR of the slab deconvolution")
    r.add_argument("--inversion-snr", type=float, help="Wiener SNR of the LCT filter")
    r.add_argument("--falloff", type=float, help="radiometric exponent of the inversion")
    r.add_argument("--max-path", type=float, help="keep round-trip paths below this (m)")
    r.add_argument("--bins", type=int, help="rebin the kept window to this many bins")
    r.add_argument("--slab-thickness", type=float, help="slab thickness (m)")
    r.add_argument("--mu-a", type=float, help="slab absorption coefficient (1/m)")
    r.add_argument("--mu-s-prime", type=float, help="slab reduced scattering coefficient (1/m)")
    r.add_argument("--n", type=float, help="slab refractive index (relative)")
    r.add_argument("--no-slab", action="store_true", help="plain NLOS: skip the deconvolution")
    _add_precision(r)
    add_device(r)
    r.set_defaults(func=cmd_reconstruct)
