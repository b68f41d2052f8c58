"""The retroreflective material (clnlos.physics.retroreflector): the data-sheet fit, the
spot average against an independent integration, the simulated falloff in both regimes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clnlos.errors import ParameterError
from clnlos.forward.model import ForwardModel
from clnlos.forward.scene import Scene
from clnlos.physics.retroreflector import (
    ASTM_D4956_TYPE_I_WHITE,
    Retroreflector,
    spot_factor,
)


def test_preset_reproduces_the_datasheet_points_it_was_fitted_to():
    r = Retroreflector.preset()
    sheet = ASTM_D4956_TYPE_I_WHITE["ra_cd_lx_m2"]
    for (obs, ent) in [(0.2, -4.0), (0.5, -4.0), (0.2, 30.0)]:
        beta = math.radians(abs(ent))
        ra = r.cone_slice(beta) * math.cos(beta) ** 2 * math.exp(
            -obs ** 2 / (2 * r.divergence_deg ** 2))                      # Eq. 1 and 2
        assert ra == pytest.approx(sheet[(obs, ent)], rel=1e-9)
    assert 0.2 < r.divergence_deg < 0.5 and 30 < r.acceptance_deg < 60
    assert float(r.cone_slice(math.radians(r.acceptance_deg + 1))) == 0.0


@pytest.mark.parametrize("ratio", [0.05, 0.7, 1.0, 3.0, 20.0])
def test_spot_average_matches_an_integration_over_the_disc(ratio):
    """f0 exp(-alpha^2 / (2 sigma^2)) averaged over a disc of angular radius beta_s, by a
    2D midpoint rule on a Cartesian grid of the disc (not the closed form's polar integral)."""
    sigma, r = math.radians(0.35), 0.8
    beta_s = ratio * sigma
    n = 801
    u = (np.arange(n) + 0.5) / n * 2 - 1
    X, Y = np.meshgrid(u * beta_s, u * beta_s)
    inside = X ** 2 + Y ** 2 <= beta_s ** 2
    num = np.exp(-(X ** 2 + Y ** 2) / (2 * sigma ** 2))[inside].mean()
    retro = Retroreflector.preset(divergence_deg=math.degrees(sigma), spot_radius_m=beta_s * r)
    assert float(retro.spot_factor(r)) == pytest.approx(num, rel=2e-4)
    # the limits: 1 for a small spot, 2 sigma^2 / beta_s^2 for a large one
    assert float(spot_factor(1e-9)) == pytest.approx(1.0)
    assert float(spot_factor(50.0)) == pytest.approx(1 / 50.0, rel=1e-12)


def _plate_signal(queue, z, material):
    d = {"scan": {"width_m": 0.04, "points": 4},
         "time": {"bin_width_s": 40e-12, "bins": 512, "start_s": 0.0},
         "sampling": {"density_per_m2": 4e6},
         "objects": [{"shape": "rectangle", "size_m": [0.02, 0.02],
                      "translate_m": [0.0, 0.0, z], "material": material}]}
    fm = ForwardModel(Scene.from_dict(d), dtype=np.float64, queue=queue)
    return float(np.sum(fm.run()))


@pytest.mark.parametrize("material, exponent", [
    ({"model": "retroreflective", "divergence_deg": 0.05, "spot_radius_m": 0.05,
      "diffuse_albedo": 0.0}, 2.0),   # the spot holds the whole cone: 1 / r^2
    ({"model": "retroreflective", "divergence_deg": 10.0, "spot_radius_m": 1e-4,
      "diffuse_albedo": 0.0}, 4.0),   # the cone is far wider than the spot: 1 / r^4
    ("lambertian", 4.0),
])
def test_simulated_falloff_exponent(queue, material, exponent):
    near, far = _plate_signal(queue, 0.4, material), _plate_signal(queue, 0.8, material)
    measured = math.log(near / far) / math.log(2.0)
    assert measured == pytest.approx(exponent, abs=0.05)


def test_bad_retroreflective_field_is_named():
    d = {"scan": {"width_m": 0.04, "points": 4},
         "time": {"bin_width_s": 40e-12, "bins": 64},
         "objects": [{"shape": "rectangle", "size_m": [0.02, 0.02], "translate_m": [0, 0, 0.4],
                      "material": {"model": "retroreflective", "spot_radius_m": -1}}]}
    with pytest.raises(ParameterError, match="objects\\[0\\].material.spot_radius_m"):
        Scene.from_dict(d)
    d["objects"][0]["material"] = {"model": "retroreflective", "spot_radius": 0.01}
    with pytest.raises(ParameterError, match="spot_radius_m"):
        Scene.from_dict(d)
