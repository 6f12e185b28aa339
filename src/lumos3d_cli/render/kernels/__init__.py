"""numba kernels of the CPU rasterizer. Arrays in, arrays out; no torch here."""
