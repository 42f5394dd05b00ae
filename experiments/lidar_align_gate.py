"""The LiDAR alignment (`[engine] align_lidar`) on maps that sit right but are noisy and mixed
at depth edges, and on misregistered ones: EPE / bad-3 of the engine with the stage off, with
the old gate (an offset that is not the identity, ≥ MIN_JUMPS jumps, ≥ MIN_GAIN × the
identity's score: OLD_MIN_GAIN) and with the current one (`Offset.moves`).

    python tools/real_pairs.py --rows R ... (scene folders at several densities), then
    python experiments/lidar_align_gate.py --set dev PAIR_FOLDER ... [--json OUT]
    python experiments/lidar_align_gate.py --set fresh PAIR_FOLDER ... [--json OUT]

Kinds of map (each built from the folder's sparse.pfm and disp.pfm):
- right: N(0, σ) on every point, and mixed returns: a point with a depth edge within `reach`
  px along its row takes the other surface's disparity with probability `share`;
- all: the same, with `drop` of the points removed;
- moved / turned: the map turned about the image centre and moved (sub-pixel moves rounded per
  point, as a projection would), clean or with noise and mixed returns.
The engine runs with the stage off on the map as the gate leaves it (the stage is the
engine's last change to the map, so this equals the stage on); runs are cached per map.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from lidar_misregistration import moved  # noqa: E402
from lidar_noise import noisy  # noqa: E402

from edge_depth.metrics import disparity_metrics  # noqa: E402
from edge_depth.runtime.lidar_align import MIN_JUMPS, Offset, offset  # noqa: E402
from edge_depth.runtime.lidar_rows import map_points  # noqa: E402
from edge_depth.sim.folder import read_scene_folder  # noqa: E402

OLD_MIN_GAIN = 1.15  # the old gate's bar: the peak's score over the identity's

# name -> (σ px, mixed share, mixed reach px, drop share, turn °, dx px, dy px)
DEV = {
    "right_n050": (0.5, 0.5, 2, 0.0, 0.0, 0, 0),
    "right_n100": (1.0, 0.5, 2, 0.0, 0.0, 0, 0),
    "right_n150": (1.5, 0.5, 2, 0.0, 0.0, 0, 0),
    "all_n100_drop30": (1.0, 0.5, 2, 0.3, 0.0, 0, 0),
    "moved_2_1": (0.0, 0.0, 0, 0.0, 0.0, 2, 1),
    "moved_m3_0": (0.0, 0.0, 0, 0.0, 0.0, -3, 0),
    "moved_1.5_1_noisy": (0.5, 0.5, 2, 0.0, 0.0, 1.5, 1),
    "moved_0_m2_noisy": (1.0, 0.5, 2, 0.0, 0.0, 0, -2),
    "turned_075": (0.0, 0.0, 0, 0.0, 0.75, 0, 0),
    "turned_m05_1_0_noisy": (0.5, 0.5, 2, 0.0, -0.5, 1, 0),
}
DEV_SEEDS = (1, 2)
# made after the gate was designed: other σ, reach, share, drop, offsets and seeds
FRESH = {
    "right_n075": (0.75, 0.35, 3, 0.0, 0.0, 0, 0),
    "right_n125": (1.25, 0.35, 3, 0.0, 0.0, 0, 0),
    "right_n100_r1": (1.0, 0.7, 1, 0.0, 0.0, 0, 0),
    "all_n125_drop50": (1.25, 0.35, 3, 0.5, 0.0, 0, 0),
    "moved_m1_2": (0.0, 0.0, 0, 0.0, 0.0, -1, 2),
    "moved_3_m2_noisy": (0.75, 0.35, 3, 0.0, 0.0, 3, -2),
    "moved_m1.5_0_noisy": (0.5, 0.35, 3, 0.0, 0.0, -1.5, 0),
    "moved_0_1": (0.0, 0.0, 0, 0.0, 0.0, 0, 1),
    "turned_m1": (0.0, 0.0, 0, 0.0, -1.0, 0, 0),
    "turned_05_m2_1_noisy": (0.75, 0.35, 3, 0.0, 0.5, -2, 1),
}
FRESH_SEEDS = (201, 202)


def mixed(sparse: np.ndarray, gt: np.ndarray, rng: np.random.Generator, share: float,
          reach: int) -> np.ndarray:
    """Each point with a depth edge (GT min and max ≥ 2 px apart) within `reach` px along its
    row takes, with probability `share`, the other surface's disparity (the far side's
    minimum if it is nearer the maximum, else the maximum)."""
    out = sparse.copy()
    if share <= 0 or reach <= 0:
        return out
    ys, xs = map_points(sparse)
    g = np.where(np.isfinite(gt) & (gt > 0), gt, np.nan)
    w = gt.shape[1]
    window = np.stack([g[ys, np.clip(xs + k, 0, w - 1)] for k in range(-reach, reach + 1)])
    with warnings.catch_warnings():  # an all-unknown window: NaN, not an edge
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = np.nanmin(window, axis=0), np.nanmax(window, axis=0)
    edge = np.isfinite(lo) & (hi - lo >= 2.0) & (rng.random(len(ys)) < share)
    d = sparse[ys, xs]
    other = np.where(np.abs(d - hi) < np.abs(d - lo), lo, hi)
    out[ys[edge], xs[edge]] = other[edge]
    return out


def variant(scene, kind: tuple, seed: int) -> np.ndarray:
    """One kind of map (DEV's or FRESH's tuple) from a scene's sparse map and GT."""
    sigma, share, reach, drop, turn, dx, dy = kind
    rng = np.random.default_rng(seed)
    sparse = mixed(scene.sparse, scene.disp, rng, share, reach)
    if sigma > 0:
        sparse = noisy(sparse, sigma, rng)
    if drop > 0:
        sparse = np.where(rng.random(sparse.shape) < drop, 0.0, sparse).astype(np.float32)
    if (turn, dx, dy) != (0.0, 0, 0):
        sparse = moved(sparse, dx, dy, turn)
    return sparse.astype(np.float32)


def old_moves(found: Offset) -> bool:
    """The gate before the held-out test: not the identity, enough jumps, MIN_GAIN."""
    return (found.dx, found.dy, found.turn_deg) != (0, 0, 0.0) and \
        found.jumps >= MIN_JUMPS and found.gain >= OLD_MIN_GAIN


class Runs:
    """The engine (stage off) on a scene and a map, cached by (scene, map) bytes."""

    def __init__(self) -> None:
        from edge_depth.runtime.engine import Engine
        from edge_depth.runtime.options import EngineOptions

        options = dataclasses.replace(EngineOptions(), align_lidar=False)
        self.engine = Engine(options=options)
        self.cache: dict[tuple[str, int], tuple[float, float]] = {}

    def metrics(self, name: str, scene, sparse: np.ndarray) -> tuple[float, float]:
        key = (name, hash(sparse.tobytes()))
        if key not in self.cache:
            result = self.engine.infer(scene.left, scene.right, sparse, iters=4)
            m = disparity_metrics(result.disparity, scene.disp)
            self.cache[key] = (float(m["epe"]), float(m["bad3"]))
        return self.cache[key]


def run_set(folders: list[Path], kinds: dict, seeds: tuple[int, ...]) -> list[dict]:
    """Per (folder, kind, seed): EPE / bad-3 with the stage off, the old gate and this one,
    and the offset found."""
    runs, rows = Runs(), []
    for folder in folders:
        scene = read_scene_folder(folder)
        for name, kind in kinds.items():
            for seed in seeds:
                sparse = variant(scene, kind, seed)
                found = offset(scene.left, sparse)
                back = found.undo(sparse)
                row = dict(pair=folder.name, kind=name, seed=seed,
                           off=runs.metrics(folder.name, scene, sparse),
                           old=runs.metrics(folder.name, scene,
                                            back if old_moves(found) else sparse),
                           new=runs.metrics(folder.name, scene,
                                            back if found.moves else sparse),
                           offset=[found.dx, found.dy, found.turn_deg],
                           gain=round(found.gain, 3), jumps=found.jumps,
                           held_out_z=round(found.held_out_z, 2),
                           old_moves=bool(old_moves(found)), moves=bool(found.moves))
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def summary(rows: list[dict]) -> str:
    """A markdown table per kind: mean EPE / bad-3 off, old, new; moved counts; worst."""
    lines = ["| kind | maps | off EPE / bad-3 | old gate | new gate | old moved | new moved "
             "| worst new vs off |", "|---|---|---|---|---|---|---|---|"]
    for kind in dict.fromkeys(r["kind"] for r in rows):
        sel = [r for r in rows if r["kind"] == kind]
        mean = {k: np.mean([r[k] for r in sel], axis=0) for k in ("off", "old", "new")}
        worst = max(r["new"][0] / r["off"][0] - 1 for r in sel)
        lines.append(
            f"| {kind} | {len(sel)} | {mean['off'][0]:.3f} / {mean['off'][1]:.2f} | "
            f"{mean['old'][0]:.3f} / {mean['old'][1]:.2f} | "
            f"{mean['new'][0]:.3f} / {mean['new'][1]:.2f} | "
            f"{sum(r['old_moves'] for r in sel)} | {sum(r['moves'] for r in sel)} | "
            f"{100 * worst:+.1f} % |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folders", nargs="+", type=Path, help="real-pair scene folders")
    p.add_argument("--set", choices=("dev", "fresh"), default="dev")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    kinds, seeds = (DEV, DEV_SEEDS) if args.set == "dev" else (FRESH, FRESH_SEEDS)
    rows = run_set(args.folders, kinds, seeds)
    print(summary(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
