"""BRDF models and materials: measured data (data), analytic models and the confocal
retro-reflection slice (models), fits and the torch MLP (fit, mlp), textures (texture),
stored models (store), the seed's ten presets (presets)."""
