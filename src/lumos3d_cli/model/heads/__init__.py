"""Prediction heads on the aggregator tokens: cameras, depth and per-pixel Gaussians."""
