"""Float64 numpy references of every kernel, written independently of the kernel code."""
