"""The public Python API, re-exported at the package top (``clnlos.read_capture`` ...): the
functions the CLI commands call, so a notebook and ``clnlos reconstruct`` give the same volume.

Units are SI throughout: transients ``[t, y, x]`` in photon counts (or radiance per bin for a
noise-free simulation), volumes ``[z, y, x]`` in albedo (arbitrary units), lengths in m, times
in s.
"""

from __future__ import annotations

import os
import time
import warnings
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np
import pyopencl as cl
from numpy.typing import DTypeLike

from clnlos.config import (
    FIELD_NAMES,
    ReconstructionConfig,
    Slab,
    check_light_in_window,
    drop_other_methods_settings,
    load_toml,
    plausibility_warnings,
    python_keywords,
    scene_plausibility,
    slab_from_table,
)
from clnlos.brdf.store import FitQualityWarning
from clnlos.brdf.texture import read_texture, texture_fit_warning
from clnlos.errors import InputFileError, MissingParameterError, ParameterError
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.inverse.pipeline import Reconstruction
from clnlos.inverse.preprocessing import resolve_geometry, setup_slab
from clnlos.inverse.pipeline import reconstruct as run_pipeline
from clnlos.io.capture import SUPPLIED, Capture, without_direct
from clnlos.io.figures import volume_axes
from clnlos.io.files import read_capture as read_any
from clnlos.io.files import read_volume
from clnlos.io.formats.common import array_capture
from clnlos.io.layout import parse_axes
from clnlos.io.outputs import provenance
from clnlos.runtime.device import get_queue

if TYPE_CHECKING:  # annotations only: matplotlib is imported when a figure is drawn
    from matplotlib.axes import Axes

class PlausibilityWarning(UserWarning):
    """A geometry value implausible for a lab NLOS capture (a unit slip?), or one the user
    gave that contradicts the capture's (``clnlos.config.plausibility_warnings``)."""


PathLike = str | os.PathLike
Device = str | cl.CommandQueue | None  # a device spec ("cpu", "0:0", "pocl") or a queue
CONFIG_FIELDS = tuple(f for f in ReconstructionConfig.__dataclass_fields__ if f != "user_fields")


def read_capture(path: PathLike | np.ndarray, *, axes: str | None = None) -> Capture:
    """Read a confocal capture: clnlos or y-tal HDF5, MATLAB ``.mat`` v5/v7/v7.3 (the CDT, LCT
    and f-k layouts, or one 3-D array of any name), NumPy ``.npy``, HDF5 of another tool
    (one 3-D dataset), chosen by content; or wrap a NumPy array already in memory.

    ``axes``: the stored axes in order, e.g. ``"x,y,t"`` or ``"t,-y,x"``
    (``clnlos.io.layout``), for an array that records no layout (``.npy``, ``.mat``, other
    HDF5, an array in memory); default: the layout's own, else assumed from the shape
    (``attrs["axes"]`` says which, a reconstruction's notes name it).

    Returns a ``clnlos.io.capture.Capture``: ``transient`` ``[t, y, x]``,
    ``bin_width_s`` (s), ``start_s`` (s, round trip of bin 0 from the scan plane),
    ``scan_width_m`` (m, side along x) and the file's attributes (a clnlos simulation records
    its scene and slab there)."""
    if isinstance(path, np.ndarray):
        return array_capture(path, "the array", given=None if axes is None else
                             parse_axes(axes), what="the array", fmt="array",
                             order=np.shape(path))
    if not isinstance(path, str | os.PathLike):
        raise TypeError(f"path: expected a capture file path (str or os.PathLike) or a NumPy "
                        f"array; got {type(path).__name__}")
    return read_any(path, axes=axes)


def load_scene(scene: PathLike | Scene | Mapping[str, Any]) -> Scene:
    """A ``clnlos.forward.scene.Scene`` from a TOML path, a parsed table or a Scene."""
    if isinstance(scene, Scene):
        return scene
    if isinstance(scene, Mapping):
        return Scene.from_dict(dict(scene))
    return Scene.from_toml(scene)


def simulate(scene: PathLike | Scene | Mapping[str, Any], *, dtype: DTypeLike = np.float32,
             device: Device = None,
             progress: Callable[[str, int, int], None] | None = None,
             allow_implausible: bool = False,
             names: Mapping[str, str] | None = None) -> Capture:
    """Simulate the confocal capture of a scene (``clnlos simulate`` without the files).

    ``scene``: a scene TOML path, its parsed table or a ``clnlos.forward.scene.Scene``.
    ``device``: an OpenCL device spec (``"cpu"``, ``"0:0"``, ...) or queue (default: as the
    CLI). ``progress(stage, done, total)`` is called as each recorded stage finishes. Before
    any work the scene's geometry meets the plausibility rule
    (``clnlos.config.scene_plausibility``): a value no NLOS capture can have is an
    ``ImplausibleValueError`` unless ``allow_implausible``, an unusual one a
    ``PlausibilityWarning``; ``names`` maps options to how messages name them (the CLI
    passes its flags; default the keywords).

    Returns the capture ``[t, y, x]`` (float32; photon counts with a ``[detector]``, else
    1/(m^2 sr) per bin), with its geometry and the attributes a capture file records (scene,
    slab, stages, ``seconds`` of simulation, provenance), so ``reconstruct`` applies the
    recorded slab as it does for a file. A texture material of a BRDF fit that is not usable
    warns (``FitQualityWarning``)."""
    sc = load_scene(scene)
    for line in scene_plausibility(width_m=sc.width_m, bin_width_s=sc.bin_width_s,
                                   bins=sc.bins, start_s=sc.start_s,
                                   pulse_width_s=sc.pulse_width_s, allow=allow_implausible,
                                   accept=(names or {}).get("allow_implausible",
                                                            "allow_implausible=True")):
        warnings.warn(line, PlausibilityWarning, stacklevel=2)
    for line in material_fit_warnings(sc):
        warnings.warn(line, FitQualityWarning, stacklevel=2)
    t0 = time.perf_counter()
    fm = ForwardModel(sc, dtype=dtype, queue=get_queue(device))
    done = iter(range(1, len(fm.stages) + 1))
    tau = fm.run(progress=None if progress is None
                 else (lambda name: progress(name, next(done), len(fm.stages))))
    seconds = time.perf_counter() - t0
    attrs = {**fm.setup_attrs(), **provenance(device=fm.queue.device.name.strip()),
             "seconds": seconds,
             "units": "photon counts" if sc.detector else "1/(m^2 sr) per bin"}
    ny, nx = tau.shape[1:]
    return Capture(np.asarray(tau, np.float32), sc.bin_width_s, sc.start_s, sc.width_m,
                   "simulated", attrs,
                   scan_height_m=None if ny == nx else sc.width_m * ny / nx)


def material_fit_warnings(scene: Scene) -> list[str]:
    """The warnings of the BRDF fits a scene's texture materials tabulate: one line per
    texture of a fit that is not usable (``clnlos.brdf.texture.texture_fit_warning``)."""
    out = []
    for path in scene.texture_paths():
        line = texture_fit_warning(read_texture(path), path)
        if line and line not in out:
            out.append(line)
    return out


def reconstruction_config(config: PathLike | Mapping[str, Any] | ReconstructionConfig | None
                          = None, *, method: str | None = None,
                          names: Mapping[str, str] | None = None,
                          notes: list[str] | None = None,
                          **options: Any) -> ReconstructionConfig:
    """The validated reconstruction parameters: ``config`` (a TOML path, its parsed table or a
    ``clnlos.config.ReconstructionConfig``; default the built-in defaults), then
    ``method`` and ``options`` (``clnlos.config.ReconstructionConfig`` field names,
    e.g. ``snr=1e5``, ``iterations=50``, ``slab={"thickness_m": 0.0254, ...}``) over it.

    A field the method does not read is refused, naming it as ``names`` says (the CLI passes
    its flags) or as the option's name; where ``method`` overrides the config's, the config's
    settings for its own method are left unused instead, with a note appended to ``notes``
    (``clnlos.config.drop_other_methods_settings``)."""
    unknown = sorted(set(options) - set(CONFIG_FIELDS))
    if unknown:
        raise ParameterError(unknown[0], options[unknown[0]],
                             "a reconstruction option: " + ", ".join(CONFIG_FIELDS))
    table: dict = {}
    if isinstance(config, ReconstructionConfig):
        cfg = config
    elif isinstance(config, Mapping):
        table = dict(config)
        cfg = ReconstructionConfig.from_dict(table)
    elif config is not None:
        table = load_toml(config)
        cfg = ReconstructionConfig.from_dict(table)
    else:
        cfg = ReconstructionConfig()
    changes = dict(options)
    if method is not None:
        changes["method"] = method
    slab = changes.get("slab")
    if slab is not None and not isinstance(slab, Slab):
        changes["slab"], nd = slab_from_table(dict(slab), section="slab")
        if nd is not None:
            changes.setdefault("n_dipoles", nd)
    given = {**ReconstructionConfig.given_fields(table),
             **{f: f for f in changes if f != "method"}, **(names or {})}
    cfg = cfg.replace(**changes)
    if method is not None or "method" in options:  # the file's other method's settings
        said = (names or {}).get("method")
        said = f"{said} {cfg.method}" if said else f"method={cfg.method!r}"
        file_fields = {f: n for f, n in ReconstructionConfig.given_fields(table).items()
                       if f not in changes}
        cfg, unused, dropped = drop_other_methods_settings(cfg, file_fields, said)
        given = {f: n for f, n in given.items() if f not in unused}
        if notes is not None:
            notes.extend(dropped)
    return cfg.validate(given)


def check_capture(capture: Capture, config: ReconstructionConfig, *,
                  names: Mapping[str, str] | None = None, python: bool = False) -> None:
    """The checks a reconstruction runs on a capture before any work: its geometry and time
    window (``clnlos.inverse.preprocessing.resolve_geometry``), the plausibility rule
    (``clnlos.config.plausibility_warnings``: an ``ImplausibleValueError`` for a value no NLOS
    capture can have unless ``allow_implausible``, a ``PlausibilityWarning`` per unusual or
    contradicting value; ``python``: the capture's own values accepted by keyword), some
    signal, light inside the kept window (``clnlos.config.check_light_in_window``)."""
    names = dict(names or {})
    capture, _ = without_direct(capture, config.direct_cut_s, bin_width_s=config.bin_width_s,
                                start_s=config.start_s)
    bw, start, sw = resolve_geometry(capture, config, names=names)
    given = {f: names.get(f, FIELD_NAMES[f]) for f in ("scan_width_m", "bin_width_s", "start_s")
             if getattr(config, f) is not None}
    for line in plausibility_warnings(
            nt=capture.transient.shape[0], bin_width_s=bw, start_s=start, scan_width_m=sw,
            recorded=stored_geometry(capture), given=given,
            allow=config.allow_implausible, python=python):
        warnings.warn(line, PlausibilityWarning, stacklevel=3)
    if not np.any(capture.transient):
        raise InputFileError(f"{capture.source or 'the capture'}: the capture holds no signal "
                             "(all zero): nothing to reconstruct")
    check_light_in_window(capture.transient, bw, start, config, names=names,
                          source=capture.source or "the capture")


def stored_geometry(capture: Capture) -> dict:
    """The geometry a capture's file states, field -> value: None where it states none,
    also where its reader took the value from the layout's published code
    (``clnlos.io.capture.SUPPLIED``): a value given over that contradicts no file."""
    return {field: None if capture.attrs.get(attr) else getattr(capture, field)
            for field, attr, _, _ in SUPPLIED}


def with_slab(config: ReconstructionConfig, capture: Capture, *, no_slab: bool = False
              ) -> tuple[ReconstructionConfig, str | None]:
    """(config, note): a config without a slab takes the one the capture recorded (a clnlos
    simulation; ``clnlos.inverse.preprocessing.setup_slab``) unless ``no_slab``; the note says
    which (None where the config names its slab)."""
    if no_slab:
        return config.replace(slab=None), None
    if config.slab is not None:
        return config, None
    return setup_slab(config, capture)


def reconstruct(capture: Capture | PathLike, method: str | None = None, *,
                config: PathLike | Mapping[str, Any] | ReconstructionConfig | None = None,
                no_slab: bool = False, dtype: DTypeLike = np.float32, device: Device = None,
                names: Mapping[str, str] | None = None,
                log: Callable[[str], None] | None = None,
                progress: Callable[[int, int], None] | None = None,
                setup: Callable[[str], None] | None = None,
                **options: Any) -> Reconstruction:
    """Reconstruct the hidden albedo volume of a capture, as ``clnlos reconstruct`` does.

    ``capture``: a ``clnlos.io.capture.Capture``, a file path (``read_capture``) or a NumPy
    array ``[t, y, x]`` of counts with ``bin_width_s=`` (s) and ``scan_width_m=`` (m) among the
    options (its start: t = 0 at bin 0 unless ``start_s=``).
    ``method``: ``"lct"`` (light-cone transform), ``"fk"`` (f-k migration) or
    ``"iterative"`` (regularised inversion of the light-cone operator; default the config's,
    else ``"lct"``). ``config`` and ``options``: ``reconstruction_config``. Without a slab
    in them the slab the capture recorded is deconvolved first (``no_slab=True`` skips it);
    the note saying so goes to ``log`` (default: the first of ``Reconstruction.notes``).
    ``progress(k, n)`` follows the iterative method's iterations, ``setup(step)`` its set-up.

    Returns a ``clnlos.inverse.pipeline.Reconstruction``: ``volume`` ``[z, y, x]``
    (albedo, a.u.; depth bin k spans [k, k + 1) c dt / 2 behind the scan plane), ``extents``
    (m), ``params`` (the SNRs and rules that ran), ``notes``, ``timings_s``."""
    python = names is None  # a Python caller: its messages name keywords, not flags
    config_notes: list[str] = []
    cfg = reconstruction_config(config, method=method, names=names, notes=config_notes,
                                **options)
    capture = as_capture(capture, axes=cfg.axes)
    try:
        check_capture(capture, cfg, names={f: f for f in options} if python else names,
                      python=python)
    except MissingParameterError as exc:
        if not python:
            raise
        raise MissingParameterError(python_keywords(exc.name),
                                    python_keywords(exc.allowed)) from None
    cfg, note = with_slab(cfg, capture, no_slab=no_slab)
    if note and log is not None:
        log(note)
    queue = get_queue(device)
    rec = run_pipeline(capture, cfg, dtype=dtype, device=queue, progress=progress,
                       setup=setup)
    if note and log is None:
        rec.notes.insert(0, note)
    rec.notes[:0] = config_notes
    rec.params.update(layout_used(capture))
    if cfg.method == "iterative" and cfg.iterations == 0:
        rec.notes.append("--iterations 0: no iteration ran; the volume is the iterative "
                         "method's warm start (its LCT reconstruction)")
    if python:
        rec.notes[:] = [python_keywords(n) for n in rec.notes]
    return rec


def as_capture(capture: Any, *, axes: str | None = None) -> Capture:
    """``capture`` as a Capture: a Capture as it is (read again from its file with ``axes``
    where they differ from the layout it was read with), a path read (``read_capture``), a
    NumPy array wrapped without geometry (``reconstruct`` then needs ``bin_width_s=`` and
    ``scan_width_m=``); anything else a TypeError naming the argument."""
    if isinstance(capture, Capture):
        return capture if axes is None else reoriented(capture, axes)
    if isinstance(capture, np.ndarray | str | os.PathLike):
        return read_capture(capture, axes=axes)
    raise TypeError(f"capture: expected a clnlos Capture (clnlos.simulate, "
                    f"clnlos.read_capture), a capture file path, or a NumPy array with "
                    f"bin_width_s= and scan_width_m=; got {type(capture).__name__}")


def reoriented(capture: Capture, axes: str) -> Capture:
    """A capture read with another layout: as it is where it was read with ``axes``; a file
    that records no layout read again with them; an array in memory turned from the layout
    it was read with; a capture that records its layout (clnlos, y-tal, a simulation) an
    InputFileError."""
    layout = parse_axes(axes)
    was = capture.attrs.get("axes")
    if was is not None and str(parse_axes(was)) == str(layout):
        return capture
    src = capture.source or "the capture"
    if was is None:
        raise InputFileError(f"{src}: records its layout ([t, y, x]); a layout given (axes "
                             f"{layout}) is for arrays stored without one (.npy, .mat, HDF5 "
                             "of other tools)")
    if capture.attrs.get("format") == "array":
        return read_capture(parse_axes(was).from_tyx(capture.transient), axes=str(layout))
    if not os.path.isfile(src):
        raise InputFileError(f"{src}: not a file to read again with axes {layout}; read it "
                             "with clnlos.read_capture(path, axes=...)")
    return read_capture(src, axes=str(layout))


def layout_used(capture: Capture) -> dict:
    """The layout a reconstruction's capture was read with, for its record: ``axes_used``
    (``clnlos.io.layout``; "t,y,x" for a format that records [t, y, x]) and ``axes_source``
    ("given", the layout's own, assumed, or recorded by the file)."""
    return {"axes_used": capture.attrs.get("axes", "t,y,x"),
            "axes_source": capture.attrs.get("axes_source", "recorded by the file")}


def plot_volume(volume: Reconstruction | np.ndarray | PathLike, ax: Axes | None = None, *,
                extents: Mapping[str, float] | None = None, view: str = "xy",
                gamma: float | None = None, log: bool = False,
                colorbar: bool = True) -> Axes:
    """Draw a volume on matplotlib axes and return them (a new figure's when ``ax`` is None).

    ``volume``: a ``clnlos.inverse.pipeline.Reconstruction``, an array ``[z, y, x]``
    (with ``extents`` in m, else voxel indices) or a volume file of ``clnlos reconstruct``.
    ``view``: ``"xy"`` (maximum over depth), ``"xz"`` / ``"yz"`` (maximum over y / x, depth
    down the vertical axis), ``"depth"`` (depth of the brightest voxel, m). ``gamma`` or
    ``log`` rescale the display (value / max)^gamma or log10(value / max)."""
    if isinstance(volume, Reconstruction):
        vol, ext = volume.volume, volume.extents
    elif isinstance(volume, np.ndarray):
        vol, ext = volume, extents
    elif isinstance(volume, str | os.PathLike):
        vol, ext, _ = read_volume(volume)
    else:
        hint = (" (a capture: reconstruct it first, clnlos.reconstruct(capture))"
                if isinstance(volume, Capture) else "")
        raise TypeError(f"volume: expected a Reconstruction (clnlos.reconstruct), a volume "
                        f"array [z, y, x] or a volume file path; got "
                        f"{type(volume).__name__}{hint}")
    return volume_axes(np.asarray(vol), dict(ext) if ext else None, ax=ax, view=view,
                       gamma=gamma, log=log, colorbar=colorbar)
