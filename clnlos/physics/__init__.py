"""Pure physics and parameter types (no OpenCL): the slab, the grids the stages share, the
one light-cone PSF."""
