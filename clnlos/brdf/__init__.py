"""BRDF models and materials (analytic models; the confocal retro-reflection slice)."""

from clnlos.brdf.models import MODELS, BRDFModel, make_model, retro_slice

__all__ = ["MODELS", "BRDFModel", "make_model", "retro_slice"]
