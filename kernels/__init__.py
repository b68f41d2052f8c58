"""OpenCL kernel sources of clnlos, shipped as package data (``clnlos.kernels``).

The ``.cl`` files are read through :mod:`importlib.resources` by :mod:`clnlos.runtime.programs`;
nothing here is imported for its code.
"""
