"""The OpenCL runtime: devices, contexts and queues, programs, buffers, FFT plans, caches,
limits, and the checks of the environment."""
