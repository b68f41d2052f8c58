"""Reconstruction, stage by stage: noise estimate and SNR rules, the slab deconvolution,
the inversion methods (LCT, f-k, iterative) behind one contract, the composed pipeline."""
