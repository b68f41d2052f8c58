"""Photon noise of the detector: Poisson counts of the expected transient.

    N ~ Poisson(eta tau + dark),  eta = photons emitted x efficiency x etendue (m^2 sr),
    dark = dark-count rate x exposure x bin width x repetition rate (counts per bin)

per scan point: the photons emitted and the exposure are those of one scan point's dwell
(``[detector] exposure_s`` is per scan point, so the counts of a scan point do not depend on
how many points the scan has)

with tau in 1/(m^2 sr) per bin (:mod:`clnlos.forward.model`); the generator is a
``numpy.random.Generator`` (seeded by the scene's ``seed``), so a capture is reproducible.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clnlos.forward.scene import Scene


def photon_counts(tau: np.ndarray, scene: Scene, rng: np.random.Generator) -> np.ndarray:
    """Poisson counts (float32) of the scene's detector for the expected transient ``tau``."""
    det = scene.detector
    eta = det.photons_emitted() * det.efficiency * det.etendue_m2_sr
    dark = det.dark_count_rate_hz * det.exposure_s * scene.bin_width_s * det.rep_rate_hz
    lam = np.maximum(tau.astype(np.float64), 0) * eta + dark
    return rng.poisson(lam).astype(np.float32)


@dataclass
class PhotonNoise:
    """The photon-noise stage of a scene: each call draws from a fresh generator seeded by
    the scene's ``seed`` (the same scene gives the same counts)."""

    scene: Scene

    @classmethod
    def of_scene(cls, scene: Scene) -> PhotonNoise:
        return cls(scene)

    def __call__(self, tau: np.ndarray) -> np.ndarray:
        return photon_counts(tau, self.scene, np.random.default_rng(self.scene.seed))
