"""A soak of the sim-robot daemon: does its memory grow? (docs/reliability.md)

    python experiments/soak.py --minutes 60 --out out/soak [--config CONFIG]

Runs `edge-depth run --config CONFIG` (the sim robot, raw logging, rotation) for the given time,
samples the resident memory (RSS, the daemon and its child processes together, from /proc)
every `--every` seconds, and deletes all but the newest `--keep` rotated parts as it goes so
the disk does not fill (a stand-in for a ring buffer: the daemon itself never deletes).
At the end it stops the daemon with SIGINT (its closing summary is kept in OUT/daemon.log),
writes OUT/rss.csv (seconds, MB) and prints the least-squares RSS slope after the warm-up.
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

PAGE_KB = 4


def _children(pid: int) -> list[int]:
    """`pid` and every process under it (/proc/PID/task/*/children)."""
    found, todo = [], [pid]
    while todo:
        p = todo.pop()
        found.append(p)
        for task in Path(f"/proc/{p}/task").glob("*"):
            try:
                todo += [int(c) for c in (task / "children").read_text().split()]
            except OSError:
                continue
    return found


def rss_mb(pid: int) -> float:
    """Resident memory of `pid` and its children in MB (2**20 bytes)."""
    total_kb = 0
    for p in _children(pid):
        try:
            fields = Path(f"/proc/{p}/statm").read_text().split()
        except OSError:
            continue
        total_kb += int(fields[1]) * PAGE_KB
    return total_kb / 1024


def slope_mb_per_min(samples: list[tuple[float, float]], warmup_s: float) -> float:
    """The least-squares slope of RSS against time after `warmup_s`, in MB per minute."""
    t, mb = np.array([s for s in samples if s[0] >= warmup_s]).T
    return float(np.polyfit(t / 60.0, mb, 1)[0])


def _prune(folder: Path, keep: int) -> None:
    parts = sorted(folder.glob("*.mcap"))
    for old in parts[:-keep]:
        old.unlink(missing_ok=True)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--minutes", type=float, default=60.0)
    p.add_argument("--every", type=float, default=10.0, help="seconds between RSS samples")
    p.add_argument("--warmup-min", type=float, default=5.0)
    p.add_argument("--keep", type=int, default=2, help="rotated parts kept on disk")
    p.add_argument("--config", default="experiments/sim_robot_soak.toml")
    p.add_argument("--out", default="out/soak")
    p.add_argument("--bin", default=str(Path(sys.executable).parent / "edge-depth"))
    args = p.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    logs = Path("out/soak_log")  # the config's [log] out folder
    logs.mkdir(parents=True, exist_ok=True)
    with open(out / "daemon.log", "w") as daemon_log:
        daemon = subprocess.Popen([args.bin, "run", "--config", args.config],
                                  stdout=daemon_log, stderr=subprocess.STDOUT)
        samples = _sample(daemon, args, logs, out)
        daemon.send_signal(signal.SIGINT)
        code = daemon.wait(timeout=120)
    _prune(logs, 0)
    slope = slope_mb_per_min(samples, args.warmup_min * 60)
    summary = {"minutes": args.minutes, "samples": len(samples), "exit_code": code,
               "rss_first_mb": samples[0][1], "rss_last_mb": samples[-1][1],
               "rss_max_mb": max(mb for _, mb in samples),
               "slope_after_warmup_mb_per_min": round(slope, 4)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(json.dumps(summary))
    return 0 if code == 0 else 1


def _sample(daemon: subprocess.Popen, args, logs: Path, out: Path) -> list[tuple[float, float]]:
    start, samples = time.monotonic(), []
    with open(out / "rss.csv", "w") as csv:
        csv.write("seconds,rss_mb\n")
        while (now := time.monotonic() - start) < args.minutes * 60:
            if daemon.poll() is not None:
                raise SystemExit(f"the daemon exited ({daemon.returncode}) after {now:.0f} s; "
                                 f"see {out / 'daemon.log'}")
            samples.append((now, rss_mb(daemon.pid)))
            csv.write(f"{now:.1f},{samples[-1][1]:.1f}\n")
            csv.flush()
            _prune(logs, args.keep)
            time.sleep(args.every)
    return samples


if __name__ == "__main__":
    sys.exit(main())
