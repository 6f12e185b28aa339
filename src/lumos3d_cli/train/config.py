"""Training configuration: YAML files validated into these dataclasses (typed_config), with
`key=value` overrides; the resolved config is saved next to every checkpoint.

Two stages share one schema: `teacher` trains on normal-light images supervised by the
dataset's cameras and sparse depth plus rendering; `student` trains on degraded images with
reconstruction + cross-illumination distillation from a frozen teacher + the Lumos loss.
"""

from __future__ import annotations

import logging

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import yaml

from lumos3d_cli.data.degradations import Degradation
from lumos3d_cli.errors import InputError
from lumos3d_cli.losses.appearance import SSIM_WEIGHT
from lumos3d_cli.losses.loss_config import LossConfig
from lumos3d_cli.train.selection import SELECTION_SCORES
from lumos3d_cli.typed_config import apply_overrides, from_dict, to_dict

logger = logging.getLogger(__name__)


@dataclass
class DataConfig:
    """Where the scenes are and how samples are drawn (see data/)."""

    root: str = "../shared/data/scenes"
    layout: Literal["scenes", "dl3dv"] = "scenes"
    scenes: list[str] = field(default_factory=list)  # empty: every scene found
    exclude: list[str] = field(default_factory=list)
    dl3dv_downsample: int = 4
    views: int = 4  # context views per sample
    width: int = 224  # network image size (multiples of the patch size)
    height: int = 168
    crop_scale: tuple[float, float] = (0.6, 1.0)
    flip: bool = True
    samples_per_scene: int = 4  # per epoch

    def __post_init__(self) -> None:
        if self.views < 1:
            raise ValueError(f"data.views={self.views} must be at least 1")
        if self.width < 1 or self.height < 1:
            raise ValueError(f"data.width x data.height = {self.width}x{self.height} must be positive multiples of the "
                             "patch size")
        if not 0 < self.crop_scale[0] <= self.crop_scale[1] <= 1:
            raise ValueError(f"data.crop_scale={self.crop_scale} must satisfy 0 < low <= high <= 1")
        for key in ("samples_per_scene", "dl3dv_downsample"):
            if getattr(self, key) < 1:
                raise ValueError(f"data.{key}={getattr(self, key)} must be at least 1")


@dataclass
class BracketConfig:
    """root: the brackets folder (None: no bracket samples); weight of their appearance loss in
    the total; batch_size: bracket samples per step (each one view); ssim_weight: w of the
    appearance loss; validation_samples: held-out pairs of each mode scored at each validation,
    spread evenly over them (None: every pair of the 20 held-out brackets);
    well_exposed: also train on inputs that are already (nearly) well exposed, paired with the
    target (data/brackets.py), so the head learns to leave such photos as they are. Validation
    scores both kinds apart: bracket_psnr on the restoration pairs (comparable across runs),
    bracket_well_exposed_psnr on the well-exposed ones."""

    root: str | None = None
    weight: float = 1.0
    batch_size: int = 4
    ssim_weight: float = SSIM_WEIGHT
    validation_samples: int | None = None
    well_exposed: bool = False

    def __post_init__(self) -> None:
        if self.batch_size < 1 or (self.validation_samples is not None and self.validation_samples < 1) or self.weight < 0:
            raise ValueError("brackets.batch_size and brackets.validation_samples must be at least 1, brackets.weight >= 0")


@dataclass
class OptimConfig:
    lr: float = 2e-4
    weight_decay: float = 0.05
    betas: tuple[float, float] = (0.9, 0.95)
    warmup_steps: int = 1000
    steps: int = 30000
    min_lr_ratio: float = 0.1  # cosine decays to lr * min_lr_ratio
    grad_clip: float = 1.0
    backbone_lr_multiplier: float = 1.0  # the aggregator's lr = lr * this

    def __post_init__(self) -> None:
        positive = {"grad_clip": self.grad_clip}
        # lr 0 is allowed: a run that only validates, or tests that the weights stay put
        non_negative = {"lr": self.lr, "weight_decay": self.weight_decay, "backbone_lr_multiplier": self.backbone_lr_multiplier}
        for key, value in positive.items():
            if not math.isfinite(value) or value <= 0:
                raise ValueError(f"{key}: {value} must be a positive number")
        for key, value in non_negative.items():
            if not math.isfinite(value) or value < 0:
                raise ValueError(f"{key}: {value} must be a number of at least 0")
        if not all(math.isfinite(beta) and 0 <= beta < 1 for beta in self.betas):
            raise ValueError(f"betas: {list(self.betas)} must be two numbers in [0, 1)")
        if not 0 <= self.min_lr_ratio <= 1:
            raise ValueError(f"min_lr_ratio: {self.min_lr_ratio} must be in [0, 1]")
        if self.warmup_steps < 0:
            raise ValueError(f"warmup_steps: {self.warmup_steps} must be at least 0")


@dataclass
class TrainConfig:
    stage: Literal["teacher", "student"]
    output: str
    model: str = "tiny"  # architecture name (random init) or checkpoint to start from
    # switch the starting model's appearance ('regression' | 'operator'; model/appearance/conversion.py)
    appearance: str | None = None
    # with `appearance: operator`: channels of the per-view local gain grid (0: none; None: the
    # architecture's own)
    local_correction_channels: int | None = None
    teacher: str | None = None  # frozen teacher checkpoint (student stage)
    # what the frozen teacher sees: the normal-light images (the paper's cross-illumination
    # distillation) or the student's own degraded input (the paper's ablation)
    teacher_input: Literal["normal-light", "degraded"] = "normal-light"
    data: DataConfig = field(default_factory=DataConfig)
    degrade: Degradation = field(default_factory=Degradation)  # data.degradations, student stage
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    brackets: BracketConfig = field(default_factory=BracketConfig)  # real exposure brackets (train/bracket_samples.py)
    # top-level modules that train (e.g. [illumination_head]); empty: all (train/trainable.py)
    trainable: list[str] = field(default_factory=list)
    # false: no multi-view samples (nor teacher), each step is the bracket appearance loss only
    multiview: bool = True
    # how multi-view samples are scored: "objective" (the stage's full objective: render, teacher,
    # Lumos loss) or "appearance" (the predicted operator applied to the degraded views against the
    # normal-light views with the appearance loss alone: no rendering, no teacher; for stages that
    # train only the illumination head)
    multiview_loss: Literal["objective", "appearance"] = "objective"
    batch_size: int = 1  # scenes per step per process
    seed: int = 0
    device: Literal["auto", "cpu", "cuda"] = "auto"
    precision: Literal["fp32", "bf16"] = "fp32"
    gradient_checkpointing: bool = False
    log_every: int = 10
    checkpoint_every: int = 500
    validate_every: int = 0  # 0: no validation renders
    # also validate the starting weights (step 0) of a fresh run, so that a stage that fine-tunes a
    # trained model can select them when no step of its own scores better
    validate_at_start: bool = False
    validation_views: int = 2  # views per row block of the validation picture
    validation_samples: int = 8  # samples scored at each validation (validation.jsonl)
    # the validation.jsonl score that picks the checkpoint (train/selection.py; e.g. bracket_psnr):
    # each validation that beats every earlier one writes output/selected.safetensors; None: none
    select: str | None = None
    max_nonfinite_steps: int = 5
    tensorboard: bool = False

    def __post_init__(self) -> None:
        if not self.multiview and self.brackets.root is None:
            raise ValueError("multiview: false leaves only the bracket samples: set brackets.root")
        if self.stage == "student" and self.multiview and self.multiview_loss == "objective" and not self.teacher:
            raise ValueError("stage 'student' needs `teacher`: a checkpoint of the normal-light model")
        if self.multiview_loss == "appearance" and self.stage != "student":
            raise ValueError("multiview_loss: appearance scores a restoration: it needs stage 'student'")
        if not 0 <= self.seed < 2**63:  # what numpy's and torch's generators both take, and an int64 holds
            raise ValueError(f"seed: {self.seed} must be a whole number from 0 to 2**63 - 1")
        for key, value in (("batch_size", self.batch_size), ("optim.steps", self.optim.steps),
                           ("validation_samples", self.validation_samples)):
            if value < 1:
                raise ValueError(f"{key}: {value} must be at least 1")
        for key in ("log_every", "max_nonfinite_steps", "validation_views"):
            if getattr(self, key) < 1:
                raise ValueError(f"{key}: {getattr(self, key)} must be at least 1")
        for key in ("checkpoint_every", "validate_every"):
            if getattr(self, key) < 0:
                raise ValueError(f"{key}: {getattr(self, key)} must be at least 0 (0: never)")
        if self.select is not None:
            if self.select not in SELECTION_SCORES:
                raise ValueError(f"select: {self.select!r} is not a validation score; use one of {', '.join(SELECTION_SCORES)}")
            if self.select.startswith("bracket_") and self.brackets.root is None:
                raise ValueError(f"select: {self.select} scores the held-out brackets: set brackets.root")
            if not self.validate_every:
                raise ValueError("select needs validations: set validate_every")
        if self.validate_at_start and not self.validate_every:
            raise ValueError("validate_at_start adds a validation to those of validate_every: set validate_every")


def warn_of_idle_settings(config: TrainConfig) -> None:
    """Warnings for settings a run of this length never reaches (a short test of a long config:
    allowed, but said): a warmup longer than the run, a selection with no validation in it."""
    optim = config.optim
    if optim.warmup_steps > optim.steps:
        logger.warning("optim.warmup_steps %d is more than optim.steps %d: the learning rate never reaches optim.lr "
                       "(it peaks at %.2g of it)", optim.warmup_steps, optim.steps, optim.steps / optim.warmup_steps)
    if config.select is not None and config.validate_every > optim.steps and not config.validate_at_start:
        logger.warning("select: %s, but validate_every %d is more than optim.steps %d: no validation runs, so nothing "
                       "is selected", config.select, config.validate_every, optim.steps)


def training_inputs(config: TrainConfig, config_file: Path | str) -> list[Path]:
    """The files and folders a run reads (the outputs must stay clear of them): the config file,
    the data, the brackets, the teacher and a starting checkpoint."""
    paths = [config_file, config.data.root, config.brackets.root, config.teacher]
    if Path(config.model).suffix or Path(config.model).exists():  # a checkpoint, not an architecture name
        paths.append(config.model)
    return [Path(path) for path in paths if path]


def _yaml_problem(error: yaml.YAMLError) -> str:
    """PyYAML's message (over lines: the context, a caret under the column) in one line."""
    mark = getattr(error, "problem_mark", None)
    where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
    return f"{where} ({getattr(error, 'problem', None) or ' '.join(str(error).split())})"


_MERGE_TAG = "tag:yaml.org,2002:merge"  # `<<: *anchor`, YAML 1.1's merge key


class _UniqueKeyLoader(yaml.SafeLoader):
    """YAML's safe loader, refusing a key given twice in one mapping (a second `optim:` block
    replaced the first without a word: 6 steps became 30,000). Merge keys (`<<: *base`) work as
    in `yaml.safe_load`: a key given explicitly beside them overrides the merged one, as YAML
    intends, so only the explicit keys must be unique."""

    def flatten_mapping(self, node):
        """Resolves the merge keys (which have no constructor of their own), noting first the keys
        each mapping gives itself: a mapping merged into another is flattened with it, before
        its own turn, and its merged keys must not then count as written twice."""
        explicit = self.__dict__.setdefault("_explicit_keys", {})
        if id(node) not in explicit:
            explicit[id(node)] = (node, [key_node for key_node, _ in node.value if key_node.tag != _MERGE_TAG])
        super().flatten_mapping(node)

    def construct_mapping(self, node, deep=False):
        self.flatten_mapping(node)
        seen = set()
        for key_node in self._explicit_keys[id(node)][1]:
            key = self.construct_object(key_node, deep=True)
            try:
                hash(key)
            except TypeError:  # `? [a, b]`: no config key is a list
                raise yaml.constructor.ConstructorError(None, None, f"a key {key!r} that is not a name",
                                                        key_node.start_mark) from None
            if key in seen:
                raise yaml.constructor.ConstructorError(None, None, f"key {key!r} given twice in one mapping",
                                                        key_node.start_mark)
            seen.add(key)
        return super().construct_mapping(node, deep=deep)


def _override_value(text: str):
    """An override's value by YAML's rules, a key given twice in it refused as in a file
    (`'optim={lr: 1, lr: 2}'`); InputError (one line) when it is not YAML."""
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as error:
        raise InputError(f"override value {text!r}: invalid YAML{_yaml_problem(error)}; quote it or correct it") from None


def _non_finite(values, prefix: str = "") -> list[str]:
    """The keys of `values` (nested mappings and lists) whose number is NaN or infinite."""
    if isinstance(values, dict):
        return [key for name, value in values.items() for key in _non_finite(value, f"{prefix}{name}.")]
    if isinstance(values, list):
        return [key for index, value in enumerate(values) for key in _non_finite(value, f"{prefix}{index}.")]
    return [prefix.rstrip(".")] if isinstance(values, float) and not math.isfinite(values) else []


def load_config(path: Path | str, overrides: list[str] = ()) -> TrainConfig:
    """Read a YAML config, apply `key=value` overrides, validate (every number finite: a NaN
    background or an infinite colour cast skipped every step, and a run that trained nothing
    wrote its final weights)."""
    path = Path(path)
    try:
        values = yaml.load(path.read_text(encoding="utf-8"), Loader=_UniqueKeyLoader) or {}
    except OSError as error:
        raise InputError(f"{path}: cannot read config ({error.strerror})") from error
    except UnicodeDecodeError as error:
        raise InputError(f"{path}: not a UTF-8 text file (byte {error.object[error.start]:#04x} at offset "
                         f"{error.start}); give a YAML config") from None
    except yaml.YAMLError as error:
        raise InputError(f"{path}: invalid YAML{_yaml_problem(error)}; correct the file") from None
    if not isinstance(values, dict):
        raise InputError(f"{path}: a config must be a YAML mapping")
    apply_overrides(values, overrides, _override_value)
    try:
        config = from_dict(TrainConfig, values)
    except InputError as error:  # "missing required key(s)" of an empty file named no file at all
        source = f"{path} with its overrides" if overrides else str(path)
        raise InputError(f"{source}: {error}") from error
    non_finite = _non_finite(to_dict(config))  # after conversion: `nan` written as a string is a float here
    if non_finite:
        raise InputError(f"config {', '.join(non_finite)}: not a finite number; give one (NaN and infinity train "
                         "nothing)")  # from the file or an override: named as the key, as the other config errors are
    return config


def config_to_yaml(config: TrainConfig) -> str:
    return yaml.safe_dump(to_dict(config), sort_keys=False)
