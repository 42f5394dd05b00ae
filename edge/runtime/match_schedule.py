"""When the full-resolution matching's block matching runs: beside the network's graphs.

StereoBM (`EdgeMatch.matched`) needs only the image pair and a disparity count, and releases
the GIL, so it runs on the matching's own thread while the graphs run:

- a fixed count: from the frame's start, beside the encoder;
- "auto" (the count from the network's own disparity), where the graphs leave a core idle:
  the choice's pair-only terms (`EdgeMatch.pair_terms`) beside the encoder, then StereoBM
  with the count guessed from the disparity one step before the last, beside that step
  (after the encoder with a single step); should the final disparity need another count it
  matches again after the graphs (`starts` counts both);
- otherwise after the graphs, beside the choice's preparation (`EdgeMatch.prepare`) and,
  where the gate reaches far from the LiDAR, SGBM's matching there (`EdgeMatch.far_matched`).

With every core in the graphs, StereoBM beside them slowed them by as much as it saved, and
beside the memory-bound upsampling by more (docs/experiments.md). The outputs are the same
whichever way a frame ran.
"""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from edge_depth.runtime.edge_match import EdgeMatch, Prepared, disparities_for


class MatchSchedule:
    """The matching's thread (started on first use) and its counters, for one engine.
    `early`: whether "auto" may start before the network ends (a core left idle)."""

    def __init__(self, match: EdgeMatch, downsample: int, early: bool) -> None:
        self.match, self.downsample, self.early = match, downsample, early
        self._thread: ThreadPoolExecutor | None = None
        # frames whose matching started before the network's end, and of those, how many
        # matched again because the final disparity needed another count than the guess
        self.starts = {"early": 0, "again": 0}

    def submit(self, fn, *args) -> Future:
        if self._thread is None:
            self._thread = ThreadPoolExecutor(1, "edge-match")
        return self._thread.submit(fn, *args)

    def frame(self, left: np.ndarray, right: np.ndarray, sparse: np.ndarray,
              iters: int) -> FrameMatch:
        """This frame's matching (the (H, W) inputs as the graphs see them), started where
        it can start now."""
        return FrameMatch(self, left, right, sparse, iters)

    def guess_count(self, disparity: np.ndarray) -> int:
        """The "auto" count a low-resolution step output (1, 1, h, w) would give: its largest
        value brought to full-resolution pixels (the convex upsampling never exceeds it)."""
        low = disparity[0, 0]
        return disparities_for(low * self.downsample, low.shape[1] * self.downsample)


class FrameMatch:
    """One frame's matching: `after_step` as the network iterates (step -1: the encoder),
    then `finish` with the network's final disparity and confidence."""

    def __init__(self, schedule: MatchSchedule, left: np.ndarray, right: np.ndarray,
                 sparse: np.ndarray, iters: int) -> None:
        self.schedule, self.pair, self.sparse = schedule, (left, right), sparse
        self.copies: list[np.ndarray] | None = None  # the pair for the thread (buffers reused)
        self.terms: Future | None = None
        self.early: tuple[int, Future] | None = None  # (count, job): started before the end
        match = schedule.match
        if match.num_disparities:
            self.early = self._start(match.num_disparities)
        self.guess_after = iters - 2 if self.early is None and schedule.early else iters
        if self.guess_after < iters:
            self.copies = self._copy()
            self.terms = schedule.submit(match.pair_terms, *self.copies)

    def _copy(self) -> list[np.ndarray]:
        return [a.copy() for a in (*self.pair, self.sparse)]

    def _start(self, count: int) -> tuple[int, Future]:
        """StereoBM with `count` on the thread, then the choice's pair-only terms (already
        submitted as `terms`, or computed there after it)."""
        match = self.schedule.match
        left, right, sparse = self.copies or self._copy()
        terms = self.terms or self.schedule.submit(match.pair_terms, left, right, sparse)
        # the thread runs one job at a time, in order: `terms` is done before this one starts
        return count, self.schedule.submit(
            lambda: (match.matched(left, right, count), terms.result()))

    def after_step(self, step: int, disparity: np.ndarray) -> None:
        """The network's disparity after `step` (-1: the encoder's): the guess's moment?"""
        if step == self.guess_after:
            self.early = self._start(self.schedule.guess_count(disparity))

    def finish(self, disparity: np.ndarray, confidence: np.ndarray
               ) -> tuple[np.ndarray, int, int, int, Prepared | None]:
        """(disparity with the matched pixels taken, pixels taken, pixels beyond the count,
        the gate's pixels SGBM matched far from the LiDAR (0: it did not run), the choice's
        preparation for the median), waiting for StereoBM if it still runs."""
        schedule, match = self.schedule, self.schedule.match
        count = match.count_for(disparity)
        beyond = match.beyond_px(disparity, count)
        # the terms computed beside the encoder (a deadline may have stopped the steps
        # before the guess)
        terms = None if self.terms is None else self.terms.result()
        found = None
        if self.early is not None:
            early_count, job = self.early
            found, terms = job.result()
            schedule.starts["early"] += 1
            if early_count != count:  # the guess missed: StereoBM again, the count right
                schedule.starts["again"] += 1
                found = None
        # late (no guess, or a missed one): StereoBM matches while the choice prepares
        late = None if found is not None else schedule.submit(match.matched, *self.pair, count)
        prepared = match.prepare(*self.pair, disparity, confidence, self.sparse, terms)
        far = match.far_matched(*self.pair, prepared, count)  # SGBM here, StereoBM beside it
        found = found if late is None else late.result()
        out, taken = match.finish(prepared, disparity, found, far)
        far_px = 0 if prepared is None or prepared.far is None \
            else int(np.count_nonzero(prepared.far))  # `far_matched` ran exactly there
        return out, taken, beyond, far_px, prepared
