import pytest
import yaml


@pytest.fixture
def tiny_config(tmp_path, shared_data):
    """Write a small, fast training config and return its path; `changes` update it."""

    def make(stage="teacher", name="run", **changes):
        values = {
            "stage": stage,
            "output": str(tmp_path / name),
            "model": "tiny",
            "data": {"root": str(shared_data / "scenes"), "views": 2, "width": 56, "height": 42,
                     "scenes": ["video_fox", "statue", "llff_fern"]},
            "optim": {"steps": 6, "warmup_steps": 2},
            "log_every": 1,
            "checkpoint_every": 0,
        }
        for key, value in changes.items():
            section, _, field = key.partition("__")
            if field:
                values.setdefault(section, {})[field] = value
            else:
                values[key] = value
        path = tmp_path / f"{name}.yaml"
        path.write_text(yaml.safe_dump(values))
        return path

    return make
