"""The reflectance a reconstruction assumes (``--brdf``, ``[inversion] brdf``): the retro
lobe (:class:`clnlos.physics.lobe.RetroLobe`) of a preset, a BRDF texture or a fitted model,
and the ladder of lobes that ``"auto"`` chooses from.

A spec is one of: ``"lambertian"`` (the default: every method's physics), ``"auto"`` (the
lobe chosen from the capture, :mod:`clnlos.inverse.brdf_choice`), a material name
(:func:`clnlos.brdf.presets.material_names`: the seed's ten presets and the analytic ones),
or a file: a BRDF texture (``clnlos brdf texture``, its retro slice) or a fitted model
(``clnlos brdf fit``, its retro slice sampled at :data:`clnlos.physics.lobe.THETA_NODES`
angles), told apart by their ``format`` attribute.

The ``auto`` ladder: GGX microfacet lobes (ks = 1, f0 = 1) of roughness AUTO_ALPHAS, each
over a Lambertian floor of AUTO_FLOOR of its peak, and the Lambertian lobe: half widths from
0.4 to 16 degrees, the span of the measured presets' lobes (quartz glass 0.4 deg to the black
anode plate's 11.6 deg), a factor of about three apart.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from pathlib import Path

from clnlos.brdf.catalog import (
    AUTO,
    LAMBERTIAN,
    TEXTURE_FORMAT,
    check_brdf_spec,
    file_format,
    is_file_spec,
)
from clnlos.brdf.models import BRDFModel, retro_slice
from clnlos.brdf.presets import (
    ANALYTIC_PRESETS,
    RETROREFLECTIVE,
    preset_model,
    preset_table,
    retroreflector,
)
from clnlos.brdf.store import load_model
from clnlos.brdf.texture import read_texture
from clnlos.physics.lobe import THETA_NODES, RetroLobe

AUTO_ALPHAS = (0.01, 0.03, 0.1, 0.3)  # GGX roughness of the "auto" ladder's lobes
AUTO_FLOOR = 0.01                     # their Lambertian floor, a fraction of the peak


def model_lobe(model, name: str) -> RetroLobe:
    return RetroLobe.from_samples(retro_slice(model, THETA_NODES), name)


def retro_lobe(spec: str, base_dir=".") -> RetroLobe:
    """The retro lobe of a spec (not ``"auto"``; :func:`check_brdf_spec` first)."""
    if is_file_spec(spec):
        path = Path(base_dir) / spec
        if file_format(path) == TEXTURE_FORMAT:
            return RetroLobe.from_samples(read_texture(path).retro, str(spec))
        model, _ = load_model(path)
        return model_lobe(model, str(spec))
    return named_lobe(spec.lower())


@lru_cache(maxsize=64)
def named_lobe(key: str) -> RetroLobe:
    """The retro lobe of a material name (lower case), built once per process."""
    if key == LAMBERTIAN:
        return RetroLobe.lambert()
    if key == RETROREFLECTIVE:
        return RetroLobe.retroreflector(retroreflector(key), key)
    if key in preset_table():
        return model_lobe(preset_model(key), key)
    model = ANALYTIC_PRESETS.get(key)
    if model is None:
        return RetroLobe.lambert()
    return model_lobe(model, key)


@lru_cache(maxsize=16)
def ladder_lobe(alpha: float) -> RetroLobe:
    """A GGX lobe of roughness ``alpha`` (ks = 1, f0 = 1) over a Lambertian floor of
    AUTO_FLOOR of its peak."""
    spec = BRDFModel("microfacet", {"kd": 0.0, "ks": 1.0, "alpha": alpha, "f0": 1.0})
    f = retro_slice(spec, THETA_NODES)
    return RetroLobe.from_samples(f + AUTO_FLOOR * float(f.max()), f"ggx alpha {alpha:g}")


def lobe_by_name(name: str) -> RetroLobe:
    """The lobe a reconstruction recorded by name (``brdf_used``): a spec, or a lobe of the
    ``"auto"`` ladder (its challengers are specs)."""
    for lobe in auto_ladder():
        if lobe.name == name:
            return lobe
    return retro_lobe(name)


class AutoLadder(Sequence):
    """The Lambertian lobe, then GGX lobes of ever smaller roughness (AUTO_ALPHAS), each built
    when first indexed (:func:`ladder_lobe`, cached per process): the lobe search's walk
    stops at the first lobe that gains nothing, and a GGX lobe costs about 0.2 s to tabulate,
    so the lobes past it are not built."""

    _alphas = tuple(sorted(AUTO_ALPHAS, reverse=True))

    def __init__(self):
        self._lambert = RetroLobe.lambert()  # one object per ladder, as the GGX lobes are

    def __len__(self) -> int:
        return 1 + len(self._alphas)

    def __getitem__(self, k):
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        i = range(len(self))[k]  # IndexError past either end, negative indices from the end
        return self._lambert if i == 0 else ladder_lobe(self._alphas[i - 1])

    def __add__(self, other) -> list[RetroLobe]:
        return list(self) + list(other)


def auto_ladder() -> AutoLadder:
    """The lobes ``"auto"`` chooses among: the Lambertian, then ever sharper lobes (built as
    they are reached, :class:`AutoLadder`)."""
    return AutoLadder()


def auto_challengers() -> list[RetroLobe]:
    """The lobes ``"auto"`` scores beside the ladder, each against the ladder's choice
    (:func:`clnlos.inverse.brdf_choice.challenge`): the retroreflector
    (:mod:`clnlos.physics.retroreflector`), a family of its own (its falloff in r)."""
    return [named_lobe(RETROREFLECTIVE)]


__all__ = ["AUTO", "AutoLadder", "LAMBERTIAN", "auto_challengers", "auto_ladder",
           "check_brdf_spec", "lobe_by_name", "retro_lobe"]
