"""Choices of the jobs' options that the command line shows in its options and `--help`: here
so that it can name them without importing torch, pycolmap and the rest of the jobs
(pipeline.presets and pipeline.scene_geometry, which use them, import those)."""

DEFAULT_RESTORE_PRESET = "balanced"
GEOMETRY_SOURCES = ("auto", "network", "sfm")
EXPOSURE_KEYS = ("content", "fixed")  # pipeline.presets.RestorePreset.exposure_key
