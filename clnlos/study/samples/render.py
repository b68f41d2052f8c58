"""Study samples: simulate a hidden object on the rig, reconstruct it, score it.

A sample is a JSON-able dict (:mod:`clnlos.study.plan.scenes`: the target, its material,
exposure, seed, the swept overrides, the inversion and the ``brdf`` it assumes); with the rig
it defines one scene (:func:`~clnlos.study.plan.scenes.scene_dict`) and its reconstruction
(:func:`sample_config`). Its result
is cached on disk as ``<cache>/<sha1 of sample, grid and code version>.npz`` (written
atomically, with the mode the umask gives), so reruns and interrupted runs resume and a
changed clnlos never reuses an old result. Each entry also holds its key and a SHA-256 of
its arrays, and is checked when read (readable, exactly the result's keys, shapes and
dtypes, its key, its checksum): a bad entry is deleted, recomputed and reported in one
warning naming the file. Samples run serially or through Dask (local processes with pinned
threads, or an existing cluster): each worker process builds its own OpenCL context.

Ground truth per sample: the scan cells at least half covered by surfaces facing the scan
plane (:func:`clnlos.study.score.metrics.truth_mask`), the mean depth of the surface elements, and
the
covered fraction per cell (for PSNR).
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import time
import warnings
import zipfile
import zlib
import threading
from collections import OrderedDict
from contextlib import contextmanager
from dataclasses import asdict, dataclass, replace
from importlib import resources
from pathlib import Path

import numpy as np

from clnlos.physics.constants import C0
from clnlos.version import __version__
from clnlos.brdf.lobes import LAMBERTIAN, lobe_by_name
from clnlos.config import ReconstructionConfig, snr_rule_applies
from clnlos.errors import ParameterError
from clnlos.forward.model import ForwardModel
from clnlos.forward.noise import photon_counts
from clnlos.forward.scene import Scene
from clnlos.inverse.pipeline import reconstruct
from clnlos.inverse.preprocessing import bins_for
from clnlos.io.capture import Capture
from clnlos.io.files import atomic_path
from clnlos.io.outputs import install_sigterm_cleanup
from clnlos.io.progress import progress_bar
from clnlos.runtime.caches import CACHES
from clnlos.runtime.device import get_queue
from clnlos.runtime.programs import code_digest, kernel_families
from clnlos.study.file.spec import StudyGrid
from clnlos.study.plan.scenes import (
    BINS_PER_FWHM,
    capture_bins,
    rig_temporal_fwhm_s,
    scene_dict,
    window_m,
)
from clnlos.study.score.legibility import box_baseline_iou
from clnlos.study.score.metrics import coverage_image, iou, otsu_threshold, peak_depth_m
from clnlos.study.score.quality import METRICS, quality_metrics


EXPECTED_BUDGET_BYTES = 256 << 20  # host bytes of noise-free transients kept per process

# what shapes a sample's result: every kernel family, the physics, forward, operator, runtime,
# inverse, io and BRDF packages, the top-level modules, the study's sampling and metrics
CODE_MODULES = ("clnlos.config", "clnlos.checks", "clnlos.diffusion", "clnlos.errors",
                "clnlos.settings", "clnlos.physics", "clnlos.forward", "clnlos.operators",
                "clnlos.runtime", "clnlos.inverse", "clnlos.io", "clnlos.brdf",
                "clnlos.study.plan.scenes", "clnlos.study.samples.render", "clnlos.study.score")


def code_version() -> str:
    """clnlos version and a hash of what shapes a sample's result (:data:`CODE_MODULES`,
    every kernel source, the BRDF presets; :func:`clnlos.runtime.programs.code_digest`, the
    hash the spectrum cache uses): part of each cache key, so results computed by other code
    are never reused."""
    presets = resources.files("clnlos.brdf").joinpath("presets.json")
    digest = code_digest(CODE_MODULES, kernel_families(), [presets])
    return f"{__version__}+{digest[:16]}"


def sample_key(sample: dict, grid: StudyGrid, version: str) -> str:
    blob = json.dumps({"sample": sample, "grid": asdict(grid), "code": version},
                      sort_keys=True)
    return hashlib.sha1(blob.encode()).hexdigest()



@dataclass(frozen=True)
class Expected:
    """What every exposure and noise draw of one scene shares: the noise-free transient
    [t, y, x] (float32, as the forward model reads it out), the capture's recorded setup,
    the true coverage of each scan cell and the targets' mean depth (m)."""

    tau: np.ndarray
    attrs: dict
    cover: np.ndarray
    true_depth_m: float


class ExpectedTransients:
    """The noise-free transients of the scenes a process rendered last, least recently used
    dropped first past ``budget_bytes`` (host memory): the samples of one scene at several
    exposures and noise realisations simulate it once."""

    def __init__(self, budget_bytes: int = EXPECTED_BUDGET_BYTES):
        self.budget = budget_bytes
        self._items: OrderedDict[str, Expected] = OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: str, build) -> Expected:
        with self._lock:
            hit = self._items.get(key)
            if hit is not None:
                self._items.move_to_end(key)
                return hit
        value = build()
        with self._lock:
            self._items[key] = value
            while len(self._items) > 1 and sum(
                    v.tau.nbytes for v in self._items.values()) > self.budget:
                self._items.popitem(last=False)
        return value

    def clear(self) -> None:
        with self._lock:
            self._items.clear()


EXPECTED = ExpectedTransients()
CACHES.register("study noise-free transients", EXPECTED.clear)


def expected_key(sample: dict, grid: StudyGrid) -> str:
    """What a sample's noise-free transient depends on: its scene without the detector's
    exposure and the noise seed."""
    d = scene_dict(sample, grid)
    d.pop("seed")
    d["detector"] = {k: v for k, v in d["detector"].items() if k != "exposure_s"}
    return json.dumps(d, sort_keys=True)


def expected_capture(scene: Scene, queue) -> Expected:
    """The scene's forward model without its photon noise, run once."""
    fm = ForwardModel(replace(scene, detector=None), queue=queue)
    tau = fm.run()
    attrs = fm.setup_attrs()
    if scene.detector is not None:
        attrs["stages"] = json.dumps([*json.loads(attrs["stages"]), "photon_noise"])
    cover = np.clip(coverage_image(fm.samples.elements, scene.scan_centres()), 0.0, 1.0)
    return Expected(tau, attrs, cover, float(np.mean(fm.samples.elements.pos[:, 2])))


def render_sample(sample: dict, grid: StudyGrid, device: str | None = None) -> dict:
    """Simulate (the noise-free transient shared by a scene's exposures and noise draws,
    then the photon counts of this one), reconstruct and score one sample."""
    queue = get_queue(device)
    t0 = time.perf_counter()
    scene = Scene.from_dict(scene_dict(sample, grid))
    exp = EXPECTED.get(expected_key(sample, grid), lambda: expected_capture(scene, queue))
    counts = (exp.tau if scene.detector is None else photon_counts(
        exp.tau, scene, np.random.default_rng(scene.seed))).astype(np.float32)
    cap = Capture(counts, scene.bin_width_s, scene.start_s, scene.width_m, "simulated",
                  dict(exp.attrs))
    t1 = time.perf_counter()
    rec = reconstruct(cap, sample_config(sample, grid, scene.slab), device=queue)
    t2 = time.perf_counter()
    vol = rec.volume
    mip = vol.max(axis=0)
    mip = mip / mip.max() if mip.max() > 0 else mip
    cover = exp.cover
    mask = cover >= 0.5
    pred = mip > otsu_threshold(mip)
    dz = rec.extents["voxel_depth_m"]
    depth = peak_depth_m(vol, dz)
    true_depth = exp.true_depth_m
    mse = float(np.mean((mip - cover) ** 2))
    depth_map = ((np.argmax(vol, axis=0) + 0.5) * dz).astype(np.float32)
    return {"mip": mip.astype(np.float32), "truth": cover.astype(np.float32),
            "depth_map": depth_map, "iou": iou(pred, mask),
            "iou_box_baseline": box_baseline_iou(mask), "depth_m": float(depth),
            **figure8_slices(cap.transient, vol), "bin_width_s": float(cap.bin_width_s),
            "voxel_depth_m": float(dz),
            "true_depth_m": true_depth, "depth_error_m": abs(float(depth) - true_depth),
            "psnr_db": float(10 * np.log10(1.0 / max(mse, 1e-12))),
            "counts": float(cap.transient.sum()),
            "simulate_s": t1 - t0, "reconstruct_s": t2 - t1,
            "lobe_halfwidth_deg": lobe_halfwidth_deg(rec.params),
            **{f"q_{k}": v for k, v in quality_metrics(vol, dz).items()}}


def sample_config(sample: dict, grid: StudyGrid, slab) -> ReconstructionConfig:
    """The reconstruction of a sample: its method (the rig's default where it names none),
    the window of its depth (on bins of the study's ``[reconstruction] bin_width_s`` where
    it sets one), the rig's iterations and SNR rule (where the method takes it), the
    ``brdf`` it assumes."""
    method = sample.get("method", grid.method)
    rule = {"snr_rule": grid.snr_rule} if snr_rule_applies(grid.snr_rule, method) else {}
    brdf = {"brdf": sample["brdf"]} if "brdf" in sample else {}
    it = {"iterations": grid.iterations} if method == "iterative" else {}
    window = window_m(sample, grid)
    cfg = ReconstructionConfig(max_path_m=window, slab=slab, method=method, **it, **rule,
                               **brdf).validate()
    bins = study_bins(cfg, sample, grid)
    return cfg if bins is None else cfg.replace(bins=bins).validate()


def study_bins(cfg: ReconstructionConfig, sample: dict, grid: StudyGrid) -> int | None:
    """The bins a sample's inversion runs on where the study sets them: the
    ``[reconstruction] bin_width_s``, else the rig's temporal FWHM (pulse and bin in
    quadrature) over BINS_PER_FWHM where the method's own default is finer (None: the
    method's default)."""
    window = cfg.max_path_m
    bw = grid.reconstruction_bin_width_s or rig_temporal_fwhm_s(grid) / BINS_PER_FWHM
    if bw <= grid.bin_width_s:
        return None
    bins = max(1, int(round(window / (C0 * bw))))
    nt = capture_bins(sample, grid)
    own = bins_for(cfg, nt, grid.bin_width_s, 0.0)
    if grid.reconstruction_bin_width_s is None and own is not None and own <= bins:
        return None
    return bins


def lobe_halfwidth_deg(params: dict) -> float:
    """Half width (deg) of the retro lobe a reconstruction assumed (90: Lambertian), from what
    it recorded (``brdf_used``)."""
    name = params.get("brdf_used")
    if name is None or name == LAMBERTIAN:
        return 90.0
    return math.degrees(lobe_by_name(name).halfwidth_rad())


def figure8_slices(transient: np.ndarray, volume: np.ndarray) -> dict[str, np.ndarray]:
    """What the seed's Figure 8 shows of one sample (float32): the measurement integrated over
    time [y, x] with its x-t [t, x] and y-t [t, y] slices through the scan centre, and the
    reconstruction's x-z [z, x] and y-z [z, y] maximum projections."""
    t = np.asarray(transient, np.float32)
    ny, nx = t.shape[1:]
    return {"meas_image": t.sum(axis=0), "meas_xt": t[:, ny // 2, :].copy(),
            "meas_yt": t[:, :, nx // 2].copy(),
            "vol_xz": volume.max(axis=1).astype(np.float32),
            "vol_yz": volume.max(axis=2).astype(np.float32)}


# what render_sample returns: float32 [points, points] images and float64 numbers
RESULT_IMAGES = ("mip", "truth", "depth_map", "meas_image")
RESULT_SLICES = ("meas_xt", "meas_yt", "vol_xz", "vol_yz")  # float32 [t or z, points]
RESULT_TIMES = ("simulate_s", "reconstruct_s")  # seconds: all a re-render may change
RESULT_NUMBERS = ("iou", "iou_box_baseline", "depth_m", "true_depth_m", "depth_error_m",
                  "psnr_db", "counts", "bin_width_s", "voxel_depth_m", "lobe_halfwidth_deg",
                  *RESULT_TIMES,
                  *(f"q_{m}" for m in METRICS))
# the entry's own fields beside the result
ENTRY_KEY, ENTRY_CHECKSUM = "_key", "_checksum"
# what np.load raises on a damaged .npz
NPZ_ERRORS = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)


def result_checksum(res: dict) -> str:
    """SHA-256 of a result's arrays (names, dtypes, shapes and bytes, in name order)."""
    h = hashlib.sha256()
    for k in sorted(res):
        a = np.ascontiguousarray(res[k])
        h.update(f"{k}:{a.dtype.str}:{a.shape};".encode())
        h.update(memoryview(a).cast("B") if a.size else b"")
    return h.hexdigest()


def entry_problem(z: dict[str, np.ndarray], key: str, grid: StudyGrid) -> str | None:
    """Why a loaded cache entry is not the result of sample ``key`` on ``grid`` (None when
    it is): its keys, the images' shapes and dtypes, the numbers', its key, its checksum."""
    expected = {*RESULT_IMAGES, *RESULT_SLICES, *RESULT_NUMBERS, ENTRY_KEY, ENTRY_CHECKSUM}
    missing, extra = sorted(expected - set(z)), sorted(set(z) - expected)
    if missing or extra:
        return (f"has {'no ' + ', '.join(missing) if missing else ''}"
                f"{'; ' if missing and extra else ''}"
                f"{'unexpected ' + ', '.join(extra) if extra else ''}")
    img = (grid.points, grid.points)
    for k in RESULT_IMAGES:
        if z[k].shape != img or z[k].dtype != np.float32:
            return f"has {k} {z[k].dtype}{list(z[k].shape)}, float32{list(img)} expected"
    for k in RESULT_SLICES:
        if z[k].ndim != 2 or z[k].shape[1] != grid.points or z[k].dtype != np.float32:
            return f"has {k} {z[k].dtype}{list(z[k].shape)}, float32[n, {grid.points}] expected"
    for k in RESULT_NUMBERS:
        if z[k].shape != () or z[k].dtype.kind != "f":
            return f"has {k} {z[k].dtype}{list(z[k].shape)}, a number expected"
    if z[ENTRY_KEY].shape != () or str(z[ENTRY_KEY]) != key:
        return "holds another sample's key"
    res = {k: v for k, v in z.items() if k not in (ENTRY_KEY, ENTRY_CHECKSUM)}
    if str(z[ENTRY_CHECKSUM]) != result_checksum(res):
        return "fails its SHA-256 check (corrupt)"
    return None


def load_entry(path: Path, key: str, grid: StudyGrid) -> tuple[dict | None, str | None]:
    """(the cached result at ``path``, None) when it is there and checked
    (:func:`entry_problem`); (None, why) for a bad entry, which is deleted; (None, None)
    when there is none."""
    if not path.is_file():
        return None, None
    try:
        with open(path, "rb") as fh:
            f = np.load(fh, allow_pickle=False)
            if not isinstance(f, np.lib.npyio.NpzFile):
                raise ValueError("a single array, not an .npz archive")
            with f:
                z = {k: f[k] for k in f.files}
        problem = entry_problem(z, key, grid)
    except NPZ_ERRORS as exc:
        problem = f"is unreadable ({type(exc).__name__}: {' '.join(str(exc).split())})"
    if problem is None:
        return {k: (v.item() if v.ndim == 0 else v) for k, v in z.items()
                if k not in (ENTRY_KEY, ENTRY_CHECKSUM)}, None
    path.unlink(missing_ok=True)
    return None, f"study cache entry {path} {problem}: deleted; the sample is recomputed"


def _cached(sample: dict, grid: StudyGrid, cache: Path, version: str,
            device: str | None) -> tuple[dict, str | None]:
    """(the sample's result, from the cache or rendered and stored; the one-line note on a
    bad entry that was replaced, else None). Runs on Dask workers: the note travels back
    to the client, which reports it."""
    key = sample_key(sample, grid, version)
    path = cache / f"{key}.npz"
    res, note = load_entry(path, key, grid)
    if res is not None:
        return res, None
    res = render_sample(sample, grid, device)

    entry = {k: np.asarray(v) for k, v in res.items()}
    entry[ENTRY_CHECKSUM] = np.asarray(result_checksum(entry))
    entry[ENTRY_KEY] = np.asarray(key)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **entry)
    return res, note


def _report(pairs: list[tuple[dict, str | None]]) -> list[dict]:
    """The results, each note of a replaced cache entry given as one warning."""
    for _, note in pairs:
        if note:
            warnings.warn(note, UserWarning, stacklevel=3)
    return [res for res, _ in pairs]


def _pin_threads(threads: int) -> dict:
    """Environment for worker processes: ``threads`` host threads each (PoCL and the FFT)."""
    t = str(threads)
    return {"POCL_MAX_PTHREAD_COUNT": t, "CLNLOS_THREADS": t, "OMP_NUM_THREADS": t,
            "MKL_NUM_THREADS": t, "OPENBLAS_NUM_THREADS": t}


@dataclass
class SamplePool:
    """Where a study's samples render: in this process (``client`` None), or on Dask (local
    worker processes with pinned threads, or an existing cluster). One pool serves every
    render of a study (its samples, its refined exposures, the transport comparison): its
    workers keep their OpenCL programs and noise-free transients from one call to the next."""

    client: object = None
    cluster: object = None

    def close(self) -> None:
        if self.client is not None:
            self.client.close()
        if self.cluster is not None:
            self.cluster.close()


@contextmanager
def sample_pool(workers: int = 1, scheduler: str | None = None):
    """A :class:`SamplePool`: serial for one worker, local Dask processes (workers x threads
    = cores), or the cluster at ``scheduler``; closed on exit. Dask's own log lines (its
    workers' start and stop) are kept from the user's terminal while it runs."""
    if scheduler is None and workers <= 1:
        yield SamplePool()
        return
    import distributed  # noqa: F401  (optional: the study extra; its loggers, configured)

    logs = [logging.getLogger(n) for n in ["distributed", *logging.root.manager.loggerDict]
            if n.startswith("distributed")]
    levels = [log.level for log in logs]
    for log in logs:
        log.setLevel(logging.ERROR)
    try:
        pool = _dask_pool(workers, scheduler)
        try:
            # a worker stopped by SIGTERM removes the cache entry it was writing
            pool.client.run(install_sigterm_cleanup, chain=True)
            yield pool
        finally:
            pool.close()
    finally:
        for log, level in zip(logs, levels, strict=True):
            log.setLevel(level)


def _dask_pool(workers: int, scheduler: str | None) -> SamplePool:
    from dask.distributed import Client, LocalCluster  # optional: the study extra

    if scheduler is not None:
        try:
            return SamplePool(Client(scheduler))
        except (OSError, TimeoutError, ValueError) as exc:  # nothing there, refused, ...
            why = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise ParameterError("--scheduler", scheduler, "the address of a running Dask "
                                 f"scheduler (connecting failed: {why})") from None
    threads = max(1, (os.cpu_count() or 1) // workers)
    saved = {k: os.environ.get(k) for k in _pin_threads(threads)}
    os.environ.update(_pin_threads(threads))  # inherited by the spawned workers
    try:
        import dask  # optional: the study extra

        # Dask's nanny sets MALLOC_TRIM_THRESHOLD_ in workers, which switches off glibc's
        # dynamic mmap threshold: every large FFT buffer is then mmap-ed and page-faulted
        # anew (a sample took 2.6x longer, most of it in the kernel). The workers get
        # the thread pinning above instead, and glibc's defaults.
        with dask.config.set({"distributed.nanny.pre-spawn-environ": {}}):
            cluster = LocalCluster(n_workers=workers, threads_per_worker=1,
                                   processes=True, dashboard_address=None)
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
    return SamplePool(Client(cluster), cluster)


def run_samples(samples: list[dict], grid: StudyGrid, cache: Path, *, workers: int = 1,
                scheduler: str | None = None, device: str | None = None,
                desc: str = "samples", pool: SamplePool | None = None,
                bar=None) -> list[dict]:
    """Render every sample (cached) in ``pool``, else in a pool of its own (serially, on
    local Dask processes, or on an existing cluster); ``bar``: a progress bar to move (one
    of its own, ``desc``, otherwise)."""
    if pool is None:
        with sample_pool(workers, scheduler) as own:
            return run_samples(samples, grid, cache, device=device, desc=desc, pool=own,
                               bar=bar)
    if bar is None:
        with progress_bar(len(samples), desc, "sample") as own_bar:
            return run_samples(samples, grid, cache, device=device, pool=pool, bar=own_bar)
    cache.mkdir(parents=True, exist_ok=True)
    version = code_version()
    if pool.client is None:
        out = []
        for s in samples:
            out.append(_cached(s, grid, cache, version, device))
            bar.update(1)
        return _report(out)
    from dask.distributed import as_completed  # optional: the study extra

    futs = [pool.client.submit(_cached, s, grid, cache, version, device, pure=False)
            for s in samples]
    index = {f.key: i for i, f in enumerate(futs)}
    out: list = [None] * len(samples)
    for f in as_completed(futs):
        out[index[f.key]] = f.result()
        bar.update(1)
    return _report(out)


MAX_WORKERS = 256  # local worker processes at most


def check_scheduler_address(name: str, address) -> str:
    """A Dask scheduler address: ``[tcp://|tls://]host:port`` (port 1-65535; ``inproc://``,
    ``ucx://`` and ``ws[s]://`` addresses as Dask writes them); else a ParameterError."""
    allowed = "a Dask scheduler address such as tcp://host:8786"
    if not isinstance(address, str) or not address.strip() or any(c.isspace()
                                                                   for c in address):
        raise ParameterError(name, address, allowed)
    scheme, sep, loc = address.partition("://")
    if not sep:
        scheme, loc = "tcp", address
    if scheme not in ("tcp", "tls", "inproc", "ucx", "ws", "wss"):
        raise ParameterError(name, address, allowed + " (protocol tcp, tls, inproc, ucx, ws "
                             "or wss)")
    if scheme == "inproc":
        return address
    host, colon, port = loc.rpartition(":")
    if not colon or not host.strip("[]") or not port.isdigit() or not 0 < int(port) < 65536:
        raise ParameterError(name, address, allowed + " (host and a port from 1 to 65535)")
    return address


def cpu_workers(requested: int | None) -> int:
    return max(1, requested if requested is not None else (os.cpu_count() or 1))
