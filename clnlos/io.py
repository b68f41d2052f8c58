"""Reading captures and writing results (HDF5, PNG), atomically.

Capture formats
---------------
* clnlos HDF5 (written by ``clnlos simulate``): dataset ``transient`` float32 [t, y, x] with
  x and y increasing with index; attributes ``bin_width_s``, ``start_s`` (time of the start
  of bin 0, round trip from the scan plane), ``scan_width_m``.
* CDT ``.mat`` (MATLAB v7.3 = HDF5; Lindell & Wetzstein 2020): dataset ``meas``, which h5py
  returns as (x, y, t) with y running down; it is mapped to [t, y, x] with +y up, checked on
  the published letters (they read "UT", U on the left). 16 ps bins, bin 0 at t = 0. The
  scan width is not in the file and must come from the configuration.

Every output is written to a temporary file in the target folder and renamed into place, so
an interrupted or failed run leaves nothing half-written.
"""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import ClnlosError, InputFileError

CDT_MAT_BIN_WIDTH_S = 16e-12  # the CDT capture format's histogram bin


@dataclass
class Capture:
    """A confocal transient [t, y, x] with its time and scan geometry (SI units)."""

    transient: np.ndarray
    bin_width_s: float | None
    start_s: float
    scan_width_m: float | None
    source: str = ""
    attrs: dict = field(default_factory=dict)

    def recorded_scene(self) -> dict | None:
        """The scene a clnlos simulation recorded in the file (parsed TOML), else None."""
        import tomllib

        text = self.attrs.get("scene")
        if not isinstance(text, str) or not text.strip():
            return None
        try:
            return tomllib.loads(text)
        except tomllib.TOMLDecodeError:
            return None

    def recorded_slab(self):
        """(Slab, n_dipoles) of the slab a clnlos simulation recorded (attribute ``slab``, a
        JSON [slab] table, or the [slab] of the recorded scene), else None."""
        from .config import slab_from_table

        table = None
        raw = self.attrs.get("slab")
        if isinstance(raw, str) and raw.strip().startswith("{"):
            try:
                table = json.loads(raw)
            except json.JSONDecodeError:
                table = None
        if table is None:
            scene = self.recorded_scene()
            table = scene.get("slab") if scene else None
        if not isinstance(table, dict):
            return None
        try:
            return slab_from_table(table, section="capture [slab]")
        except ClnlosError:  # a recorded slab that no longer validates: not used
            return None


def _validate_transient(arr, path) -> np.ndarray:
    if arr.ndim != 3:
        raise InputFileError(f"{path}: transient must be 3D [t, y, x], got shape {arr.shape}")
    if min(arr.shape) < 1:
        raise InputFileError(f"{path}: transient is empty, shape {arr.shape}")
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise InputFileError(f"{path}: transient must be real numbers, got dtype {arr.dtype}")
    arr = np.asarray(arr, np.float32)
    if not np.all(np.isfinite(arr)):
        raise InputFileError(f"{path}: transient holds NaN or Inf values")
    if np.any(arr < 0):
        raise InputFileError(f"{path}: transient holds negative counts (min {arr.min():.3g})")
    return arr


def read_capture(path: str | os.PathLike) -> Capture:
    """Read a clnlos HDF5 capture or a CDT ``.mat`` capture (see module docstring)."""
    import h5py

    path = Path(path)
    if not path.is_file():
        raise InputFileError(f"{path}: no such file")
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputFileError(f"{path}: not a readable HDF5/MATLAB v7.3 file ({exc})") from None
    try:
        with f:
            if "transient" in f:
                ds = f["transient"]
                try:
                    arr = _validate_transient(ds[()], path)
                except (OSError, ValueError) as exc:
                    raise InputFileError(f"{path}: cannot read dataset 'transient' ({exc})"
                                         ) from None
                at = dict(ds.attrs) | dict(f.attrs)

                def num(name, required):
                    if name not in at:
                        if required:
                            raise InputFileError(f"{path}: attribute {name!r} missing")
                        return None
                    try:
                        v = float(np.asarray(at[name]).reshape(()))
                    except (TypeError, ValueError):
                        raise InputFileError(f"{path}: attribute {name!r} is not a number"
                                             ) from None
                    if not np.isfinite(v):
                        raise InputFileError(f"{path}: attribute {name!r} = {v} is not finite")
                    return v

                return Capture(arr, num("bin_width_s", True), num("start_s", False) or 0.0,
                               num("scan_width_m", False), str(path),
                               {k: _plain(v) for k, v in at.items()})
            if "meas" in f:
                try:
                    raw = f["meas"][()]
                except (OSError, ValueError) as exc:
                    raise InputFileError(f"{path}: cannot read dataset 'meas' ({exc})") from None
                if raw.ndim != 3:
                    raise InputFileError(f"{path}: 'meas' must be 3D, got shape {raw.shape}")
                # h5py axes (x, y, t) with y running downwards in the published figures
                # -> ours [t, y, x] with +y up (the letters read correctly, seen from the
                # scan side looking into the hidden volume).
                arr = _validate_transient(np.transpose(raw, (2, 1, 0))[:, ::-1, :], path)
                return Capture(np.ascontiguousarray(arr), CDT_MAT_BIN_WIDTH_S, 0.0, None,
                               str(path), {"format": "cdt-mat"})
            raise InputFileError(f"{path}: no dataset 'transient' (clnlos) or 'meas' (CDT .mat);"
                                 f" found {sorted(f.keys())}")
    except InputFileError:
        raise
    except (OSError, KeyError, ValueError) as exc:
        raise InputFileError(f"{path}: unreadable ({exc})") from None


def _plain(v):
    if isinstance(v, bytes):
        return v.decode("utf-8", "replace")
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    return v


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path beside ``path``; rename it onto ``path`` only on success."""
    path = Path(path)
    if path.parent and not path.parent.exists():
        path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(FileNotFoundError):
            os.unlink(tmp)
        raise


def _attr_value(v):
    if v is None:
        return "none"
    if isinstance(v, dict | list | tuple):
        return json.dumps(v)
    return v


def write_h5(path, datasets: dict[str, np.ndarray], attrs: dict) -> Path:
    """Write datasets and file attributes to ``path`` atomically."""
    import h5py

    with atomic_path(path) as tmp:
        with h5py.File(tmp, "w") as f:
            for name, arr in datasets.items():
                f.create_dataset(name, data=arr, compression="gzip", compression_opts=4)
            for k, v in attrs.items():
                f.attrs[k] = _attr_value(v)
    return Path(path)


def write_capture(path, transient: np.ndarray, *, bin_width_s: float, start_s: float,
                  scan_width_m: float, attrs: dict | None = None) -> Path:
    """Write the clnlos capture format (see module docstring)."""
    a = {"bin_width_s": float(bin_width_s), "start_s": float(start_s),
         "scan_width_m": float(scan_width_m), "format": "clnlos-capture-1"}
    a.update(attrs or {})
    return write_h5(path, {"transient": np.asarray(transient, np.float32)}, a)


def save_figure(fig, path) -> Path:
    """Save a matplotlib figure to PNG atomically and close it."""
    import matplotlib.pyplot as plt

    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return Path(path)
