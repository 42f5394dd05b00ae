"""The engine's disparity on one sim scene, per runtime and precision, saved to compare what
two CPUs compute: run it natively and under experiments/avx2_cpu.sh (an emulated AVX2-only
CPU), then compare the two files.

    python experiments/ort_on_avx2.py run out/native.npz
    bash experiments/avx2_cpu.sh .venv/bin/python experiments/ort_on_avx2.py run out/avx2.npz
    python experiments/ort_on_avx2.py compare out/native.npz out/avx2.npz
"""

from __future__ import annotations

import argparse
import time

import numpy as np


def run(out: str, runtimes: list[str], precisions: list[str], size: tuple[int, int]) -> None:
    from edge_depth.runtime.engine import Engine
    from edge_depth.sim import RigConfig, make_sample

    rig = RigConfig(width=size[0], height=size[1], focal_px=0.7 * size[0],
                    max_disparity_px=0.1 * size[0])
    sample = make_sample(1_000_002, rig, "beams16")
    sparse, valid = sample.sparse_disparity("left")
    args = (sample.left, sample.right, (sparse * valid).astype(np.float32))
    results = {}
    for runtime in runtimes:
        for precision in precisions:
            start = time.perf_counter()
            engine = Engine(precision=precision, threads=2, runtime=runtime, edge_match=0,
                            bf16=False)
            results[f"{runtime}/{precision}"] = engine.infer(*args).disparity
            print(f"{engine.describe()}: {time.perf_counter() - start:.1f} s", flush=True)
    np.savez(out, **results)


def compare(a_path: str, b_path: str) -> None:
    a, b = np.load(a_path), np.load(b_path)
    print("| output | max abs px | mean abs px |\n|---|---|---|")
    for key in sorted(set(a) & set(b)):
        diff = np.abs(a[key] - b[key])
        print(f"| {key} | {diff.max():.2g} | {diff.mean():.2g} |")
    keys = sorted(a)
    for i, first in enumerate(keys):  # within each file: the runtimes and precisions apart
        for second in keys[i + 1:]:
            for name, f in ((a_path, a), (b_path, b)):
                if first in f and second in f:
                    diff = np.abs(f[first] - f[second])
                    print(f"{name}: {first} vs {second}: max {diff.max():.2g}, "
                          f"mean {diff.mean():.2g} px")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    r = sub.add_parser("run")
    r.add_argument("out")
    r.add_argument("--runtimes", default="onnxruntime,openvino")
    r.add_argument("--precisions", default="fp32,int8")
    r.add_argument("--size", default="320x200", help="WxH of the scene")
    c = sub.add_parser("compare")
    c.add_argument("a")
    c.add_argument("b")
    args = parser.parse_args()
    if args.command == "run":
        w, h = (int(x) for x in args.size.split("x"))
        run(args.out, args.runtimes.split(","), args.precisions.split(","), (w, h))
    else:
        compare(args.a, args.b)


if __name__ == "__main__":
    main()
