"""`edge-depth synth`: write a batch of synthetic scene folders, all or nothing."""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from edge_depth.errors import EdgeError
from edge_depth.sim.folder import write_scene_folder
from edge_depth.sim.rig import make_sample
from edge_depth.sim.scene import RigConfig


class OutputError(EdgeError):
    """The output location cannot be written."""


class Progress:
    """`synth: 40/260 things pairs` on stderr: redrawn in place on a terminal; where stderr is
    a log file (nohup, CI), a line at each tenth of the work instead of one endless line."""

    def __init__(self, count: int, what: str) -> None:
        self.count, self.what = count, what
        self.tty = sys.stderr.isatty()
        self._next = 0

    def __call__(self, done: int) -> None:
        line = f"synth: {done}/{self.count} {self.what}"
        if self.tty:
            print(f"\r{line}", end="", file=sys.stderr, flush=True)
        elif done >= self._next or done == self.count:
            print(line, file=sys.stderr, flush=True)
            self._next = done + max(1, self.count // 10)

    def close(self) -> None:
        if self.tty:
            print(file=sys.stderr)


def synth_command(out: Path, count: int, seed: int, size: tuple[int, int], lidar: str) -> int:
    """Write `count` scene folders OUT/000000 ... seeded seed, seed+1, ...

    The output directory is checked for writability before any scene is rendered; if a scene
    fails midway, the scenes written by this call are removed again.
    """
    rig = RigConfig(width=size[0], height=size[1])
    _writable(out)
    written: list[Path] = []
    progress = Progress(count, "scenes")
    try:
        for i in range(count):
            sample = make_sample(seed + i, rig, lidar)
            folder = out / f"{seed + i:06d}"
            write_scene_folder(folder, sample, lidar_name=lidar)
            written.append(folder)
            progress(i + 1)
        progress.close()
    except BaseException:
        for folder in written:
            shutil.rmtree(folder, ignore_errors=True)
        raise
    print(f"wrote {count} scene folders to {out} ({size[0]}x{size[1]}, lidar {lidar})")
    return 0


def _writable(out: Path) -> None:
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output directory {out}: {exc.strerror}") from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise OutputError(f"output directory {out} is not writable")


def things_folders_command(out: Path, count: int, seed: int, size: tuple[int, int],
                           view_spread: float = 1.0, clean_cameras: bool = False) -> int:
    """Things-world pairs as scene folders for evaluation, with the real pair's LiDAR recipe
    (16 rows of the GT, every 2nd column, N(0, 0.1 px); `tools/real_pairs.py`)."""
    import json

    import cv2
    import numpy as np

    from edge_depth.sim.folder import write_pfm
    from edge_depth.sim.gt_lidar import GtLidarPattern
    from edge_depth.sim.world import WorldConfig, make_things_sample

    cfg = WorldConfig(width=size[0], height=size[1], view_spread=view_spread,
                      clean_cameras=clean_cameras)
    _writable(out)
    progress = Progress(count, "things scenes")
    for i in range(count):
        sample = make_things_sample(seed + i, cfg)
        folder = out / f"{seed + i:07d}"
        folder.mkdir(exist_ok=True)
        pattern = GtLidarPattern.evenly(cfg.height, 16, column_step=2, noise_px=0.1)
        sparse = pattern.sample(sample.disp_left, np.random.default_rng(seed + i))
        cv2.imwrite(str(folder / "left.png"), sample.left)
        cv2.imwrite(str(folder / "right.png"), sample.right)
        write_pfm(folder / "disp.pfm", np.where(sample.disp_left > 0, sample.disp_left,
                                                np.inf).astype(np.float32))
        cv2.imwrite(str(folder / "occ.png"), sample.occ_left.astype(np.uint8) * 255)
        write_pfm(folder / "sparse.pfm", sparse)
        (folder / "meta.json").write_text(json.dumps(dict(
            focal_px=cfg.focal_px, baseline_m=cfg.baseline_m, cx=cfg.cx, cy=cfg.cy,
            seed=seed + i, generator="edge.sim.world", lidar="16 GT rows, every 2nd column",
            view_spread=view_spread, clean_cameras=clean_cameras)))
        progress(i + 1)
    progress.close()
    print(f"wrote {count} things scene folders to {out} ({size[0]}x{size[1]})")
    return 0


def things_command(out: Path, count: int, seed: int, size: tuple[int, int],
                   workers: int = 1, view_spread: float = 1.0,
                   clean_cameras: bool = False) -> int:
    """Render `count` pairs of the things world into OUT/NNNNNNN.npz (seeds seed …), the
    training set of `tools/train.py --data things:OUT`. Pairs already there are kept, so an
    interrupted run continues; `workers` processes render in parallel."""
    from concurrent.futures import ProcessPoolExecutor

    from edge_depth.sim.things_store import generate
    from edge_depth.sim.world import WorldConfig

    cfg = WorldConfig(width=size[0], height=size[1], view_spread=view_spread,
                      clean_cameras=clean_cameras)
    _writable(out)
    chunk = 25
    starts = list(range(seed, seed + count, chunk))
    done = rendered = 0
    progress = Progress(count, "things pairs")
    from edge_depth.workers import one_thread_each

    with one_thread_each(), ProcessPoolExecutor(max(1, workers)) as pool:
        jobs = [pool.submit(generate, out, min(chunk, seed + count - s), s, cfg) for s in starts]
        for job in jobs:
            rendered += job.result()
            done = min(done + chunk, count)
            progress(done)
    progress.close()
    print(f"wrote {rendered} things pairs to {out} ({count - rendered} were already there; "
          f"{size[0]}x{size[1]})")
    return 0
