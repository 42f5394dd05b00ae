"""Whether two Python threads run numpy work on two cores at once on this host: each numpy
call releases the GIL, but has to take it back, so a call short next to that hand-over gains
nothing from a second thread. Three measures: (1) the same ufunc loop on one thread, then on
two threads at once, at several array sizes (speed-up 2 = both cores busy); (2) the same
loop in two processes at once (no GIL: whether the two cores are really two); (3) the
engine's weighted median (`edge.runtime.edge_median`) on a 640×400 frame with 30 % of it
gated, its chunks on one thread against split in two halves on two threads.

    python experiments/thread_scaling.py
    bash experiments/avx2_kernels.sh python experiments/thread_scaling.py
"""

from __future__ import annotations

import statistics
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from edge_depth.runtime import edge_median
from edge_depth.runtime.backends import cpu_description

OPS = {"minimum": lambda a, b, o: np.minimum(a, b, out=o),
       "sin": lambda a, b, o: np.sin(a, out=o)}
LOOP_S = 0.25  # each loop's length on one thread


def loop(op: str, n: int, calls: int) -> None:
    a = np.random.default_rng(0).random(n, dtype=np.float32)
    b, o = a.copy(), a.copy()
    for _ in range(calls):
        OPS[op](a, b, o)


def speed_up(op: str, n: int) -> tuple[float, float]:
    """(µs a call, two threads' speed-up over one) for `op` on n float32."""
    t = time.perf_counter()
    loop(op, n, 200)
    calls = max(200, int(200 * LOOP_S / (time.perf_counter() - t)))
    t = time.perf_counter()
    loop(op, n, calls)
    one = time.perf_counter() - t
    threads = [threading.Thread(target=loop, args=(op, n, calls)) for _ in range(2)]
    t = time.perf_counter()
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    two = time.perf_counter() - t
    return one / calls * 1e6, 2 * one / two


def process_speed_up(n: int = 65536, calls: int = 20000) -> float:
    """Two processes running the `minimum` loop from the same moment, against one alone: each
    times its own loop (their start-up is not counted), so 2 is both cores busy at once."""
    def code(start: float) -> str:
        return (f"import time, sys; sys.path.insert(0, {str(__file__.rsplit('/', 1)[0])!r}); "
                f"from thread_scaling import loop; loop('minimum', {n}, 200); "
                f"time.sleep(max(0.0, {start} - time.time())); "
                f"t = time.perf_counter(); loop('minimum', {n}, {calls}); "
                f"print(time.perf_counter() - t)")
    one = float(subprocess.run([sys.executable, "-c", code(0.0)], capture_output=True,
                               text=True, check=True).stdout)
    start = time.time() + 2.0  # both imported and warm by then
    procs = [subprocess.Popen([sys.executable, "-c", code(start)], stdout=subprocess.PIPE,
                              text=True) for _ in range(2)]
    both = max(float(p.communicate()[0]) for p in procs)
    return 2 * one / both


def median_halves(rounds: int = 30) -> tuple[float, float]:
    """The weighted median's ms on one thread and with its chunks in two halves on two."""
    rng = np.random.default_rng(0)
    disparity = (rng.random((400, 640)) * 60).astype(np.float32)
    grey = (rng.random((400, 640)) * 255).astype(np.float32)
    mask = rng.random((400, 640)) < 0.3
    median = edge_median.EdgeMedian()
    pool = ThreadPoolExecutor(1)
    chunk = edge_median.CHUNK_PX
    original = median._medians

    def split(centre, offsets, steps, level):  # the whole gate arrives as one "chunk"
        half = (len(centre) // 2 + chunk - 1) // chunk * chunk

        def part(lo, hi):
            return [original(centre[i:min(i + chunk, hi)], offsets, steps, level)
                    for i in range(lo, hi, chunk)]
        other = pool.submit(part, half, len(centre))
        return np.concatenate(part(0, half) + other.result())

    times = []
    for variant in ("one", "two"):
        if variant == "two":
            edge_median.CHUNK_PX = 1 << 30
            object.__setattr__(median, "_medians", split)
        reference = median.apply(disparity, grey, mask)
        ms = []
        for _ in range(rounds):
            t = time.perf_counter()
            out = median.apply(disparity, grey, mask)
            ms.append((time.perf_counter() - t) * 1000)
        assert np.array_equal(out, reference)
        times.append(statistics.median(ms))
    edge_median.CHUNK_PX = chunk
    return times[0], times[1]


def main() -> None:
    cpu = cpu_description()
    print(f"# {cpu['model']}, {' '.join(cpu['isa'])}")
    print("| op | float32 | µs a call | two threads' speed-up |")
    print("|---|---|---|---|")
    for op, n in (("minimum", 8192), ("minimum", 65536), ("sin", 65536),
                  ("minimum", 1 << 20), ("sin", 1 << 20)):
        us, gain = speed_up(op, n)
        print(f"| {op} | {n} | {us:.1f} | {gain:.2f}× |")
    print(f"two processes' speed-up (minimum, 65536): {process_speed_up():.2f}×")
    one, two = median_halves()
    print(f"weighted median, 30 % of 640×400 gated: one thread {one:.2f} ms, "
          f"two halves on two threads {two:.2f} ms")


if __name__ == "__main__":
    main()
