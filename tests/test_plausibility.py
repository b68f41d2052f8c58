"""Units that cannot be (issue 58, item 3): one plausibility rule (clnlos.checks.PLAUSIBLE)
for every reader, flag, config key, keyword and scene key. A value no NLOS capture can have
ends in one ``clnlos: error:`` line naming it and the likely unit slip, exit 2, before any
work (no pipeline, no forward model, no output); ``--allow-implausible`` accepts it with a
warning line; a value merely unusual keeps a warning (tests/test_new_user.py)."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest
import scipy.io

import clnlos
from clnlos.app.cli import main
from clnlos.checks import PLAUSIBLE, plausibility
from clnlos.errors import ImplausibleValueError
from clnlos.io.files import write_capture
from clnlos.io.formats.mat import lct_rect_data
from clnlos.io.formats.tal import write_tal

NT, N = 300, 4


def _tau(nt: int = NT) -> np.ndarray:
    tau = np.zeros((nt, N, N), np.float32)
    tau[nt // 2] = 1.0
    return tau


@pytest.fixture
def no_work(monkeypatch):
    """Building a reconstruction pipeline or a forward model fails the test: the checks must
    come first."""
    from clnlos import api
    from clnlos.inverse import pipeline

    def boom(*a, **k):
        raise AssertionError("work started before the plausibility check")

    monkeypatch.setattr(pipeline.ReconstructionPipeline, "__init__", boom)
    monkeypatch.setattr(api, "ForwardModel", boom)


def _run(args):
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(args)
    return rc, err.getvalue()


def _error_line(rc, err) -> str:
    assert rc == 2, err
    lines = [ln for ln in err.strip().splitlines() if not ln.startswith("clnlos: note:")]
    assert len(lines) == 1 and lines[0].startswith("clnlos: error:"), err
    assert "--allow-implausible" in lines[0] and lines[0].endswith("accepts it"), lines[0]
    return lines[0]


def _files(tmp_path) -> dict:
    """A plausible capture, and one file per reader stating an impossible value."""
    tau = _tau()
    write_capture(tmp_path / "ok.h5", tau, bin_width_s=16e-12, start_s=0.0, scan_width_m=0.3)
    write_capture(tmp_path / "wide.h5", tau, bin_width_s=16e-12, start_s=0.0,
                  scan_width_m=200.0)
    write_tal(tmp_path / "ns.hdf5", tau, bin_width_s=32e-9, start_s=0.0, scan_width_m=0.3)
    scipy.io.savemat(tmp_path / "lct.mat", {"rect_data": lct_rect_data(_tau(2048)),
                                             "width": 0.15, "bin_resolution": 4e-9})
    np.save(tmp_path / "c.npy", tau)
    return {"ok": tmp_path / "ok.h5", "wide": tmp_path / "wide.h5",
            "tal": tmp_path / "ns.hdf5", "lct": tmp_path / "lct.mat", "npy": tmp_path / "c.npy"}


@pytest.mark.parametrize("case,needle", [
    ("--bin-width", "--bin-width 3.2e-08: a bin of 32 ns, beyond the 10 ns any NLOS capture "
                    "can have (a time in ns typed for ps: 32 ps?)"),
    ("--scan-width", "--scan-width 200: a scan 200 m wide, beyond the 20 m any NLOS capture "
                     "can have (a length in cm typed as m: 2 m?)"),
    ("[capture] start_s", "capture.start_s = 2e-05: the window starts 2998 m deep"),
    ("[preprocess] max_path_m", "preprocess.max_path_m = 5000: a path of 5000 m reaches "
                                "2500 m deep"),
    ("clnlos HDF5", "scan_width_m = 200 (from the capture): a scan 200 m wide"),
    ("y-tal", "bin_width_s = 3.2e-08 (from the capture): a bin of 32 ns"),
    ("LCT .mat", "bin_width_s = 4e-09 (from the capture): the time window (2048 bins) reaches "
                 "1228 m deep, beyond the 1000 m any NLOS capture can have"),
])
def test_a_unit_slip_on_any_reader_flag_or_key_is_one_line_before_work(tmp_path, no_work,
                                                                        case, needle):
    f = _files(tmp_path)
    out = tmp_path / "v.h5"
    cfg = tmp_path / "p.toml"
    args = {"--bin-width": [str(f["npy"]), "--bin-width", "32e-9", "--scan-width", "0.3"],
            "--scan-width": [str(f["ok"]), "--scan-width", "200"],
            "[capture] start_s": [str(f["ok"]), "--config", str(cfg)],
            "[preprocess] max_path_m": [str(f["ok"]), "--config", str(cfg)],
            "clnlos HDF5": [str(f["wide"])], "y-tal": [str(f["tal"])],
            "LCT .mat": [str(f["lct"])]}[case]
    cfg.write_text({"[capture] start_s": "[capture]\nstart_s = 2e-5\n",
                    "[preprocess] max_path_m": "[preprocess]\nmax_path_m = 5000.0\n"}.get(
                        case, ""))
    line = _error_line(*_run(["reconstruct", *args, "-o", str(out)]))
    assert needle in line, line
    assert not out.exists() and not out.with_suffix(".png").exists()


def test_an_impossible_file_value_is_accepted_when_asked(tmp_path):
    f = _files(tmp_path)
    rc, err = _run(["reconstruct", str(f["wide"]), "-o", str(tmp_path / "v.h5"),
                    "--allow-implausible"])
    assert rc == 0, err
    warn = [ln for ln in err.splitlines() if ln.startswith("clnlos: warning:")]
    assert len(warn) == 1 and warn[0].endswith("(accepted: --allow-implausible)"), err


def test_python_keywords_and_the_capture_say_how_to_accept_in_python(tmp_path, no_work):
    f = _files(tmp_path)
    cap = clnlos.read_capture(f["ok"])
    with pytest.raises(ImplausibleValueError, match=r"^bin_width_s=3.2e-08: a bin of 32 ns.*"
                       r"; allow_implausible=True accepts it$"):
        clnlos.reconstruct(cap, bin_width_s=32e-9)
    with pytest.raises(ImplausibleValueError, match=r"^scan_width_m = 200 \(from the "
                       r"capture\).*; allow_implausible=True accepts it$"):
        clnlos.reconstruct(f["wide"])


@pytest.mark.parametrize("key,value,needle", [
    ("bin_width_s", 32e-9, "time.bin_width_s = 3.2e-08: a bin of 32 ns"),
    ("pulse_width_s", 35e-9, "laser.pulse_width_s = 3.5e-08: a pulse of 35 ns"),
    ("width_m", 60.0, "scan.width_m = 60: a scan 60 m wide"),
])
def test_a_scene_slip_stops_simulate_before_work(tmp_path, no_work, key, value, needle):
    scene = {"scan": "width_m = 0.3\npoints = 4", "time": "bin_width_s = 32e-12\nbins = 64",
             "laser": "pulse_width_s = 35e-12"}
    section = {"bin_width_s": "time", "pulse_width_s": "laser", "width_m": "scan"}[key]
    scene[section] = scene[section].replace(
        next(ln for ln in scene[section].splitlines() if ln.startswith(key)), f"{key} = {value}")
    text = "".join(f"[{k}]\n{v}\n" for k, v in scene.items()) + (
        '[[objects]]\nshape = "rectangle"\nsize_m = [0.1, 0.1]\ntranslate_m = [0, 0, 0.4]\n')
    (tmp_path / "s.toml").write_text(text)
    line = _error_line(*_run(["simulate", str(tmp_path / "s.toml"), "-o",
                              str(tmp_path / "c.h5")]))
    assert needle in line and not (tmp_path / "c.h5").exists(), line


def test_the_rule_is_one_table():
    """Each kind: usual inside, unusual between, impossible outside (both sides)."""
    for kind, p in PLAUSIBLE.items():
        lo, hi = p.usual
        plo, phi = p.possible
        assert plo <= lo < hi <= phi, kind
        assert plausibility(kind, (lo + hi) / 2)[0] == "usual"
        assert plausibility(kind, phi)[0] == "unusual" and plausibility(kind, plo)[0] in (
            "unusual", "usual")
        assert plausibility(kind, phi * 1.01 + 1e-30)[0] == "impossible"
