"""Linear operators with their adjoints, shared by the forward model and the inversions:
the operator contract, mass-conserving resampling, spectral (FFT) filters."""
