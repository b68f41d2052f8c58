"""The public Python API (clnlos.read_capture, simulate, reconstruct, plot_volume, study.run)
is the CLI's code path: the same capture gives the identical volume either way, with the
slab the capture recorded deconvolved."""

from __future__ import annotations

import matplotlib
import numpy as np
import pytest

import clnlos
from clnlos.app.cli import main
from clnlos.errors import ParameterError
from clnlos.io.files import read_volume
from helpers import SMALL_SCENE as SCENE

matplotlib.use("Agg")



@pytest.fixture(scope="module")
def scene_capture(tmp_path_factory, queue):
    """(scene path, capture file written by ``clnlos simulate``): 8 x 8 x 160, photon
    counts, behind the CDT slab (recorded in the file)."""
    d = tmp_path_factory.mktemp("api")
    scene = d / "scene.toml"
    scene.write_text(SCENE)
    cap = d / "capture.h5"
    assert main(["simulate", str(scene), "-o", str(cap), "--device", "pocl"]) == 0
    return scene, cap


@pytest.mark.parametrize("method,flags,options", [
    ("lct", [], {}),
    ("iterative", ["--iterations", "15"], {"iterations": 15}),
])
def test_cli_and_api_give_the_identical_volume(scene_capture, tmp_path, queue, method, flags,
                                               options, capsys):
    scene, cap = scene_capture
    out = tmp_path / "v.h5"
    assert main(["reconstruct", str(cap), "-o", str(out), "--method", method, "--device",
                 "pocl", *flags]) == 0
    assert "using the slab recorded in the capture" in capsys.readouterr().err
    cli_volume, cli_extents, attrs = read_volume(out)

    rec = clnlos.reconstruct(clnlos.read_capture(cap), method=method, device=queue, **options)
    assert "deconvolve" in " ".join(rec.stages)
    assert rec.notes[0].startswith("using the slab recorded in the capture")
    np.testing.assert_array_equal(rec.volume.astype(np.float32), cli_volume)
    assert {k: rec.extents[k] for k in cli_extents} == pytest.approx(cli_extents, rel=1e-12)

    # a path reads the same capture; no_slab gives another volume (the slab did act)
    again = clnlos.reconstruct(cap, method=method, device=queue, **options)
    np.testing.assert_array_equal(again.volume, rec.volume)
    plain = clnlos.reconstruct(cap, method=method, device=queue, no_slab=True, **options)
    assert not np.array_equal(plain.volume, rec.volume)


def test_in_memory_simulation_is_the_file(scene_capture, queue):
    """clnlos.simulate(scene) is the capture ``clnlos simulate`` writes (same transient,
    geometry and recorded slab), so its reconstruction is the CLI's too."""
    scene, cap = scene_capture
    mem = clnlos.simulate(scene, device=queue)
    disk = clnlos.read_capture(cap)
    np.testing.assert_array_equal(mem.transient, disk.transient)
    assert (mem.bin_width_s, mem.start_s, mem.scan_width_m) == (
        disk.bin_width_s, disk.start_s, disk.scan_width_m)
    assert mem.recorded_slab() == disk.recorded_slab()
    a = clnlos.reconstruct(mem, method="fk", device=queue)
    b = clnlos.reconstruct(disk, method="fk", device=queue)
    np.testing.assert_array_equal(a.volume, b.volume)


def test_options_are_config_fields_and_checked(scene_capture, queue):
    _, cap = scene_capture
    with pytest.raises(ParameterError, match="snr_rle"):
        clnlos.reconstruct(cap, snr_rle="gcv", device=queue)
    with pytest.raises(ParameterError, match="iterations"):  # lct does not read it
        clnlos.reconstruct(cap, method="lct", iterations=5, device=queue)
    cfg = clnlos.reconstruction_config({"inversion": {"method": "fk"}}, snr=1e5)
    assert (cfg.method, cfg.snr, cfg.slab) == ("fk", 1e5, None)


@pytest.mark.parametrize("view", ["xy", "xz", "yz", "depth"])
def test_plot_volume_returns_labelled_axes(scene_capture, queue, view):
    _, cap = scene_capture
    rec = clnlos.reconstruct(cap, method="lct", device=queue, snr=1e5, inversion_snr=1e3)
    ax = clnlos.plot_volume(rec, view=view)
    assert isinstance(ax, matplotlib.axes.Axes)
    assert "(m)" in ax.get_xlabel() and "(m)" in ax.get_ylabel()
    image = ax.get_images()[0]
    left, right, _, _ = image.get_extent()
    assert (left, right) == pytest.approx((rec.extents["x_min_m"], rec.extents["x_max_m"])
                                          if view != "yz" else
                                          (rec.extents["y_min_m"], rec.extents["y_max_m"]))
    assert len(ax.figure.axes) == 2  # the image and its colour bar
    fig, axes = matplotlib.pyplot.subplots(1, 2)
    assert clnlos.plot_volume(rec.volume, axes[1], view=view) is axes[1]  # into subplots
    matplotlib.pyplot.close("all")


def test_study_run_is_the_function_and_the_module_stays_importable(monkeypatch, tmp_path):
    """clnlos.study(...) and clnlos.study.run(...) run the study file `clnlos study` runs
    through the same run_study (recorded here instead of run: the study itself is
    tests/test_study.py's); the command line's overrides reach it."""
    import clnlos.study as study_pkg
    from clnlos.study.file.spec import load_study

    calls = []
    monkeypatch.setattr(study_pkg, "run_study",
                        lambda out, study, **kw: calls.append((out, study, kw)) or {"ok": 1})
    assert clnlos.study.run(tmp_path / "s") == {"ok": 1}
    out, study, kw = calls[-1]
    assert out == tmp_path / "s" and study == load_study("quick")
    assert kw == {"workers": None, "scheduler": None, "device": None, "labels": None}
    assert clnlos.study("full", tmp_path, method="lct", labels="fft", n_dataset=3,
                        transport="confocal", workers=1) == {"ok": 1}
    _, study, kw = calls[-1]
    assert (study.name, study.grid.method, study.methods, study.classifier.labels,
            study.classifier.extras, study.transport) == (
        "full", "lct", ("lct",), "fft", 3, None) and kw["workers"] == 1
    with pytest.warns(UserWarning, match="no real CDT capture"):
        clnlos.study.run(tmp_path, real_data=tmp_path)  # a folder without cdt/*.mat
    assert calls[-1][1].real_data is None
