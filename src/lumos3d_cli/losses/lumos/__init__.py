"""The Lumos loss: 0.1 content (VGG features) + 1.0 image L1 + 0.01 voxel statistics."""
