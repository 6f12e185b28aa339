"""Transformer building blocks: attention, RoPE, MLP, LayerScale, blocks, patch embeddings."""
