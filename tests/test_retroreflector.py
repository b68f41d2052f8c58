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
@pytest.mark.fp64
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


# ---------------------------------------------------------------- the inversions' side
def test_retro_lobe_falls_off_as_one_over_r_squared_where_the_spot_holds_the_cone():
    """G(0, z) of clnlos.physics.lobe relative to the Lambertian 1/r^4: ~ z^2 (net 1/r^2) for
    a spot far wider than the cone, ~ constant (1/r^4) for one far narrower."""
    from clnlos.physics.lobe import RetroLobe, lobe_weight_table
    z = np.array([0.4, 0.8])
    wide = RetroLobe.retroreflector(Retroreflector.preset(
        divergence_deg=0.05, spot_radius_m=0.05, diffuse_albedo=0.0), "wide")
    narrow = RetroLobe.retroreflector(Retroreflector.preset(
        divergence_deg=10.0, spot_radius_m=1e-4, diffuse_albedo=0.0), "narrow")
    g_wide = lobe_weight_table(wide, z, 0.01, (1, 1))[:, 0, 0]
    g_narrow = lobe_weight_table(narrow, z, 0.01, (1, 1))[:, 0, 0]
    assert g_wide[1] / g_wide[0] == pytest.approx(4.0, rel=0.01)
    assert g_narrow[1] / g_narrow[0] == pytest.approx(1.0, rel=0.01)
    assert not wide.lambertian and not wide.flat


def test_closed_form_methods_take_lambertian_or_retroreflective_only():
    from clnlos.config import ReconstructionConfig
    from clnlos.inverse.methods import RETROREFLECTIVE_FALLOFF, Inversion
    cfg = ReconstructionConfig(method="lct", brdf="retroreflective").validate()
    inv = Inversion.__new__(Inversion)
    inv.config = cfg
    assert inv.falloff() == {"falloff": RETROREFLECTIVE_FALLOFF}
    inv.config = cfg.replace(falloff=3.0)  # an explicit falloff wins
    assert inv.falloff() == {"falloff": 3.0}
    inv.config = ReconstructionConfig(method="fk", brdf="lambertian").validate()
    assert inv.falloff() == {}  # the method's own
    for bad in ("auto", "glossy-paint"):
        with pytest.raises(ParameterError, match="retroreflective"):
            ReconstructionConfig(method="fk", brdf=bad).validate()
    cfg = ReconstructionConfig(method="lct", brdf="retroreflective").validate(
        {"brdf": "--brdf"})  # set by the user: lct reads it
    assert cfg.brdf == "retroreflective"


def test_auto_challenger_must_beat_the_walk_by_the_margin():
    from clnlos.brdf.lobes import auto_challengers, auto_ladder
    from clnlos.inverse.brdf_choice import challenge
    ladder, (retro,) = auto_ladder(), auto_challengers()
    assert retro.name == "retroreflective"
    tried = [(ladder[0].name, 0.5), (ladder[1].name, 0.6)]
    scores = {retro.name: 0.3}
    best, out = challenge(ladder[0], tried, [retro], lambda lb: scores[lb.name])
    assert best is retro and out[-1] == (retro.name, 0.3)
    best, _ = challenge(ladder[0], tried, [retro], lambda lb: scores[lb.name],
                        lambda a, b: 0.25)  # a gain of 0.2 within a margin of 0.25
    assert best is ladder[0]
    scores[retro.name] = 0.55
    assert challenge(ladder[0], tried, [retro], lambda lb: scores[lb.name])[0] is ladder[0]


def test_power_iteration_norm_does_not_overflow_float32(queue):
    import pyopencl.array as cla

    from clnlos.inverse.solvers import device_norm
    x = np.full(1000, 1e25, np.float32)  # its sum of squares is past float32's range
    assert device_norm(cla.to_device(queue, x)) == pytest.approx(1e25 * math.sqrt(1000),
                                                                 rel=1e-5)
    assert device_norm(cla.to_device(queue, np.zeros(4, np.float32))) == 0.0


def test_bistatic_transport_refuses_a_retroreflector(queue):
    d = {"scan": {"width_m": 0.04, "points": 4},
         "time": {"bin_width_s": 40e-12, "bins": 256},
         "slab": {"thickness_m": 0.0254, "mu_a": 0.53, "mu_s_prime": 262.0, "n": 1.12},
         "transport": {"model": "bistatic"},
         "objects": [{"shape": "rectangle", "size_m": [0.02, 0.02], "translate_m": [0, 0, 0.4],
                      "material": "retroreflective"}]}
    with pytest.raises(ParameterError, match="retroreflective"):
        ForwardModel(Scene.from_dict(d), queue=queue)
