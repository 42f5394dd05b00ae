"""Two `experiments/judge_engine_change.sh` runs compared by group of data sets, for a rule's
clauses: per path, how many sets are identical, the largest EPE change (%) and bad-3 change
(points) with LiDAR, and the mean EPE change. A group is a name and a shell-style pattern on
the sets' names; a set may be read from a further folder (`--extra`, later wins).

    python experiments/judge_summary.py runs/judge_ref runs/judge_new \
        --group "clean=aloe,motorcycle,aloe_r8,motorcycle_r8,test16" \
        --group "noisy=*_n0[4-9]*,*_n1[0-9]*" [--extra REF_DIR:NEW_DIR]
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import statistics
from pathlib import Path


def results(folders: list[Path], path: str) -> dict[str, dict]:
    """Set name -> its evaluation (`net` with LiDAR) on `path`, later folders winning."""
    out: dict[str, dict] = {}
    for folder in folders:
        for f in sorted(folder.glob(f"eval_{path}_*.json")):
            out[f.stem[len(f"eval_{path}_"):]] = json.loads(f.read_text())["net"]
    return out


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("reference", type=Path)
    p.add_argument("change", type=Path)
    p.add_argument("--group", action="append", required=True, metavar="NAME=PATTERNS",
                   help="comma-separated fnmatch patterns on the sets' names")
    p.add_argument("--extra", action="append", default=[], metavar="REF:NEW")
    p.add_argument("--paths", default="avx2 native ort")
    args = p.parse_args()
    refs = [args.reference] + [Path(e.split(":")[0]) for e in args.extra]
    news = [args.change] + [Path(e.split(":")[1]) for e in args.extra]
    for path in args.paths.split():
        ref, new = results(refs, path), results(news, path)
        print(f"\n{path}:\n")
        print("| group | sets | identical | largest EPE change | largest bad-3 change | mean EPE "
              "change |")
        print("|---|---|---|---|---|---|")
        for group in args.group:
            name, patterns = group.split("=", 1)
            names = sorted(n for n in ref if n in new and any(
                fnmatch.fnmatch(n, pat) for pat in patterns.split(",")))
            if not names:
                print(f"| {name} | 0 | | | | |")
                continue
            epe = {n: 100 * (new[n]["epe"] / ref[n]["epe"] - 1) for n in names}
            bad3 = {n: new[n]["bad3"] - ref[n]["bad3"] for n in names}
            same = sum(new[n]["epe"] == ref[n]["epe"] and new[n]["bad3"] == ref[n]["bad3"]
                       for n in names)
            worst, worst3 = max(epe, key=epe.get), max(bad3, key=bad3.get)
            print(f"| {name} | {len(names)} | {same} | {epe[worst]:+.2f} % ({worst}) | "
                  f"{bad3[worst3]:+.2f} ({worst3}) | {statistics.mean(epe.values()):+.2f} % |")


if __name__ == "__main__":
    main()
