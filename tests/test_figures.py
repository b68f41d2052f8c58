"""The Pillow-drawn reconstruction figure (clnlos.io.raster) and the parallel HDF5 writer
(clnlos.io.deflate)."""

import h5py
import numpy as np
import pytest

from clnlos.io.deflate import DeflatedArray, chunk_shape, write_dataset
from clnlos.io.raster import Panel, RasterFigure, colormap_lut, nice_ticks, tick_label


# ------------------------------------------------------------------ ticks and colours
@pytest.mark.parametrize("lo,hi", [(-0.3, 0.3), (0.0, 1.228), (1.04, 1.2), (0.25, 0.2501),
                                   (-5e-3, 7e-3), (0.0, 2500.0), (3.0, 3.0)])
def test_nice_ticks_lie_in_the_range_on_round_steps(lo, hi):
    ticks, dec = nice_ticks(lo, hi)
    assert len(ticks) >= 1
    if hi > lo:
        assert 2 <= len(ticks) <= 6
        assert ticks.min() >= lo - 1e-12 * (hi - lo) and ticks.max() <= hi + 1e-12 * (hi - lo)
        step = np.diff(ticks)
        np.testing.assert_allclose(step, step[0])
        mantissa = step[0] / 10.0 ** np.floor(np.log10(step[0]))
        assert min(abs(mantissa - m) for m in (1, 2, 2.5, 5, 10)) < 1e-9
        labels = [tick_label(v, dec) for v in ticks]
        assert len(set(labels)) == len(labels)  # enough decimals to tell ticks apart
        assert not any(lab.startswith("-0") and float(lab) == 0 for lab in labels)


def test_colour_maps_match_matplotlib():
    import matplotlib

    x = np.linspace(0, 1, 256)
    for name, tol in (("gray", 0.5), ("viridis", 6.0)):
        ref = matplotlib.colormaps[name](x)[:, :3] * 255
        assert np.abs(colormap_lut(name).astype(float) - ref).max() <= tol, name
    with pytest.raises(ValueError):
        colormap_lut("jet")


def test_raster_figure_draws_images_with_origin_lower(tmp_path):
    """A bright bottom-left quadrant of the data is drawn bottom-left in the panel; NaN is
    white; the PNG is written and has the canvas size."""
    from PIL import Image

    img = np.zeros((40, 40))
    img[:20, :20] = 1.0  # rows 0..19 = low y
    img[30:, 30:] = np.nan
    fig = RasterFigure([Panel(img, (-1, 1, -1, 1), "t", "x (m)", "y (m)", "viridis", "v")],
                       width_px=500, height_px=400)
    path = tmp_path / "f.png"
    fig.savefig(path)
    a = np.asarray(Image.open(path).convert("RGB")).astype(int)
    assert a.shape == (400, 500, 3)
    lut = colormap_lut("viridis")
    low, high = lut[0], lut[255]
    is_low = (a == low).all(axis=2)
    is_high = (a == high).all(axis=2)
    # the image box: the low-value pixels outside the colour bar (left of its column)
    rows, cols = np.nonzero(is_low)
    bar_col = cols.max()
    in_image = is_low & (np.arange(500)[None, :] < bar_col - 20)
    rows, cols = np.nonzero(in_image | (is_high & (np.arange(500)[None, :] < bar_col - 20)))
    top, bottom, left, right = rows.min(), rows.max(), cols.min(), cols.max()
    h, w = bottom - top, right - left
    assert h > 100 and abs(h - w) <= 3  # square (equal aspect)
    assert is_high[bottom - h // 4, left + w // 4]  # bright bottom-left (origin lower)
    assert is_low[top + h // 4, left + w // 4]
    assert (a[top + h // 12, right - w // 12] == 255).all()  # NaN: white


def test_volume_figure_png(tmp_path):
    from clnlos.io.figures import volume_figure
    from clnlos.io.files import save_figure_file

    vol = np.zeros((32, 12, 12), np.float32)
    vol[10, 3:8, 4:6] = 1.0
    ext = {"depth_min_m": 0.0, "depth_max_m": 1.2, "voxel_depth_m": 1.2 / 32,
           "x_min_m": -0.3, "x_max_m": 0.3, "y_min_m": -0.3, "y_max_m": 0.3}
    out = save_figure_file(volume_figure(vol, ext, "test"), tmp_path / "v.png")
    assert out.stat().st_size > 5000


# ------------------------------------------------------------------ parallel deflate
@pytest.mark.parametrize("shape,dtype", [((37, 64, 96), np.float32), ((300, 700), np.float64),
                                         ((2_100_000,), np.int16), ((9, 128, 128), np.complex64),
                                         ((5, 3), np.float32)])
def test_parallel_deflate_reads_back_through_hdf5s_own_filters(tmp_path, shape, dtype):
    """Chunks shuffled and deflated by our threads and written raw decompress, through the
    HDF5 library's gzip + shuffle filters, to the array (last chunk padded, every dtype)."""
    rng = np.random.default_rng(0)
    a = np.round(rng.standard_normal(shape) * 30)  # counts-like: compressible
    if np.dtype(dtype).kind == "c":
        a = a + 1j * np.round(rng.standard_normal(shape))
    a = a.astype(dtype)
    a.reshape(-1)[: a.size // 3] = 0
    path = tmp_path / "d.h5"
    with h5py.File(path, "w") as f:
        write_dataset(f, "x", DeflatedArray(a) if a.ndim > 1 else a)
    with h5py.File(path, "r") as f:
        d = f["x"]
        np.testing.assert_array_equal(d[()], a)
        assert d.compression == "gzip" and d.shuffle
    assert a.nbytes < 1000 or path.stat().st_size < 0.5 * a.nbytes


def test_arrays_that_do_not_deflate_are_stored_uncompressed(tmp_path):
    """Dense float noise (an f-k volume) would shrink by a few per cent for most of the
    write time: it is stored as is, and reads back exactly."""
    a = np.random.default_rng(1).random((40, 64, 64), dtype=np.float32)
    d = DeflatedArray(a)
    assert not d.compressed
    with h5py.File(tmp_path / "r.h5", "w") as f:
        write_dataset(f, "x", d)
    with h5py.File(tmp_path / "r.h5", "r") as f:
        assert f["x"].compression is None
        np.testing.assert_array_equal(f["x"][()], a)


def test_chunks_are_whole_planes_of_about_a_megabyte():
    assert chunk_shape((512, 128, 128), 4) == (16, 128, 128)
    assert chunk_shape((3, 2048, 2048), 4) == (1, 2048, 2048)
    assert chunk_shape((10,), 8) == (10,)
