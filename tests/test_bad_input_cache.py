"""Issue 23, items 3 and 6: caches verified on read; resources bounded before reading or
allocating."""

import os
import shutil
import warnings
from dataclasses import replace

import numpy as np
import pytest
from reference.scene_ref import points_transient

from clnlos.io.formats.mat import lct_rect_data
from clnlos.config import ReconstructionConfig
from clnlos.inverse.pipeline import reconstruct
from clnlos.io.capture import Capture
from clnlos.physics.slab import CDT_SLAB
from clnlos.runtime.caches import PIPELINES
from clnlos.runtime.spectrum_cache import HEADER, SUFFIX

SHAPE_T, WIDTH, DT = 96, 0.5, 48e-12  # 4.6 ns: every arrival inside (no tail fill)


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


def _payload_blocks_swapped(path, other):
    """Two 4 KiB blocks of the spectrum trade places: every byte value still there."""
    b = bytearray(path.read_bytes())
    one, two = HEADER.size, HEADER.size + 5 * 4096
    b[one:one + 4096], b[two:two + 4096] = b[two:two + 4096], b[one:one + 4096]
    path.write_bytes(bytes(b))


def _truncated(path, other):
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def _other_entry(path, other):
    shutil.copyfile(other, path)


def _headerless(path, other):
    """An entry as the previous clnlos wrote it (the raw spectrum, no header)."""
    path.write_bytes(path.read_bytes()[HEADER.size:])


@pytest.mark.parametrize("damage", [_zero_filled, _payload_bit_flipped, _payload_scaled,
                                    _payload_blocks_swapped, _truncated, _other_entry,
                                    _headerless])
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
    from clnlos.study.file.spec import StudyGrid

    return replace(StudyGrid(), points=8, bin_width_s=64e-12, iterations=5,
                   density_per_m2=1e4)


def _sample(seed=0):
    from clnlos.study.plan.scenes import dataset_samples

    return {**dataset_samples(1, [{"material": "standard white plate"}], seed)[0],
            "slab_thickness_m": 0.0}


@pytest.fixture()
def study_entry(tmp_path, monkeypatch):
    """(cache folder, the entry of one tiny sample, its result, a counter of renders)."""
    from clnlos.study.samples import render as dataset

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
    from clnlos.study.samples.render import run_samples

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
    from clnlos.study.samples.render import RESULT_TIMES

    cache, entry, res, renders = study_entry
    damage(entry)
    (again,), notes = _run_study_samples(cache)
    assert len(renders) == 1  # recomputed
    assert len(notes) == 1 and str(entry) in notes[0] and "deleted" in notes[0]
    assert "\n" not in notes[0]
    assert sorted(again) == sorted(res)
    for k, v in res.items():
        if k not in RESULT_TIMES:  # the render's own seconds
            np.testing.assert_array_equal(again[k], v)
    (third,), notes = _run_study_samples(cache)  # stored again, read back silently
    assert len(renders) == 1 and notes == []
    assert third["iou"] == res["iou"]


def test_study_entry_of_another_sample_is_not_used(study_entry):
    cache, entry, res, renders = study_entry
    from clnlos.study.samples.render import code_version, sample_key

    other = _sample(seed=1)
    target = cache / f"{sample_key(other, _grid(), code_version())}.npz"
    shutil.copyfile(entry, target)  # the right size and format, another sample's result
    _, notes = _run_study_samples(cache, [other])
    assert len(renders) == 1 and len(notes) == 1 and str(target) in notes[0]
    assert "another sample" in notes[0]


def test_study_entry_follows_the_umask(tmp_path, monkeypatch):
    from clnlos.study.samples import render as dataset

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
    from clnlos.study.samples.render import RESULT_IMAGES, RESULT_NUMBERS, RESULT_SLICES

    _, _, res, _ = study_entry
    assert set(res) == set(RESULT_IMAGES) | set(RESULT_SLICES) | set(RESULT_NUMBERS)


# ------------------------------------------------------------------ resources
NT, NY, NX = 64, 6, 8


def _one_error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("clnlos: error:"), err
    return err[0]


def _write_capture(path, kind):
    """A small capture [NT, NY, NX] in one of the formats clnlos reads."""
    import h5py
    import scipy.io

    from clnlos.io.files import write_capture
    from clnlos.io.formats.tal import write_tal

    tau = np.random.default_rng(0).random((NT, NY, NX)).astype(np.float32)
    if kind == "clnlos":
        write_capture(path, tau, bin_width_s=DT, start_s=0.0, scan_width_m=WIDTH)
    elif kind == "tal":
        write_tal(path, tau, bin_width_s=DT, start_s=0.0, scan_width_m=WIDTH)
    elif kind == "npy":
        np.save(path, tau)
    elif kind == "mat5-cdt":
        scipy.io.savemat(path, {"meas": tau[:, ::-1, :]})
    elif kind == "mat5-lct":
        scipy.io.savemat(path, {"rect_data": lct_rect_data(tau), "width": 0.2,
                                "bin_resolution": DT})
    else:  # MATLAB v7.3, CDT layout
        with h5py.File(path, "w") as f:
            f["meas"] = np.transpose(tau[:, ::-1, :])
    return path


FORMATS = ["clnlos", "tal", "npy", "mat5-cdt", "mat5-lct", "mat73"]
SUFFIXES = {"clnlos": ".h5", "tal": ".hdf5", "npy": ".npy"}


def _never_read(monkeypatch):
    """Make every reader's validation (which sees the data) fail the test."""
    from clnlos.io.formats import clnlos_h5, mat, npy_array, tal

    def boom(*a, **k):
        raise AssertionError("the data were read")

    for mod in (clnlos_h5, mat, npy_array, tal):
        monkeypatch.setattr(mod, "validate_transient", boom)


@pytest.mark.parametrize("kind", FORMATS)
def test_capture_size_is_checked_against_host_memory_before_reading(tmp_path, monkeypatch,
                                                                    kind):
    from clnlos.errors import MemoryLimitError
    from clnlos.io.formats import read_capture
    from clnlos.runtime import limits

    path = _write_capture(tmp_path / f"c{SUFFIXES.get(kind, '.mat')}", kind)
    seen = []
    with limits.capture_use(lambda *a: seen.append(a)):
        read_capture(path)  # fits: read as before, the declared size seen first
    ((shape, bin_width, start),) = seen
    assert shape[0] == NT and sorted(shape[1:]) == sorted((NY, NX))  # [t, y, x]
    assert start == 0.0
    assert bin_width is None if kind in ("npy", "mat5-lct") else bin_width > 0
    monkeypatch.setattr(limits, "host_available_bytes", lambda: 1000)
    _never_read(monkeypatch)
    with pytest.raises(MemoryLimitError) as exc:
        read_capture(path)
    msg = str(exc.value)
    assert str(path) in msg and "of host memory" in msg and "1000 B is available" in msg
    assert f"{NT} x" in msg


def test_capture_declaring_a_huge_transient_is_refused_before_it_is_read(tmp_path,
                                                                         monkeypatch, capsys):
    """An 8 KB HDF5 declaring a 8192 x 4096 x 4096 transient (its chunks never written; 512
    GiB: more than any host this runs on, so the old code's read fails at once too)."""
    import h5py

    from clnlos.app.cli import main

    path = tmp_path / "huge.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("transient", shape=(8192, 4096, 4096), dtype="f4",
                         chunks=(64, 64, 64), compression="gzip")
        f.attrs.update(bin_width_s=DT, start_s=0.0, scan_width_m=WIDTH)
    assert path.stat().st_size < 8192
    _never_read(monkeypatch)
    assert main(["reconstruct", str(path), "-o", str(tmp_path / "r.h5")]) == 2
    err = _one_error_line(capsys)
    assert str(path) in err and "8192 x 4096 x 4096" in err and " needs " in err
    assert "memory" in err or "per buffer" in err
    assert not (tmp_path / "r.h5").exists()


class _SmallDevice:
    name = "small test device"
    max_mem_alloc_size = 64 * 2**20
    global_mem_size = 256 * 2**20


class _SmallQueue:
    device = _SmallDevice()


def test_reconstruction_buffers_are_checked_against_the_device_before_reading(tmp_path,
                                                                              monkeypatch):
    """The pipeline's spectrum of a 512 x 128 x 128 capture (2 x 1024 x 256 x 129 complex,
    258 MiB) does not fit a 64 MiB allocation: refused with the declared shape; with
    --bins 64 it does (33 MiB)."""
    from clnlos.app.commands import _pipeline_fits
    from clnlos.errors import DeviceMemoryError
    from clnlos.inverse.preprocessing import device_bytes_needed
    from clnlos.runtime.limits import capture_use

    cfg = ReconstructionConfig(method="lct").validate()
    total, largest = device_bytes_needed((512, 128, 128), bin_width_s=DT, start_s=0.0,
                                         config=cfg)
    assert largest == 2 * 512 * 2 * 128 * 129 * 8 and total > 2 * largest
    check = _pipeline_fits("c.h5", cfg, _SmallQueue(), np.float32)
    with pytest.raises(DeviceMemoryError, match="512 x 128 x 128.*small test device"):
        check((512, 128, 128), DT, 0.0)
    _pipeline_fits("c.h5", replace(cfg, bins=64), _SmallQueue(), np.float32)(
        (512, 128, 128), DT, 0.0)
    # through a reader: refused before the data are read
    path = _write_capture(tmp_path / "c.h5", "clnlos")
    _never_read(monkeypatch)
    tiny = type("Tiny", (), {"device": type("D", (), {"name": "tiny",
                                                      "max_mem_alloc_size": 4096,
                                                      "global_mem_size": 8192})()})()
    from clnlos.io.formats import read_capture

    with capture_use(_pipeline_fits(path, cfg, tiny, np.float32)):
        with pytest.raises(DeviceMemoryError, match=f"{NT} x {NY} x {NX}"):
            read_capture(path)


def test_legitimate_large_sizes_pass_the_checks(queue):
    """A 512 x 128 x 128 capture on the test device, the demo scene and the study's
    scenes, textures of 64 and 128 nodes: nothing refused."""
    from importlib import resources

    from clnlos.app.commands import _pipeline_fits
    from clnlos.forward.sampling import check_scene_size
    from clnlos.forward.scene import Scene
    from clnlos.runtime.limits import declared_capture
    from clnlos.study.file.spec import StudyGrid
    from clnlos.study.plan.scenes import dataset_samples, scene_dict

    declared_capture("c.h5", (512, 128, 128), 4)
    cfg = ReconstructionConfig(method="iterative").validate()
    _pipeline_fits("c.h5", cfg, queue, np.float32)((512, 128, 128), 16e-12, 0.0)
    demo = resources.files("clnlos.data").joinpath("demo_scene.toml")
    check_scene_size(Scene.from_toml(demo), queue.device, np.float32)
    for s in dataset_samples(8, [{"material": "standard white plate"}], 0):
        check_scene_size(Scene.from_dict(scene_dict(s, StudyGrid())), queue.device,
                         np.float32)


SCENE = """[scan]
width_m = 0.3
points = 4
[time]
bin_width_s = 32e-12
bins = 64
[[objects]]
translate_m = [0.0, 0.0, 0.5]
"""


def test_scene_surface_elements_are_bounded_before_sampling(tmp_path, monkeypatch, capsys):
    """10 m x 10 m at 1e10 per m^2: 1e12 elements, refused before any is built."""
    from clnlos.app.cli import main
    from clnlos.forward import sampling as forward

    def boom(*a, **k):
        raise AssertionError("sampled")

    monkeypatch.setattr(forward, "sample_object", boom)
    scene = tmp_path / "s.toml"
    scene.write_text(SCENE + 'shape = "rectangle"\nsize_m = [10.0, 10.0]\n'
                     "[sampling]\ndensity_per_m2 = 1e10\n")
    assert main(["simulate", str(scene), "-o", str(tmp_path / "c.h5")]) == 2
    err = _one_error_line(capsys)
    assert "sampling.density_per_m2 = 1e+10" in err and "1e+12 surface elements" in err
    assert " needs " in err and "memory" in err
    assert not (tmp_path / "c.h5").exists()


@pytest.mark.parametrize("shape,count", [
    ('shape = "rectangle"\nsize_m = [0.1, 0.2]', 100 * 200),
    ('shape = "sphere"\nradius_m = 0.1', round(4 * np.pi * 0.01 * 1e6)),
    ('shape = "letters"\ntext = "UT"\nheight_m = 0.15\nstroke_m = 0.04', None)])
def test_element_count_bounds_what_sampling_builds(tmp_path, shape, count):
    from clnlos.forward.sampling import element_count, sample_object
    from clnlos.forward.scene import Scene

    scene = tmp_path / "s.toml"
    scene.write_text(SCENE + shape + "\n[sampling]\ndensity_per_m2 = 1e6\n")
    sc = Scene.from_toml(scene)
    n = element_count(sc.objects[0], sc.density_per_m2, sc.base_dir)
    built = len(sample_object(sc.objects[0], sc.density_per_m2, sc.base_dir))
    if count is not None:
        assert n == pytest.approx(count, rel=1e-3)
    assert built <= n <= 2.5 * built  # letters: the cells of their box


def test_scene_strings_are_bounded_and_not_echoed(tmp_path, capsys):
    from clnlos.app.cli import main

    scene = tmp_path / "s.toml"
    # sizes the old code survives: 300 letters at a low density, a 1 MB file name
    scene.write_text(SCENE + f'shape = "letters"\ntext = "{"A" * 300}"\n'
                     "[sampling]\ndensity_per_m2 = 1e3\n")
    assert main(["simulate", str(scene), "-o", str(tmp_path / "c.h5")]) == 2
    err = _one_error_line(capsys)
    assert "objects[0].text" in err and "at most 256 characters" in err
    assert "(300 characters)" in err and len(err) < 300
    scene.write_text(SCENE + f'shape = "sphere"\nmaterial = "{"m" * 1_000_000}.h5"\n')
    assert main(["simulate", str(scene), "-o", str(tmp_path / "c.h5")]) == 2
    err = _one_error_line(capsys)
    assert "objects[0].material" in err and "4096 characters" in err
    assert "(1000003 characters)" in err and len(err) < 300


def _phong_model(tmp_path):
    from clnlos.brdf.models import BRDFModel
    from clnlos.brdf.store import save_model

    path = tmp_path / "m.h5"
    save_model(path, BRDFModel("phong", {"kd": 0.2, "ks": 0.8, "shininess": 40.0}), {}, {})
    return path


def test_texture_resolution_is_bounded_before_allocating(tmp_path, capsys):
    from clnlos.app.cli import main

    model = _phong_model(tmp_path)
    out = tmp_path / "t.h5"
    assert main(["brdf", "texture", str(model), "-o", str(out), "--resolution", "4096"]) == 2
    err = _one_error_line(capsys)
    assert "4096 x 4096 x 4096" in err and "--resolution" in err
    assert " needs 512.5 GiB of host memory; " in err and "available" in err
    assert not out.exists()


def test_texture_is_tabulated_in_chunks_like_the_whole_grid():
    """A grid of three evaluation chunks gives the values of one evaluation of the grid
    (at the nodes the point samples resolve: the others are averaged, tests/test_brdf.py)."""
    from clnlos.brdf.models import BRDFModel
    from clnlos.brdf.texture import TABULATE_CHUNK, grow, sharp_nodes, tabulate

    m = BRDFModel("phong", {"kd": 0.2, "ks": 0.8, "shininess": 40.0})
    n, nd = 96, 64
    assert 2 * TABULATE_CHUNK < n * n * nd <= 3 * TABULATE_CHUNK
    th = np.minimum(np.linspace(0, np.pi / 2, n), np.pi / 2 - 1e-6)
    TI, TS, DP = np.meshgrid(th, th, np.linspace(0, np.pi, nd), indexing="ij")
    whole = np.maximum(m(TI.ravel(), 0 * TI.ravel(), TS.ravel(), DP.ravel()), 0)
    whole = whole.reshape(TI.shape).astype(np.float32)
    point = ~grow(sharp_nodes(whole))
    assert point.mean() > 0.9
    np.testing.assert_array_equal(tabulate(m, n, nd, 8).texture[point], whole[point])


def test_texture_file_declaring_a_huge_grid_is_refused_before_reading(tmp_path):
    import h5py

    from clnlos.brdf.texture import FORMAT, VERSION, read_texture
    from clnlos.errors import MemoryLimitError

    path = tmp_path / "t.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("texture", shape=(8192, 8192, 8192), dtype="f4",
                         chunks=(64, 64, 64), compression="gzip")
        f["retro"] = np.ones(16, np.float32)
        f.attrs.update(format=FORMAT, version=VERSION)
    with pytest.raises(MemoryLimitError, match="8192 x 8192 x 8192.*host memory"):
        read_texture(path)


def test_host_memory_comes_from_meminfo_capped_by_the_cgroup(tmp_path, monkeypatch):
    from clnlos.runtime import limits

    info = tmp_path / "meminfo"
    info.write_text("MemTotal:       24000000 kB\nMemAvailable:    2000000 kB\n")
    cap = tmp_path / "memory.max"
    monkeypatch.setattr(limits, "MEMINFO", str(info))
    monkeypatch.setattr(limits, "CGROUP_LIMITS", (str(cap),))
    cap.write_text("max\n")
    assert limits.host_available_bytes() == 2000000 * 1024
    cap.write_text(f"{2**30}\n")
    assert limits.host_available_bytes() == 2**30
    with pytest.raises(limits.MemoryLimitError, match="2.0 GiB of host memory; 1.0 GiB"):
        limits.check_memory("a step", host=2 * 2**30)
    limits.check_memory("a step", host=2**29)


@pytest.mark.parametrize("name,suffix", [("transient", ".h5"), ("meas", ".mat"),
                                         ("rect_data", ".mat")])
def test_a_group_where_the_dataset_belongs_is_still_one_line(tmp_path, capsys, name, suffix):
    import h5py

    from clnlos.app.cli import main

    path = tmp_path / f"g{suffix}"
    with h5py.File(path, "w") as f:
        f.create_group(name)
        f.attrs["bin_width_s"] = DT
    assert main(["reconstruct", str(path), "-o", str(tmp_path / "r.h5"),
                 "--scan-width", "0.3"]) == 2
    assert str(path) in _one_error_line(capsys)
