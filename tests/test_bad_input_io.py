"""Inputs are never overwritten, implied outputs never replace a file clnlos did not write
(unless --force), temporaries are removed on SIGTERM as on Ctrl-C, and a failed write (a full
disk) is one error line naming the user's path (issue 23, items 2 and 7)."""

import contextlib
import errno
import io
import json
import os
import signal
import stat
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from clnlos.app.cli import main

CSV_HEADER = "theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf\n"
SCENE = ("[scan]\nwidth_m = 0.3\npoints = 4\n[time]\nbin_width_s = 2e-11\nbins = 64\n"
         "start_s = 2e-9\n"
         "[[objects]]\nshape = \"rectangle\"\ntranslate_m = [0.0, 0.0, 0.4]\n")
FOREIGN_PNG = b"\x89PNG\r\n\x1a\n" + b"a photo the user keeps"


def _run(args):
    err = io.StringIO()
    with contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, err.getvalue()


def _one_error_line(rc, err) -> str:
    assert rc == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    errors = [ln for ln in lines if ln.startswith("clnlos: error:")]
    assert len(errors) == 1 and lines[-1] == errors[0], err
    assert not any(ln.startswith(("Traceback", "  ")) for ln in lines), err
    return errors[0]


def _snapshot(paths):
    return {p: (p.read_bytes() if p.is_file() else None) for p in paths}


def _no_temporaries(d: Path):
    left = [p for p in d.rglob("*") if p.name.endswith(".tmp")]
    assert not left, left


def _capture(d: Path) -> Path:
    from clnlos.io.files import write_capture

    return write_capture(d / "c.h5", np.ones((40, 4, 4), np.float32), bin_width_s=2e-11,
                         start_s=0.0, scan_width_m=0.3)


def _measured_dir(d: Path) -> Path:
    m = d / "measured"
    m.mkdir()
    rows = "".join(f"{ti},0,{ts},180,{0.1 + 0.01 * ti / 10:.3f}\n"
                   for ti in (10, 30, 50) for ts in (10, 30, 50))
    (m / "paint_gonio.csv").write_text(CSV_HEADER + rows)
    (m / "paint_test.csv").write_text(CSV_HEADER + "60,0,60,180,0.120\n")
    return m


# ------------------------------------------------------------------ inputs are never outputs
@pytest.mark.parametrize("name", ["paint_gonio.csv", "paint_test.csv"])
def test_brdf_evaluate_refuses_a_csv_of_its_folder_as_output(tmp_path, name):
    m = _measured_dir(tmp_path)
    before = _snapshot(list(m.iterdir()))
    line = _one_error_line(*_run(["brdf", "evaluate", str(m), "-o", str(m / name),
                                  "--models", "lambert"]))
    assert str(m / name) in line and "input" in line, line
    assert _snapshot(list(m.iterdir())) == before
    assert not (m / name).with_suffix(".json").exists()


def _texture(path: Path) -> Path:
    from clnlos.brdf.models import BRDFModel
    from clnlos.brdf.texture import tabulate, write_texture

    write_texture(path, tabulate(BRDFModel("phong", {}), 4, 4, 8))
    return path


@pytest.mark.parametrize("case", ["texture", "retro_csv", "figure_onto_retro_csv"])
def test_simulate_refuses_a_file_the_scene_names_as_output(tmp_path, case):
    """A BRDF texture (``material = "tex.h5"``) or a ``brdf_retro_csv`` is read by the
    simulation: written over (by the capture or by the PNG beside it), the scene would lose
    it. (A mesh must be .obj/.ply, never an output name.)"""
    sub = tmp_path / "scenes"
    sub.mkdir()
    if case == "texture":
        name, out, line = "tex.h5", "scenes/tex.h5", 'material = "tex.h5"'
        read = _texture(sub / name)
    else:
        name = "retro.h5" if case == "retro_csv" else "sim.png"
        out, line = f"scenes/{name}" if case == "retro_csv" else "scenes/sim.h5", \
            f'brdf_retro_csv = "{name}"'
        read = sub / name
        read.write_text("theta_deg,brdf\n0,0.5\n45,0.3\n90,0.1\n")
    scene = sub / "s.toml"
    scene.write_text(SCENE + line + "\n")
    before = _snapshot([scene, read])
    # -o relative to the current folder, the scene's file relative to the scene: the check
    # compares the resolved paths
    with contextlib.chdir(tmp_path):
        err = _one_error_line(*_run(["simulate", str(scene), "-o", out]))
    assert name in err and "input" in err, err
    assert _snapshot([scene, read]) == before
    assert not (tmp_path / out).with_suffix(".png").exists() or case == "figure_onto_retro_csv"
    assert not (sub / "sim.h5").exists()
    _no_temporaries(tmp_path)


def test_demo_refuses_a_file_its_scene_names_as_output(tmp_path):
    """The demo's folder files are outputs: the scene's texture there is refused."""
    import importlib.resources

    text = importlib.resources.files("clnlos").joinpath("data", "demo_scene.toml").read_text()
    out = tmp_path / "demo"
    out.mkdir()
    tex = out / "capture.h5"  # a texture named like the demo's capture, in its folder
    tex.write_bytes(b"texture")
    scene = out / "s.toml"
    scene.write_text(text.replace('material = "lambertian"', 'material = "capture.h5"', 1))
    assert 'material = "capture.h5"' in scene.read_text()
    line = _one_error_line(*_run(["demo", "-o", str(out), "--scene", str(scene), "--force"]))
    assert "capture.h5" in line and "input" in line, line
    assert tex.read_bytes() == b"texture"


# ------------------------------------------------------------------ implied paths
def _implied_case(d: Path, case: str):
    """(arguments, the foreign file in the way) of a command whose output beside or in the
    named output would replace a file the user never named."""
    cap = _capture(d)
    vol = d / "v.h5"
    with h5py.File(vol, "w") as f:
        f["volume"] = np.ones((4, 3, 3), np.float32)
        f.attrs.update({"depth_min_m": 0.0, "depth_max_m": 0.4, "voxel_depth_m": 0.1,
                        "x_min_m": -0.15, "x_max_m": 0.15, "y_min_m": -0.15, "y_max_m": 0.15,
                        "voxel_lateral_m": 0.1})
    scene = d / "s.toml"
    scene.write_text(SCENE)
    m = _measured_dir(d)
    model = d / "m.h5"
    assert main(["brdf", "fit", str(m / "paint_gonio.csv"), "--model", "lambert", "-o",
                 str(model)]) == 0
    if case == "reconstruct":
        return ["reconstruct", str(cap), "-o", str(d / "r.h5")], d / "r.png"
    if case == "simulate":
        return ["simulate", str(scene), "-o", str(d / "sim.h5")], d / "sim.png"
    if case == "plot":
        return ["plot", str(vol)], d / "v.png"
    if case == "brdf_plot":
        return ["brdf", "plot", str(model)], d / "m.png"
    if case == "brdf_evaluate":
        return (["brdf", "evaluate", str(m), "-o", str(d / "t.csv"), "--models", "lambert"],
                d / "t.json")
    folder = d / "out"
    folder.mkdir()
    if case == "demo":
        return ["demo", "-o", str(folder)], folder / "volume_fk.png"
    if case == "study":
        return ["study", "-o", str(folder), "--workers", "1"], folder / "results.json"
    if case == "bench":
        return ["bench", "--tiny", "--only", "diffusion", "-o", str(folder)], \
            folder / "bench.html"
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["reconstruct", "simulate", "plot", "brdf_plot",
                                  "brdf_evaluate", "demo", "study", "bench"])
def test_implied_output_never_replaces_a_foreign_file(tmp_path, case):
    args, foreign = _implied_case(tmp_path, case)
    content = FOREIGN_PNG if foreign.suffix == ".png" else b'{"mine": 1}\n'
    foreign.write_bytes(content)
    files = sorted(p for p in tmp_path.rglob("*") if p.is_file())
    before = _snapshot(files)
    line = _one_error_line(*_run(args))
    assert str(foreign) in line and "--force" in line, line
    assert sorted(p for p in tmp_path.rglob("*") if p.is_file()) == files  # nothing written
    assert _snapshot(files) == before
    _no_temporaries(tmp_path)


def test_force_replaces_a_foreign_figure_and_reruns_replace_their_own(tmp_path):
    from clnlos.io.outputs import written_by_clnlos

    cap = _capture(tmp_path)
    out, png = tmp_path / "r.h5", tmp_path / "r.png"
    png.write_bytes(FOREIGN_PNG)
    assert not written_by_clnlos(png)
    assert main(["reconstruct", str(cap), "-o", str(out), "--force"]) == 0
    assert png.read_bytes() != FOREIGN_PNG and written_by_clnlos(png)
    assert written_by_clnlos(out)
    # a rerun replaces clnlos's own figure without --force, and so does plot beside it
    assert main(["reconstruct", str(cap), "-o", str(out)]) == 0
    assert main(["plot", str(out)]) == 0
    assert written_by_clnlos(png)
    _no_temporaries(tmp_path)


def test_written_by_clnlos_recognises_only_its_own_markers(tmp_path):
    from clnlos.io.outputs import HTML_GENERATOR, stamp, written_by_clnlos

    own_json, other_json = tmp_path / "a.json", tmp_path / "b.json"
    own_json.write_text(json.dumps(stamp({"x": 1})))
    other_json.write_text(json.dumps({"x": 1, "clnlos_version": "0"}))  # not its first key
    own_html, other_html = tmp_path / "a.html", tmp_path / "b.html"
    own_html.write_text(f"<!doctype html><html><head>{HTML_GENERATOR}</head></html>")
    other_html.write_text("<!doctype html><html><head></head><body>clnlos</body></html>")
    plain_h5 = tmp_path / "p.h5"
    with h5py.File(plain_h5, "w") as f:
        f["volume"] = np.ones(3)
    assert written_by_clnlos(own_json) and written_by_clnlos(own_html)
    assert not written_by_clnlos(other_json) and not written_by_clnlos(other_html)
    assert not written_by_clnlos(plain_h5) and written_by_clnlos(_capture(tmp_path))
    assert not written_by_clnlos(tmp_path / "missing.png")


# ------------------------------------------------------------------ SIGTERM
CHILD_RECONSTRUCT = """
import sys, time
import clnlos.app.reconstruct
from clnlos.app.cli import main

real = clnlos.app.reconstruct.write_h5_file

def slow_write(path, datasets, attrs):
    real(path, datasets, attrs)           # the temporary is complete on disk ...
    print("writing", path, flush=True)    # ... and the run is stopped before the rename
    time.sleep(60)

clnlos.app.reconstruct.write_h5_file = slow_write
sys.exit(main(sys.argv[1:]))
"""


def test_sigterm_during_a_write_leaves_no_temporary(tmp_path):
    cap = _capture(tmp_path)
    out = tmp_path / "rec.h5"
    p = subprocess.Popen([sys.executable, "-c", CHILD_RECONSTRUCT, "reconstruct", str(cap),
                          "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         text=True)
    try:
        line = p.stdout.readline()
        assert line.startswith("writing"), (line, p.stderr.read() if p.poll() else "")
        tmp = Path(line.split(" ", 1)[1].strip())
        assert tmp.exists() and tmp.name.endswith(".tmp")
        p.send_signal(signal.SIGTERM)
        rc = p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    err = p.stderr.read()
    assert rc == 128 + signal.SIGTERM, err
    lines = [ln for ln in err.strip().splitlines() if ln.startswith("clnlos:")]
    assert lines[-1] == "clnlos: error: terminated (SIGTERM)", err
    assert "Traceback" not in err
    assert not out.exists() and not out.with_suffix(".png").exists()
    _no_temporaries(tmp_path)


CHILD_WORKER = """
import sys, time
from pathlib import Path
from clnlos.io.outputs import install_sigterm_cleanup, write_group

install_sigterm_cleanup(chain=True)  # a worker process: remove, then die as before
with write_group([Path(sys.argv[1])]) as (tmp,):
    tmp.write_bytes(b"x" * 4096)
    print(tmp, flush=True)
    time.sleep(60)
"""


def test_sigterm_in_a_worker_removes_its_temporaries_and_still_ends_it(tmp_path):
    """The chained handler (installed in Dask workers) removes what was being written and
    then ends the process as SIGTERM did before."""
    p = subprocess.Popen([sys.executable, "-c", CHILD_WORKER, str(tmp_path / "e.npz")],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        tmp = Path(p.stdout.readline().strip())
        assert tmp.exists(), p.stderr.read() if p.poll() else tmp
        p.send_signal(signal.SIGTERM)
        rc = p.wait(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert rc == -signal.SIGTERM
    assert not (tmp_path / "e.npz").exists()
    _no_temporaries(tmp_path)


def test_live_temporaries_are_removed_by_the_exit_backstop(tmp_path):
    from clnlos.io import outputs as outputs

    cm = outputs.write_group([tmp_path / "a.h5", tmp_path / "a.png"])
    tmps = cm.__enter__()
    for t in tmps:
        t.write_bytes(b"partial")
    assert all(t in outputs._LIVE for t in tmps)
    outputs.remove_live_temporaries()  # what atexit runs
    assert not any(t.exists() for t in tmps) and not outputs._LIVE
    assert not cm.__exit__(KeyboardInterrupt, KeyboardInterrupt(), None)  # not swallowed
    _no_temporaries(tmp_path)
    assert not (tmp_path / "a.h5").exists()


def test_main_restores_the_sigterm_handler(tmp_path):
    """In-process callers (tests, notebooks) get their handler back."""
    before = signal.getsignal(signal.SIGTERM)
    assert main(["plot", str(tmp_path / "missing.h5")]) == 2
    assert signal.getsignal(signal.SIGTERM) is before


# ------------------------------------------------------------------ full disk
def _full_disk(message_of):
    """A write_h5_file that leaves a partial temporary and raises what a full disk raises."""
    def write(path, datasets, attrs):
        Path(path).write_bytes(b"partial")
        raise message_of(str(path))
    return write


@pytest.mark.parametrize("kind", ["errno", "h5py_text"])
def test_full_disk_names_the_users_path_in_one_line(tmp_path, monkeypatch, kind):
    import clnlos.app.reconstruct

    make = {"errno": lambda tmp: OSError(errno.ENOSPC, "No space left on device", tmp),
            "h5py_text": lambda tmp: OSError(
                f"Can't write data (file write failed: name = '{tmp}', errno = 28, error "
                "message = 'No space left on device')\n  (while closing the file)")}[kind]
    cap = _capture(tmp_path)
    monkeypatch.setattr(clnlos.app.reconstruct, "write_h5_file", _full_disk(make))
    out = tmp_path / "rec.h5"
    line = _one_error_line(*_run(["reconstruct", str(cap), "-o", str(out)]))
    assert line.startswith(f"clnlos: error: cannot write {out}: "), line
    assert "No space left on device" in line and ".tmp" not in line, line
    assert not out.exists() and not out.with_suffix(".png").exists()
    _no_temporaries(tmp_path)


def test_bench_report_is_written_atomically_and_a_full_disk_names_it(tmp_path, monkeypatch):
    import clnlos.bench

    out = tmp_path / "b"
    assert main(["bench", "--tiny", "--only", "diffusion", "-o", str(out)]) == 0
    before = _snapshot([out / "bench.json", out / "bench.html"])

    def full(path, *a, **kw):
        Path(path).write_text("<!doctype html><html><head>")  # half a page ...
        raise OSError(errno.ENOSPC, "No space left on device")  # ... write(): no filename

    monkeypatch.setattr(clnlos.bench, "write_html", full)
    line = _one_error_line(*_run(["bench", "--tiny", "--only", "diffusion", "-o", str(out)]))
    assert str(out / "bench.html") in line and "No space left on device" in line, line
    assert _snapshot([out / "bench.json", out / "bench.html"]) == before  # the old pair
    _no_temporaries(tmp_path)


def test_bench_rows_are_written_together_with_the_umask_mode(tmp_path):
    from clnlos.bench.harness import read_rows, write_rows

    old = os.umask(0o022)
    try:
        paths = write_rows([{"kernel": "k", "median_s": 1.0}], tmp_path / "rows", "bench_k")
    finally:
        os.umask(old)
    for p in paths:
        assert stat.S_IMODE(p.stat().st_mode) == 0o644, p
    assert read_rows(paths[1]) == [{"kernel": "k", "median_s": 1.0}]
    assert json.loads(paths[1].read_text())["provenance"]["clnlos_version"]
    assert paths[0].read_text().splitlines() == ["kernel,median_s", "k,1.0"]
    _no_temporaries(tmp_path)
