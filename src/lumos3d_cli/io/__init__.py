"""Input and output: images, colour encoding, Gaussian scenes, cameras."""
