"""The material question on real captures (clnlos.study.real.materials): the score, the
crossing of the keep level, and on the shared LCT release: a retroreflective S keeps its
image with far fewer photons than the diffuse S."""

from __future__ import annotations

import numpy as np
import pytest

from clnlos.study.real.materials import (
    KEEP_LEVEL,
    RealPlan,
    binned_scan,
    blob_control,
    capture_rows,
    headline_ratios,
    image_score,
)


def _letter_s(n: int = 32) -> np.ndarray:
    img = np.zeros((n, n))
    s = n // 8
    img[s:2 * s, s:n - s] = img[s:n // 2, s:2 * s] = 1
    img[n // 2 - s // 2:n // 2 + s // 2, s:n - s] = 1
    img[n // 2:n - s, n - 2 * s:n - s] = img[n - 2 * s:n - s, s:n - s] = 1
    return img


def test_a_blob_and_noise_fail_the_score_a_noisy_copy_keeps_it():
    ref = _letter_s()
    assert blob_control(ref) < KEEP_LEVEL
    rng = np.random.default_rng(0)
    assert image_score(rng.random(ref.shape), ref) < 0.2
    assert image_score(ref + 0.05 * rng.standard_normal(ref.shape), ref) > KEEP_LEVEL
    assert image_score(ref[:, ::-1], ref) < KEEP_LEVEL  # a mirrored S is not the S


def test_binned_scan_keeps_the_photons():
    y = np.random.default_rng(1).poisson(2.0, (10, 8, 8)).astype(np.float32)
    b = binned_scan(y, 4)
    assert b.shape == (10, 4, 4) and b.sum() == y.sum()
    assert binned_scan(y, 3) is y  # not a divisor: unchanged


def test_retroreflective_s_needs_fewer_photons_than_the_diffuse_s(shared_data, queue):
    paths = [shared_data / "lct" / f"{n}.mat" for n in ("data_diffuse_s", "data_s_u")]
    if not all(p.exists() for p in paths):
        pytest.skip("the LCT release is not in ../shared/data/lct")
    plan = RealPlan(ladder=(1.0, 0.1, 0.01), seeds=1, inversions=("lct",), points=32,
                    bin_width_s=32e-12)
    caps = [capture_rows(p, plan, queue) for p in paths]
    for c in caps:
        assert c["blob_ncc"] < KEEP_LEVEL and c["reference"]["reflectance"]
    (head,) = headline_ratios(caps)
    assert head["retroreflective"]["reflectance"] == "retroreflective"
    assert head["ratio"] > 3.0, head
