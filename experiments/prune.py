"""A lighter update block (and backbone) from a trained checkpoint: its channels cut to the
ones the next layers use most, as the start of a fine-tuning run (`tools/train.py --init OUT`).

    python experiments/prune.py edge/models/sparse_stereo.pt --out runs/prune/h48.pt \
        --hidden 48 --context 32 --motion 48 --head 32 --feature 48 [--widths 12,24,32]

`--widths`: the shared backbone's channels at 1/2, 1/4 and 1/8 (`prune_backbone`).

The step graph's cost is mostly the GRU's gates, whose convolutions scale with (hidden +
motion) × hidden; at 4 iterations it is ~40 % of the int8 engine (`docs/experiments.md`).
Cutting channels of a trained network keeps most of what it does, which
training from scratch would take the ~50 000 steps the shipped model had to relearn.

Each group keeps the channels whose weights in the layers that read them have the largest
L2 norm, in their original order: the GRU state (read by the gates, the Δd head and the mask
head; the confidence head reads the kept ones), the context (the gates), the motion features
(the gates; the disparity, the motion features' last channel, is always kept), the motion
encoder's correlation branch (its output convolution), the heads' hidden widths (their last
convolution) and the correlation features (ranked by their own weights; scaled so that the
correlation's 1/√C keeps its size). A size
equal to the checkpoint's keeps that group as it is, so the full sizes give back the same
network.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from edge_depth.model.config import ModelConfig

SIZES = {"hidden": "hidden_dim", "context": "context_dim", "motion": "motion_dim",
         "head": "head_dim", "feature": "feature_dim"}


def _keep(score: torch.Tensor, n: int) -> torch.Tensor:
    """The indices of the n largest scores, in ascending index order."""
    if n > score.numel():
        raise SystemExit(f"cannot keep {n} of {score.numel()} channels (a prune only cuts)")
    return torch.sort(torch.topk(score, n).indices).values


def _col_norm(*weights: torch.Tensor) -> torch.Tensor:
    """Squared L2 norm of each input channel over the given (out, in, kh, kw) weights."""
    return sum(w.pow(2).sum((0, 2, 3)) for w in weights)


def _rows(s: dict, name: str, index: torch.Tensor) -> None:
    """Layer `name`'s output channels cut to `index`: its weight and bias, and a batch norm's
    running statistics."""
    for suffix in ("weight", "bias", "running_mean", "running_var"):
        if f"{name}.{suffix}" in s:
            s[f"{name}.{suffix}"] = s[f"{name}.{suffix}"][index]


def _cols(s: dict, name: str, index: torch.Tensor) -> None:
    """Layer `name`'s input channels cut to `index`."""
    s[name + ".weight"] = s[name + ".weight"][:, index]


def prune_state(state: dict, config: ModelConfig, sizes: dict[str, int]) -> tuple[dict,
                                                                                ModelConfig]:
    """`state` (a SparseStereoNet state dict of `config`, gru_levels 1) cut to `sizes` (keys
    of SIZES; missing ones keep the checkpoint's); returns the new state dict and config."""
    if config.gru_levels != 1:
        raise SystemExit("prune supports gru_levels 1 (the deployed configuration)")
    s = {k: v.clone() for k, v in state.items()}
    h = config.hidden_dim
    m = int(state["update.motion.out.weight"].shape[0]) + 1  # the motion features' width
    zr, q = s["update.gru.convzr.weight"], s["update.gru.convq.weight"]
    new = {key: sizes.get(key) or getattr(config, field) for key, field in SIZES.items()}
    if new["motion"] < 2:
        raise SystemExit("--motion needs at least 2 (the disparity is one of its channels)")

    # each group's kept channels, ranked by the layers that read them
    keep_h = _keep(_col_norm(zr[:, :h], q[:, :h], s["update.delta.0.weight"],
                             s["update.mask.0.weight"]), new["hidden"])
    keep_c = _keep(_col_norm(zr[:, h + m:], q[:, h + m:]), new["context"])
    keep_m = torch.cat([_keep(_col_norm(zr[:, h:h + m - 1], q[:, h:h + m - 1]),
                              new["motion"] - 1), torch.tensor([m - 1])])
    corr_out = s["update.motion.corr.weight"].shape[0]
    keep_mc = _keep(_col_norm(s["update.motion.out.weight"][:, :corr_out]), new["motion"])
    keep_kd = _keep(_col_norm(s["update.delta.2.weight"]), new["head"])
    keep_km = _keep(_col_norm(s["update.mask.2.weight"]), new["head"])
    feat = s["encoders.feature_head.weight"]
    keep_f = _keep(feat.pow(2).sum((1, 2, 3)), new["feature"])

    def rows(name: str, index: torch.Tensor) -> None:
        _rows(s, name, index)

    def cols(name: str, index: torch.Tensor) -> None:
        _cols(s, name, index)

    scale = (new["feature"] / config.feature_dim) ** 0.25  # each side: √ of the 1/√C change
    rows("encoders.feature_head", keep_f)
    s["encoders.feature_head.weight"] *= scale
    s["encoders.feature_head.bias"] *= scale
    rows("encoders.context_head", torch.cat([keep_h, h + keep_c]))
    rows("update.motion.corr", keep_mc)
    disp_branch = torch.arange(corr_out, s["update.motion.out.weight"].shape[1])
    cols("update.motion.out", torch.cat([keep_mc, disp_branch]))
    rows("update.motion.out", keep_m[:-1])
    gru_in = torch.cat([keep_h, h + keep_m, h + m + keep_c])
    for name, out in (("update.gru.convzr", torch.cat([keep_h, h + keep_h])),
                      ("update.gru.convq", keep_h)):
        rows(name, out)
        cols(name, gru_in)
    for head, keep_k in (("delta", keep_kd), ("mask", keep_km)):
        cols(f"update.{head}.0", keep_h)
        rows(f"update.{head}.0", keep_k)
        cols(f"update.{head}.2", keep_k)
    if "refine.head.0.weight" in s:  # the confidence head reads the state and the spread
        spread = torch.arange(h, s["refine.head.0.weight"].shape[1])
        cols("refine.head.0", torch.cat([keep_h, spread]))
    pruned = ModelConfig.from_dict({**config.to_dict(), "hidden_dim": new["hidden"],
                                    "context_dim": new["context"], "motion_dim": new["motion"],
                                    "head_dim": new["head"], "feature_dim": new["feature"]})
    return s, pruned


def _block(s: dict, name: str, inner: torch.Tensor, out: torch.Tensor,
           source: torch.Tensor) -> None:
    """A residual block (`edge.model.extractor.ResidualBlock`) cut: its inner channels
    (conv1's outputs, conv2's inputs) to `inner`, its outputs (conv2's and the skip's, with
    their batch norms; a block without a skip has none) to `out`, its inputs (conv1's and the
    skip's) to `source`."""
    for layer in ("conv1", "norm1"):
        _rows(s, f"{name}.{layer}", inner)
    _cols(s, f"{name}.conv2", inner)
    for layer in ("conv2", "norm2", "skip.0", "skip.1"):
        if f"{name}.{layer}.weight" in s:
            _rows(s, f"{name}.{layer}", out)
    for layer in ("conv1", "skip.0"):
        if f"{name}.{layer}.weight" in s:
            _cols(s, f"{name}.{layer}", source)


def prune_backbone(state: dict, config: ModelConfig, widths: tuple[int, int, int]
                   ) -> tuple[dict, ModelConfig]:
    """The shared backbone cut to `widths` (its channels at 1/2, 1/4 and 1/8). Each block's
    inner channels are ranked by its second convolution's input weights; each stage's output
    by the layers that read it: the stem's by the 1/4 block, the 1/4 block's by the 1/8
    block, the 1/8 block's by the feature, context and affinity heads (the affinity block adds
    its input to its output, so its output keeps the same channels). Batch-norm statistics
    follow their channels. Needs the backbone without its 1/2-resolution block (the shipped
    one) and downsample 8."""
    if config.half_res_block or config.downsample != 8:
        raise SystemExit("--widths needs half_res_block false and downsample 8 (the shipped "
                         "network's backbone)")
    for new, old in zip(widths, config.widths, strict=True):
        if not 1 <= new <= old:
            raise SystemExit(f"--widths: each 1 to the checkpoint's {config.widths} (a prune "
                             f"only cuts), got {widths}")
    s = dict(state)
    b, e = "encoders.backbone.", "encoders."
    stem = _keep(_col_norm(s[b + "layer2.conv1.weight"], s[b + "layer2.skip.0.weight"]),
                 widths[0])
    quarter = _keep(_col_norm(s[b + "layer3.conv1.weight"], s[b + "layer3.skip.0.weight"]),
                    widths[1])
    eighth = _keep(_col_norm(s[e + "feature_head.weight"], s[e + "context_head.weight"],
                             s[e + "affinity_block.conv1.weight"]), widths[2])
    inner2 = _keep(_col_norm(s[b + "layer2.conv2.weight"]), widths[1])
    inner3 = _keep(_col_norm(s[b + "layer3.conv2.weight"]), widths[2])
    inner_a = _keep(_col_norm(s[e + "affinity_block.conv2.weight"]), widths[2])
    for layer in ("stem.0", "stem.1"):
        _rows(s, b + layer, stem)
    _block(s, b + "layer2", inner2, quarter, stem)
    _block(s, b + "layer3", inner3, eighth, quarter)
    _block(s, e + "affinity_block", inner_a, eighth, eighth)
    for head in ("feature_head", "context_head", "affinity_head"):
        _cols(s, e + head, eighth)
    return s, ModelConfig.from_dict({**config.to_dict(), "widths": tuple(widths)})


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--out", type=Path, required=True, help="the pruned checkpoint (.pt)")
    for key in SIZES:
        p.add_argument(f"--{key}", type=int, default=None,
                       help=f"channels to keep (default: the checkpoint's {SIZES[key]})")
    p.add_argument("--widths", default=None,
                   help="the backbone's channels at 1/2, 1/4 and 1/8, e.g. 12,24,32 "
                   "(default: as they are)")
    args = p.parse_args(argv)
    ckpt = torch.load(args.checkpoint, weights_only=False, map_location="cpu")
    config = ModelConfig.from_dict(ckpt["config"])
    sizes = {k: getattr(args, k) for k in SIZES if getattr(args, k) is not None}
    for k, v in sizes.items():
        if v < 1:
            p.error(f"--{k} must be at least 1, got {v}")
    state, pruned = prune_state(ckpt["model"], config, sizes)
    if args.widths is not None:
        widths = tuple(int(w) for w in args.widths.split(","))
        if len(widths) != 3:
            p.error(f"--widths: three channel counts, e.g. 12,24,32, got {args.widths}")
        state, pruned = prune_backbone(state, pruned, widths)
    before = sum(v.numel() for v in ckpt["model"].values())
    after = sum(v.numel() for v in state.values())
    args.out.parent.mkdir(parents=True, exist_ok=True)
    torch.save({**ckpt, "model": state, "config": pruned.to_dict(),
                "pruned_from": str(args.checkpoint),
                "pruned": {k: getattr(pruned, f) for k, f in SIZES.items()}}, args.out)
    print(f"{args.out}: {before:,} -> {after:,} parameters "
          + ", ".join(f"{SIZES[k]} {getattr(config, SIZES[k])} -> {getattr(pruned, SIZES[k])}"
                      for k in SIZES) + f", widths {config.widths} -> {pruned.widths}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
