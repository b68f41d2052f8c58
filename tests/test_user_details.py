"""The small things a user meets (issue 58, item 7): the iterative bar counts to where the
solver stops, the depth map's colour bar spans the volume's depths, the Python API's notes
name keywords alone, ``[detector] exposure_s`` is per scan point."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from reference.scene_ref import points_transient

import clnlos
from clnlos.app import reconstruct as app_reconstruct
from clnlos.app.cli import main
from clnlos.config import ReconstructionConfig
from clnlos.io.capture import Capture
from clnlos.io.figures import volume_axes, volume_figure
from clnlos.io.formats.mat import lct_rect_data
from clnlos.io.progress import progress_bar


def test_the_iterative_bar_counts_to_the_iterations_that_run(tmp_path, queue, monkeypatch):
    """Without a slab and with its iterations left to the rule, the solver stops where the
    data's light-cone SNR says (well before the config's 200): the bar's total is that."""
    bars = []

    def recorded(total, desc, unit):
        bar = progress_bar(total, desc, unit)
        bars.append(bar)
        return bar

    monkeypatch.setattr(app_reconstruct, "progress_bar", recorded)
    n, nt, dt, width = 8, 64, 48e-12, 0.3
    tau = points_transient([(0.02, -0.01, 0.3)], [1.0], nt, n, width, dt)
    tau = np.random.default_rng(0).poisson(200 * tau / tau.max()).astype(np.float32)
    cfg = ReconstructionConfig(method="iterative").validate()
    rec = app_reconstruct.reconstruct_to_files(Capture(tau, dt, 0.0, width),
                                               tmp_path / "v.h5", cfg, queue=queue)
    stop = rec.params["iterations_stop"]
    assert rec.params["iterations_rule"] == "snr" and stop < cfg.iterations
    (bar,) = bars
    assert bar.total == stop and bar.n == rec.solver["iterations"] <= stop


def test_the_depth_colour_bar_spans_the_volumes_depths():
    vol = np.zeros((50, 4, 4), np.float32)
    vol[20, 1, 1], vol[30, 2, 2] = 1.0, 0.5  # depths 0.61 and 0.81 m
    e = {"depth_min_m": 0.2, "depth_max_m": 1.2, "voxel_depth_m": 0.02, "x_min_m": -1.0,
         "x_max_m": 1.0, "y_min_m": -1.0, "y_max_m": 1.0}
    depth = volume_figure(vol, e).panels[1]
    assert depth.limits == (0.2, 1.2)
    assert np.nanmin(depth.img) == pytest.approx(0.61) and np.nanmax(depth.img) == \
        pytest.approx(0.81)
    assert volume_axes(vol, e, view="depth").images[0].get_clim() == (0.2, 1.2)


def test_python_notes_name_keywords_and_the_cli_flags(tmp_path, queue, capsys):
    """The LCT layout without its bin width: the note names ``bin_width_s=`` in Python and
    ``--bin-width`` on the command line, never both."""
    tau = np.zeros((1024, 8, 8), np.float32)
    tau[:40] = 1000.0
    tau[700:704, 3:5, 3:5] = 30.0
    scipy.io.savemat(tmp_path / "c.mat", {"rect_data": lct_rect_data(tau), "width": 0.2})
    rec = clnlos.reconstruct(tmp_path / "c.mat", device=queue, inversion_snr=1e3)
    text = "\n".join(rec.notes)
    assert "override with bin_width_s=, start_s=)" in text
    assert "(brdf=lambertian for a diffuse target)" in text
    assert "(change with bins=)" in text and "direct_cut_s=, 0 keeps them" in text
    assert "--" not in text and "/ " not in text, text
    assert main(["reconstruct", str(tmp_path / "c.mat"), "-o",
                 str(tmp_path / "v.h5"), "--inversion-snr", "1e3"]) == 0
    err = capsys.readouterr().err
    assert "override with --bin-width, [capture] start_s)" in err
    assert "bin_width_s=" not in err and "/ " not in err, err


def test_exposure_is_per_scan_point(queue):
    """The counts of a scan point do not depend on how many points the scan has, and grow
    with ``exposure_s``: the exposure is each point's dwell."""
    def counts(points, exposure):
        scene = {"seed": 1, "scan": {"width_m": 0.3, "points": points},
                 "time": {"bin_width_s": 32e-12, "bins": 128},
                 "objects": [{"shape": "rectangle", "size_m": [0.2, 0.2],
                              "translate_m": [0, 0, 0.4]}],
                 "detector": {"exposure_s": exposure, "etendue_m2_sr": 1e-6}}
        return clnlos.simulate(scene, device=queue).transient.sum(axis=0, dtype=np.float64)

    three = counts(3, 1e-4)
    assert three.min() > 1e6
    # the 9 x 9 scan's points 1, 4, 7 sit where the 3 x 3 scan's are
    np.testing.assert_allclose(counts(9, 1e-4)[1::3, 1::3], three, rtol=5e-3)
    np.testing.assert_allclose(counts(3, 2e-4), 2 * three, rtol=5e-3)
