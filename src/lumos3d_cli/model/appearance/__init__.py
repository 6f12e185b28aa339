"""Appearance as a per-scene restoration operator in linear light, applied to the photos' own
pixels: the operator (curve and colour matrix), the per-view local gain grid, the illumination
head that predicts both from the aggregator's tokens, and their application to full-resolution
photos."""
