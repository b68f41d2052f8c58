"""What a new user met (issue 51): a method flag over a config written for another method, units
that passed unnoticed, Python inputs that failed inside pathlib, notes naming CLI flags in
Python, and the smaller items (a missing scan width, --iterations 0, a scene target out of
its window, the plot's title)."""

from __future__ import annotations

import json
import warnings

import h5py
import matplotlib
import numpy as np
import pytest

import clnlos
from clnlos.api import PlausibilityWarning
from clnlos.app.cli import main
from clnlos.checks import PLAUSIBLE
from clnlos.config import (
    ReconstructionConfig,
    drop_other_methods_settings,
    plausibility_warnings,
    python_keywords,
)
from clnlos.errors import InputFileError, MissingParameterError
from helpers import SMALL_SCENE as SCENE

matplotlib.use("Agg")

LCT_CONFIG = """[deconvolution]
snr = 1e4
[inversion]
method = "lct"
snr = 1e4
falloff = 4.0
"""
ITERATIVE_CONFIG = """[deconvolution]
snr_rule = "thinning"
[inversion]
method = "iterative"
iterations = 5
brdf = "quartz glass"
l1_weight = 0.01
"""


@pytest.fixture(scope="module")
def files(tmp_path_factory, queue):
    d = tmp_path_factory.mktemp("newuser")
    (d / "scene.toml").write_text(SCENE)
    (d / "lct.toml").write_text(LCT_CONFIG)
    (d / "it.toml").write_text(ITERATIVE_CONFIG)
    assert main(["simulate", str(d / "scene.toml"), "-o", str(d / "cap.h5"),
                 "--device", "pocl"]) == 0
    return d


# ------------------------------------------------------------------ item 1
@pytest.mark.parametrize("config,method,unused", [
    ("lct.toml", "fk", {"inversion_snr"}),
    ("it.toml", "lct", {"iterations", "brdf", "l1_weight", "snr_rule"}),
    ("it.toml", "fk", {"iterations", "brdf", "l1_weight", "snr_rule"}),
])
def test_a_method_flag_leaves_the_configs_other_settings_unused(files, capsys, config,
                                                                method, unused):
    out = files / f"rec_{method}_{config}.h5"
    extra = ["--iterations", "3"] if method == "iterative" else []
    assert main(["reconstruct", str(files / "cap.h5"), "-o", str(out), "--config",
                 str(files / config), "--method", method, "--device", "pocl", *extra]) == 0
    err = capsys.readouterr().err
    notes = [line for line in err.splitlines() if f"--method {method}: the config's" in line]
    assert len(notes) == 1, err
    for field in unused:
        assert f".{'snr' if field == 'inversion_snr' else field} = " in notes[0], notes[0]
    with h5py.File(out) as f:
        params = json.loads(f.attrs["params"])
    assert params["method"] == method
    defaults = ReconstructionConfig()
    for field in unused - ({"iterations"} if method == "iterative" else set()):
        assert params[field] == getattr(defaults, field), field


def test_a_flag_the_method_does_not_read_is_still_refused(files, capsys):
    """The user's own flag, not the file's: an error as before."""
    code = main(["reconstruct", str(files / "cap.h5"), "-o", str(files / "x.h5"), "--config",
                 str(files / "lct.toml"), "--method", "fk", "--inversion-snr", "1e3"])
    assert code == 2
    assert "--inversion-snr = 1000.0: allowed only with method" in capsys.readouterr().err


def test_python_method_over_a_config_notes_it_in_python_words(files, queue):
    rec = clnlos.reconstruct(files / "cap.h5", method="fk", config=files / "lct.toml",
                             device=queue)
    assert rec.notes[0].startswith("method='fk': the config's inversion.snr = 10000"), rec.notes
    notes: list[str] = []
    cfg = clnlos.reconstruction_config({"inversion": {"method": "iterative", "brdf": "auto"}},
                                       method="lct", notes=notes)
    assert cfg.brdf == "lambertian" and "inversion.brdf = 'auto'" in notes[0]
    # the same method: nothing dropped, nothing said
    cfg, unused, said = drop_other_methods_settings(
        ReconstructionConfig(method="lct", inversion_snr=1e4), {"inversion_snr": "i.snr"},
        "--method lct")
    assert cfg.inversion_snr == 1e4 and not unused and not said


# ------------------------------------------------------------------ item 3
@pytest.mark.parametrize("flags,needle", [
    (["--scan-width", "15"], "--scan-width 15: a scan 15 m wide, more than the 10 m usual"),
    (["--bin-width", "8e-9"], "--bin-width 8e-09: a bin of 8 ns, more than the 1 ns usual"),
    (["--bin-width", "4e-9"], "--bin-width 4e-09: a bin of 4 ns, more than the 1 ns usual"),
])
def test_unusual_units_warn_once_naming_flag_value_and_file(files, capsys, flags, needle):
    main(["reconstruct", str(files / "cap.h5"), "-o", str(files / "w.h5"), "--force",
          *flags])
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("clnlos: warning:")]
    assert len(lines) == 1, err
    assert needle in lines[0] and "the capture gives" in lines[0], lines[0]
    assert lines[0].startswith(f"clnlos: warning: {flags[0]} ")
    assert ("0.3 m" if "--scan-width" in flags else "20 ps") in lines[0]


def test_a_flag_contradicting_the_capture_says_so(files, capsys):
    assert main(["reconstruct", str(files / "cap.h5"), "-o", str(files / "c.h5"), "--force",
                 "--scan-width", "0.35", "--device", "pocl"]) == 0
    err = capsys.readouterr().err
    assert ("clnlos: warning: --scan-width 0.35 contradicts the 0.3 m the capture gives"
            in err), err


def test_plausibility_limits_and_plain_values():
    rec = {"scan_width_m": 0.3, "bin_width_s": 16e-12, "start_s": 0.0}
    ok = dict(nt=512, bin_width_s=16e-12, start_s=0.0, scan_width_m=0.3, recorded=rec)
    assert plausibility_warnings(**ok, given={}) == []
    assert plausibility_warnings(**ok, given={"scan_width_m": "--scan-width"}) == []
    usual_scan = PLAUSIBLE["scan_width_m"].usual[1]
    wide = plausibility_warnings(**{**ok, "scan_width_m": usual_scan * 1.5},
                                 given={"scan_width_m": "capture.scan_width_m"})
    assert len(wide) == 1 and wide[0].startswith("capture.scan_width_m = 15:")
    deep_bw = 2 * PLAUSIBLE["depth_m"].usual[1] * 1.1 / 3e8 / 4096  # 179 ps: a usual bin
    deep = plausibility_warnings(**{**ok, "nt": 4096, "bin_width_s": deep_bw},
                                 given={"bin_width_s": "bin_width_s"})
    assert len(deep) == 1 and deep[0].startswith(f"bin_width_s={deep_bw:g}: the time window")
    # a file's own unusual value (nothing given): named as the file's
    own = plausibility_warnings(**{**ok, "bin_width_s": 4e-9,
                                     "recorded": {**rec, "bin_width_s": 4e-9}}, given={})
    assert len(own) == 1 and "(from the capture)" in own[0]


def test_python_warns_with_the_keyword(files, queue):
    cap = clnlos.read_capture(files / "cap.h5")
    with pytest.warns(PlausibilityWarning, match=r"scan_width_m=15: a scan 15 m wide"):
        clnlos.reconstruct(cap, scan_width_m=15.0, device=queue)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        clnlos.reconstruct(cap, device=queue)  # plausible: no warning


# ------------------------------------------------------------------ item 4
def test_python_inputs(files, queue):
    cap = clnlos.read_capture(files / "cap.h5")
    for bad in (None, 3, [1, 2]):
        with pytest.raises(TypeError, match=r"^capture: expected a clnlos Capture"):
            clnlos.reconstruct(bad)
    with pytest.raises(TypeError, match=r"^volume: .*a capture: reconstruct it first"):
        clnlos.plot_volume(cap)
    with pytest.raises(TypeError, match=r"^volume: expected"):
        clnlos.plot_volume(None)
    arr = np.array(cap.transient)
    with pytest.raises(MissingParameterError, match=r"^bin_width_s= is needed: .*give "
                       r"bin_width_s= \(s\)"):
        clnlos.reconstruct(arr, device=queue)
    with pytest.raises(MissingParameterError, match=r"^scan_width_m= is needed"):
        clnlos.reconstruct(arr, bin_width_s=cap.bin_width_s, device=queue)
    rec = clnlos.reconstruct(arr, bin_width_s=cap.bin_width_s, scan_width_m=cap.scan_width_m,
                             slab=None, device=queue)
    same = clnlos.reconstruct(cap, no_slab=True, device=queue)
    np.testing.assert_allclose(rec.volume, same.volume, rtol=1e-5, atol=1e-6)
    with pytest.raises(InputFileError, match="^the array: transient holds negative"):
        clnlos.reconstruct(-arr, bin_width_s=2e-11, scan_width_m=0.3, device=queue)


def test_cli_missing_scan_width_says_it_is_needed(files, capsys):
    np.save(files / "a.npy", clnlos.read_capture(files / "cap.h5").transient)
    assert main(["reconstruct", str(files / "a.npy"), "-o", str(files / "a.h5"),
                 "--bin-width", "2e-11"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("clnlos: error: --scan-width is needed: ") and "None" not in err


def test_notes_in_python_name_the_keyword():
    assert python_keywords("a longer capture, or --max-path 2.26 to stop there") == \
        "a longer capture, or max_path_m=2.26 to stop there"
    assert python_keywords("(--no-slab to skip)") == "(no_slab=True to skip)"
    assert python_keywords("--snr-rule gcv and --snr 1e5") == "snr_rule=gcv and snr=1e5"


# ------------------------------------------------------------------ item 7
def test_iterations_zero_is_noted(files, queue):
    rec = clnlos.reconstruct(files / "cap.h5", method="iterative", iterations=0, device=queue)
    assert any(n.startswith("iterations=0: no iteration ran") for n in rec.notes), rec.notes


def test_a_far_target_names_its_distance_and_the_time_fields(tmp_path, capsys):
    scene = SCENE.replace("translate_m = [0.03, 0.0, 0.3]", "translate_m = [0.03, 0.0, 50.0]")
    (tmp_path / "far.toml").write_text(scene)
    assert main(["simulate", str(tmp_path / "far.toml"), "-o", str(tmp_path / "f.h5")]) == 2
    err = capsys.readouterr().err
    assert "50 m behind the relay plane" in err and "[time] start_s" in err, err


def test_plot_title_names_the_method(files):
    from clnlos.app.commands import plot_title

    out = files / "t_fk.h5"
    assert main(["reconstruct", str(files / "cap.h5"), "-o", str(out), "--method", "fk",
                 "--force"]) == 0
    with h5py.File(out) as f:
        assert plot_title(out, dict(f.attrs)) == "t_fk.h5 (fk)"
    assert plot_title(out, {}) == "t_fk.h5"
