"""Defaults a capture's format suggests where the user gave none (pure, no OpenCL).

A reader records what the published pipeline of its format does (attributes of
:class:`clnlos.io.capture.Capture`): the LCT release (:mod:`clnlos.io.formats.mat`) is
reconstructed by its published code at 16 ps (its 4 ps bins summed in fours) with the
radiometric weighting (t/T)^2 of retroreflective targets (``isdiffuse = 0``). A flag or config
field the user sets always wins; each default taken is one note line.
"""

from __future__ import annotations

from clnlos.config import METHOD_FALLOFF, ReconstructionConfig


def format_defaults(attrs: dict, config: ReconstructionConfig, *, bins_kept: int,
                    bin_width_s: float) -> tuple[ReconstructionConfig, list[str]]:
    """(config, notes): ``config`` with the falloff (attribute ``falloff_default``, for a
    method that weights by one) and the time bin (``bin_width_default_s``: the kept window
    of ``bins_kept`` bins of ``bin_width_s`` rebinned to it) the format suggests, where
    the config leaves them to the default."""
    notes = []
    changes = {}
    hint = attrs.get("falloff_default")
    own = METHOD_FALLOFF.get(config.method)
    if hint is not None and config.falloff is None and own is not None and float(hint) != own:
        changes["falloff"] = float(hint)
        notes.append(f"falloff {float(hint):g}: {attrs.get('falloff_source', 'the format')}"
                     " (--falloff 4 / falloff=4 for a diffuse target)")
    target = attrs.get("bin_width_default_s")
    if target and config.bins is None and float(target) > bin_width_s:
        bins = max(1, int(round(bins_kept * bin_width_s / float(target))))
        if bins < bins_kept:
            changes["bins"] = bins
            notes.append(f"{bins} bins of {bins_kept * bin_width_s / bins * 1e12:.3g} ps: "
                         f"{attrs.get('bin_width_default_source', 'the format')} "
                         "(--bins / bins= to change)")
    return (config.replace(**changes) if changes else config), notes
