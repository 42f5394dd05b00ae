"""How far each GRU step still moves the disparity, and what stopping there would cost: for
every frame, the mean |Δd| of each step's 1/8-resolution disparity (in full-resolution px) and
the whole engine's EPE / bad-3 after 1..MAX steps (selection, matching and median included).
A stopping rule "after step i ≥ MIN, stop where that step moved the disparity by less than τ"
is then scored for several τ from the same runs, per data set: mean EPE, bad-3 and steps.

    python experiments/converge.py --sets val [--frames 8] [--json out/converge_val.json]
    python experiments/converge.py --sets real --json out/converge_real.json

Sets: "val" the rig's validation split (seeds 2 000 000 + i; never trained on, not the
test split) with 16 beams, 32 beams, a planar scanner and no LiDAR; "real" the Middlebury
pairs (16 and 8 rows), their eight variants, stereo only on the two pairs, and the rig's test
split (data/test16). Engine options as `tools/evaluate.py` sets them (int8, default runtime
and kernels: wrap in experiments/avx2_kernels.sh for an AVX2-only CPU's).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from edge_depth.metrics import disparity_metrics
from edge_depth.runtime.engine import Engine
from edge_depth.runtime.options import EngineOptions
from edge_depth.sim import RigConfig, make_sample
from edge_depth.sim.folder import read_scene_folder

MAX_ITERS = 4
TAUS = (0.0, 0.05, 0.1, 0.15, 0.2, 0.3, 0.5)
REAL = ("aloe", "motorcycle", "aloe_r8", "motorcycle_r8")


def frames(sets: str, count: int):
    """(set name, frame name, left, right, sparse, ground truth)."""
    if sets == "val":
        rig = RigConfig()
        for pattern in ("beams16", "beams32", "planar", "none"):
            for i in range(count):
                sample = make_sample(2_000_000 + i, rig, "beams16" if pattern == "none"
                                     else pattern)
                sparse, valid = sample.sparse_disparity("left")
                sparse = (sparse * valid).astype(np.float32)
                if pattern == "none":
                    sparse = np.zeros_like(sparse)
                yield f"rig {pattern}", str(i), sample.left, sample.right, sparse, \
                    sample.disp_left
        return
    for name in REAL + tuple(sorted(p.name for p in Path("data/variants").iterdir())):
        path = Path("data") / name if name in REAL else Path("data/variants") / name
        scene = read_scene_folder(path)
        yield name, name, scene.left, scene.right, scene.sparse, scene.disp
    for name in ("aloe", "motorcycle"):
        scene = read_scene_folder(Path("data") / name)
        yield f"{name} stereo only", name, scene.left, scene.right, \
            np.zeros_like(scene.sparse), scene.disp
    for path in sorted(Path("data/test16").iterdir()):
        scene = read_scene_folder(path)
        yield "test16", path.name, scene.left, scene.right, scene.sparse, scene.disp


class StepTrace:
    """Wraps the engine's step session: each step's mean |Δd| in full-resolution px."""

    def __init__(self, engine: Engine) -> None:
        self.session, self.downsample = engine.sessions["step"], engine.downsample
        self.moves: list[float] = []
        self.before: np.ndarray | None = None

    def run(self, feeds):
        outputs = self.session.run(feeds)
        before = self.before if self.before is not None else feeds["disparity"]
        self.moves.append(float(np.abs(outputs[0] - before).mean()) * self.downsample)
        self.before = np.array(outputs[0])
        return outputs

    def __getattr__(self, name):
        return getattr(self.session, name)


def measure(engine: Engine, left, right, sparse, gt) -> dict:
    trace = StepTrace(engine)
    engine.sessions["step"] = trace
    try:
        by_iters = []
        for iters in range(1, MAX_ITERS + 1):
            trace.moves, trace.before = [], None
            result = engine.infer(left, right, sparse, iters=iters)
            m = disparity_metrics(result.disparity, gt)
            by_iters.append((m["epe"], m["bad3"]))
        return {"moves": trace.moves, "epe": [e for e, _ in by_iters],
                "bad3": [b for _, b in by_iters]}
    finally:
        engine.sessions["step"] = trace.session


def stop_at(moves: list[float], tau: float, first: int) -> int:
    """Steps run under the rule: after step i ≥ `first`, stop if it moved less than tau."""
    for i, move in enumerate(moves, start=1):
        if i >= first and move < tau:
            return i
    return len(moves)


def score(rows: list[dict], first: int) -> list[str]:
    lines = ["| set | frames | " + " | ".join(f"τ {t}" for t in TAUS) + " |",
             "|---|---|" + "---|" * len(TAUS)]
    for name in dict.fromkeys(r["set"] for r in rows):
        group = [r for r in rows if r["set"] == name]
        cells = []
        for tau in TAUS:
            steps = [stop_at(r["moves"], tau, first) for r in group]
            epe = np.mean([r["epe"][s - 1] for r, s in zip(group, steps, strict=True)])
            bad3 = np.mean([r["bad3"][s - 1] for r, s in zip(group, steps, strict=True)])
            cells.append(f"{epe:.3f} / {bad3:.2f} / {np.mean(steps):.1f}")
        lines.append(f"| {name} | {len(group)} | " + " | ".join(cells) + " |")
    return lines


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--sets", choices=("val", "real"), default="val")
    p.add_argument("--frames", type=int, default=8, help="val: frames per LiDAR pattern")
    p.add_argument("--first", type=int, default=2, help="the rule's fewest steps")
    p.add_argument("--runtime", default="auto")
    p.add_argument("--json", type=Path)
    args = p.parse_args()
    engine = Engine(options=EngineOptions(precision="int8", runtime=args.runtime))
    print(engine.describe())
    rows = []
    for name, frame, left, right, sparse, gt in frames(args.sets, args.frames):
        row = dict(set=name, frame=frame, **measure(engine, left, right, sparse, gt))
        rows.append(row)
        print(f"{name} {frame}: moves " + " ".join(f"{m:.3f}" for m in row["moves"]) +
              " | EPE " + " ".join(f"{e:.3f}" for e in row["epe"]), flush=True)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(rows, indent=1))
    print("\nEPE / bad-3 / mean steps, by the stopping threshold τ (px, after step "
          f"≥ {args.first}; τ 0 = always {MAX_ITERS}):")
    print("\n".join(score(rows, args.first)))


if __name__ == "__main__":
    main()
