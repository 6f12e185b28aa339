"""What the illumination head should read: aggregator tokens, the photos' log histograms, or both.

The head alone (model/appearance/illumination_head.py) is trained on the training split of the
SICE brackets (data/brackets.py) with the appearance loss (losses/appearance.py), on the tokens
of a frozen bundled model's aggregator (computed once), then scored on the 20 held-out brackets
at full resolution. Variants: tokens only, histograms only (tokens replaced by zeros), both;
each with the local grid. A brackets-only measurement: the multi-view training of the full
network is not part of it.

    .venv/bin/python benchmarks/illumination_features.py [--steps 1500] [--mode low-light]

Writes the "illumination-features" section of docs/model-card.md (unless --no-doc).
"""

from __future__ import annotations

import argparse
import logging
import statistics
import sys
import time
from pathlib import Path

import lumos3d_cli  # noqa: F401  (first: it sets OMP_WAIT_POLICY=PASSIVE, as the CLI runs, before torch loads)
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from report import SHARED_DATA, markdown_table, table_section, write_section  # noqa: E402

from lumos3d_cli.data.brackets import bracket_pairs, read_srgb  # noqa: E402
from lumos3d_cli.eval.metrics import auto_gamma, psnr, ssim  # noqa: E402
from lumos3d_cli.losses.appearance import appearance_loss  # noqa: E402
from lumos3d_cli import load_model  # noqa: E402
from lumos3d_cli.model.appearance.illumination_head import IlluminationHead  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
MODEL_CARD = REPO / "docs" / "model-card.md"
BRACKETS = SHARED_DATA / "brackets"
BATCH = 8
LEARNING_RATE = 1e-3

logger = logging.getLogger("illumination_features")


def _encode(model, pairs) -> dict[str, torch.Tensor]:
    """-> tokens [N, 1, P, D] of the last aggregator layer, network inputs and targets [N, 1, 3, h, w],
    full-resolution inputs and targets [N, 3, H, W]."""
    tokens, inputs, targets, photos, references = [], [], [], [], []
    last = model.architecture.depth - 1
    with torch.no_grad():
        for pair in pairs:
            photo, reference = read_srgb(pair.input_path), read_srgb(pair.target_path)
            network = model.prepare(photo[None]).images  # [1, 3, h, w]
            tokens.append(model.aggregator(network[None], [last])[last])
            inputs.append(network)
            targets.append(model.prepare(reference[None]).images)
            photos.append(photo)
            references.append(reference)
    return {"tokens": torch.cat(tokens), "inputs": torch.stack(inputs), "targets": torch.stack(targets),
            "photos": torch.stack(photos), "references": torch.stack(references)}  # fmt: skip


def _train(head: IlluminationHead, data: dict, steps: int, zero_tokens: bool, seed: int) -> None:
    generator = torch.Generator().manual_seed(seed)
    optimiser = torch.optim.AdamW(head.parameters(), lr=LEARNING_RATE, weight_decay=0.01)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, steps)
    count = data["tokens"].shape[0]
    for step in range(steps):
        batch = torch.randint(0, count, (BATCH,), generator=generator)
        tokens = data["tokens"][batch]
        if zero_tokens:
            tokens = torch.zeros_like(tokens)
        operator = head(tokens, data["inputs"][batch])
        loss = appearance_loss(operator.apply(data["inputs"][batch]), data["targets"][batch])
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        schedule.step()
        if step % 250 == 0 or step == steps - 1:
            logger.info("  step %d: loss %.4f", step, float(loss.detach()))


def _evaluate(head: IlluminationHead | None, data: dict, zero_tokens: bool) -> tuple[float, float]:
    """Mean PSNR / SSIM of the held-out photos restored at full resolution (auto-gamma if no head)."""
    psnrs, ssims = [], []
    with torch.no_grad():
        for i in range(data["tokens"].shape[0]):
            photo, reference = data["photos"][i], data["references"][i]
            if head is None:
                restored = auto_gamma(photo)
            else:
                tokens = data["tokens"][i : i + 1]
                operator = head(torch.zeros_like(tokens) if zero_tokens else tokens, data["inputs"][i : i + 1])
                restored = operator.apply(photo[None, None])[0, 0]
            psnrs.append(float(psnr(restored, reference)))
            ssims.append(float(ssim(restored, reference)))
    return statistics.mean(psnrs), statistics.mean(ssims)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mode", default="low-light", choices=("low-light", "over-exposure"))
    parser.add_argument("--steps", type=int, default=1500)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--no-doc", action="store_true", help="print the table only")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    torch.manual_seed(args.seed)
    torch.set_num_threads(1)  # this machine is shared; small tensors gain little from threads
    model = load_model(args.mode)
    architecture = model.architecture
    started = time.perf_counter()
    train = _encode(model, bracket_pairs(BRACKETS, args.mode, "train"))
    validation = _encode(model, bracket_pairs(BRACKETS, args.mode, "validation"))
    logger.info("encoded %d training and %d held-out pairs in %.0f s", len(train["tokens"]), len(validation["tokens"]),
                time.perf_counter() - started)
    rows = [["auto-gamma (blind)", "-", "%.2f / %.3f" % _evaluate(None, validation, False)]]
    variants = {"tokens only": (0, False), "histograms only": (16, True), "tokens + histograms": (16, False)}
    for label, (bins, zero_tokens) in variants.items():
        torch.manual_seed(args.seed)
        head = IlluminationHead(2 * architecture.embed_dim, architecture.patch_start_index, architecture.patch_size,
                                histogram_bins=bins)
        logger.info("%s", label)
        started = time.perf_counter()
        _train(head, train, args.steps, zero_tokens, args.seed)
        minutes = (time.perf_counter() - started) / 60
        rows.append([label, f"{minutes:.1f}", "%.2f / %.3f" % _evaluate(head, validation, zero_tokens)])
        logger.info("  -> %s", rows[-1][-1])
    table = markdown_table(["head input", "training (min)", f"held-out brackets, {args.mode}: PSNR / SSIM"], rows)
    print(table)
    if args.no_doc:
        return
    text = table_section(
        f"### Illumination head: what it reads ({args.mode})",
        f"The illumination head alone, trained {args.steps} steps (batch {BATCH}, AdamW {LEARNING_RATE}, cosine) on the "
        f"{len(train['tokens'])} training-split bracket pairs with the appearance loss, on the frozen tokens of the "
        f"bundled {args.mode} model's aggregator; scored on the {len(validation['tokens'])} held-out pairs at full "
        "resolution (local 8x8 grid on in every variant). Written by `benchmarks/illumination_features.py`.",
        table,
    )  # fmt: skip
    write_section(f"illumination-features-{args.mode}", text, MODEL_CARD)


if __name__ == "__main__":
    main()
