"""The camera rate with each key frame's own output carried from the key frame before while
the engine runs on it in a thread of its own (the frames after it wait for its result, as
they do now): an experiment in latency, the daemon patched, nothing in the package.

    python experiments/key_frame_ahead.py run --config experiments/sim_robot_camera_rate.toml

Every `edge-depth` command works; with `[engine] rate = "camera"` a key frame that the last
key frame reaches is submitted to a one-thread pool and its output is the carry; the next
frame first waits for that engine run and makes it the key frame. The first key frame, and
one whose flow is lost, run in line as before.
"""

import sys
import time
from concurrent.futures import ThreadPoolExecutor

from edge_depth import daemon

POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="key-frame")


def settle(pipeline) -> None:
    """A key frame's engine run still going: wait for it, then make it the key frame."""
    pending = getattr(pipeline, "_pending", None)
    if pending is not None:
        pipeline._pending = None
        future, stamp_ns, scan_ns, left = pending
        pipeline.propagator.key(stamp_ns, scan_ns, left, future.result())


def infer_ahead(self, p):
    assert self.engine is not None, "the recorder infers nothing"
    p.queued_ms = (time.perf_counter() - p.t0) * 1000 - p.timings["rectify"] \
        - p.timings["project"]
    carry = self.propagator
    if carry is not None:
        settle(self)

    def run_engine():
        return self.engine.infer(p.left, p.right, p.sparse, iters=self.iters,
                                 deadline_ms=self.deadline_ms, focal_px=self.focal_px,
                                 baseline_m=self.baseline_m, stamp_ns=p.frame.stamp_ns,
                                 started=p.t0)

    if carry is not None:
        stamp, scan = p.frame.stamp_ns, p.points_stamp_ns
        wanted = carry.wants_engine(stamp, scan)
        ahead = wanted and carry.last is not None and scan is not None and \
            0 <= stamp - carry.last.stamp_ns <= 0.25e9
        if ahead:
            self._pending = (POOL.submit(run_engine), stamp, scan, p.left)
        if not wanted or ahead:
            carried = carry.carry(stamp, p.left, self.focal_px, self.baseline_m,
                                  self.principal_point)
            if carried is not None:
                p.carried = True
                return carried
            if ahead:  # the flow is lost: this frame's own engine run, waited for
                settle(self)
                return carry.last.result
    result = run_engine()
    if carry is not None:
        carry.key(p.frame.stamp_ns, p.points_stamp_ns, p.left, result)
    return result


daemon.Pipeline.infer = infer_ahead  # type: ignore[method-assign]

from edge_depth.cli import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
