"""Training data: degradation synthesis, datasets, view sampling."""
