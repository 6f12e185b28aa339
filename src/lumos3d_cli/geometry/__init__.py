"""Registered geometry: structure-from-motion, given poses, similarity transforms, network depth
aligned to sparse points, and the multi-view consistency of depth maps."""
