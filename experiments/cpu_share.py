"""A command's CPU share in its steady state: the process's user + system time (of all its
threads; `exec`-ing wrappers such as experiments/avx2_kernels.sh keep the PID) sampled every
0.5 s from /proc, reported over the last `--last` seconds before it exits (a live run that
stops after --max-frames is then still in its stream, past its start-up).

    python experiments/cpu_share.py [--last 6] -- COMMAND ...

Prints the command's output, then "CPU share: N % of one core over the last S s (M cores)".
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time

TICKS = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid: int) -> float | None:
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / TICKS  # utime, stime


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--last", type=float, default=6.0)
    p.add_argument("command", nargs="+")
    args = p.parse_args()
    child = subprocess.Popen(args.command)
    samples: list[tuple[float, float]] = []
    while child.poll() is None:
        used = cpu_seconds(child.pid)
        if used is not None:
            samples.append((time.monotonic(), used))
        time.sleep(0.5)
    end = samples[-1][0] if samples else 0.0
    window = [s for s in samples if s[0] >= end - args.last]
    if len(window) >= 2:
        (t0, c0), (t1, c1) = window[0], window[-1]
        print(f"CPU share: {100 * (c1 - c0) / (t1 - t0):.0f} % of one core over the last "
              f"{t1 - t0:.1f} s ({os.cpu_count()} cores)", flush=True)
    return child.returncode


if __name__ == "__main__":
    sys.exit(main())
