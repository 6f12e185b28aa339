"""Training that fails safe, through the real `lumos3d train` in a child process (issue 17): a
signal ends a run with a checkpoint and a non-zero exit; resuming says where it resumes; a damaged
or missing checkpoint falls back to the newest intact one, naming what it skipped."""

import errno
import json
import logging
import re
import shutil
import signal
from pathlib import Path

import pytest

from lumos3d_cli.errors import InputError
from lumos3d_cli.model.checkpoints import read_provenance
from lumos3d_cli.train.config import load_config
from lumos3d_cli.train.distributed import setup_distributed
from lumos3d_cli.train.trainer import Trainer

from assertions import expect_input_error
from processes import interrupt_when, run_lumos3d


def _output(config) -> Path:
    return Path(str(config).replace(".yaml", ""))


def _unwrapped(text: str) -> str:
    """stderr without whitespace: log lines are wrapped (long paths folded) at the console width."""
    return re.sub(r"\s+", "", text)


def _trained(config):
    """Four steps in this process with checkpoints after steps 2 and 4 (`latest` names step 4)."""
    Trainer(load_config(config, []), setup_distributed("cpu")).run()
    checkpoints = _output(config) / "checkpoints"
    assert sorted(p.name for p in checkpoints.glob("step_*")) == ["step_00000002", "step_00000004"]
    return checkpoints


def test_sigint_stops_with_a_checkpoint_and_exit_130_then_resume_says_where(tiny_config):
    config = tiny_config(name="stopped", optim__steps=1000)
    output = _output(config)
    stopped = interrupt_when(("train", config), lambda _: (output / "metrics.jsonl").is_file(), signal.SIGINT, poll=0.2)
    assert stopped.code == 130, stopped.err[-3000:]
    assert stopped.last_line.startswith("interrupted by SIGINT: stopped after step "), stopped.err[-3000:]
    assert stopped.last_line.endswith("saved; continue with --resume")
    step = int((output / "checkpoints" / "latest").read_text().strip().removeprefix("step_"))
    assert 1 <= step < 1000 and f"step_{step:08d}" in stopped.last_line
    assert [p.name for p in output.rglob(".*")] == [".lumos3d-manifest.json"]  # no temporaries, only the run's list
    resumed = run_lumos3d("train", config, "--resume", "--max-steps", step + 1, "--json")
    assert resumed.code == 0, resumed.err[-3000:]
    assert f"resuming from step {step} ({output / 'checkpoints' / f'step_{step:08d}'})" in resumed.err
    assert json.loads(resumed.out)["steps_done"] == step + 1


def test_a_corrupt_training_state_falls_back_to_the_newest_intact_checkpoint(tiny_config):
    config = tiny_config(name="corrupt", optim__steps=4, checkpoint_every=2)
    checkpoints = _trained(config)
    damaged = checkpoints / "step_00000004" / "training_state.pt"
    damaged.write_bytes(damaged.read_bytes()[:100])
    result = run_lumos3d("train", config, "--resume", "--json")
    assert result.code == 0, result.err[-3000:]
    err = _unwrapped(result.err)
    assert _unwrapped(f"skipping checkpoint step_00000004: {damaged}: cannot be read (RuntimeError:") in err
    assert _unwrapped("the checkpoint is damaged") in err and "internal error" not in result.err
    assert "resuming from step 2" in result.err
    summary = json.loads(result.out)
    assert summary["steps_done"] == 4 and summary["skipped_steps"] == 0


def test_latest_naming_a_missing_step_folder(tiny_config):
    config = tiny_config(name="missing", optim__steps=4, checkpoint_every=2)
    checkpoints = _trained(config)
    (checkpoints / "latest").write_text("step_00000099\n")
    fallback = run_lumos3d("train", config, "--resume", "--max-steps", 4)
    assert fallback.code == 0, fallback.err[-3000:]
    assert _unwrapped(f"{checkpoints / 'latest'} names {checkpoints / 'step_00000099'}, which is missing") in _unwrapped(fallback.err)
    assert "resuming from step 4" in fallback.err
    for folder in checkpoints.glob("step_*"):
        for file in folder.iterdir():
            file.unlink()
        folder.rmdir()
    expect_input_error(run_lumos3d("train", config, "--resume"),
                       f"{checkpoints / 'latest'} names step_00000099, but the folder {checkpoints / 'step_00000099'} is missing")


def test_max_steps_below_one_is_refused(tiny_config):
    config = tiny_config(name="zero")
    expect_input_error(run_lumos3d("train", config, "--max-steps", 0), "--max-steps 0: give the number of steps")
    assert not _output(config).exists()


def test_a_validation_of_diverged_weights_ends_the_run_as_diverged_not_as_bad_input(tiny_config):
    config = tiny_config(name="diverged", optim__steps=6, optim__warmup_steps=0, validate_every=2)
    result = run_lumos3d("train", config, "optim.lr=1e30")
    assert result.code == 1, result.err  # once exit 2, as if the data were at fault
    assert result.err.strip().splitlines()[-1].startswith("error: validation after step 2: the model's output is not finite")
    assert "training diverged" in result.err


def test_a_misspelt_exclusion_is_named(tiny_config, caplog):
    """A warning, not a refusal: a fixed hold-out list on a partial copy of a dataset names scenes
    that are not there; a misspelling trains on the scene it meant to leave out, and is said."""
    config = load_config(tiny_config(name="exclude"), ["data.exclude=[stattue]"])
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli"):
        trainer = Trainer(config, setup_distributed("cpu"))
    assert "data.exclude: stattue: no such training scene" in caplog.text
    assert "statue" in {record.name for record in trainer.dataset.records}


def test_an_excluded_scene_is_never_read_and_scenes_too_small_are_warned_of(tiny_config, shared_data, tmp_path, caplog):
    """data.exclude leaves a damaged scene out before reading it (it was read first, and refused the
    run); a scene with fewer photos than data.views is named in a warning (it was an info line)."""
    root = tmp_path / "root"
    root.mkdir()
    for name in ("statue", "llff_fern"):
        (root / name).symlink_to(shared_data / "scenes" / name)
    (root / "broken" / "images").mkdir(parents=True)  # holds no images: an error when read
    (root / "small" / "images").mkdir(parents=True)
    shutil.copy(next((shared_data / "scenes" / "statue" / "images").iterdir()), root / "small" / "images")
    config = tiny_config(name="broken", data__root=str(root), data__scenes=[])
    with pytest.raises(InputError, match="broken/images: folder holds no images"):
        Trainer(load_config(config, []), setup_distributed("cpu"))
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli"):
        trainer = Trainer(load_config(config, ["data.exclude=[broken]"]), setup_distributed("cpu"))
    assert {record.name for record in trainer.dataset.records} == {"statue", "llff_fern"}
    assert "1 scene(s) have fewer than 2 posed views and are not used: small" in caplog.text


def test_cuda_on_a_machine_without_it_is_refused_naming_the_setting(tiny_config, monkeypatch):
    import pytest
    import torch

    from lumos3d_cli.errors import InputError

    machine_has_cuda = torch.cuda.is_available()
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(InputError, match="device cuda: CUDA is not available on this machine; train with device=cpu"):
        setup_distributed("cuda")
    assert setup_distributed("auto").device.type == "cpu"
    config = tiny_config(name="nocuda")
    if not machine_has_cuda:  # the command line, end to end, where the machine really has none
        expect_input_error(run_lumos3d("train", config, "device=cuda"), "device cuda: CUDA is not available")
        assert not _output(config).exists()


def test_a_resume_refuses_a_config_that_changes_what_the_run_learns(tiny_config):
    """The optimizer's saved state carries the run's learning rate, betas and parameter groups: a
    resume with another `optim.lr` went on at the old rate while config.yaml recorded the new one,
    and another `trainable` ended in an internal error. How long the run goes and how it reports
    may change."""
    config = tiny_config(name="changed", optim__steps=4, checkpoint_every=2)
    checkpoints = _trained(config)
    saved = (checkpoints / "step_00000004" / "config.yaml").read_text()
    for override, named in (("optim.lr=0.05", "optim.lr 0.0002 -> 0.05"),
                            ("trainable=[camera_head]", "trainable [] -> ['camera_head']"),
                            ("model=small", "model 'tiny' -> 'small'")):
        result = run_lumos3d("train", config, override, "optim.steps=6", "--resume")
        expect_input_error(result, f"{checkpoints / 'step_00000004'}: this config differs from the run's in {named}",
                           "resume with its config.yaml, or start a new run with --new-run")
        assert (checkpoints / "step_00000004" / "config.yaml").read_text() == saved
    # validations scored on other samples would be compared with the earlier ones
    expect_input_error(run_lumos3d("train", config, "validation_samples=3", "optim.steps=6", "--resume"),
                       "validation_samples 8 -> 3")
    # a checkpoint of an earlier release lacks keys added since: their defaults are no change
    import yaml

    older = yaml.safe_load(saved)
    del older["brackets"]["well_exposed"]
    (checkpoints / "step_00000004" / "config.yaml").write_text(yaml.safe_dump(older))
    # the data moved (another path, same files) and the reporting changed: the run goes on
    moved = _output(config).parent / "scenes-moved"
    moved.symlink_to(Path(load_config(config, []).data.root).resolve(), target_is_directory=True)
    result = run_lumos3d("train", config, "optim.steps=6", "log_every=2", "checkpoint_every=3", f"data.root={moved}",
                         "--resume", "--json")
    assert result.code == 0, result.err[-3000:]
    assert json.loads(result.out)["steps_done"] == 6


def test_a_resume_from_an_older_checkpoint_drops_what_later_steps_wrote(tiny_config):
    """The newest checkpoint damaged, the run goes on from the one before: the final weights and
    the validation picture of the step it no longer reaches were left beside its own."""
    config = tiny_config(name="older", optim__steps=6, checkpoint_every=3, validate_every=3, validation_samples=1)
    Trainer(load_config(config, []), setup_distributed("cpu")).run()
    output = _output(config)
    assert (output / "final.safetensors").is_file() and (output / "validation" / "step_00000006.png").is_file()
    damaged = output / "checkpoints" / "step_00000006" / "training_state.pt"
    damaged.write_bytes(damaged.read_bytes()[:100])
    result = run_lumos3d("train", config, "--resume", "--max-steps", 5, "--json")
    assert result.code == 0, result.err[-3000:]
    assert not (output / "final.safetensors").exists() and not (output / "validation" / "step_00000006.png").exists()
    assert (output / "validation" / "step_00000003.png").is_file()
    assert [json.loads(line)["step"] for line in (output / "validation.jsonl").read_text().splitlines()] == [3]
    manifest = json.loads((output / ".lumos3d-manifest.json").read_text())["files"]
    assert "final.safetensors" not in manifest and "validation/step_00000006.png" not in manifest


def test_a_resume_past_the_final_step_drops_the_shorter_runs_final_weights(tiny_config):
    """A finished 4-step run resumed to 8 steps and stopped at 6 by --max-steps kept the 4-step
    final.safetensors beside a config of 8 steps, as if it were the run's final weights."""
    config = tiny_config(name="longer", optim__steps=4)
    Trainer(load_config(config, []), setup_distributed("cpu")).run()
    output = _output(config)
    assert read_provenance(output / "final.safetensors")["steps"] == 4
    result = run_lumos3d("train", config, "optim.steps=8", "--resume", "--max-steps", 6, "--json")
    assert result.code == 0, result.err[-3000:]
    assert json.loads(result.out)["steps_done"] == 6 and not (output / "final.safetensors").exists()
    assert "final.safetensors" not in json.loads((output / ".lumos3d-manifest.json").read_text())["files"]
    result = run_lumos3d("train", config, "optim.steps=8", "--resume", "--json")  # on to the end: final again
    assert result.code == 0, result.err[-3000:]
    assert read_provenance(output / "final.safetensors")["steps"] == 8
    result = run_lumos3d("train", config, "optim.steps=8", "--resume", "--json")  # nothing left to do: kept
    assert result.code == 0, result.err[-3000:]
    assert read_provenance(output / "final.safetensors")["steps"] == 8


def test_files_may_move_on_resume_but_not_appear_or_go():
    from lumos3d_cli.train.resume_config import _may_differ

    assert _may_differ("data.root", "/data/scenes", "/mnt/scenes") and _may_differ("log_every", 10, 1)
    assert _may_differ("model", "runs/a/final.safetensors", "/moved/final.safetensors")
    assert not _may_differ("model", "tiny", "small")  # an architecture, not a file
    assert not _may_differ("brackets.root", None, "/data/brackets")  # the bracket loss switched on mid-run
    assert not _may_differ("teacher", "/t.safetensors", None) and not _may_differ("optim.lr", 2e-4, 0.05)
    assert _may_differ("data.root", "scenes", "/data/scenes")  # a bare relative folder that moved
    assert not _may_differ("teacher", "low-light", "over-exposure")  # another bundled model, not a file that moved
    assert _may_differ("teacher", "runs/t/final.safetensors", "/moved/final.safetensors")


def test_a_damaged_config_in_the_newest_checkpoint_falls_back_like_damaged_weights(tiny_config):
    config = tiny_config(name="badconfig", optim__steps=4, checkpoint_every=2)
    checkpoints = _trained(config)
    (checkpoints / "step_00000004" / "config.yaml").write_text("optim: [unclosed")
    result = run_lumos3d("train", config, "--resume", "--json")
    assert result.code == 0, result.err[-3000:]
    assert "skipping checkpoint step_00000004" in result.err and "resuming from step 2" in result.err


def test_bad_data_met_mid_run_keeps_the_steps_done(tiny_config, monkeypatch):
    """A photo that cannot be read, met at step 3 of a run that checkpoints every 4 steps: the
    three steps done were lost; a checkpoint after step 3 is saved and --resume goes on from it."""
    config = tiny_config(name="damaged", optim__steps=6, checkpoint_every=4)
    trainer = Trainer(load_config(config, []), setup_distributed("cpu"))
    load_batch = trainer._load_batch

    def damaged_at_step_3(step):
        if step == 3:
            raise InputError("scene/images/006.jpg: cannot be read (truncated)")
        return load_batch(step)

    monkeypatch.setattr(trainer, "_load_batch", damaged_at_step_3)
    with pytest.raises(InputError, match=r"006.jpg: cannot be read \(truncated\); the checkpoint of the 3 steps done is "
                                         r"saved: replace the file, then add --resume \(or start a new run with its scene "
                                         r"in data.exclude\)"):
        trainer.run()
    run = Path(str(config).replace(".yaml", ""))
    assert (run / "checkpoints" / "latest").read_text().strip() == "step_00000003"
    # the file replaced (here: the reader works again), the run continues from step 3; leaving its
    # scene out instead would change what validation scores, which a resume refuses
    with pytest.raises(InputError, match=r"differs from the run's in data.exclude"):
        Trainer(load_config(config, ["data.exclude=[statue]"]), setup_distributed("cpu")).run(resume=True)
    resumed = Trainer(load_config(config, []), setup_distributed("cpu")).run(resume=True)
    assert resumed.steps_done == 6 and resumed.history[0].step == 3


def test_a_new_run_beside_the_current_folder_given_as_dot(tmp_path, monkeypatch):
    """`lumos3d train ... output=. --new-run` in a run folder: "PosixPath('.') has an empty name"."""
    from lumos3d_cli.train.run_folder import numbered_folder

    (tmp_path / "run").mkdir()
    monkeypatch.chdir(tmp_path / "run")
    assert numbered_folder(Path(".")) == tmp_path / "run-2"
    (tmp_path / "run" / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "run" / "sub")
    assert numbered_folder(Path("..")) == tmp_path / "run-2"  # was "sub/..-2"


def test_a_collective_that_failed_because_another_rank_stopped_is_said_so():
    """When one rank stopped on bad data (or was killed), the others reported gloo's "Connection
    reset by peer" as an internal error to report."""
    import torch

    from lumos3d_cli.errors import RunError
    from lumos3d_cli.train.distributed import DistributedContext, peer_stopped

    two = DistributedContext(1, 2, 1, torch.device("cpu"))
    failed = RuntimeError("[../third_party/gloo/gloo/transport/tcp/pair.cc:537] Read error [127.0.0.1]:1234: "
                          "Connection reset by peer")
    stopped = peer_stopped(failed, two)
    assert isinstance(stopped, RunError) and "rank 1: another process of this distributed run stopped" in str(stopped)
    assert peer_stopped(RuntimeError("shapes do not match"), two) is None  # a real fault stays one
    assert peer_stopped(failed, DistributedContext(0, 1, 0, torch.device("cpu"))) is None


def test_a_run_that_ends_diverged_fails_without_final_weights(tiny_config):
    """optim.lr=1e30: steps 1-3 skipped, then "4 steps done", exit 0 and a final.safetensors of
    the diverged weights (NaN cameras downstream)."""
    config = tiny_config(name="ends-diverged", optim__steps=4, optim__warmup_steps=0, checkpoint_every=2)
    result = run_lumos3d("train", config, "optim.lr=1e30", "--json")
    assert result.code == 1 and "Traceback" not in result.err, result.err[-3000:]
    assert result.err.strip().splitlines()[-1].startswith("error: training ended after 4 steps, but the last 3 steps "
                                                          "were skipped for a non-finite loss or gradient")
    assert _unwrapped("(3 skipped in all); training diverged, and no checkpoint of this run holds weights from before: "
                      "start a new run (--new-run) with a lower optim.lr") in _unwrapped(result.err)
    assert result.out == "" and not (_output(config) / "final.safetensors").exists()
    # after one skipped step (one bad batch, as far as the run can tell) step 2 was still saved
    assert [p.name for p in _output(config).glob("checkpoints/step_*")] == ["step_00000002"]


def _full_disk_in_torch_save(obj, handle):
    handle.write(b"PK\x03\x04")  # torch's writer raises its own error over the file's OSError
    try:
        raise OSError(errno.ENOSPC, "No space left on device")
    except OSError:
        raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 704 vs 598") from None


def _full_disk_in_safetensors(tensors, filename, metadata=None):
    from safetensors import SafetensorError

    Path(filename).write_bytes(b"\x00" * 8)
    raise SafetensorError("Error while serializing: I/O error: No space left on device (os error 28)")


@pytest.mark.parametrize("module, name, writer", [("torch", "save", _full_disk_in_torch_save),
                                                  ("lumos3d_cli.io.weight_files", "save_file", _full_disk_in_safetensors)],
                         ids=["training-state", "weights"])
def test_a_full_disk_during_a_checkpoint_is_named_and_leaves_the_earlier_ones(tiny_config, monkeypatch, module, name,
                                                                               writer):
    """A full disk in the middle of a checkpoint ended the run as an internal error (torch's
    RuntimeError, safetensors' SafetensorError)."""
    import importlib

    trainer = Trainer(load_config(tiny_config(name=f"full-{name}", optim__steps=3, checkpoint_every=1), []),
                      setup_distributed("cpu"))
    target = importlib.import_module(module)
    real_writer = getattr(target, name)
    saves = {"n": 0}

    def full_at_the_second_save(*args, **kwargs):
        saves["n"] += 1
        return (writer if saves["n"] == 2 else real_writer)(*args, **kwargs)

    monkeypatch.setattr(target, name, full_at_the_second_save)
    checkpoints = trainer.output / "checkpoints"
    with pytest.raises(InputError, match=rf"^{re.escape(str(checkpoints))}: no space left on the device while writing "
                                         r"the checkpoint of step 2, which was not kept; make room or make the folder "
                                         r"writable, then continue with --resume$"):
        trainer.run()
    assert sorted(p.name for p in checkpoints.iterdir()) == ["latest", "step_00000001"]  # nothing half-written
    assert (checkpoints / "latest").read_text().strip() == "step_00000001"


def test_a_full_disk_while_selecting_is_no_bad_sample(tiny_config, monkeypatch):
    """selected.safetensors' full disk went the way of a bad validation sample: a checkpoint
    written onto the full disk, and advice to leave a scene out."""
    import errno

    from lumos3d_cli.train import trainer as trainer_module

    trainer = Trainer(load_config(tiny_config(name="full-select", optim__steps=4, validate_every=2,
                                              validation_samples=1, select="psnr"), []), setup_distributed("cpu"))
    real_save = trainer_module.save_checkpoint

    def full_for_the_selection(model, path, *args, **kwargs):
        if path.name == "selected.safetensors":
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_save(model, path, *args, **kwargs)

    monkeypatch.setattr(trainer_module, "save_checkpoint", full_for_the_selection)
    with pytest.raises(InputError) as error:
        trainer.run()
    assert str(error.value) == (f"{trainer.output}: no space left on the device while writing selected.safetensors, which "
                                "was not kept; make room or make the folder writable, then continue with --resume")


def test_a_failure_of_a_checkpoint_writer_that_is_no_full_disk_stays_an_error(tiny_config, monkeypatch):
    import torch

    trainer = Trainer(load_config(tiny_config(name="writer-bug", optim__steps=1, checkpoint_every=1), []),
                      setup_distributed("cpu"))

    def broken(obj, handle):
        raise RuntimeError("a writer bug")

    monkeypatch.setattr(torch, "save", broken)
    with pytest.raises(RuntimeError, match="a writer bug"):
        trainer.run()


def test_a_torn_last_log_line_is_dropped_and_damage_elsewhere_is_named(tmp_path, caplog):
    """A run killed while appending to metrics.jsonl left '{"step": 99, "lr": 0.0001, "ski', and
    --resume ended in an internal JSONDecodeError."""
    from lumos3d_cli.train.run_logs import RunLogs

    logs = RunLogs(tmp_path, tensorboard=False)
    for step in range(3):
        logs.append_step(step, 1e-4, False, 0.1, 0, {"total": 1.0})
    with open(tmp_path / "metrics.jsonl", "a") as handle:
        handle.write('{"step": 99, "lr": 0.0001, "ski')
    (tmp_path / "validation.jsonl").write_text('{"step": 2, "psnr": 20.0}\n{"step": 4, "ps')
    with caplog.at_level(logging.WARNING, logger="lumos3d_cli"):
        logs.truncate(2)
        assert logs.validated_steps() == {2}
    assert [json.loads(line)["step"] for line in (tmp_path / "metrics.jsonl").read_text().splitlines()] == [0, 1]
    assert f"{tmp_path / 'metrics.jsonl'}: dropping its last line, which a stopped run left unfinished" in caplog.text
    (tmp_path / "metrics.jsonl").write_text('{"step": 0}\n{"step": 1, "lr\n{"step": 2}\n')
    with pytest.raises(InputError, match=rf"^{re.escape(str(tmp_path / 'metrics.jsonl'))}: line 2 is not a log entry"):
        logs.truncate(2)


def test_a_checkpoint_config_that_is_not_text_is_skipped_like_damaged_weights(tiny_config):
    """A checkpoint's config.yaml that is not UTF-8 ended --resume in an internal UnicodeDecodeError;
    the docs say a config that cannot be read skips its checkpoint."""
    config = tiny_config(name="binary-config", optim__steps=4, checkpoint_every=2)
    checkpoints = _trained(config)
    (checkpoints / "step_00000004" / "config.yaml").write_bytes(b"\xff\xfe\x00")
    resumed = Trainer(load_config(config, []), setup_distributed("cpu")).run(resume=True)
    assert resumed.history[0].step == 2 and resumed.steps_done == 4
