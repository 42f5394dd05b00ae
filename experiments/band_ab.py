"""The band refinement against its version at a git revision, on the same inputs: whether the
outputs are equal to the bit, and each one's time (docs/experiments.md).

    python experiments/band_parts.py data/aloe data/motorcycle data/test16/100000[0-3] \
        --dump runs/band_inputs.npz   # the engine's inputs to the band, once
    python experiments/band_ab.py runs/band_inputs.npz --rev HEAD~1 [--rounds 3]
    bash experiments/avx2_kernels.sh .venv/bin/python experiments/band_ab.py ...

`--rev`'s edge/runtime/band_sgm.py (and its band_paths.py) is imported from a copy under
runs/ (its numba kernels compiled there once); the two alternate pair by pair, after an
untimed call each. Per round: the mean time a pair of each.
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from edge_depth.runtime import band_sgm

KEYS = ("left", "right", "prior", "confidence", "sparse")


def module_at(rev: str):
    """band_sgm as it was at `rev`, with the aggregation (band_paths) of `rev` too where it had
    one."""
    short = subprocess.run(["git", "rev-parse", "--short", rev], check=True,
                           capture_output=True, text=True).stdout.strip()
    folder = Path("runs/band_ab")
    folder.mkdir(parents=True, exist_ok=True)
    text = _at(rev, "edge/runtime/band_sgm.py")
    paths = _at(rev, "edge/runtime/band_paths.py", missing_ok=True)
    if paths is not None:
        _load(folder, f"band_paths_{short}", paths)
        text = text.replace("from edge_depth.runtime.band_paths import",
                            f"from band_paths_{short} import")
    return _load(folder, f"band_sgm_{short}", text)


def _at(rev: str, path: str, missing_ok: bool = False) -> str | None:
    done = subprocess.run(["git", "show", f"{rev}:{path}"], capture_output=True, text=True)
    if done.returncode != 0 and missing_ok:
        return None
    done.check_returncode()
    return done.stdout


def _load(folder: Path, name: str, text: str):
    """`text` as module `name`, from a file in `folder` (numba caches its kernels there)."""
    path = folder / f"{name}.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up; band_sgm imports it
    spec.loader.exec_module(module)
    return module


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("inputs", type=Path, help="an .npz from band_parts.py --dump")
    p.add_argument("--rev", default="HEAD")
    p.add_argument("--rounds", type=int, default=3)
    args = p.parse_args()
    cv2.setNumThreads(2)
    old = module_at(args.rev)
    for module in (old, band_sgm):
        module.use_threads(2)
    with np.load(args.inputs) as z:
        pairs = [{k: z[f"{i}_{k}"] for k in KEYS} for i in range(int(z["n"]))]
    for i, x in enumerate(pairs):
        a, changed_a = old.refine(**x)
        b, changed_b = band_sgm.refine(**x)
        differ = ~((a == b) | (np.isnan(a) & np.isnan(b)))
        print(f"pair {i}: {'equal' if not differ.any() else f'{differ.sum()} px differ'}, "
              f"refined {changed_a} px at {args.rev}, {changed_b} now")
    for r in range(args.rounds):
        times = {args.rev: 0.0, "now": 0.0}
        for x in pairs:
            for name, module in ((args.rev, old), ("now", band_sgm)):
                t = time.perf_counter()
                module.refine(**x)
                times[name] += (time.perf_counter() - t) * 1000
        print(f"round {r + 1}: " + ", ".join(f"{k} {v / len(pairs):.1f} ms"
                                              for k, v in times.items()))


if __name__ == "__main__":
    main()
