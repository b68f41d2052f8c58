"""Issue 42 items 5 and 6: a result that holds little or nothing ends with one note line
naming the cause; a flag the method does not read, an input clnlos cannot read as meant and
a typo are one error line (exit 2) that names what to change; Ctrl-C exits 130."""

import contextlib
import io
import json

import h5py
import numpy as np
import pytest
from reference.scene_ref import points_transient

import clnlos.app.commands
from clnlos.app.cli import main
from clnlos.io.files import write_capture
from clnlos.physics.slab import CDT_SLAB


def _run(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, out.getvalue(), err.getvalue()


def _error(args) -> str:
    rc, _, err = _run(args)
    lines = [ln for ln in err.splitlines() if ln.startswith("clnlos: error:")]
    assert rc == 2 and len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


def _notes(err) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("clnlos: note:")]


@pytest.fixture(scope="module")
def point_capture(tmp_path_factory):
    """Two points 0.3-0.4 m behind a plain relay wall: 8 x 8 scan, 160 bins of 32 ps, on a
    floor of 1e-9 of the peak (a simulation's FFT round-off: every bin 'lit')."""
    d = tmp_path_factory.mktemp("pc")
    tau = points_transient([(0.02, 0.0, 0.3), (-0.05, 0.03, 0.4)], [1, 1], 160, 8, 0.3,
                           32e-12)
    tau += 1e-9 * tau.max()
    write_capture(d / "c.h5", tau.astype(np.float32), bin_width_s=32e-12, start_s=0.0,
                  scan_width_m=0.3)
    return d / "c.h5"


@pytest.mark.parametrize("flags,needle", [
    (["--method", "lct", "--depth-min", "0.3"], '--depth-min = 0.3: allowed only with method '
                                                '"iterative"'),
    (["--method", "fk", "--l1-weight", "auto"], "--l1-weight"),
    (["--method", "fk", "--inversion-snr", "100"], 'only with method "lct" or "iterative"'),
    (["--method", "fk", "--iterations", "5"], 'only with method "iterative"'),
    (["--snr-rule", "thinning", "--method", "lct"], '"auto", "gcv" or "reproducibility"'),
])
def test_a_flag_the_method_does_not_read_is_refused(tmp_path, point_capture, flags, needle):
    line = _error(["reconstruct", str(point_capture), "-o", str(tmp_path / "v.h5"), *flags])
    assert needle in line, line
    assert not (tmp_path / "v.h5").exists()


def test_a_toml_key_the_method_does_not_read_is_refused(tmp_path, point_capture):
    cfg = tmp_path / "r.toml"
    cfg.write_text("[inversion]\nl1_weight = 2.0\n")
    line = _error(["reconstruct", str(point_capture), "-o", str(tmp_path / "v.h5"),
                   "--config", str(cfg)])
    assert "inversion.l1_weight" in line and '"lct" does not use it' in line, line
    rc, _, err = _run(["reconstruct", str(point_capture), "-o", str(tmp_path / "v.h5"),
                       "--config", str(cfg), "--method", "iterative", "--iterations", "3"])
    assert rc == 0, err


@pytest.mark.parametrize("flags,needle", [
    (["--max-path", "0.05"], "before the capture's first arrival at 0.595 m"),
    (["--max-path", "0.0001"], "the volume has 1 depth bin(s)"),
    (["--method", "iterative", "--iterations", "5", "--l1-weight", "10"],
     "the volume is all zero: l1_weight = 10"),
    (["--method", "iterative", "--iterations", "5", "--depth-min", "0.5"],
     "depth_min_m = 0.5 m starts the volume behind the capture's first arrival"),
])
def test_results_that_hold_little_say_why(tmp_path, point_capture, flags, needle):
    rc, _, err = _run(["reconstruct", str(point_capture), "-o", str(tmp_path / "v.h5"),
                       *flags])
    assert rc == 0, err
    assert any(needle in n for n in _notes(err)), err


def test_dark_counts_only_are_noted(tmp_path):
    rng = np.random.default_rng(0)
    write_capture(tmp_path / "d.h5", rng.poisson(0.3, (128, 8, 8)).astype(np.float32),
                  bin_width_s=32e-12, start_s=0.0, scan_width_m=0.3)
    rc, _, err = _run(["reconstruct", str(tmp_path / "d.h5"), "-o", str(tmp_path / "v.h5")])
    assert rc == 0 and any("no bin of the capture rises above its background" in n
                           for n in _notes(err)), err


def test_an_all_zero_volume_is_not_drawn_as_a_depth_map(monkeypatch):
    import clnlos.io.figures as figures

    monkeypatch.setattr(figures, "RasterFigure", lambda panels, **kw: panels)
    ext = {"x_min_m": -0.1, "x_max_m": 0.1, "y_min_m": -0.1, "y_max_m": 0.1,
           "depth_min_m": 0.0, "depth_max_m": 1.0, "voxel_depth_m": 0.1}
    titles = [p.title for p in figures.volume_figure(np.zeros((10, 4, 4)), ext)]
    assert "all zero" in titles[0] and "none (the volume is all zero)" in titles[1], titles


def test_capture_files_that_do_not_say_what_they_hold(tmp_path, point_capture):
    with h5py.File(tmp_path / "f99.h5", "w") as f:
        f["transient"] = np.ones((8, 4, 4), np.float32)
        f.attrs.update({"bin_width_s": 1e-11, "scan_width_m": 0.3,
                        "format": "clnlos-capture-99"})
    assert "'clnlos-capture-99'" in _error(["reconstruct", str(tmp_path / "f99.h5"), "-o",
                                            str(tmp_path / "v.h5")])
    with h5py.File(tmp_path / "g.h5", "w") as f:
        f.create_group("transient")["x"] = [1.0]
        f.attrs["bin_width_s"] = 1e-11
    assert "'transient' is an HDF5 group" in _error(["reconstruct", str(tmp_path / "g.h5"),
                                                     "-o", str(tmp_path / "v.h5")])
    np.save(tmp_path / "n.npy", np.ones((8, 4, 4), np.float32))
    line = _error(["reconstruct", str(tmp_path / "n.npy"), "-o", str(tmp_path / "v.h5"),
                   "--bin-width", "1e-11"])
    assert "n.npy does not store the scan width" in line, line
    with h5py.File(point_capture) as f:  # one side of a non-square scan: which one?
        sub = f["transient"][:, :, :6]
    with h5py.File(tmp_path / "ns.h5", "w") as f:
        f["transient"] = sub
        f.attrs.update({"bin_width_s": 32e-12, "scan_width_m": 0.3})
    line = _error(["reconstruct", str(tmp_path / "ns.h5"), "-o", str(tmp_path / "v.h5")])
    assert "8 x 6 [y, x] scan (not square)" in line and "--scan-width" in line, line


def test_scene_and_slab_typos_name_the_field(tmp_path):
    scene = {"scan": {"width_m": 0.3, "points": 8}, "time": {"bin_width_s": 3.2e-11,
                                                            "bins": 64},
             "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1],
                          "translate_m": [0, 0, 0.3]},
                         {"shape": "sphere", "radius_m": 0.05, "translate_m": [0, 0, 0.4],
                          "material": "lambertain"}]}
    (tmp_path / "s.toml").write_text(_toml(scene))
    line = _error(["simulate", str(tmp_path / "s.toml"), "-o", str(tmp_path / "c.h5")])
    assert "objects[1].material = 'lambertain'" in line and "'lambertian'?" in line, line
    line = _error(["reconstruct", str(tmp_path / "c.h5"), "-o", str(tmp_path / "v.h5"),
                   "--mu-a", "5"])
    assert "a slab needs all of --slab-thickness, --mu-a, --mu-s-prime, --n (given: --mu-a)" \
        in line, line


def test_a_grid_too_large_names_the_scene(tmp_path):
    scene = {"scan": {"width_m": 0.3, "points": 4096},
             "time": {"bin_width_s": 3.2e-11, "bins": 256},
             "objects": [{"shape": "rectangle", "size_m": [0.1, 0.1],
                          "translate_m": [0, 0, 0.3]}],
             "slab": {"thickness_m": CDT_SLAB.thickness_m, "mu_a": CDT_SLAB.mu_a,
                      "mu_s_prime": CDT_SLAB.mu_s_prime, "n": CDT_SLAB.n},
             "sampling": {"density_per_m2": 1e3}}
    (tmp_path / "s.toml").write_text(_toml(scene))
    line = _error(["simulate", str(tmp_path / "s.toml"), "-o", str(tmp_path / "c.h5")])
    assert "time.bins = 256 x scan.points = 4096^2" in line, line


def test_brdf_evaluate_of_no_material_and_study_without_real_data(tmp_path):
    for name in ("chrome_gonio.csv", "chrome_test.csv"):
        (tmp_path / name).write_text("")
    line = _error(["brdf", "evaluate", str(tmp_path), "--material", "nothing", "-o",
                   str(tmp_path / "e.csv"), "--models", "five-param"])
    assert "--material = 'nothing'" in line and "chrome" in line, line
    assert not (tmp_path / "e.csv").exists()
    pytest.importorskip("torch")
    for path in (tmp_path / "none", tmp_path / "chrome_test.csv"):
        line = _error(["study", "--real-data", str(path), "-o", str(tmp_path / "s"),
                       "--workers", "1"])
        assert f"--real-data {path}" in line, line


def test_ctrl_c_exits_130(monkeypatch, tmp_path, point_capture):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(clnlos.app.commands, "reconstruct_to_files",
                        lambda *a, **k: interrupted(a))
    rc, _, err = _run(["reconstruct", str(point_capture), "-o", str(tmp_path / "v.h5")])
    assert rc == 130 and "clnlos: error: interrupted" in err, err


def _toml(d: dict) -> str:
    """A small TOML writer for the tables above (no tomli_w here)."""
    lines = []
    for key, table in d.items():
        if isinstance(table, list):
            for t in table:
                lines.append(f"[[{key}]]")
                lines += [f"{k} = {json.dumps(v)}" for k, v in t.items()]
        else:
            lines.append(f"[{key}]")
            lines += [f"{k} = {json.dumps(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"
