"""Where the engine's milliseconds go on each kernel set, against SGBM and twice SGBM: one
stacked bar per `tools/bench.py --json` file (its last run's stage medians and SGBM; the ratio
written beside it is the median of its runs), for docs/speed.md.

    python experiments/speed_picture.py out/isa/bench_native.json out/isa/bench_avx2.json \
        --labels "AVX-512 VNNI + BF16 kernels" "AVX2 kernels" --out docs/speed_by_isa.png

The engine's parts: the encoder, its steps (the bench's median step × the iterations), the
upsampling, the matching, the weighted median, and the rest of the int8 engine's median
(the LiDAR selection, scaling, padding and depth); the rest can come out negative on a noisy
run, where the stage medians add up to more than the engine's own.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

PARTS = (("encoder", "encoder"), ("steps", None), ("upsample", "upsampling"),
         ("edge_match", "matching"), ("edge_median", "weighted median"))
COLOURS = ("#4c72b0", "#55a868", "#c44e52", "#8172b2", "#ccb974", "#999999")


def engine_parts(bench: dict, iters: int = 4) -> list[tuple[str, float]]:
    """(label, ms) of the int8 engine at `iters` iterations, from a bench JSON."""
    stages = {k: v["median_ms"] for k, v in bench["stages"].items()}
    parts = []
    for key, label in PARTS:
        if key == "steps":
            parts.append((f"{iters} steps", iters * stages["step"]))
        else:
            parts.append((label, stages[key]))
    total = bench["engine_ms"]["int8"][str(iters)]
    parts.append(("selection and the rest", total - sum(ms for _, ms in parts)))
    return parts


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("benches", nargs="+", type=Path, help="tools/bench.py --json files")
    p.add_argument("--labels", nargs="+", default=None, help="one per file")
    p.add_argument("--out", type=Path, required=True, help="the PNG")
    p.add_argument("--iters", type=int, default=4, help="the engine's iterations (default 4)")
    args = p.parse_args(argv)
    labels = args.labels or [b.stem for b in args.benches]
    if len(labels) != len(args.benches):
        p.error(f"{len(args.benches)} files but {len(labels)} labels")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 1.2 + 1.1 * len(args.benches)))
    for row, path in enumerate(args.benches):
        bench = json.loads(path.read_text())
        left = 0.0
        for (part, ms), colour in zip(engine_parts(bench, args.iters), COLOURS, strict=True):
            ax.barh(row, ms, left=left, color=colour, edgecolor="white",
                    label=part if row == 0 else None)
            if ms >= 4:
                ax.text(left + ms / 2, row, f"{ms:.0f}", ha="center", va="center",
                        color="white", fontsize=8)
            left += ms
        sgbm = bench["sgbm_ms"]
        ax.plot([sgbm, sgbm], [row - 0.4, row + 0.4], color="black", lw=1.5,
                label="SGBM" if row == 0 else None)
        ax.plot([2 * sgbm] * 2, [row - 0.4, row + 0.4], color="black", lw=1.5, ls="--",
                label="2 × SGBM" if row == 0 else None)
        runs = len(bench.get("runs", [])) or 1
        ax.text(max(left, 2 * sgbm) + 1.5, row,
                f"engine {left:.0f} ms, SGBM {sgbm:.0f} ms\n"
                f"{bench.get('ratio_median', bench['ratios']['int8_vs_sgbm']):.2f}× SGBM: "
                f"the median of {runs} runs", va="center", fontsize=8)
    ax.set_yticks(range(len(labels)), labels)
    ax.invert_yaxis()
    ax.set_xlabel(f"ms a frame (640×400, 2 threads, int8 engine at {args.iters} iterations)")
    ax.set_xlim(0, max(ax.get_xlim()[1], 1) * 1.4)
    ax.legend(ncol=4, fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.35),
              frameon=False)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=110, bbox_inches="tight")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
