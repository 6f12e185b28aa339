"""Test-time refinement: the forward pass's Gaussians (and optionally its cameras) optimised
against the restored input views through the CPU rasterizer's backward (`refine_gaussians`)."""
