"""Evaluation: image metrics, the LOM protocol, reports."""
