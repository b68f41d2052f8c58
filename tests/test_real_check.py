"""The real check (clnlos.study.real.check) on a capture whose truth is known: a simulated
capture of an asymmetric letter, read as a real one. Its from-capture twin keeps the letter's
orientation and place, and predicts the photons the capture needs: 1.5-2.0x on three noise
seeds (the twin's letter is the reconstruction's, the true one blurred once more:
docs/study-file.md), within 2.5x here."""

import numpy as np
import pytest

from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.io.files import write_capture
from clnlos.study.file.spec import parse_study
from clnlos.study.real.check import check_capture
from clnlos.study.real.materials import ncc
from clnlos.study.samples.materials import prepare_materials

RIG = {"scan": {"width_m": 0.6, "points": 16}, "time": {"bin_width_s": 32e-12},
       "laser": {"pulse_width_s": 60e-12},
       "detector": {"power_w": 0.4, "exposure_s": 1e-4, "etendue_m2_sr": 1e-8,
                    "dark_count_rate_hz": 1e5}}


@pytest.fixture(scope="module")
def capture_l(tmp_path_factory):
    """A photon-count capture of a white "L" 0.35 m tall at 0.5 m, no slab, with a floor
    of dark counts: the "real" capture of the test."""
    d = tmp_path_factory.mktemp("real")
    scene = Scene.from_dict({**RIG, "seed": 11, "time": {"bin_width_s": 32e-12, "bins": 200},
                             "objects": [{"shape": "letters", "text": "L", "height_m": 0.35,
                                          "stroke_m": 0.08,
                                          "translate_m": [0.0, 0.0, 0.5]}]})
    cap = ForwardModel(scene).capture()
    path = d / "l.h5"
    write_capture(path, cap.transient, bin_width_s=cap.bin_width_s, start_s=cap.start_s,
                  scan_width_m=cap.scan_width_m)
    return path, d


def test_a_simulated_capture_is_predicted_by_its_from_capture_twin(capture_l):
    path, d = capture_l
    study = parse_study({**RIG, "materials": [{"name": "white", "brdf": "lambertian"}],
                         "targets": [{"text": "L", "height_m": 0.35, "depth_m": 0.5}],
                         "real": [{"capture": str(path), "material": "white"}]})
    mats, _ = prepare_materials(study, d)
    row = check_capture(study.real[0], mats["white"], study, d, None)
    real, twin = row["arrays"]["reference"], row["arrays"]["twin_reference"]
    assert ncc(real, twin) > 0.8                       # the same letter, the same way up
    assert ncc(real, twin) > ncc(real, twin[::-1]) + 0.1
    assert ncc(real, twin) > ncc(real, twin[:, ::-1]) + 0.1
    assert row["twin"]["kind"] == "from-capture"
    assert row["twin"]["depth_m"] == pytest.approx(0.5, abs=0.03)
    assert row["measured_status"] == row["predicted_status"] == "bracketed"
    for key in ("measured", "predicted"):                # every series bracketed in 1.5x
        for s in row["series"][key]:
            assert s["kept"] / s["lost"] <= 1.5 + 1e-9
    lo, hi = row["photons_needed_measured_interval"]
    assert lo <= row["photons_needed_measured"] <= hi
    assert 0.8 <= row["ratio"] <= 2.5 and row["ratio_bound"] is None
    assert np.isfinite(row["signal_photons"]) and row["signal_photons"] < row["photons"]
