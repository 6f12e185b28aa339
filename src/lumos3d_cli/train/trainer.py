"""The training loop shared by both stages, one process or many (DistributedDataParallel).

Everything a step draws at random depends only on (seed, step, rank): the samples, the crop and
mirror, the degradation. Together with exact checkpoints (weights, optimizer, scheduler) a
resumed run reproduces the losses of an uninterrupted one.
"""

from __future__ import annotations

import contextlib
import logging
import signal
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import NoReturn

import numpy as np
import torch
from torch.nn.parallel import DistributedDataParallel

from lumos3d_cli.data.degradations import degrade, white_balance_shift
from lumos3d_cli.data.multiview_dataset import MultiViewDataset
from lumos3d_cli.data.scene_records import scan_dl3dv, scan_scene_folders
from lumos3d_cli.errors import STOP_SIGNALS, DiskError, InputError, Interrupted, NonFiniteError, RunError
from lumos3d_cli.losses.appearance import appearance_loss
from lumos3d_cli.losses.objective import StageBatch, TrainingObjective
from lumos3d_cli.model.appearance.conversion import with_appearance
from lumos3d_cli.model.architectures import ARCHITECTURES
from lumos3d_cli.model.checkpoints import read_provenance, save_checkpoint
from lumos3d_cli.model.loading import load_model
from lumos3d_cli.model.lumos3d import Lumos3D, build_model
from lumos3d_cli.model.voxelize import PointsBeyondVoxelGrid
from lumos3d_cli.train.bracket_samples import BracketSamples, check_bracket_model
from lumos3d_cli.train.checkpointing import (
    CONFIG_FILE,
    MODEL_FILE,
    TrainingState,
    disk_errors_named,
    load_training_checkpoint,
    newest_checkpoint_before,
    resume_candidates,
    save_training_checkpoint,
)
from lumos3d_cli.train.config import TrainConfig, config_to_yaml, warn_of_idle_settings
from lumos3d_cli.train.distributed import DistributedContext, all_reduce_mean, any_rank, average_gradients, peer_stopped
from lumos3d_cli.io.output_lock import folder_lock
from lumos3d_cli.train.run_files import RunFiles
from lumos3d_cli.train.run_folder import (
    FINAL_FILE,
    RUN_FILE,
    RunIdentity,
    check_run_folder,
    read_run,
    remove_unfinished_run,
    start_run,
)
from lumos3d_cli.train.resume_config import read_run_config, require_same_training
from lumos3d_cli.train.run_logs import RunLogs
from lumos3d_cli.train.schedule import learning_rate_factor
from lumos3d_cli.train.selection import SELECTED_FILE, best_earlier_score, drop_stale_selection, is_improvement
from lumos3d_cli.train.trainable import restrict_training
from lumos3d_cli.train.validation import render_views, validate, validation_picture

logger = logging.getLogger(__name__)

# The epoch validation draws its samples from: a step reaches it only after 2^31 passes over the data.
VALIDATION_EPOCH = 2**31
# The schedule follows the step count, taken or skipped (`Trainer.step`): torch warns when a run's first
# step is a skipped one, as if the two calls came in the wrong order.
warnings.filterwarnings("ignore", message=r"Detected call of `lr_scheduler\.step\(\)` before", category=UserWarning)


@dataclass
class StepReport:
    """What one optimisation step produced (averaged over ranks)."""

    step: int
    learning_rate: float
    terms: dict[str, float]
    skipped: bool
    seconds: float


@dataclass
class TrainResult:
    """What `Trainer.run` did. `stop_signal`: the signal that stopped the run early (after a
    checkpoint was saved), None when it ran to its end or stopped on `stop_after`.
    `selected_checkpoint`: output/selected.safetensors when the run selects (config `select`)
    and it exists. `skipped_steps`: the steps of the whole run skipped for a non-finite loss or
    gradient (those before a resume included)."""

    steps_done: int
    history: list[StepReport] = field(default_factory=list)
    final_checkpoint: Path | None = None
    stopped_early: bool = False
    stop_signal: int | None = None
    last_checkpoint: Path | None = None
    selected_checkpoint: Path | None = None
    skipped_steps: int = 0


# Steps skipped in a row from which the weights, not one batch, are taken to be what failed: two
# batches in a row (training draws them at random) are not both broken.
_DIVERGED_IN_A_ROW = 2


def check_max_steps(max_steps: int | None) -> None:
    """`max_steps` counts every step of the run, done before a resume included; 0 or less would
    run nothing, so it is refused rather than read as "no limit"."""
    if max_steps is not None and max_steps < 1:
        raise InputError(f"{max_steps}: give the number of steps to train to in total (1 or more)", parameter="max_steps")


def _configured_model(key: str, source: str, device: str | torch.device, alternatives: str = "") -> Lumos3D:
    """The checkpoint the config's `key` names, loaded onto `device`; a bad one is named as that
    key (with `alternatives` to it), not as a --checkpoint the user never passed."""
    try:
        return load_model(source, device=device)
    except InputError as error:
        if error.parameter is None:
            raise
        raise InputError(f"the config's {key} {error.detail}{alternatives}") from error


class Trainer:
    def __init__(self, config: TrainConfig, context: DistributedContext, on_step: Callable[[StepReport], None] | None = None,
                 on_resume: Callable[[int, Path], None] | None = None):
        """`on_step(report)` runs after every step; `on_resume(step, folder)` once a resumed run
        has loaded the checkpoint it continues from."""
        self.config = config
        self.context = context
        self.on_step = on_step
        self.on_resume = on_resume
        self.output = Path(config.output)
        self.device = context.device
        if context.is_main:
            warn_of_idle_settings(config)
        torch.manual_seed(config.seed)
        self.dataset = self._dataset()
        self.model = self._student().to(self.device)
        self.model.set_gradient_checkpointing(config.gradient_checkpointing)
        self.teacher = self._teacher()
        self.brackets = self._brackets()
        self._check_multiview_loss()
        # the stage's full objective scores multi-view samples only there: a bracket-only or
        # appearance-only stage builds none (nor warns of its terms)
        uses_objective = config.multiview and config.multiview_loss == "objective"
        self.objective = TrainingObjective(config.loss, config.stage).to(self.device) if uses_objective else None
        self.optimizer = torch.optim.AdamW(
            self._parameter_groups(), lr=config.optim.lr, betas=config.optim.betas, weight_decay=config.optim.weight_decay
        )
        optim = config.optim
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, lambda step: learning_rate_factor(step, optim.warmup_steps, optim.steps, optim.min_lr_ratio)
        )
        self.network = (
            DistributedDataParallel(self.model, device_ids=[self.device.index] if self.device.type == "cuda" else None)
            if context.enabled else self.model
        )
        # The bracket-only and appearance-only stages call the model's own methods, not the
        # DistributedDataParallel wrapper's forward, so its reducer shares nothing: their gradients
        # are averaged by hand (`average_gradients`).
        self._loss_goes_through_the_wrapper = config.multiview and config.multiview_loss != "appearance"
        self._stop_requested = False
        self._stop_signal: int | None = None
        self.nonfinite_in_a_row = 0  # steps skipped in a row for a non-finite loss or gradient
        self.nonfinite_total = 0
        self._logs: RunLogs | None = None  # opened by `run` once the folder is the run's
        self.run_identity: RunIdentity | None = None  # the run the output folder holds (train/run_folder.py)
        # rank 0: whether this process started a fresh run in the folder, and whether any of its work
        # (a step, a validation) counts; a run started that fails before any is removed (`run`)
        self._started_fresh = False
        self._kept_work = False
        self._files: RunFiles | None = None  # rank 0: the files the run writes whole (train/run_files.py)

    # -- set-up ---------------------------------------------------------------------------------

    def _dataset(self) -> MultiViewDataset:
        data = self.config.data
        if data.layout == "dl3dv":
            records = scan_dl3dv(data.root, data.dl3dv_downsample, data.scenes or None, data.exclude)
        else:
            records = scan_scene_folders(data.root, data.scenes or None, data.exclude)
        if not records:
            raise InputError(f"{data.root}: no training scenes left after data.scenes/data.exclude")
        try:
            return MultiViewDataset(
                records, data.views, (data.width, data.height), data.crop_scale, data.flip,
                require_poses=self.config.stage == "teacher", seed=self.config.seed, samples_per_scene=data.samples_per_scene,
            )
        except ValueError as error:
            raise InputError(f"{data.root}: {error}; lower data.views or add scenes with more photos") from error

    def _student(self) -> Lumos3D:
        source = self.config.model
        if source in ARCHITECTURES:
            model = build_model(source, seed=self.config.seed)
        else:
            model = _configured_model("model", source, "cpu", f", nor an architecture ({', '.join(ARCHITECTURES)})")
        if self.config.appearance is not None:
            model = with_appearance(model, self.config.appearance, self.config.local_correction_channels)
        patch = model.architecture.patch_size
        data = self.config.data
        if data.width % patch or data.height % patch:
            raise InputError(f"data.width x data.height = {data.width}x{data.height} must be multiples of the patch size {patch}")
        restrict_training(model, self.config.trainable)
        return model.train()

    def _teacher(self) -> Lumos3D | None:
        if self.config.stage != "student" or not self.config.multiview or self.config.multiview_loss != "objective":
            return None
        teacher = _configured_model("teacher", self.config.teacher, self.device)
        return teacher.eval().requires_grad_(False)

    def _brackets(self) -> BracketSamples | None:
        config = self.config.brackets
        if config.root is None:
            return None
        check_bracket_model(self.model, config)
        data = self.config.data
        return BracketSamples(config, self.config.degrade.mode, (data.width, data.height), data.crop_scale, self.config.seed)

    def _parameter_groups(self) -> list[dict]:
        backbone = [p for n, p in self.model.named_parameters() if n.startswith("aggregator.") and p.requires_grad]
        heads = [p for n, p in self.model.named_parameters() if not n.startswith("aggregator.") and p.requires_grad]
        multiplier = self.config.optim.backbone_lr_multiplier
        return [{"params": backbone, "lr": self.config.optim.lr * multiplier}, {"params": heads, "lr": self.config.optim.lr}]

    # -- data -----------------------------------------------------------------------------------

    def _sample_indices(self, step: int) -> list[int]:
        """Global sample ids of this rank's share of `step`."""
        size = self.config.batch_size
        first = (step * self.context.world_size + self.context.rank) * size
        return list(range(first, first + size))

    def _load_batch(self, step: int) -> dict[str, torch.Tensor]:
        return self._load_samples(self._sample_indices(step))

    def _load_samples(self, sample_ids: list[int]) -> dict[str, torch.Tensor]:
        samples = []
        for sample_id in sample_ids:
            self.dataset.set_epoch(sample_id // len(self.dataset))
            samples.append(self.dataset[sample_id % len(self.dataset)])
        keys = ("images", "intrinsics", "extrinsics", "sparse_depth", "has_poses")
        return {key: torch.stack([s[key] for s in samples]).to(self.device) for key in keys}

    def _generator(self, step: int) -> torch.Generator:
        seed = int(np.random.SeedSequence([self.config.seed, step, self.context.rank]).generate_state(1)[0])
        return torch.Generator().manual_seed(seed)

    def inputs_and_targets(self, batch: dict[str, torch.Tensor], step: int) -> tuple[torch.Tensor, torch.Tensor]:
        """(network input, normal-light targets), both [B, V, 3, H, W]."""
        generator = self._generator(step)
        targets = white_balance_shift(batch["images"].cpu(), self.config.degrade.white_balance, generator)
        if self.config.stage == "teacher":
            return targets.to(self.device), targets.to(self.device)
        degraded, _ = degrade(targets, self.config.degrade, generator)
        return degraded.to(self.device), targets.to(self.device)

    # -- one step -------------------------------------------------------------------------------

    def _autocast(self):
        enabled = self.config.precision == "bf16"
        return torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=enabled)

    def _losses(self, step: int) -> dict[str, torch.Tensor]:
        """This step's loss terms (scalars) and their weighted sum "total"."""
        terms = {}
        if self.config.multiview and self.config.multiview_loss == "appearance":
            terms = self._multiview_appearance_losses(step)
        elif self.config.multiview:
            terms = self._multiview_losses(step)
        if self.brackets is not None:  # one-view bracket samples: the appearance loss only
            with self._autocast():
                terms["brackets"] = self.brackets.loss(self.model, step, self.context.rank, self.context.world_size, self.device)
            terms["total"] = terms.get("total", 0) + self.config.brackets.weight * terms["brackets"]
        return terms

    def _multiview_losses(self, step: int) -> dict[str, torch.Tensor]:
        """The stage's objective (losses/objective.py) on this step's multi-view samples."""
        batch = self._load_batch(step)
        inputs, targets = self.inputs_and_targets(batch, step)
        with self._autocast():
            output = self.network(inputs)
            teacher = None
            if self.teacher is not None:
                teacher_sees = targets if self.config.teacher_input == "normal-light" else inputs
                with torch.no_grad():
                    teacher = self.teacher(teacher_sees)
        renders, rendered_depth = render_views(output, self.config.loss.background)
        stage_batch = StageBatch(targets, batch["extrinsics"], batch["intrinsics"], batch["sparse_depth"], batch["has_poses"])
        return self.objective(output, renders, rendered_depth, stage_batch, teacher)

    def _multiview_appearance_losses(self, step: int) -> dict[str, torch.Tensor]:
        """The appearance loss of the operator predicted from this step's degraded multi-view
        samples, applied to them, against their normal-light views (no render, no teacher)."""
        batch = self._load_batch(step)
        inputs, targets = self.inputs_and_targets(batch, step)
        with self._autocast():
            operator = self.model.predict_appearance(inputs)
            loss = appearance_loss(operator.apply(inputs), targets, self.config.brackets.ssim_weight)
        return {"appearance": loss, "total": loss}

    def _check_multiview_loss(self) -> None:
        if self.config.multiview_loss == "appearance" and self.model.illumination_head is None:
            raise InputError(f"multiview_loss: appearance trains the restoration operator, but architecture "
                             f"'{self.model.architecture.name}' regresses colours: set `appearance: operator`")

    def step(self, step: int) -> StepReport:
        started = time.perf_counter()
        self.optimizer.zero_grad(set_to_none=True)
        try:
            terms = self._losses(step)
            finite = bool(torch.isfinite(terms["total"]))
        except NonFiniteError as error:
            logger.warning("step %d: %s", step, error)
            terms, finite = {}, False
        except PointsBeyondVoxelGrid as error:  # a diverged model's finite but useless geometry
            logger.warning("step %d: the predicted geometry cannot be fused: %s", step, error)
            terms, finite = {}, False
        if any_rank(not finite, self.context):
            finite = False
        if finite:
            terms["total"].backward()
            if not self._loss_goes_through_the_wrapper:
                average_gradients([p for p in self.model.parameters() if p.requires_grad], self.context)
            norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.config.optim.grad_clip)
            finite = not any_rank(not bool(torch.isfinite(norm)), self.context)
        learning_rate = self.optimizer.param_groups[-1]["lr"]
        if finite:
            self.optimizer.step()
            self.nonfinite_in_a_row = 0
        else:
            self.optimizer.zero_grad(set_to_none=True)
            self.nonfinite_in_a_row += 1
            self.nonfinite_total += 1
            if self.nonfinite_in_a_row >= self.config.max_nonfinite_steps:
                raise self._diverged(f"training stopped at step {step}: {self.nonfinite_in_a_row} steps in a row had a "
                                     "non-finite loss or gradient", step - self.nonfinite_in_a_row + 1)
        self.scheduler.step()
        values = {name: float(all_reduce_mean(value.detach().float(), self.context)) for name, value in terms.items()}
        return StepReport(step, learning_rate, values, not finite, time.perf_counter() - started)

    # -- outputs --------------------------------------------------------------------------------

    def _state(self, step: int) -> TrainingState:
        return TrainingState(
            step, self.optimizer.state_dict(), self.scheduler.state_dict(), torch.get_rng_state(),
            self.nonfinite_in_a_row, self.nonfinite_total,
        )

    def _provenance(self, step: int) -> dict:
        return {
            "stage": self.config.stage, "steps": step, "data": self.config.data.root,
            "degradation": self.config.degrade.mode if self.config.stage == "student" else "none",
            "teacher": self.config.teacher, "seed": self.config.seed, "world_size": self.context.world_size,
        }

    def _untrusted_weights(self) -> str | None:
        """Why the weights are not to be saved as the run's (None: they may be): the last
        `_DIVERGED_IN_A_ROW` steps or more were skipped, so the weights, not one batch, made their
        loss or gradient non-finite (a skipped step leaves the weights as they were: one bad batch
        says nothing of them, and refusing them failed a 30,000-step run on its last batch), or
        a weight is not finite. Every rank holds the same weights and counts, so all agree."""
        skipped = self.nonfinite_in_a_row
        if skipped >= _DIVERGED_IN_A_ROW:
            return f"the last {skipped} steps were skipped for a non-finite loss or gradient"
        tensors = self.model.state_dict().values()
        if not all(bool(torch.isfinite(tensor).all()) for tensor in tensors if tensor.is_floating_point()):
            return "the weights are not finite"
        return None

    def _diverged(self, what: str, first_bad_step: int) -> RunError:
        """The error of a run that diverged: `what` happened, first seen at the step of index
        `first_bad_step`. It names the newest checkpoint whose weights still trained (a
        checkpoint holding N steps is what step N starts from): --resume takes the newest one
        and the run's optimizer with the rate that diverged, and refuses another optim.lr."""
        run_id = self.run_identity.run_id if self.run_identity is not None else None
        before = newest_checkpoint_before(self.output, run_id, first_bad_step)
        if before is None:
            return RunError(f"{what}; training diverged, and no checkpoint of this run holds weights from before: "
                            "start a new run (--new-run) with a lower optim.lr")
        return RunError(f"{what}; training diverged. {before} holds the weights from before: start a new run from them "
                        f"with a lower rate (model={before / MODEL_FILE} optim.lr=... --new-run); --resume would go "
                        "on with the rate that diverged (a resume may not change optim.lr)")

    def save(self, step: int) -> Path | None:
        """Checkpoint after `step` steps (rank 0 writes; every rank waits for it); None, saving
        nothing, when the weights cannot be trusted (`_untrusted_weights`): retention keeps the
        last three checkpoints, which must not all be a diverged model's."""
        untrusted = self._untrusted_weights()
        if untrusted is not None:
            logger.warning("no checkpoint saved of the %d steps done: %s", step, untrusted)
            return None
        folder = None
        if self.context.is_main:
            folder = save_training_checkpoint(
                self.output, step, self.model, self._state(step), config_to_yaml(self.config), self._provenance(step),
                self.run_identity.run_id if self.run_identity is not None else None,
            )
            logger.info("saved checkpoint %s", folder)
        if self.context.enabled:
            torch.distributed.barrier()
        return folder

    def _note_a_changed_world_size(self, folder: Path) -> None:
        """Warn when the run resumes with another number of processes than its checkpoint's: each
        step then draws another number of samples, and the sample ids go on from a different
        place (some drawn again, some never), so the losses no longer reproduce."""
        if not self.context.is_main:
            return
        saved = read_provenance(folder / MODEL_FILE).get("world_size")
        if isinstance(saved, int) and saved != self.context.world_size:
            logger.warning("resuming a run of %d process(es) with %d: each step now draws %s samples, and the samples "
                           "drawn no longer follow the uninterrupted run's", saved, self.context.world_size,
                           "more" if self.context.world_size > saved else "fewer")

    def resume(self) -> int:
        """Load the newest intact checkpoint of this output folder (the one `latest` names; a
        damaged or missing one is skipped with a warning for the next older); returns the step to
        continue at."""
        problems = []
        run_id = self.run_identity.run_id if self.run_identity is not None else None
        for folder in resume_candidates(self.output, run_id):
            config_file = folder / CONFIG_FILE
            try:
                saved = read_run_config(config_file, TrainConfig)
                if saved is None:  # a checkpoint without its config (removed, or an earlier release's): the run's
                    config_file = self.output / CONFIG_FILE
                    saved = read_run_config(config_file, TrainConfig)
            except InputError as error:  # a damaged checkpoint, as one whose weights cannot be read
                logger.warning("skipping checkpoint %s: %s", folder.name, error)
                problems.append(str(error))
                continue
            if saved is not None:  # a config that changes what the run learns is refused, not skipped
                require_same_training(config_file, saved, self.config)
            try:
                state = load_training_checkpoint(folder, self.model)
            except InputError as error:
                logger.warning("skipping checkpoint %s: %s", folder.name, error)
                problems.append(str(error))
                continue
            if problems:
                logger.info("resuming from %s instead, the newest intact checkpoint", folder)
            self._note_a_changed_world_size(folder)
            self.optimizer.load_state_dict(state.optimizer)
            self.scheduler.load_state_dict(state.scheduler)
            # the step it continues at takes this config's schedule (a resumed run may train
            # longer: the saved rate was the old schedule's), as the steps after it do
            for group, base_lr, factor in zip(self.optimizer.param_groups, self.scheduler.base_lrs,
                                              self.scheduler.lr_lambdas):
                group["lr"] = base_lr * factor(self.scheduler.last_epoch)
            torch.set_rng_state(state.torch_rng)
            self.nonfinite_in_a_row, self.nonfinite_total = state.nonfinite_in_a_row, state.nonfinite_total
            if self.on_resume is not None:
                self.on_resume(state.step, folder)
            return state.step
        raise InputError(f"{self.output}: no intact checkpoint to resume from ({'; '.join(problems)})")

    def _keep_the_steps_done(self, error: InputError, steps_done: int, start: int) -> NoReturn:
        """Bad data met mid-run (a damaged photo, hours in), by a step or a validation: the weights
        of the `steps_done` are saved, so the run goes on with --resume once the file is replaced;
        then `error` is raised, saying so. (Under torchrun the other ranks
        wait in this step's all-reduce until torchrun ends them: only one process saves.)"""
        if self.context.enabled or steps_done == start:
            raise error
        untrusted = self._untrusted_weights()
        if untrusted is not None:  # `save` refuses them (and refused them at a multiple of checkpoint_every)
            raise InputError(f"{error}; no checkpoint of the {steps_done} steps done was saved ({untrusted}): replace "
                             "the file, then add --resume to go on from the newest checkpoint") from error
        if not (self.config.checkpoint_every and steps_done % self.config.checkpoint_every == 0):
            self.save(steps_done)  # (at a multiple of checkpoint_every it is saved already)
        raise InputError(f"{error}; the checkpoint of the {steps_done} steps done is saved: replace the file, then add "
                         "--resume (or start a new run with its scene in data.exclude)") from error

    def _log(self, report: StepReport) -> None:
        if self._logs is not None:
            self._logs.append_step(report.step, report.learning_rate, report.skipped, report.seconds, self.nonfinite_total,
                                   report.terms)

    def _validation_samples(self):
        """`validation_samples` samples fixed across the run, as (batch, network input, targets):
        the first of `VALIDATION_EPOCH`, which no run reaches, so never a training step's views,
        crops or degradation (those of epoch 0 were steps 0..N-1's own inputs). They come from
        the training scenes: held-out data is the brackets' (`brackets.validation_samples`)."""
        first = VALIDATION_EPOCH * len(self.dataset)
        for sample_id in range(first, first + min(self.config.validation_samples, len(self.dataset))):
            batch = self._load_samples([sample_id])
            yield (batch, *self.inputs_and_targets(batch, sample_id))

    def validate(self, step: int) -> Path | None:
        """Validation after `step` steps on rank 0 (train/validation.py), and the selection of
        the best step so far (train/selection.py); returns the picture's path."""
        if not self.context.is_main:
            return None
        extra = self.brackets.scores(self.model.eval(), self.device) if self.brackets is not None else None
        samples = list(self._validation_samples())  # read first: a damaged image is the data's (exit 2), not divergence
        try:
            line, path = validate(self.model, samples, step, self.output, self.config.validation_views,
                                  self.config.loss.background, self._autocast, extra)
        except NonFiniteError as error:  # the weights, not the data: the run diverged (exit 1, not bad input)
            raise self._diverged(f"validation after step {step}: the model's output is not finite ({error})", step) from error
        except PointsBeyondVoxelGrid as error:
            raise self._diverged(f"validation after step {step}: the predicted geometry cannot be fused ({error})",
                                 step) from error
        self._kept_work = True
        self._files.record(path)
        self.model.train()
        if self.config.select is not None:
            self._select(step, line[self.config.select])
        return path

    def _select(self, step: int, score: float) -> None:
        key = self.config.select
        best = best_earlier_score(self.output / "validation.jsonl", key, step)
        if is_improvement(score, best):
            with disk_errors_named(self.output, SELECTED_FILE):
                save_checkpoint(self.model, self.output / SELECTED_FILE,
                                {**self._provenance(step), "selected_by": key, "score": score}, overwrite=True)
            self._files.record(self.output / SELECTED_FILE)
            logger.info("selected step %d: %s %.4f (best before: %s)", step, key, score,
                        "none" if best is None else f"{best:.4f}")

    # -- the loop -------------------------------------------------------------------------------

    def _written_by_a_run(self) -> list[Path]:
        """The files a run writes whole that its folder may hold (the validation pictures by the
        names it gives them)."""
        pictures = [path for path in (self.output / "validation").glob("step_*.png")
                    if path.stem.removeprefix("step_").isdigit() and path == validation_picture(self.output, int(path.stem[5:]))]
        return [self.output / name for name in (RUN_FILE, "config.yaml", FINAL_FILE, SELECTED_FILE)] + sorted(pictures)

    def _replaced_on_resume(self, start: int, end: int) -> list[Path]:
        """The files a run resumed at `start` that trains to `end` writes whole: its config, the
        selection it may redo, the final weights when it reaches optim.steps, and the validation
        pictures of the steps it redoes."""
        every = self.config.validate_every
        redone = [validation_picture(self.output, step) for step in range(start + 1, end + 1) if every and step % every == 0]
        final = [self.output / FINAL_FILE] if end >= self.config.optim.steps else []
        return [self.output / "config.yaml", self.output / SELECTED_FILE, *final, *redone]

    def _abandoned_on_resume(self, start: int) -> list[Path]:
        """The files a resume at `start` leaves out of date: the pictures of validations after
        `start` (a resume from an older checkpoint, the newest damaged), and final weights of any
        step count but `start` when the run has reached optim.steps there: saved later, or of an
        earlier, shorter optim.steps that this run goes on past (a resume stopped by --max-steps
        or a signal would leave them as the run's "final" weights). The resume removes them:
        they are the work of steps it does again, or superseded; a checkpoint holds the weights
        it goes on from."""
        pictures = [path for path in self._written_by_a_run() if path.parent.name == "validation"
                    and int(path.stem.removeprefix("step_")) > start]
        final = self.output / FINAL_FILE
        # only the run's own, as it wrote it (a file of the user's there is the replacement check's to refuse)
        superseded = (final.is_file() and self._files.manifest.owns(final)
                      and not (start >= self.config.optim.steps and int(read_provenance(final).get("steps", -1)) == start))
        return [*([final] if superseded else []), *pictures]

    def _request_stop(self, signum, frame) -> None:
        logger.warning("%s: saving a checkpoint and stopping after this step", signal.Signals(signum).name)
        self._stop_requested = True
        self._stop_signal = self._stop_signal or signum

    def run(self, resume: bool = False, max_steps: int | None = None, stop_after: int | None = None,
            config_file: Path | str | None = None) -> TrainResult:
        """Train to optim.steps (or `max_steps`, at least 1): a fresh run into an output folder that
        holds no other run (its run.json records `config_file`), or with `resume` the run the
        folder holds, from its newest intact checkpoint (train/run_folder.py). `stop_after`
        behaves like a signal arriving during that step (used to test interruption). A signal
        (STOP_SIGNALS) ends the run after the current step with a checkpoint; `stop_signal` of
        the result names it."""
        check_max_steps(max_steps)
        # Every rank checks before any writes (a barrier apart), so all see the same folder.
        check_run_folder(self.output, [], resume)
        if self.context.enabled:
            torch.distributed.barrier()
        created = not self.output.exists()
        self.output.mkdir(parents=True, exist_ok=True)
        try:
            with folder_lock(self.output, "train") if self.context.is_main else contextlib.nullcontext():
                # Rank 0 holds the run folder (another `train` into it is refused) and checks again
                # under the lock: a run that started since the first check is seen now.
                if self.context.is_main:
                    check_run_folder(self.output, [], resume)
                return self._run_locked(resume, max_steps, stop_after, config_file)
        except BaseException as error:
            # A fresh run of this process that ends before any work of it counts (bad data met in
            # its first step) leaves nothing: its run.json would refuse the rerun, and there is
            # nothing to resume. Only a run this process started: a refusal at the lock or at the
            # second check means the files are another run's.
            if self._started_fresh and not self._kept_work:
                remove_unfinished_run(self.output, created)
            stopped = peer_stopped(error, self.context)
            if stopped is not None:
                raise stopped from error
            raise

    def _run_locked(self, resume: bool, max_steps: int | None, stop_after: int | None,
                    config_file: Path | str | None) -> TrainResult:
        end = min(self.config.optim.steps, max_steps) if max_steps is not None else self.config.optim.steps
        if self.context.is_main:
            self._files = RunFiles(self.output)
        if resume:
            self.run_identity = read_run(self.output)
        elif self.context.is_main:
            self.run_identity = start_run(self.output, config_file)
            self._started_fresh = True
            self._files.record(self.output / RUN_FILE)
        start = self.resume() if resume else 0
        if start > self.config.optim.steps:  # it went on with "6/3" and wrote "final" weights of 6 steps as 3's
            raise InputError(f"optim.steps {self.config.optim.steps}: the run has done {start} steps already; a resume "
                             f"trains on to optim.steps, so give at least {start}")
        if resume:  # before anything is replaced: the files of the user's stay as they are
            refusal = None
            if self.context.is_main:
                try:
                    self._files.adopt_if_unlisted(self._written_by_a_run())
                    abandoned = self._abandoned_on_resume(start)
                    self._files.require_replaceable([*self._replaced_on_resume(start, end), *abandoned])
                    for path in abandoned:
                        logger.info("removing %s: out of date once the run goes on from step %d", path, start)
                        path.unlink()
                        self._files.forget(path)
                except Exception as error:  # an unreadable file too: every rank must hear of it
                    refusal = error
            if any_rank(refusal is not None, self.context):  # every rank stops, not only the one that checked
                raise refusal or InputError(f"{self.output}: rank 0 refused the resume (its message says why)")
        if self.context.is_main:
            self._logs = RunLogs(self.output, self.config.tensorboard)
            self._logs.truncate(start)
            if drop_stale_selection(self.output, start):
                self._files.forget(self.output / SELECTED_FILE)
            (self.output / "config.yaml").write_text(config_to_yaml(self.config))
            self._files.record(self.output / "config.yaml")
        if self.config.validate_at_start and start == 0:
            self.validate(0)
        elif (resume and start > 0 and self.config.validate_every and start % self.config.validate_every == 0
              and (not self.context.is_main or start not in self._logs.validated_steps())):
            self.validate(start)  # due when a signal stopped the run, which saved before validating
        # A signal the process was started with ignored (nohup: SIGHUP) stays ignored.
        previous = {s: signal.signal(s, self._request_stop) for s in STOP_SIGNALS if signal.getsignal(s) is not signal.SIG_IGN}
        result = TrainResult(start)
        try:
            for step in range(start, end):
                try:
                    report = self.step(step)
                except InputError as error:
                    self._keep_the_steps_done(error, step, start)
                self._kept_work = True
                result.history.append(report)
                result.steps_done = step + 1
                if report.skipped:
                    logger.warning("step %d skipped: non-finite loss or gradient (%d in a row)", step, self.nonfinite_in_a_row)
                # the run's last step, not --max-steps': a resumed run's logs read as an uninterrupted run's
                if step % self.config.log_every == 0 or step == self.config.optim.steps - 1:
                    self._log(report)
                if self.on_step is not None:
                    self.on_step(report)
                if stop_after is not None and step + 1 == stop_after:
                    self._stop_requested = True
                if any_rank(self._stop_requested, self.context):
                    result.last_checkpoint = self.save(step + 1)
                    result.stopped_early = True
                    result.stop_signal = self._stop_signal
                    result.skipped_steps = self.nonfinite_total
                    if result.last_checkpoint is None and self.context.is_main and self._stop_signal is not None:
                        # the CLI would say a checkpoint was saved
                        raise Interrupted(self._stop_signal, f"stopped after {step + 1} steps without a checkpoint of "
                                                             f"them ({self._untrusted_weights()}); --resume goes on "
                                                             "from the run's newest checkpoint")
                    return result
                if self.config.checkpoint_every and (step + 1) % self.config.checkpoint_every == 0:
                    self.save(step + 1)
                if self.config.validate_every and (step + 1) % self.config.validate_every == 0:
                    try:
                        self.validate(step + 1)
                    except DiskError:  # writing selected.safetensors: no bad sample to leave out
                        raise
                    except InputError as error:
                        self._keep_the_steps_done(error, step + 1, start)
            untrusted = self._untrusted_weights()
            if untrusted is not None:  # its checkpoint and final weights would be the diverged model's
                raise self._diverged(f"training ended after {result.steps_done} steps, but {untrusted}; no checkpoint "
                                     f"or final weights were written of them ({self.nonfinite_total} skipped in all)",
                                     result.steps_done - self.nonfinite_in_a_row)
            if result.steps_done > start:
                self.save(result.steps_done)
            if self.context.is_main and result.steps_done >= self.config.optim.steps:
                with disk_errors_named(self.output, FINAL_FILE):
                    result.final_checkpoint = save_checkpoint(self.model, self.output / FINAL_FILE,
                                                              self._provenance(result.steps_done),
                                                              overwrite=True)  # the run's own (RunFiles)
                self._files.record(result.final_checkpoint)
            result.skipped_steps = self.nonfinite_total
            if self.config.select is not None and (self.output / SELECTED_FILE).is_file():
                result.selected_checkpoint = self.output / SELECTED_FILE
            return result
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            if self._logs is not None:
                self._logs.close()

