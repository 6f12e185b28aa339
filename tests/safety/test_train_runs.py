"""Training runs never clobber runs (issue 38, row 5): a fresh run into another run's folder is
refused or, asked to, starts in a new numbered folder; retention counts only the run's own
checkpoints; --resume continues the run the folder holds and says which."""

import json
import re
import shutil
import subprocess
import sys
import textwrap

import torch

from lumos3d_cli.model.lumos3d import build_model
from lumos3d_cli.train.checkpointing import TrainingState, resume_candidates, save_training_checkpoint
from lumos3d_cli.train.run_folder import read_run

from assertions import expect_input_error
from output_files import snapshot
from processes import run_lumos3d


def _output(config):
    return config.with_suffix("")


def test_row5_a_fresh_run_into_another_runs_folder_is_refused_and_new_run_starts_beside_it(tiny_config):
    config = tiny_config(name="run", optim__steps=3, checkpoint_every=1)
    first = run_lumos3d("train", config)
    assert first.code == 0, first.err[-3000:]
    output = _output(config)
    before = snapshot(output)
    assert len((output / "metrics.jsonl").read_text().splitlines()) == 3
    refused = run_lumos3d("train", config, "optim.steps=2")
    expect_input_error(refused, f"output {output}: holds run {read_run(output).run_id[:8]}",
                       "checkpoints up to step_00000003", "--resume", "--new-run")
    assert snapshot(output) == before
    beside = run_lumos3d("train", config, "optim.steps=2", "--new-run", "--json")
    assert beside.code == 0, beside.err[-3000:]
    assert json.loads(beside.out)["output"] == str(output.with_name("run-2"))
    assert f"this run starts in {output.with_name('run-2')}" in re.sub(r"\s+", " ", beside.err)
    assert snapshot(output) == before
    assert read_run(output.with_name("run-2")).run_id != read_run(output).run_id


def test_a_fresh_run_into_another_commands_output_folder_is_refused(tiny_config):
    """`train output=out/demo` (a restore's folder) was accepted: the run wrote its checkpoints
    beside the scene and added itself to the restore's manifest."""
    from lumos3d_cli.io.output_set import OutputSet

    config = tiny_config(name="restored", optim__steps=1)
    output = _output(config)
    with OutputSet(output, "restore", "restore scene.ply").add_file("scene.ply").staged() as staging:
        (staging.root / "scene.ply").write_text("a scene")
    before = snapshot(output)
    expect_input_error(run_lumos3d("train", config), f"output {output}: holds the outputs of `restore scene.ply`",
                       "a training run needs a folder of its own")
    assert snapshot(output) == before
    beside = run_lumos3d("train", config, "--new-run", "--json")
    assert beside.code == 0, beside.err[-3000:]
    assert json.loads(beside.out)["output"] == str(output.with_name("restored-2")) and snapshot(output) == before


def test_row5_resume_continues_the_run_the_folder_holds_and_says_which(tiny_config):
    config = tiny_config(name="resumed", optim__steps=2, checkpoint_every=1)
    assert run_lumos3d("train", config).code == 0
    run = read_run(_output(config))
    resumed = run_lumos3d("train", config, "optim.steps=3")
    assert resumed.code == 2  # not a fresh run into its folder
    resumed = run_lumos3d("train", config, "optim.steps=3", "--resume", "--json")
    assert resumed.code == 0, resumed.err[-3000:]
    assert f"resuming {run.describe()}" in re.sub(r"\s*\n\s*", " ", resumed.err)
    assert json.loads(resumed.out)["steps_done"] == 3 and read_run(_output(config)) == run
    expect_input_error(run_lumos3d("train", config, "--resume", "output=" + str(_output(config).with_name("empty"))),
                       "holds no training run to resume")


def test_retention_and_resume_see_only_the_runs_own_checkpoints(tmp_path):
    model = build_model("tiny", seed=0)
    state = TrainingState(0, {}, {}, torch.get_rng_state(), 0, 0)
    for step in (30, 40, 50):  # an earlier run's, at higher steps
        save_training_checkpoint(tmp_path, step, model, state, "", {}, "earlier", keep=3)
    for step in (1, 2, 3, 4):
        save_training_checkpoint(tmp_path, step, model, state, "", {}, "current", keep=3)
    checkpoints = tmp_path / "checkpoints"
    shutil.copytree(checkpoints / "step_00000004", checkpoints / "step_00000004_keep")  # the user's copy
    (checkpoints / "step_00000000_mine").mkdir()  # the user's notes
    (checkpoints / "step_00000000_mine" / "notes.txt").write_text("the user's")
    save_training_checkpoint(tmp_path, 5, model, state, "", {}, "current", keep=3)
    names = sorted(p.name for p in checkpoints.glob("step_*"))
    assert names == ["step_00000000_mine", *(f"step_{s:08d}" for s in (3, 4)), "step_00000004_keep",
                     *(f"step_{s:08d}" for s in (5, 30, 40, 50))]
    assert [p.name for p in resume_candidates(tmp_path, "current")] == [f"step_{s:08d}" for s in (5, 4, 3)]
    assert [p.name for p in resume_candidates(tmp_path, "earlier")][0] == "step_00000050"


def test_run_outputs_that_cannot_be_or_would_touch_inputs_are_refused_before_training(tiny_config, tmp_path):
    (tmp_path / "a-file").write_text("")
    expect_input_error(run_lumos3d("train", tiny_config(name="file", output=str(tmp_path / "a-file"))),
                       f"{tmp_path / 'a-file'}: is a file")
    expect_input_error(run_lumos3d("train", tiny_config(name="proc", output="/proc/sys/lumos3d-run")),
                       "no permission to write in /proc/sys")
    inside = tiny_config(name="inside")
    run_folder = tmp_path / "holder"
    run_folder.mkdir()
    moved = run_folder / "config.yaml"
    moved.write_text(inside.read_text().replace(str(tmp_path / "inside"), str(run_folder)))
    expect_input_error(run_lumos3d("train", moved), f"{moved}: lies inside the run folder {run_folder}")


def test_a_second_train_into_a_run_folder_in_use_is_refused(tiny_config):
    config = tiny_config(name="busy", optim__steps=1)
    assert run_lumos3d("train", config).code == 0
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import time
        from lumos3d_cli.io.output_lock import folder_lock
        with folder_lock({str(_output(config))!r}, "train"):
            print("locked", flush=True)
            time.sleep(120)
    """)], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        expect_input_error(run_lumos3d("train", config, "optim.steps=2", "--resume"),
                           f"`lumos3d train`, process {holder.pid}", "is writing its outputs here")
    finally:
        holder.kill()
        holder.wait()
