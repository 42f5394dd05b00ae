"""The paper's ablation in miniature, at equal training budgets, on the synthetic rig.

    python experiments/ablation.py --out runs/ablation --data data/test16 [--steps 500]
        [--scenes 10] [--threads 1] [--train-args "--refine 10 --data things:data/things"]

Runs (each `tools/train.py` with the same batch, crop, seed and LiDAR pattern; the supervised
runs share --steps, the self-supervised ones --self-steps):
baseline (no CSPN, no sparse input) and +CSPN+sparse, supervised; self-supervised with the
all / half1 / half2 splits of the LiDAR points. Each run resumes from its last checkpoint and
is skipped once finished, so the whole thing can be restarted. Then every model is evaluated
on the first --scenes test scenes at 4 and 16 GRU iterations, with SGBM and LiDAR-linear in
the same run; results.json and results.md go to --out.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

RUNS = {
    "baseline (sup, no CSPN, no sparse)": ["--mode", "supervised", "--no-cspn", "--no-sparse"],
    "+CSPN+sparse (sup)": ["--mode", "supervised"],
    "self, split all": ["--mode", "self", "--split", "all"],
    "self, split half1": ["--mode", "self", "--split", "half1"],
    "self, split half2": ["--mode", "self", "--split", "half2"],
}


def folder_name(name: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in name).strip("-").replace("--", "-")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--data", type=Path, required=True, help="test scene folders (with GT)")
    p.add_argument("--steps", type=int, default=500)
    p.add_argument("--self-steps", type=int, default=None,
                   help="steps of the self-supervised runs (default: --steps); each of those "
                        "costs about twice a supervised step")
    p.add_argument("--batch", type=int, default=2)
    p.add_argument("--crop", default="256x160")
    p.add_argument("--scenes", type=int, default=10)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--only", default=None, help="comma-separated run folder names")
    p.add_argument("--train-args", default="",
                   help="more tools/train.py arguments for every run (the shipped model's "
                        "architecture, its training data), e.g. \"--refine 10 "
                        "--no-half-res-block --data things:data/things\"")
    args = p.parse_args(argv)
    from edge_depth.sim.folder import list_scene_folders
    from edge_depth.tools.evaluate import evaluate, markdown_table

    folders = list_scene_folders(args.data)[: args.scenes]
    if not folders:
        p.error(f"no scene folders under {args.data}")
    common = ["--batch", str(args.batch), "--crop", args.crop,
              "--iters", "6", "--workers", "0", "--threads", str(args.threads),
              "--ckpt-every", "50", "--patterns", "beams16", "--seed", "7"]
    only = set(args.only.split(",")) if args.only else None
    summary = {}
    for name, extra in RUNS.items():
        out = args.out / folder_name(name)
        if only and out.name not in only:
            continue
        if not (out / "final.pt").exists():
            print(f"== training {name} -> {out}", flush=True)
            steps = args.self_steps if "self" in extra and args.self_steps else args.steps
            subprocess.run([sys.executable, str(ROOT / "tools" / "train.py"), "--out", str(out),
                            "--resume", "--steps", str(steps), *common, *extra,
                            *shlex.split(args.train_args)], check=True)
        result = evaluate(folders, ["net"], [4, 16], out / "final.pt")
        summary[f"{name} @4"] = result["net@4"]
        summary[f"{name} @16"] = result["net@16"]
    summary.update(evaluate(folders, ["sgbm", "lidar-linear"], [4], None))
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "results.json").write_text(json.dumps(summary, indent=2))
    table = markdown_table(summary)
    (args.out / "results.md").write_text(table + "\n")
    print(table)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
