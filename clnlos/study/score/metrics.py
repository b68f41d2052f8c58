"""Image-quality measures against known ground truth (synthetic scenes)."""

from __future__ import annotations

import numpy as np

from clnlos.forward.geometry import letters_mask
from clnlos.inverse.reproducibility import otsu_mask, otsu_threshold

__all__ = ["otsu_threshold", "iou", "letters_truth_mask", "coverage_image", "truth_mask",
           "peak_depth_m", "mip_iou"]


def iou(pred: np.ndarray, truth: np.ndarray) -> float:
    pred, truth = np.asarray(pred, bool), np.asarray(truth, bool)
    union = np.logical_or(pred, truth).sum()
    return float(np.logical_and(pred, truth).sum() / union) if union else 1.0


def letters_truth_mask(text, height_m, stroke_m, centre_xy, scan_centres) -> np.ndarray:
    """Mask [y, x] of fronto-parallel letters (no rotation) on the scan grid."""
    Y, X = np.meshgrid(scan_centres, scan_centres, indexing="ij")
    xy = np.column_stack([X.ravel() - centre_xy[0], Y.ravel() - centre_xy[1]])
    return letters_mask(text, height_m, stroke_m, xy).reshape(X.shape)


def coverage_image(elements, scan_centres: np.ndarray) -> np.ndarray:
    """Fraction of each scan cell [y, x] covered by the surface elements facing the scan
    plane (normal z < 0), projected along z."""
    n = len(scan_centres)
    pitch = scan_centres[1] - scan_centres[0] if n > 1 else 1.0
    lo = scan_centres[0] - pitch / 2
    front = elements.normal[:, 2] < 0
    ix = np.floor((elements.pos[front, 0] - lo) / pitch).astype(int)
    iy = np.floor((elements.pos[front, 1] - lo) / pitch).astype(int)
    ok = (ix >= 0) & (ix < n) & (iy >= 0) & (iy < n)
    img = np.zeros((n, n))
    np.add.at(img, (iy[ok], ix[ok]), elements.area[front][ok])
    return img / (pitch * pitch)


def truth_mask(elements, scan_centres: np.ndarray) -> np.ndarray:
    """True mask [y, x] of a scene: scan cells at least half covered (:func:`coverage_image`)."""
    return coverage_image(elements, scan_centres) >= 0.5


def peak_depth_m(volume: np.ndarray, voxel_depth_m: float) -> float:
    """Depth (m) of the brightest depth slice of a [z, y, x] volume, at the voxel centre."""
    return (float(np.argmax(volume.max(axis=(1, 2)))) + 0.5) * voxel_depth_m


def mip_iou(volume: np.ndarray, truth: np.ndarray) -> tuple[float, np.ndarray]:
    """IoU of the Otsu-thresholded max-intensity projection with the true mask."""
    pred = otsu_mask(volume)
    return iou(pred, truth), pred
