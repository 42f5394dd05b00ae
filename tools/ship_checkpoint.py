"""Turn a training run's checkpoint into the shipped one: weights and config only (no
optimizer state), with the training summary of every stage so far.

    python tools/ship_checkpoint.py runs/NAME/final.pt --note "stage 4: ..."
        [--previous edge/models/sparse_stereo.pt] [--out edge/models/sparse_stereo.pt]

The new stage is read from the run's own arguments (mode, steps, batch, crop, iterations,
data, learning rate, seed, init); `--previous` supplies the stages before it. Then `make
bundle` exports and quantizes it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edge_depth.calibration.atomic import atomic_write

STAGE_KEYS = ("mode", "steps", "batch", "crop", "iters", "patterns", "lr", "seed", "data",
              "refine", "no_half_res_block", "split", "stereo_only_share", "freeze_trunk",
              "fresh_lr_mult", "edge_weight")


def stage_from_args(args: dict, note: str) -> dict:
    stage = {k: args[k] for k in STAGE_KEYS if k in args and args[k] not in (None, False)}
    if args.get("init") not in (None, "None"):
        stage["init"] = Path(str(args["init"])).name
    stage["note"] = note
    return stage


def ship(checkpoint: Path, previous: Path | None, note: str, out: Path) -> dict:
    import torch

    ckpt = torch.load(checkpoint, map_location="cpu", weights_only=False)
    stages = []
    if previous is not None and previous.exists():
        prior = torch.load(previous, map_location="cpu", weights_only=False)
        stages = list((prior.get("training") or {}).get("stages", []))
    stage = stage_from_args(ckpt.get("args", {}), note)
    stages.append(stage)
    training = dict(mode=stage.get("mode", "supervised"), stages=stages,
                    total_steps=int(sum(s.get("steps", 0) for s in stages)))
    shipped = dict(model=ckpt["model"], config=ckpt["config"], step=int(ckpt.get("step", 0)),
                   training=training)
    with atomic_write(out) as tmp:
        torch.save(shipped, tmp)
    return training


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--note", required=True, help="what this stage was, in a few words")
    p.add_argument("--previous", type=Path, default=Path("edge/models/sparse_stereo.pt"))
    p.add_argument("--out", type=Path, default=Path("edge/models/sparse_stereo.pt"))
    args = p.parse_args(argv)
    if not args.checkpoint.is_file():
        p.error(f"{args.checkpoint}: no such checkpoint")
    training = ship(args.checkpoint, args.previous, args.note, args.out)
    print(f"{args.out}: {len(training['stages'])} stages, {training['total_steps']} steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
