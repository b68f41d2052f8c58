"""The material study: how a hidden target's BRDF changes what NLOS reconstruction recovers."""
