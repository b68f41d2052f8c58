"""The forward model, stage by stage: scene sampling, the light-cone and bistatic transport,
the slab blur Phi * Phi, the laser pulse, photon noise, and the model composed from a scene."""
