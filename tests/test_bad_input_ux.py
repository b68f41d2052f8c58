"""Issue 23 item 10: progress on the long jobs, help text with defaults, CSVs with a BOM.

Progress is checked through the callbacks the library functions drive and through the bars
on stderr (their delay set to 0), never through times.
"""

import argparse

import numpy as np
import pytest
from reference.scene_ref import points_transient

from clnlos.io import progress as progress_mod
from clnlos.app.cli import build_parser, main
from clnlos.brdf.data import read_gonio_csv, read_pbrt_brdf
from clnlos.brdf.fit import fit_analytic
from clnlos.brdf.models import BRDFModel
from clnlos.config import ReconstructionConfig
from clnlos.forward.scene import read_retro_csv
from clnlos.io.capture import Capture
from clnlos.physics.slab import CDT_SLAB

HEADER = "theta_i_deg,phi_i_deg,theta_s_deg,phi_s_deg,brdf\n"
BOM = "\ufeff"


def _csv(path, n=120, seed=0, bom=False):
    """A tiny gonioreflectometer CSV of a Phong lobe (optionally with a UTF-8 BOM)."""
    rng = np.random.default_rng(seed)
    truth = BRDFModel("phong", {"kd": 0.3, "ks": 0.6, "shininess": 12.0})
    ti = rng.choice([30.0, 45.0, 60.0], n)
    ts, ps = rng.uniform(0, 85, n), rng.uniform(0, 360, n)
    f = truth(np.radians(ti), 0 * ti, np.radians(ts), np.radians(ps))
    rows = "".join(f"{a},0,{b:.4f},{c:.4f},{d:.6f}\n" for a, b, c, d in
                   zip(ti, ts, ps, f, strict=True))
    path.write_text((BOM if bom else "") + "# material: synthetic\n" + HEADER + rows,
                    encoding="utf-8")
    return path


def _recorder():
    calls = []
    return calls, lambda done, total: calls.append((done, total))


# ------------------------------------------------------------------ CSV with a BOM
def test_gonio_csv_with_utf8_bom_reads_like_without(tmp_path):
    plain = read_gonio_csv(_csv(tmp_path / "plain.csv"))
    bom_path = tmp_path / "excel.csv"
    bom_path.write_bytes(b"\xef\xbb\xbf" + (tmp_path / "plain.csv").read_bytes())
    bom = read_gonio_csv(bom_path)
    np.testing.assert_array_equal(bom.angles, plain.angles)
    np.testing.assert_array_equal(bom.brdf, plain.brdf)
    assert bom.meta["material"] == "synthetic"  # the first (comment) line is intact
    assert bom.meta["precision"] == plain.meta["precision"]


def test_gonio_csv_with_bom_and_header_first(tmp_path):
    p = tmp_path / "h.csv"
    p.write_bytes(b"\xef\xbb\xbf" + (HEADER + "30,0,30,180,0.5\n45,0,20,90,0.25\n").encode())
    s = read_gonio_csv(p)
    assert len(s) == 2 and s.brdf.tolist() == [0.5, 0.25]


def test_brdf_fit_cli_accepts_a_bom_csv(tmp_path, capsys):
    data = _csv(tmp_path / "excel.csv", bom=True)
    assert main(["brdf", "fit", str(data), "--model", "lambert",
                 "-o", str(tmp_path / "m.h5")]) == 0
    assert (tmp_path / "m.h5").is_file()
    assert "error" not in capsys.readouterr().err


def test_retro_csv_with_bom(tmp_path):
    p = tmp_path / "retro.csv"
    p.write_bytes(b"\xef\xbb\xbftheta_deg,brdf\n0,2.0\n45,1.0\n90,0.5\n")
    th, f = read_retro_csv(p)
    np.testing.assert_allclose(np.degrees(th), [0, 45, 90])
    np.testing.assert_allclose(f, [2.0, 1.0, 0.5])


def test_pbrt_brdf_with_bom(tmp_path):
    p = tmp_path / "s.brdf"
    p.write_bytes(b"\xef\xbb\xbf" + b"2 500 600\n0.5 0 0.5 3.14159 0.2 0.4\n")
    s = read_pbrt_brdf(p)
    np.testing.assert_allclose(s.brdf, [0.3])


# ------------------------------------------------------------------ help text
def _parsers(parser, name="clnlos"):
    yield name, parser
    for a in parser._actions:
        if isinstance(a, argparse._SubParsersAction):
            for sub_name, sub in a.choices.items():
                yield from _parsers(sub, f"{name} {sub_name}")


def _default_texts(default) -> list[str]:
    if isinstance(default, list | tuple):
        return [str(v) for v in default]
    return [str(default)]


def test_every_option_of_every_command_has_help_with_its_default():
    """Each argument of each sub-command says what it is; an optional one also says what
    happens without it (its default) and, where argparse holds a default value, that value."""
    problems, seen = [], 0
    for name, parser in _parsers(build_parser()):
        formatter = parser._get_formatter()
        for a in parser._actions:
            if isinstance(a, argparse._HelpAction | argparse._VersionAction):
                continue
            if isinstance(a, argparse._SubParsersAction):
                for sub in a._choices_actions:  # every sub-command is described
                    if not (sub.help or "").strip():
                        problems.append(f"{name} {sub.dest}: no help")
                continue
            if a.help == argparse.SUPPRESS:  # hidden on purpose (test-only flags)
                continue
            seen += 1
            flag = "/".join(a.option_strings) or a.dest
            text = formatter._expand_help(a) if a.help else ""
            if not text.strip():
                problems.append(f"{name} {flag}: no help")
                continue
            if a.required or not a.option_strings or a.nargs == 0:
                continue  # positional, required or a switch: nothing to default
            if "default" not in text:
                problems.append(f"{name} {flag}: help does not state the default: {text!r}")
            elif a.default is not None:
                missing = [t for t in _default_texts(a.default) if t not in text]
                if missing:
                    problems.append(f"{name} {flag}: default {a.default!r} not in {text!r}")
    assert seen > 50
    assert not problems, "\n".join(problems)


def test_help_states_defaults_from_the_owning_modules(capsys):
    from clnlos.config import DEPTH_GUARD_M, METHOD_FALLOFF
    from clnlos.inverse.fk import DEFAULT_FALLOFF as FK_FALLOFF
    from clnlos.inverse.lct import DEFAULT_FALLOFF as LCT_FALLOFF

    assert (LCT_FALLOFF, FK_FALLOFF) == (METHOD_FALLOFF["lct"], METHOD_FALLOFF["fk"])
    assert main(["reconstruct", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    c = ReconstructionConfig()
    assert f"else {c.method})" in out
    assert f"lct {LCT_FALLOFF:g}, fk {FK_FALLOFF:g}" in out
    assert f"(default {c.iterations})" in out and f"(default {c.l1_weight})" in out
    assert f"less {DEPTH_GUARD_M:g} m" in out
    assert "whole time window" in out  # --max-path
    assert main(["brdf", "texture", "--help"]) == 0
    out = " ".join(capsys.readouterr().out.split())
    assert "(default 64)" in out and "(default 256)" in out and "output texture" in out


# ------------------------------------------------------------------ progress: brdf fit
def test_analytic_fit_drives_progress_over_its_starts(tmp_path):
    s = read_gonio_csv(_csv(tmp_path / "d.csv"))
    calls, cb = _recorder()
    fit_analytic("phong", s, starts=3, progress=cb)
    assert calls[-1] == (3, 3)
    assert all(t == 3 for _, t in calls)
    done = [d for d, _ in calls]
    assert done == sorted(done) and set(done) == {0, 1, 2, 3}
    assert len(calls) > 3 * 5  # called during each optimiser run, not only between them


def test_mlp_fit_drives_progress_over_epochs_and_networks(tmp_path):
    pytest.importorskip("torch")
    from clnlos.brdf.mlp import MLPConfig, train_mlp

    s = read_gonio_csv(_csv(tmp_path / "d.csv", n=60))
    calls, cb = _recorder()
    train_mlp(s, MLPConfig(epochs=4, members=3, width=8, depth=1, fourier=1), progress=cb)
    assert calls == [(k, 12) for k in range(1, 13)]
    calls.clear()
    train_mlp(s, MLPConfig(recipe="seed", epochs=5), progress=cb)
    assert calls == [(k, 5) for k in range(1, 6)]


def test_brdf_fit_cli_shows_a_bar_on_stderr(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(progress_mod, "PROGRESS_DELAY_S", 0.0)
    data = _csv(tmp_path / "d.csv")
    assert main(["brdf", "fit", str(data), "--model", "phong",
                 "-o", str(tmp_path / "m.h5")]) == 0
    err = capsys.readouterr().err
    assert "brdf fit phong" in err and "start" in err


def test_progress_bar_waits_for_its_delay(capsys):
    """With the default delay a short job prints nothing (the bars of every command)."""
    assert progress_mod.PROGRESS_DELAY_S > 0
    with progress_mod.progress_bar(None, "quick job", "step") as bar:
        cb = progress_mod.counter(bar)
        for k in range(5):
            progress_mod.stage(bar, f"step {k}")
            cb(k + 1, 5)
    assert "quick job" not in capsys.readouterr().err


# ------------------------------------------------------------------ progress: study CNN
def test_cnn_training_drives_progress_per_batch():
    pytest.importorskip("torch")
    from clnlos.study.judge.cnn import train_classifier

    rng = np.random.default_rng(0)
    images = rng.random((10, 8, 8)).astype(np.float32)
    labels = np.array([1, 2, 3, 1, 2, 3, 1, 2, 3, 1])
    calls, cb = _recorder()
    _, report = train_classifier(images, labels, epochs=2, batch=16, progress=cb)
    per_epoch = -(-report["n_train"] * 8 // 16)  # eight views of each training image
    total = 2 * per_epoch
    assert calls == [(k, total) for k in range(1, total + 1)]


# ------------------------------------------------------------------ progress: iterative
def _tiny_capture():
    n, nt, dt, width = 8, 64, 48e-12, 0.3
    tau = points_transient([(0.02, -0.01, 0.3)], [1.0], nt, n, width, dt)
    return Capture(tau.astype(np.float32), dt, 0.0, width)


def _iterative_config(iterations=3):
    return ReconstructionConfig(method="iterative", iterations=iterations, slab=CDT_SLAB,
                                snr=1e3, inversion_snr=1e2).validate()


def test_iterative_setup_steps_are_reported_before_the_iterations(queue):
    from clnlos.inverse.pipeline import reconstruct
    from clnlos.inverse.solvers import POWER_ITERATIONS
    from clnlos.runtime.caches import PIPELINES

    PIPELINES.clear()  # a cached pipeline would (rightly) skip the set-up
    events = []
    reconstruct(_tiny_capture(), _iterative_config(), device=queue,
                progress=lambda k, n: events.append(("it", k, n)),
                setup=lambda step: events.append(("setup", step)))
    steps = [e[1] for e in events if e[0] == "setup"]
    first_it = next(i for i, e in enumerate(events) if e[0] == "it")
    assert all(e[0] == "setup" for e in events[:first_it])
    assert all(e[0] == "it" for e in events[first_it:])
    assert steps[:3] == ["preprocess", "slab PSF", "iterative plan"]
    assert steps[3] == "light-cone operator" and steps[-1] == "LCT warm start"
    power = [s for s in steps if s.startswith("step size")]
    assert power == [f"step size (power iteration {k}/{POWER_ITERATIONS})"
                     for k in range(1, POWER_ITERATIONS + 1)]
    assert events[-1] == ("it", 3, 3)


def test_reconstruct_bar_shows_the_setup_then_the_iterations(queue, tmp_path, capsys,
                                                             monkeypatch):
    from clnlos.app.reconstruct import reconstruct_to_files
    from clnlos.runtime.caches import PIPELINES

    monkeypatch.setattr(progress_mod, "PROGRESS_DELAY_S", 0.0)
    PIPELINES.clear()
    reconstruct_to_files(_tiny_capture(), tmp_path / "v.h5", _iterative_config(),
                         queue=queue)
    err = capsys.readouterr().err
    assert "iterative" in err
    for step in ("setup: preprocess", "setup: slab PSF", "setup: light-cone operator",
                 "setup: LCT warm start"):
        assert step in err, step
    assert err.index("setup: preprocess") < err.index("setup: LCT warm start")
    assert (tmp_path / "v.h5").is_file()
