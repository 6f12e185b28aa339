"""The precisions weights are stored in (`lumos3d convert --dtype`), by name: here so that the
command line lists them in `--help` without importing torch (io.weight_files maps each name to
its torch dtype)."""

STORAGE_DTYPE_NAMES = ("float32", "float16", "bfloat16")
