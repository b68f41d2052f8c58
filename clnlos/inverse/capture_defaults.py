"""Defaults a capture's format suggests where the user gave none (pure, no OpenCL).

A reader records what the published pipeline of its format does (attributes of
:class:`clnlos.io.capture.Capture`): the LCT release (:mod:`clnlos.io.formats.mat`) is
reconstructed by its published code at 16 ps (its 4 ps bins summed in fours) with the
radiometric weighting (t/T)^2 of retroreflective targets (``isdiffuse = 0``): LCT's and
f-k's ``brdf = "retroreflective"``, and for the iterative method the same 1/r^2 falloff of
its voxels (``falloff = 2``, :mod:`clnlos.forward.transport`), where it assumes the
Lambertian lobe or lets the photons choose it (``brdf = "auto"``: the lobe chosen is then the
angular law of voxels that fall off as 1/r^2; the "retroreflective" lobe carries its own
spot, :meth:`clnlos.inverse.iterative.IterativeInversion.lobe_falloff`). A flag or config
field the user sets always wins; each default taken is one note line.
"""

from __future__ import annotations

from clnlos.brdf.catalog import AUTO
from clnlos.config import (
    CLOSED_FORM_BRDFS,
    RETROREFLECTIVE_FALLOFF,
    ReconstructionConfig,
)

CLOSED_FORM_METHODS = ("lct", "fk")  # the methods whose falloff is their reflectance
ITERATIVE = "iterative"  # its voxels' falloff takes a retroreflective hint (falloff 2)


def format_defaults(attrs: dict, config: ReconstructionConfig, *, bins_kept: int,
                    bin_width_s: float) -> tuple[ReconstructionConfig, list[str]]:
    """(config, notes): ``config`` with the reflectance (attribute ``reflectance_default``,
    for LCT and f-k, whose falloff models it) and the time bin (``bin_width_default_s``: the
    kept window of ``bins_kept`` bins of ``bin_width_s`` rebinned to it) the format suggests,
    where
    the config leaves them to the default (not set, not named in ``config.user_fields``: an
    explicit ``brdf`` or ``falloff`` keeps the method's physics)."""
    notes = []
    changes = {}
    hint = attrs.get("reflectance_default")
    chosen = {"falloff", "brdf"} & config.user_fields
    if (hint is not None and config.method in CLOSED_FORM_METHODS and config.falloff is None
            and config.brdf == "lambertian" and not chosen and hint in CLOSED_FORM_BRDFS):
        changes["brdf"] = hint
        falloff = f" (falloff {RETROREFLECTIVE_FALLOFF:g})" if hint == "retroreflective" else ""
        notes.append(f"brdf {hint}{falloff}: "
                     f"{attrs.get('reflectance_source', 'the format')} (--brdf lambertian for "
                     "a diffuse target)")
    lobe_left = ((config.brdf == "lambertian" and not chosen)
                 or (config.brdf == AUTO and "falloff" not in config.user_fields))
    if (hint == "retroreflective" and config.method == ITERATIVE and config.falloff is None
            and lobe_left):
        changes["falloff"] = RETROREFLECTIVE_FALLOFF
        notes.append(f"falloff {RETROREFLECTIVE_FALLOFF:g} (retroreflective voxels, 1/r^2): "
                     f"{attrs.get('reflectance_source', 'the format')} (--falloff 4 for a "
                     "diffuse target)")
    target = attrs.get("bin_width_default_s")
    if (target and config.bins is None and "bins" not in config.user_fields
            and float(target) > bin_width_s):
        bins = max(1, int(round(bins_kept * bin_width_s / float(target))))
        if bins < bins_kept:
            changes["bins"] = bins
            notes.append(f"{bins} bins of {bins_kept * bin_width_s / bins * 1e12:.3g} ps: "
                         f"{attrs.get('bin_width_default_source', 'the format')} "
                         "(change with --bins)")
    return (config.replace(**changes) if changes else config), notes
