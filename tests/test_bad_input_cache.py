"""Issue 23, items 3 and 6: caches verified on read; resources bounded before reading or
allocating."""

import os
import shutil
import warnings
from dataclasses import replace

import numpy as np
import pytest
from reference.scene_ref import points_transient

from clnlos.config import ReconstructionConfig
from clnlos.io import Capture
from clnlos.plans import PIPELINES
from clnlos.reconstruct import reconstruct
from clnlos.slab import CDT_SLAB
from clnlos.spectrum_cache import HEADER, SUFFIX

SHAPE_T, WIDTH, DT = 48, 0.5, 48e-12


# ------------------------------------------------------------------ spectrum cache
def _capture():
    tau = points_transient([(0.05, -0.03, 0.2), (-0.1, 0.08, 0.3)], [1, 1], SHAPE_T, 10,
                           WIDTH, DT)
    return Capture(tau.astype(np.float32), DT, 0.0, WIDTH)


def _run(queue):
    PIPELINES.clear()
    cfg = ReconstructionConfig(method="lct", slab=CDT_SLAB, snr=1e4,
                               inversion_snr=1e3).validate()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        vol = reconstruct(_capture(), cfg, device=queue).volume
    return vol, [str(w.message) for w in caught if "cache" in str(w.message)]


@pytest.fixture()
def spectra(queue, tmp_path, monkeypatch):
    """(the volume computed without a cache, the two cache entries written by a first run)."""
    monkeypatch.delenv("CLNLOS_SPECTRUM_CACHE", raising=False)
    plain, _ = _run(queue)
    monkeypatch.setenv("CLNLOS_SPECTRUM_CACHE", str(tmp_path / "spectra"))
    first, notes = _run(queue)
    np.testing.assert_array_equal(first, plain)
    assert notes == []
    return plain, sorted((tmp_path / "spectra").glob(f"*{SUFFIX}"))


def _zero_filled(path, other):
    path.write_bytes(bytes(path.stat().st_size))


def _payload_bit_flipped(path, other):
    b = bytearray(path.read_bytes())
    b[HEADER.size + len(b[HEADER.size:]) // 3] ^= 0x10
    path.write_bytes(bytes(b))


def _payload_scaled(path, other):
    """The right size and header, the spectrum's values divided by 1e5 (a volume peak
    0.43 instead of 1.6e5, as in the issue)."""
    b = path.read_bytes()
    a = np.frombuffer(b[HEADER.size:], np.float32) / np.float32(1e5)
    path.write_bytes(b[:HEADER.size] + a.tobytes())


def _truncated(path, other):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _other_entry(path, other):
    shutil.copyfile(other, path)


def _headerless(path, other):
    """An entry as the previous clnlos wrote it (the raw spectrum, no header)."""
    path.write_bytes(path.read_bytes()[HEADER.size:])


@pytest.mark.parametrize("damage", [_zero_filled, _payload_bit_flipped, _payload_scaled,
                                    _truncated, _other_entry, _headerless])
def test_bad_spectrum_entry_is_deleted_recomputed_and_named_in_one_warning(queue, spectra,
                                                                          damage):
    plain, files = spectra
    bad, other = files
    good_bytes = bad.read_bytes()
    damage(bad, other)
    vol, notes = _run(queue)
    np.testing.assert_array_equal(vol, plain)  # the recomputed spectrum, not the bad one
    assert len(notes) == 1 and str(bad) in notes[0] and "deleted" in notes[0]
    assert "\n" not in notes[0]
    assert bad.read_bytes() == good_bytes  # stored again
    vol, notes = _run(queue)  # and read back without a word
    np.testing.assert_array_equal(vol, plain)
    assert notes == []


@pytest.mark.parametrize("umask", [0o022, 0o002, 0o077])
def test_spectrum_entries_follow_the_umask(queue, tmp_path, monkeypatch, umask):
    monkeypatch.setenv("CLNLOS_SPECTRUM_CACHE", str(tmp_path))
    old = os.umask(umask)
    try:
        _run(queue)
    finally:
        os.umask(old)
    files = list(tmp_path.glob(f"*{SUFFIX}"))
    assert len(files) == 2
    assert {f.stat().st_mode & 0o777 for f in files} == {0o666 & ~umask}


# ------------------------------------------------------------------ study cache
def _grid():
    from clnlos.study.dataset import StudyGrid

    return replace(StudyGrid(), points=8, bin_width_s=64e-12, iterations=5,
                   density_per_m2=1e4)


def _sample(seed=0):
    from clnlos.study.dataset import dataset_samples

    return {**dataset_samples(1, ["standard white plate"], seed)[0], "slab_thickness_m": 0.0}


@pytest.fixture()
def study_entry(tmp_path, monkeypatch):
    """(cache folder, the entry of one tiny sample, its result, a counter of renders)."""
    from clnlos.study import dataset

    renders = []
    real = dataset.render_sample

    def counted(*a, **k):
        renders.append(1)
        return real(*a, **k)

    monkeypatch.setattr(dataset, "render_sample", counted)
    cache = tmp_path / "cache"
    (res,) = dataset.run_samples([_sample()], _grid(), cache)
    (entry,) = cache.glob("*.npz")
    renders.clear()
    return cache, entry, res, renders


def _run_study_samples(cache, samples=None):
    from clnlos.study.dataset import run_samples

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = run_samples(samples or [_sample()], _grid(), cache)
    return out, [str(w.message) for w in caught if "cache" in str(w.message)]


def _rewrite(path, change):
    with np.load(path) as z:
        d = {k: z[k] for k in z.files}
    change(d)
    with open(path, "wb") as f:
        np.savez(f, **d)


def _npz_truncated(path):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _npz_zero_filled(path):
    path.write_bytes(bytes(path.stat().st_size))


def _npz_missing_key(path):
    _rewrite(path, lambda d: d.pop("q_nr_clarity"))


def _npz_wrong_shape(path):
    _rewrite(path, lambda d: d.update(mip=d["mip"][:4]))


def _npz_wrong_dtype(path):
    _rewrite(path, lambda d: d.update(truth=d["truth"].astype(np.float64)))


def _npz_changed_value(path):
    _rewrite(path, lambda d: d.update(iou=np.asarray(0.999)))


def _npz_legacy(path):
    """An entry as the previous clnlos wrote it (no key, no checksum)."""
    _rewrite(path, lambda d: [d.pop("_key"), d.pop("_checksum")])


@pytest.mark.parametrize("damage", [_npz_truncated, _npz_zero_filled, _npz_missing_key,
                                    _npz_wrong_shape, _npz_wrong_dtype, _npz_changed_value,
                                    _npz_legacy])
def test_bad_study_entry_is_deleted_recomputed_and_named_in_one_warning(study_entry, damage):
    cache, entry, res, renders = study_entry
    damage(entry)
    (again,), notes = _run_study_samples(cache)
    assert len(renders) == 1  # recomputed
    assert len(notes) == 1 and str(entry) in notes[0] and "deleted" in notes[0]
    assert "\n" not in notes[0]
    assert sorted(again) == sorted(res)
    for k, v in res.items():
        np.testing.assert_array_equal(again[k], v)
    (third,), notes = _run_study_samples(cache)  # stored again, read back silently
    assert len(renders) == 1 and notes == []
    assert third["iou"] == res["iou"]


def test_study_entry_of_another_sample_is_not_used(study_entry):
    cache, entry, res, renders = study_entry
    from clnlos.study.dataset import code_version, sample_key

    other = _sample(seed=1)
    target = cache / f"{sample_key(other, _grid(), code_version())}.npz"
    shutil.copyfile(entry, target)  # the right size and format, another sample's result
    _, notes = _run_study_samples(cache, [other])
    assert len(renders) == 1 and len(notes) == 1 and str(target) in notes[0]
    assert "another sample" in notes[0]


def test_study_entry_follows_the_umask(tmp_path, monkeypatch):
    from clnlos.study import dataset

    monkeypatch.setattr(dataset, "render_sample",
                        lambda s, g, d: {k: np.zeros((8, 8), np.float32)
                                         for k in dataset.RESULT_IMAGES}
                        | {k: 0.5 for k in dataset.RESULT_NUMBERS})
    old = os.umask(0o002)
    try:
        dataset.run_samples([_sample()], _grid(), tmp_path)
    finally:
        os.umask(old)
    (entry,) = tmp_path.glob("*.npz")
    assert entry.stat().st_mode & 0o777 == 0o664


def test_result_schema_is_what_render_sample_returns(study_entry):
    from clnlos.study.dataset import RESULT_IMAGES, RESULT_NUMBERS

    _, _, res, _ = study_entry
    assert set(res) == set(RESULT_IMAGES) | set(RESULT_NUMBERS)
