import statistics
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from lumos3d_cli.errors import InputError, Interrupted, NonFiniteError, RunError
from lumos3d_cli.model.checkpoints import read_checkpoint
from lumos3d_cli.train.config import load_config
from lumos3d_cli.train.distributed import setup_distributed
from lumos3d_cli.train.trainer import Trainer

WORKER = Path(__file__).with_name("ddp_worker.py")


def _trainer(path, overrides=()):
    return Trainer(load_config(path, list(overrides)), setup_distributed("cpu"))


def test_resumed_run_reproduces_the_uninterrupted_losses(tiny_config, monkeypatch):
    # oneDNN's first convolutions in a one-thread process (each test worker's) round differently
    # from its later ones (1e-7 relative at step 1: the process's first run against its second,
    # without any resume); the exact comparison below is about the run's own state, so without it
    monkeypatch.setattr(torch.backends.mkldnn, "enabled", False)
    straight = _trainer(tiny_config(name="straight")).run()
    assert straight.steps_done == 6 and not straight.stopped_early
    interrupted = _trainer(tiny_config(name="resumed")).run(stop_after=3)
    assert interrupted.stopped_early and interrupted.steps_done == 3
    resumed = _trainer(tiny_config(name="resumed")).run(resume=True)
    assert resumed.steps_done == 6
    first = [r.terms["total"] for r in interrupted.history] + [r.terms["total"] for r in resumed.history]
    assert first == [r.terms["total"] for r in straight.history]
    a = read_checkpoint(straight.final_checkpoint).tensors
    b = read_checkpoint(resumed.final_checkpoint).tensors
    assert all(torch.equal(a[k], b[k]) for k in a)
    log = Path(str(tiny_config(name="resumed")).replace(".yaml", "")) / "metrics.jsonl"
    assert [json.loads(line)["step"] for line in log.read_text().splitlines()] == list(range(6))


def test_a_resume_with_another_number_of_processes_is_warned_of(tiny_config, monkeypatch, caplog):
    """A run of 2 processes resumed as 1 (or the reverse) went on silently, its effective batch
    halved and samples drawn again, and "final" recorded world_size 1."""
    config = tiny_config(name="world", optim__steps=3)
    saved_by_two = Trainer._provenance
    monkeypatch.setattr(Trainer, "_provenance", lambda self, step: {**saved_by_two(self, step), "world_size": 2})
    _trainer(config).run(stop_after=1)
    monkeypatch.undo()
    _trainer(config).run(resume=True)
    assert "resuming a run of 2 process(es) with 1: each step now draws fewer samples" in caplog.text


def test_resume_drops_the_log_lines_of_redone_work(tiny_config):
    config = tiny_config(name="logs", validate_every=2, validation_samples=1)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=3)
    # a hard kill after a later validation, before any checkpoint: its lines must not survive
    with open(run / "metrics.jsonl", "a") as handle:
        handle.write(json.dumps({"step": 3, "total": 0.0}) + "\n")
    with open(run / "validation.jsonl", "a") as handle:
        handle.write(json.dumps({"step": 4, "samples": 1, "psnr": 0.0}) + "\n")
    _trainer(config).run(resume=True)
    assert [json.loads(line)["step"] for line in (run / "metrics.jsonl").read_text().splitlines()] == list(range(6))
    validation = [json.loads(line) for line in (run / "validation.jsonl").read_text().splitlines()]
    assert [v["step"] for v in validation] == [2, 4, 6] and all(v["psnr"] > 0 for v in validation)


def test_non_finite_steps_are_skipped_then_abort(tiny_config, monkeypatch):
    trainer = _trainer(tiny_config(name="nan", max_nonfinite_steps=3))
    original = trainer.objective.forward
    calls = {"n": 0}

    def sometimes_nan(*args, **kwargs):
        terms = original(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] == 2 or calls["n"] >= 4:
            terms["total"] = terms["total"] * float("nan")
        return terms

    monkeypatch.setattr(trainer.objective, "forward", sometimes_nan)
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    with pytest.raises(RunError, match="3 steps in a row had a non-finite loss"):
        trainer.run()
    assert trainer.nonfinite_total == 4
    assert any(not torch.equal(before[k], v) for k, v in trainer.model.state_dict().items())  # good steps applied
    assert all(torch.isfinite(v).all() for v in trainer.model.state_dict().values())
    # strict JSON: the skipped step's loss is null (it was a bare NaN, which strict parsers refuse)
    log = (trainer.output / "metrics.jsonl").read_text().splitlines()
    lines = [json.loads(line, parse_constant=lambda name: pytest.fail(f"{name} in metrics.jsonl")) for line in log]
    assert lines[1]["skipped"] and lines[1]["total"] is None and not lines[0]["skipped"]


def test_a_step_outside_run_counts_a_non_finite_loss(tiny_config, monkeypatch):
    """step() is public: called on its own (no run()), a non-finite loss is skipped and counted."""
    trainer = _trainer(tiny_config(name="lone-step"))
    original = trainer.objective.forward

    def nan_total(*args, **kwargs):
        terms = original(*args, **kwargs)
        terms["total"] = terms["total"] * float("nan")
        return terms

    monkeypatch.setattr(trainer.objective, "forward", nan_total)
    before = {k: v.clone() for k, v in trainer.model.state_dict().items()}
    report = trainer.step(0)
    assert report.skipped and (trainer.nonfinite_in_a_row, trainer.nonfinite_total) == (1, 1)
    assert all(torch.equal(before[k], v) for k, v in trainer.model.state_dict().items())


def test_student_stage_logs_every_term(tiny_config, tmp_path):
    teacher = _trainer(tiny_config(name="teacher", optim__steps=1)).run()
    config = tiny_config(stage="student", name="student", model=str(teacher.final_checkpoint),
                         teacher=str(teacher.final_checkpoint), optim__steps=2, validate_every=2,
                         validation_samples=3)
    result = _trainer(config).run()
    terms = result.history[-1].terms
    assert {"mse", "distill_pose", "distill_depth", "image", "voxel", "total"} <= set(terms)
    assert all(v == v for v in terms.values())
    run = Path(str(config).replace(".yaml", ""))
    assert (run / "validation" / "step_00000002.png").is_file()
    validation = [json.loads(line) for line in (run / "validation.jsonl").read_text().splitlines()]
    assert [v["step"] for v in validation] == [2] and validation[0]["samples"] == 3
    assert 0 < validation[0]["psnr"] < 60
    cameras = validation[0]["cameras"]
    assert cameras["pairs"] == 3 and 0 <= cameras["auc_30"] <= 1 and 0 <= cameras["rotation_error_median"] <= 180


def test_validation_samples_are_no_training_steps_inputs(tiny_config):
    """Validation scored steps 0..N-1's own inputs (the same views, crop and degradation)."""
    trainer = _trainer(tiny_config(stage="teacher", name="validation", optim__steps=4, batch_size=1))
    validation = [network_input for _, network_input, _ in trainer._validation_samples()]
    assert len(validation) == min(trainer.config.validation_samples, len(trainer.dataset))
    for step in range(8):
        batch = trainer._load_batch(step)
        network_input, _ = trainer.inputs_and_targets(batch, step)
        assert all(network_input.shape != v.shape or not torch.equal(network_input, v) for v in validation), step
    again = [network_input for _, network_input, _ in trainer._validation_samples()]
    assert all(torch.equal(a, b) for a, b in zip(validation, again))  # fixed across the run


@pytest.mark.parametrize("teacher_input", ["normal-light", "degraded"])
def test_the_teacher_sees_the_configured_images(tiny_config, teacher_input):
    teacher = _trainer(tiny_config(name="teacher", optim__steps=1)).run()
    config = tiny_config(stage="student", name=f"student-{teacher_input}", model=str(teacher.final_checkpoint),
                         teacher=str(teacher.final_checkpoint), teacher_input=teacher_input, optim__steps=1,
                         degrade__mode="mixed")
    trainer = _trainer(config)
    seen = {}
    original = trainer.inputs_and_targets

    def record(batch, step):
        seen["inputs"], seen["targets"] = original(batch, step)
        return seen["inputs"], seen["targets"]

    trainer.inputs_and_targets = record
    trainer.teacher.register_forward_pre_hook(lambda module, args: seen.setdefault("teacher", args[0].clone()))
    trainer.run()
    expected = seen["targets"] if teacher_input == "normal-light" else seen["inputs"]
    assert not torch.equal(seen["inputs"], seen["targets"])
    assert torch.equal(seen["teacher"], expected)


def _torchrun() -> str:
    return str(Path(sys.executable).with_name("torchrun"))


def test_two_process_ddp_keeps_ranks_identical(tiny_config, tmp_path):
    config = tiny_config(name="ddp", optim__steps=3)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    command = [_torchrun(), "--nproc_per_node", "2", "--master_port", "29517", str(WORKER), str(config), str(tmp_path)]
    completed = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    rank0 = torch.load(tmp_path / "rank0.pt", weights_only=True)
    rank1 = torch.load(tmp_path / "rank1.pt", weights_only=True)
    assert rank0.keys() == rank1.keys()
    assert all(torch.equal(rank0[k], rank1[k]) for k in rank0)
    initial = torch.load(tmp_path / "initial.pt", weights_only=True)
    assert any(not torch.equal(initial[k], rank0[k]) for k in rank0)


@pytest.mark.parametrize("stage", ["brackets", "appearance"])
def test_two_process_ddp_keeps_ranks_identical_in_the_head_only_stages(tiny_config, tmp_path, request, stage):
    """The bracket-only stage (the shipped operator-head configs) and the multi-view appearance loss
    call the model's own methods, never the DistributedDataParallel wrapper's forward: each rank
    trained a model of its own (14 of 14 head tensors apart after 3 steps) and rank 0's was saved."""
    changes = {"stage": "student", "appearance": "operator", "trainable": ["illumination_head"], "optim__steps": 3,
               "optim__warmup_steps": 0, "optim__lr": 1e-3}
    if stage == "brackets":
        changes.update(multiview=False, brackets={"root": str(request.getfixturevalue("brackets")), "batch_size": 1})
    else:
        changes.update(multiview_loss="appearance")
    config = tiny_config(name=f"ddp-{stage}", **changes)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    command = [_torchrun(), "--nproc_per_node", "2", "--master_port", str(29521 + len(stage)), str(WORKER), str(config),
               str(tmp_path)]
    completed = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    rank0 = torch.load(tmp_path / "rank0.pt", weights_only=True)
    rank1 = torch.load(tmp_path / "rank1.pt", weights_only=True)
    initial = torch.load(tmp_path / "initial.pt", weights_only=True)
    moved = [k for k in rank0 if not torch.equal(initial[k], rank0[k])]
    assert moved and all(k.startswith("illumination_head.") for k in moved)
    assert [k for k in rank0 if not torch.equal(rank0[k], rank1[k])] == []


def test_gradients_averaged_by_hand_leave_parameters_no_rank_used_without_one(tmp_path):
    """average_gradients gave every trainable parameter a gradient, zeros where the loss never
    reached it: AdamW's weight decay then shrank the unused heads on several processes, never on
    one. A parameter some rank used gets the mean over the ranks (zeros from the others)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    command = [_torchrun(), "--nproc_per_node", "2", "--master_port", "29531",
               str(Path(__file__).with_name("gradient_worker.py")), str(tmp_path)]
    completed = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    ranks = [torch.load(tmp_path / f"rank{rank}.pt", weights_only=True) for rank in (0, 1)]
    for rank in ranks:
        torch.testing.assert_close(rank["used"], (ranks[0]["own"]["used"] + ranks[1]["own"]["used"]) / 2)
        torch.testing.assert_close(rank["partly"], ranks[0]["own"]["partly"] / 2)
        assert rank["unused"] is None


def test_torchrun_command_line(tiny_config, tmp_path):
    config = tiny_config(name="cli-ddp", optim__steps=2)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    command = [_torchrun(), "--nproc_per_node", "2", "--master_port", "29518", "-m", "lumos3d_cli", "train", str(config), "--json"]
    completed = subprocess.run(command, capture_output=True, text=True, env=env, timeout=600)
    assert completed.returncode == 0, completed.stderr[-3000:]
    summary = json.loads(completed.stdout[completed.stdout.index("{"):])
    assert summary["world_size"] == 2 and summary["steps_done"] == 2
    assert (Path(summary["output"]) / "final.safetensors").is_file()


def test_sigterm_saves_a_checkpoint_and_stops(tiny_config):
    config = tiny_config(name="signal", optim__steps=1000)
    output = Path(str(config).replace(".yaml", ""))
    lumos3d = shutil.which("lumos3d", path=os.path.dirname(sys.executable))
    process = subprocess.Popen([lumos3d, "train", str(config), "--quiet"], stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    while not (output / "metrics.jsonl").is_file() and time.time() < deadline:
        time.sleep(0.5)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 143, stderr  # 128 + SIGTERM: a scheduler sees an unfinished run
    latest = (output / "checkpoints" / "latest").read_text().strip()
    step = int(latest.split("_")[1])
    assert 1 <= step < 1000
    assert (output / "checkpoints" / latest / "model.safetensors").is_file()
    assert not (output / "final.safetensors").exists()


@pytest.mark.slow
def test_tiny_model_overfits_one_scene(tiny_config):
    """The teacher stage fits one small scene (seven LLFF photos) in 200 steps on the CPU
    (medians of the first 20 steps and the last 50, measured 2026-11-27): the rendering MSE falls
    about 10x (required: 5x), the pose term about 5x (required: 2x), and the sparse-depth term,
    confidence-weighted with -0.2 log c and so able to go below 0, from 0.33 to about -0.1
    (required: a drop of 0.3)."""
    config = tiny_config(name="overfit", data__scenes=["video_llff_fortress"], data__crop_scale=[1.0, 1.0],
                         data__flip=False, data__width=112, data__height=84, optim__steps=200, optim__warmup_steps=10,
                         optim__lr=3e-4)
    result = _trainer(config).run()

    def median(term, rows):
        return statistics.median(r.terms[term] for r in rows)

    first, last = ({term: median(term, rows) for term in ("depth", "mse", "pose")}
                   for rows in (result.history[:20], result.history[-50:]))
    assert first["depth"] - last["depth"] > 0.3, (first, last)
    assert last["mse"] < first["mse"] / 5 and last["pose"] < first["pose"] / 2, (first, last)


def test_a_fresh_run_that_fails_before_its_first_checkpoint_leaves_nothing(tiny_config, monkeypatch):
    """Bad data met in the first step once left run.json and config.yaml, which refused the rerun
    and held nothing to resume."""
    config = tiny_config(name="fails")
    run = Path(str(config).replace(".yaml", ""))
    trainer = _trainer(config)

    def unreadable(step):
        raise InputError("scenes/x/images/017.jpg: cannot decode")

    monkeypatch.setattr(trainer, "_load_batch", unreadable)
    with pytest.raises(InputError, match="cannot decode"):
        trainer.run()
    assert not run.exists()
    run.mkdir()
    (run / "notes.txt").write_text("mine")  # a folder the user made, with their file: both stay
    trainer = _trainer(config)
    monkeypatch.setattr(trainer, "_load_batch", unreadable)
    with pytest.raises(InputError):
        trainer.run()
    assert sorted(p.name for p in run.iterdir()) == ["notes.txt"]
    assert _trainer(config, ["optim.steps=1"]).run().steps_done == 1  # the rerun is not refused


def test_a_resumed_run_that_trains_longer_takes_the_new_schedules_rate_at_once(tiny_config):
    config = tiny_config(name="longer", optim__steps=4, optim__warmup_steps=1)
    _trainer(config).run()
    resumed = _trainer(config, ["optim.steps=8"]).run(resume=True)
    fresh = _trainer(tiny_config(name="fresh", optim__steps=8, optim__warmup_steps=1)).run()
    assert [r.learning_rate for r in resumed.history] == pytest.approx([r.learning_rate for r in fresh.history[4:]])


def test_resume_replaces_only_the_files_the_run_wrote_as_it_wrote_them(tiny_config):
    """An edited final.safetensors, or a picture of the user's named like a validation picture of
    the steps a resume redoes, refuses the resume by name; once moved away, the resume runs."""
    config = tiny_config(name="owned", optim__steps=4, validate_every=2, validation_samples=1)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=3)  # validation/step_00000002.png, then a checkpoint at step 3
    (run / "final.safetensors").write_bytes(b"the user's")
    with pytest.raises(InputError, match="final.safetensors: was not written by this training run"):
        _trainer(config).run(resume=True)
    assert (run / "final.safetensors").read_bytes() == b"the user's"
    (run / "final.safetensors").unlink()
    (run / "validation" / "step_00000004.png").write_bytes(b"mine")
    with pytest.raises(InputError, match="step_00000004.png: was not written by this training run"):
        _trainer(config).run(resume=True)
    (run / "validation" / "step_00000004.png").unlink()
    (run / "validation" / "step_00000002.png").write_bytes(b"an edited picture of a step it keeps")
    assert _trainer(config).run(resume=True).steps_done == 4  # the kept step's picture is not replaced
    assert (run / "validation" / "step_00000002.png").read_bytes() == b"an edited picture of a step it keeps"
    assert read_checkpoint(run / "final.safetensors").tensors  # written, and listed: a later resume may replace it
    assert _trainer(config, ["optim.steps=6"]).run(resume=True).steps_done == 6


def test_a_run_folder_of_an_earlier_release_resumes_as_before(tiny_config, caplog):
    config = tiny_config(name="unlisted", optim__steps=4)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=2)
    (run / ".lumos3d-manifest.json").unlink()
    assert _trainer(config).run(resume=True).steps_done == 4
    assert "lists no files (a run of an earlier release)" in caplog.text


def test_a_run_refused_at_the_folder_check_leaves_the_other_runs_files(tiny_config, monkeypatch):
    """Another run that starts between the two folder checks: the refusal must not take that run's
    files for this one's to clean up."""
    import lumos3d_cli.train.trainer as trainer_module

    config = tiny_config(name="raced")
    run = Path(str(config).replace(".yaml", ""))
    checks = {"n": 0}
    original = trainer_module.check_run_folder

    def another_run_starts_meanwhile(output, inputs, resume):
        checks["n"] += 1
        if checks["n"] == 2:  # the check under the lock
            (run / "run.json").write_text('{"run_id": "other", "config": "x", "started": "now"}')
            (run / "metrics.jsonl").write_text('{"step": 0}\n')
        return original(output, inputs, resume)

    monkeypatch.setattr(trainer_module, "check_run_folder", another_run_starts_meanwhile)
    with pytest.raises(InputError, match="holds run other"):
        _trainer(config).run()
    assert (run / "run.json").read_text().startswith('{"run_id": "other"') and (run / "metrics.jsonl").is_file()


def test_a_resume_without_the_runs_run_json_says_so(tiny_config):
    """run.json deleted (or another run's put there): the resume said the checkpoint `latest`
    names "is missing", beside the folder that holds it."""
    config = tiny_config(name="unnamed", optim__steps=4, checkpoint_every=2)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(max_steps=2)
    saved_by = json.loads((run / "run.json").read_text())["run_id"]
    (run / "run.json").unlink()
    with pytest.raises(InputError, match=f"saved by run {saved_by}, but .* records no run \\(its .*run.json is missing"):
        _trainer(config).run(resume=True)
    (run / "run.json").write_text('{"run_id": "other", "config": "x", "started": "now"}')
    with pytest.raises(InputError, match=f"saved by run {saved_by}, but .* records run other; put back"):
        _trainer(config).run(resume=True)
    assert (run / "checkpoints" / "step_00000002" / "model.safetensors").is_file()


def test_a_fresh_run_that_fails_after_its_first_step_keeps_its_logs_and_selection(tiny_config, monkeypatch):
    config = tiny_config(name="late", validate_every=2, validation_samples=1, select="psnr", max_nonfinite_steps=1)
    run = Path(str(config).replace(".yaml", ""))
    trainer = _trainer(config)
    original = trainer.objective.forward
    calls = {"n": 0}

    def nan_from_the_fourth_step(*args, **kwargs):
        terms = original(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] >= 4:
            terms["total"] = terms["total"] * float("nan")
        return terms

    monkeypatch.setattr(trainer.objective, "forward", nan_from_the_fourth_step)
    with pytest.raises(RunError):
        trainer.run()  # checkpoint_every 0: no checkpoint, but three steps and a validation done
    assert (run / "metrics.jsonl").is_file() and (run / "selected.safetensors").is_file()
    assert (run / "validation" / "step_00000002.png").is_file()
    # its folder says what to do, not "resume it" on one side and "nothing to resume" on the other
    with pytest.raises(InputError, match="it saved no checkpoint to resume from; start a new numbered run"):
        _trainer(config).run()
    with pytest.raises(InputError, match="which saved no checkpoint, so there is nothing to resume; start a new"):
        _trainer(config).run(resume=True)


def test_resumes_of_an_earlier_release_run_take_its_files_as_the_runs(tiny_config, caplog):
    """A folder without the run's list (a release before it), even holding another command's
    manifest: the first resume lists the run's files, and the second does not refuse them."""
    config = tiny_config(name="legacy", optim__steps=6, validate_every=2, validation_samples=1, select="psnr")
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=3)
    (run / ".lumos3d-manifest.json").write_text(
        '{"format": "lumos3d-manifest/1", "files": {"report.csv": {"bytes": 1, "sha256": "0", "command": "eval", '
        '"output_set": "eval"}}}\n')
    assert (run / "selected.safetensors").is_file()
    assert _trainer(config, ["optim.steps=4"]).run(resume=True).steps_done == 4
    assert "lists no files (a run of an earlier release)" in caplog.text
    assert _trainer(config).run(resume=True).steps_done == 6


def test_a_run_folder_whose_list_cannot_be_read_refuses_rather_than_adopts(tiny_config):
    """A damaged manifest is not an earlier release's folder: nothing in it counts as the run's, so
    an edited final.safetensors is refused, not taken as the run's and overwritten."""
    config = tiny_config(name="damaged", optim__steps=4)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=2)
    (run / ".lumos3d-manifest.json").write_text("{not json")
    (run / "final.safetensors").write_bytes(b"the user's")
    with pytest.raises(InputError, match="was not written by this training run"):  # config.yaml comes first
        _trainer(config).run(resume=True)
    assert (run / "final.safetensors").read_bytes() == b"the user's"


def test_a_run_stopped_at_a_validation_step_validates_it_on_resume(tiny_config):
    """A signal after step 4 of a run validating every 2 saved and stopped before the validation
    due there; the resumed run never made it up (validation.jsonl lacked step 4)."""
    config = tiny_config(name="stopped", validate_every=2, validation_samples=1)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=4)
    assert [json.loads(line)["step"] for line in (run / "validation.jsonl").read_text().splitlines()] == [2]
    _trainer(config).run(resume=True)
    assert [json.loads(line)["step"] for line in (run / "validation.jsonl").read_text().splitlines()] == [2, 4, 6]


def test_resume_refusals_a_missing_checkpoint_config_fewer_steps_and_another_teacher(tiny_config):
    config = tiny_config(name="guarded", optim__steps=6)
    run = Path(str(config).replace(".yaml", ""))
    _trainer(config).run(stop_after=2)
    (run / "checkpoints" / "step_00000002" / "config.yaml").unlink()  # the run's own config.yaml is compared instead
    with pytest.raises(InputError, match=r"differs from the run's in optim.lr"):
        _trainer(config, ["optim.lr=0.5"]).run(resume=True)
    _trainer(config, ["optim.steps=4"]).run(resume=True)
    with pytest.raises(InputError, match=r"optim.steps 3: the run has done 4 steps already; .* give at least 4"):
        _trainer(config, ["optim.steps=3"]).run(resume=True)


def test_a_photo_holding_nan_stops_training_as_bad_data(tiny_config, tmp_path, shared_data):
    """A float TIFF of NaN samples among a scene's photos: each step drawing it was skipped as a
    non-finite loss and the run ended "final", exit 0 (or "training diverged: lower optim.lr")."""
    import shutil

    import numpy as np
    import OpenImageIO as oiio

    root = tmp_path / "root"
    shutil.copytree(shared_data / "scenes" / "statue", root / "statue")
    images = sorted((root / "statue" / "images").iterdir())
    nan = np.full((32, 48, 3), np.nan, np.float32)
    tiff = tmp_path / "nan.tif"
    out = oiio.ImageOutput.create(str(tiff))
    assert out.open(str(tiff), oiio.ImageSpec(48, 32, 3, oiio.FLOAT)) and out.write_image(nan)
    out.close()
    for image in images:  # every photo (their names keep the cameras'), so the first step draws one
        image.write_bytes(tiff.read_bytes())
    config = tiny_config(name="nan", data__root=str(root), data__scenes=["statue"], stage="teacher")
    with pytest.raises(InputError, match=r"statue/images/.*: .* NaN or Inf") as error:
        _trainer(config).run()
    assert not isinstance(error.value, NonFiniteError)


def _nan_from(trainer, monkeypatch, bad_calls):
    """Make the loss of the steps whose call number (from 1) is in `bad_calls` NaN; returns the
    call counter."""
    original = trainer.objective.forward
    calls = {"n": 0}

    def nan_total(*args, **kwargs):
        terms = original(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] in bad_calls:
            terms["total"] = terms["total"] * float("nan")
        return terms

    monkeypatch.setattr(trainer.objective, "forward", nan_total)
    return calls


def test_a_forward_pass_that_cannot_place_its_gaussians_is_a_skipped_step(tiny_config, monkeypatch):
    """A diverging run (optim.lr=0.05) predicted points 4e17 from the origin: the voxelizer's
    ValueError ended it as an internal error, where a non-finite loss skips the step."""
    import dataclasses

    trainer = _trainer(tiny_config(name="far", optim__steps=3))
    predict = trainer.model.predict
    calls = {"n": 0}

    def far_out_at_the_second_step(images):
        prediction = predict(images)
        calls["n"] += 1
        if calls["n"] == 2:  # one pixel beyond any voxel index, the scene's scale (its median depth) as it was
            far = torch.ones_like(prediction.depth)
            far[..., 0, 0] = 1e20
            prediction = dataclasses.replace(prediction, depth=prediction.depth * far)
        return prediction

    monkeypatch.setattr(trainer.model, "predict", far_out_at_the_second_step)
    result = trainer.run()
    assert [report.skipped for report in result.history] == [False, True, False]
    assert result.skipped_steps == trainer.nonfinite_total == 1 and result.final_checkpoint.is_file()

    def broken(images):
        raise ValueError("a bug, not the weights")

    monkeypatch.setattr(trainer.model, "predict", broken)
    with pytest.raises(ValueError, match="a bug, not the weights"):  # any other ValueError is no skipped step
        trainer.step(3)


def test_checkpoints_stop_at_divergence_and_the_stop_names_one_to_start_from(tiny_config, tmp_path, monkeypatch):
    """Retention kept three checkpoints, all of the diverged weights; the message advised a
    --resume that replays the divergence and refuses another optim.lr."""
    config = tiny_config(name="diverging", optim__steps=8, checkpoint_every=1, max_nonfinite_steps=3)
    trainer = _trainer(config)
    _nan_from(trainer, monkeypatch, range(4, 100))  # step 3 is the first non-finite one
    with pytest.raises(RunError) as error:
        trainer.run()
    checkpoints = trainer.output / "checkpoints"
    # step 4 follows one skipped step (one bad batch, as far as the run can tell): saved; from two
    # in a row on, none. Retention keeps step 2, from before the first non-finite loss
    assert sorted(p.name for p in checkpoints.glob("step_*")) == ["step_00000002", "step_00000003", "step_00000004"]
    assert (checkpoints / "latest").read_text().strip() == "step_00000004"
    # step_00000003 holds the weights step 3 started from, which gave the first non-finite loss
    good = checkpoints / "step_00000002"
    assert str(error.value).startswith("training stopped at step 5: 3 steps in a row had a non-finite loss")
    assert (f"{good} holds the weights from before: start a new run from them with a lower rate "
            f"(model={good / 'model.safetensors'} optim.lr=... --new-run)") in str(error.value)
    restart = _trainer(config, [f"model={good / 'model.safetensors'}", "optim.lr=1e-5", "optim.steps=1",
                                f"output={tmp_path / 'restart'}"]).run()
    assert restart.steps_done == 1 and restart.final_checkpoint.is_file()  # what the message says works


def test_a_run_that_ends_on_skipped_steps_writes_no_weights_of_them(tiny_config, monkeypatch):
    """A run whose last steps were skipped wrote final.safetensors from the weights that made them
    non-finite and said "4 steps done"."""
    trainer = _trainer(tiny_config(name="ends-skipped", optim__steps=4, checkpoint_every=2))
    _nan_from(trainer, monkeypatch, {3, 4})
    with pytest.raises(RunError, match=r"training ended after 4 steps, but the last 2 steps were skipped for a "
                                       r"non-finite loss or gradient; no checkpoint or final weights were written of "
                                       r"them \(2 skipped in all\); training diverged"):
        trainer.run()
    assert not (trainer.output / "final.safetensors").exists()
    assert [p.name for p in (trainer.output / "checkpoints").glob("step_*")] == ["step_00000002"]


def test_one_skipped_step_at_the_end_is_one_bad_batch_not_a_diverged_run(tiny_config, monkeypatch):
    """A skipped step leaves the weights as they were: refusing them failed a run on its last
    batch, and a resume replayed that batch."""
    trainer = _trainer(tiny_config(name="last-batch", optim__steps=4, checkpoint_every=2))
    _nan_from(trainer, monkeypatch, {4})
    result = trainer.run()
    assert result.final_checkpoint.is_file() and result.skipped_steps == 1
    assert (trainer.output / "checkpoints" / "latest").read_text().strip() == "step_00000004"


def test_a_signal_after_a_skipped_step_saves_no_checkpoint_and_says_so(tiny_config, monkeypatch):
    trainer = _trainer(tiny_config(name="stop-skipped", optim__steps=4, checkpoint_every=1))
    calls = _nan_from(trainer, monkeypatch, {2, 3})
    step = trainer.step

    def signalled_in_step_3(index):
        report = step(index)
        if calls["n"] == 3:
            os.kill(os.getpid(), signal.SIGTERM)  # run()'s handler asks for a stop after this step
        return report

    monkeypatch.setattr(trainer, "step", signalled_in_step_3)
    with pytest.raises(Interrupted, match=r"stopped after 3 steps without a checkpoint of them \(the last 2 steps "
                                          r"were skipped .*\); --resume goes on from the run's newest checkpoint") as stop:
        trainer.run()
    assert stop.value.signum == signal.SIGTERM
    # step 2's weights are step 1's (a skipped step changes none): saved; step 3 followed a second skip
    assert (trainer.output / "checkpoints" / "latest").read_text().strip() == "step_00000002"
