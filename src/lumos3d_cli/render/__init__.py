"""Differentiable Gaussian rasterization: a multithreaded CPU kernel (numba), a dense pure-torch
twin for tests, and gsplat on CUDA when it is installed."""
