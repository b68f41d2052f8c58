"""Study samples: simulate a hidden object through the slab, reconstruct it, score it.

A sample is a JSON-able dict (material, object, pose, depth, exposure, seed and the grid);
its result is cached on disk as ``<cache>/<sha1 of the sample>.npz`` (written atomically), so
reruns and interrupted runs resume. Samples run serially or through Dask (local processes,
or an existing cluster): each worker process builds its own OpenCL context.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..config import ReconstructionConfig
from ..metrics import coverage_image, iou, otsu_threshold, peak_depth_m
from .clarity import clarity_score


@dataclass(frozen=True)
class StudyGrid:
    """Scan, time and reconstruction grid shared by every sample (seed Table 1 defaults)."""

    scan_width_m: float = 0.3  # 0.09 m^2
    points: int = 32
    bin_width_s: float = 16e-12
    bins: int = 512
    recon_bins: int = 128
    max_path_m: float = 2.0
    density_per_m2: float = 1e5
    snr: float = 1e4
    inversion_snr: float = 1e3
    power_w: float = 0.4
    rep_rate_hz: float = 10e6
    pulse_width_s: float = 35e-12
    wavelength_m: float = 532e-9
    etendue_m2_sr: float = 1e-9


SLAB = {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12}


# Part of every cache key: bump it when a change to the simulation or the reconstruction
# changes results (2: the forward model computes I past the scan border, as far as the slab's
# blur reaches), so that a cache folder left by an older version is not reused.
CACHE_REVISION = 2


def sample_key(sample: dict) -> str:
    return hashlib.sha1(json.dumps(sample, sort_keys=True).encode()).hexdigest()


def scene_dict(sample: dict, grid: StudyGrid) -> dict:
    obj = {"shape": sample["object"], "translate_m": [0.0, 0.0, sample["depth_m"]],
           "rotate_deg": sample.get("rotate_deg", [0.0, 0.0, 0.0]),
           "material": sample["material"], "albedo": 1.0}
    if sample["object"] == "letters":
        obj.update(text=sample.get("text", "UT"), height_m=sample.get("height_m", 0.2),
                   stroke_m=sample.get("stroke_m", 0.04))
    elif sample["object"] == "rectangle":
        obj.update(size_m=sample.get("size_m", [0.15, 0.1]))
    else:
        obj.update(radius_m=sample.get("radius_m", 0.08))
    return {"seed": int(sample["seed"]),
            "scan": {"width_m": grid.scan_width_m, "points": grid.points},
            "time": {"bin_width_s": grid.bin_width_s, "bins": grid.bins, "start_s": 0.0},
            "objects": [obj], "slab": dict(SLAB),
            "laser": {"pulse_width_s": grid.pulse_width_s},
            "detector": {"power_w": grid.power_w, "rep_rate_hz": grid.rep_rate_hz,
                         "exposure_s": sample["exposure_s"], "efficiency": 0.3,
                         "wavelength_m": grid.wavelength_m,
                         "etendue_m2_sr": grid.etendue_m2_sr, "dark_count_rate_hz": 1000.0},
            "sampling": {"density_per_m2": grid.density_per_m2, "splat_order": 1}}


def render_sample(sample: dict, grid: StudyGrid, keep_volume: bool = False,
                  device: str | None = None) -> dict:
    """Simulate, reconstruct (LCT) and score one sample; returns arrays and numbers."""
    from ..forward import ForwardModel
    from ..io import Capture
    from ..reconstruct import reconstruct
    from ..runtime import get_queue
    from ..scene import Scene

    queue = get_queue(device)
    scene = Scene.from_dict(scene_dict(sample, grid))
    fm = ForwardModel(scene, queue=queue)
    tau = fm.run()
    cfg = ReconstructionConfig(max_path_m=grid.max_path_m, bins=grid.recon_bins,
                               slab=scene.slab, snr=grid.snr,
                               inversion_snr=grid.inversion_snr).validate()
    rec = reconstruct(Capture(tau, scene.bin_width_s, 0.0, scene.width_m), cfg, device=queue)
    vol = rec.volume
    mip = vol.max(axis=0)
    mip = mip / mip.max() if mip.max() > 0 else mip
    truth = coverage_image(fm.samples.elements, scene.scan_centres())
    mask = truth >= 0.5
    pred = mip > otsu_threshold(mip)
    depth = peak_depth_m(vol, rec.extents["voxel_depth_m"])
    true_depth = float(np.mean(fm.samples.elements.pos[:, 2]))
    mse = float(np.mean((mip - np.clip(truth, 0, 1)) ** 2))
    out = {"mip": mip.astype(np.float32), "truth": truth.astype(np.float32),
           "clarity": clarity_score(mip), "iou": iou(pred, mask),
           "depth_m": float(depth), "true_depth_m": true_depth,
           "depth_error_m": abs(float(depth) - true_depth),
           "psnr_db": float(10 * np.log10(1.0 / max(mse, 1e-12))),
           "counts": float(tau.sum())}
    if keep_volume:
        ny = tau.shape[1]
        out.update(volume=vol.astype(np.float32), xt=tau[:, ny // 2, :].astype(np.float32),
                   yt=tau[:, :, ny // 2].astype(np.float32))
    return out


def _cached(sample: dict, grid: StudyGrid, cache: Path, keep_volume: bool,
            device: str | None) -> dict:
    key = sample_key({**sample, "grid": asdict(grid), "vol": keep_volume,
                      "revision": CACHE_REVISION})
    path = cache / f"{key}.npz"
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            return {k: (z[k].item() if z[k].ndim == 0 else z[k]) for k in z.files}
    res = render_sample(sample, grid, keep_volume, device)
    from ..io import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **res)
    return res


def run_samples(samples: list[dict], grid: StudyGrid, cache: Path, *, keep_volume=False,
                workers: int = 1, scheduler: str | None = None, device: str | None = None,
                desc: str = "samples") -> list[dict]:
    """Render every sample (cached), serially, on local Dask processes, or on a cluster."""
    from tqdm import tqdm

    cache.mkdir(parents=True, exist_ok=True)
    if scheduler is None and workers <= 1:
        return [_cached(s, grid, cache, keep_volume, device)
                for s in tqdm(samples, desc=desc, unit="sample")]
    from dask.distributed import Client, LocalCluster, as_completed

    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                               dashboard_address=None)
        client = Client(cluster)
    else:
        client = Client(scheduler)
    try:
        futs = [client.submit(_cached, s, grid, cache, keep_volume, device, pure=False)
                for s in samples]
        index = {f.key: i for i, f in enumerate(futs)}
        out: list = [None] * len(samples)
        for f in tqdm(as_completed(futs), total=len(futs), desc=desc, unit="sample"):
            out[index[f.key]] = f.result()
        return out
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def dataset_samples(n: int, materials: list[str], seed: int) -> list[dict]:
    """n samples varying material, object, pose, depth and noise (exposure)."""
    rng = np.random.default_rng(seed)
    texts = ["UT", "S", "T", "L", "H", "E", "F", "X"]
    out = []
    for k in range(n):
        obj = ["letters", "letters", "rectangle", "sphere"][int(rng.integers(4))]
        s = {"material": materials[int(rng.integers(len(materials)))], "object": obj,
             "depth_m": round(float(rng.uniform(0.35, 0.7)), 4),
             "rotate_deg": [round(float(rng.uniform(-25, 25)), 2),
                            round(float(rng.uniform(-25, 25)), 2), 0.0],
             "exposure_s": round(float(10 ** rng.uniform(-3, -0.5)), 6),
             "seed": int(seed * 100_003 + k)}
        if obj == "letters":
            s["text"] = texts[int(rng.integers(len(texts)))]
        out.append(s)
    return out


def cpu_workers(requested: int | None) -> int:
    return max(1, requested if requested is not None else (os.cpu_count() or 1))
