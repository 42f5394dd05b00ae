"""Full-resolution block matching at the network's uncertain edges (on with the shipped bundle).

The network works at 1/8 resolution; on real pairs all of its bad-3 loss against the SGBM +
LiDAR fusion lies at depth edges, where thin structures (leaves, spokes, cables) are finer
than its grid (docs/experiments.md). This stage runs OpenCV's StereoBM over the
frame and takes its left-right-checked value where the network is unsure at its own edges:
confidence below `max_confidence`, the network's disparity ranging over more than
`min_range_px` within `window` × `window` pixels, and the matched value warping the right view
onto the left better than the network's (mean |difference| over `photo_window` ×
`photo_window`). Where StereoBM found no checked match inside that gate (its holes: 15 % of
the frame's pixels on motorcycle), the LiDAR's nearest point is the second candidate, taken
where the left image has texture (5×5 mean |∂x| above `min_texture`) and the point warps the
right view onto the left clearly better (cost below `point_margin` × the network's).
Everything else keeps the network's value; frames without points get the block matching alone.
On a sparse LiDAR map (`far_px`: the gated pixels over FAR_PX from every point are
FAR_MIN_SHARE of the frame or more), those take SGBM's checked match instead, by the same warp
test: far from every point the network has only its stereo, which on real pairs trails SGBM's.
A frame without points is far from them everywhere; there SGBM's match must also be smooth
(`FAR_SMOOTH_PX`).
With `median` (the shipped bundle's "9x9/2") the gate then goes through a
grey-guided weighted median (`edge.runtime.edge_median`), which cleans the choice's
pixel-by-pixel mix, and the point's gate is looser (`MEDIAN_POINT_MARGIN`,
`MEDIAN_MIN_TEXTURE`).

Whether it runs is the bundle's to declare (model.json's "engine", `[engine] edge_match =
"bundle"` by default): since stage 17 the shipped bundle's head (refinement version 10, no
image-guided refinement of its own) is made to hand its unsure edges to this stage, "auto" on
every other row (`edge_match_rows = 2`); bundles of other heads keep it off unless asked. On
every row with 64 disparities it cost about 0.8× SGBM's time (`tools/bench.py`);
the engine runs the block matching on its own thread: beside its graphs with a fixed count;
with "auto", where the graphs leave a core idle, beside the last step with the count guessed
one step earlier (`pair_terms` beside the encoder), else beside the choice's preparation
(the shipped setting's time: README "Speed"). Its parameters (the point's margin and texture
gate too: docs/experiments.md) were chosen on the Middlebury motorcycle pair
(`tools/real_pairs.py --motorcycle`); Aloe was only reported. On the synthetic worlds it costs
EPE (there SGBM-like matching is 3-4× less reliable than on real pairs): the README's tables
give both.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass

import cv2
import numpy as np

from edge_depth.baselines import make_sgbm, nearest_point
from edge_depth.errors import ConfigError
from edge_depth.runtime.cells import local_range, warped_cost
from edge_depth.runtime.edge_median import OFF, EdgeMedian

BLOCK_PX = 7
MAX_CONFIDENCE = 0.9
MIN_RANGE_PX = 1.0
WINDOW_PX = 5
PHOTO_WINDOW_PX = 5
# a frame with more than this % of its pixels beyond the disparity count is counted and said
# (closing summary, /diagnostics' level on the ROS 2 profile): the count is too small there
BEYOND_PCT = 1.0
AUTO = "auto"        # the count per frame, from the network's own largest disparity ...
AUTO_MARGIN_PX = 8   # ... plus this, rounded up to StereoBM's multiple of 16
POINT_MARGIN = 0.8   # the LiDAR point's 5x5 warp cost must be below this x the network's
MIN_TEXTURE = 4.0    # ... where the left image's 5x5 mean |d/dx| (grey levels / px) exceeds
# with the weighted median after the choice, which cleans a wrong point's single pixels, a
# looser gate takes more points (docs/experiments.md, chosen on motorcycle)
MEDIAN_POINT_MARGIN = 1.0
MEDIAN_MIN_TEXTURE = 2.0
ROW_STEPS = (1, 2)   # StereoBM on every row, or every other row (half its time)
# the block matcher: OpenCV's StereoBM (the default), or its SGBM (3-way, block 5: the
# classical baseline's), which leaves far fewer holes in the gate for about SGBM's whole time
# (docs/experiments.md: on Aloe past the SGBM + LiDAR fusion on both numbers)
MATCHERS = ("bm", "sgbm")
SGBM_BLOCK_PX = 5
# Far from every LiDAR point the network's disparity rests on its stereo alone, which on real
# pairs trails SGBM's (Aloe stereo only: bad-3 12.3 %): gated pixels farther than FAR_PX from
# the nearest point take SGBM's checked match instead of StereoBM's, where it warps the right
# view onto the left better — on frames where such pixels are at least FAR_MIN_SHARE of the
# frame (a sparse map: 8-15 % with 12 or 8 rows; 0-3 % with 16 on the real pairs, up to 6 % on
# the rig's), since SGBM over their rows costs the frame 10-12 ms with AVX2 kernels
# (docs/experiments.md). With SGBM as the matcher (`matcher` "sgbm") they have its match already.
FAR_PX = 12.0
FAR_MIN_SHARE = 0.05
# A frame without points is far from them everywhere; there SGBM's match is taken only where
# it is itself smooth (its 5x5 range at most this, px): on the rig, where the network is at
# home, SGBM's wrong matches are its speckle (docs/experiments.md)
FAR_SMOOTH_PX = 2.0


@dataclass
class EdgeMatch:
    """`EdgeMatch(num_disparities)`; `apply(left, right, disparity, confidence)`.
    `num_disparities` 0: no fixed count — each call of `matched` gives its own (see
    `disparities_for`)."""

    num_disparities: int
    block_px: int = BLOCK_PX
    max_confidence: float = MAX_CONFIDENCE
    min_range_px: float = MIN_RANGE_PX
    window_px: int = WINDOW_PX
    photo_window_px: int = PHOTO_WINDOW_PX
    point_margin: float | None = None  # None: POINT_MARGIN, or MEDIAN_POINT_MARGIN with median
    min_texture: float | None = None   # None: MIN_TEXTURE, or MEDIAN_MIN_TEXTURE with median
    row_step: int = 1
    matcher: str = "bm"
    median: str = OFF  # or a pattern of edge_median.PATTERNS: the gate's weighted median
    far_px: float = 0.0  # FAR_PX: SGBM's match for gated pixels this far from every point

    def __post_init__(self) -> None:
        if self.num_disparities < 0 or self.num_disparities % 16:
            raise ConfigError("edge_match", f"{AUTO!r}, 0 (off) or a positive multiple of 16 "
                              "(StereoBM's disparity count: above the scene's largest)",
                              self.num_disparities)
        check_row_step(self.row_step)
        check_matcher(self.matcher)
        self._median = None if self.median == OFF else EdgeMedian(self.median)
        if self.point_margin is None:
            self.point_margin = POINT_MARGIN if self._median is None else MEDIAN_POINT_MARGIN
        if self.min_texture is None:
            self.min_texture = MIN_TEXTURE if self._median is None else MEDIAN_MIN_TEXTURE
        if self.far_px < 0:
            raise ConfigError("edge_match_far_px", "0 (off) or a distance in pixels", self.far_px)
        self._matchers: dict[tuple[str, int], cv2.StereoMatcher] = {}

    def _matcher(self, num_disparities: int, matcher: str = "") -> cv2.StereoMatcher:
        """The block matcher (`matcher`, default the stage's) for a count, kept per count."""
        key = (matcher or self.matcher, num_disparities)
        if key not in self._matchers and key[0] == "sgbm":
            sgbm = make_sgbm(num_disparities, SGBM_BLOCK_PX)  # the baseline's matcher,
            sgbm.setSpeckleWindowSize(100 // self.row_step)   # its speckle window per row
            self._matchers[key] = sgbm
        if key not in self._matchers:  # a few counts per scene: kept
            bm = cv2.StereoBM.create(numDisparities=num_disparities, blockSize=self.block_px)
            bm.setTextureThreshold(10)
            bm.setUniquenessRatio(15)
            bm.setDisp12MaxDiff(1)
            bm.setSpeckleWindowSize(100 // self.row_step)  # the same area of the frame
            bm.setSpeckleRange(2)
            bm.setPreFilterCap(31)
            self._matchers[key] = bm
        return self._matchers[key]

    def _count(self, num_disparities: int) -> int:
        """This call's count, or the stage's fixed one (one of them is required)."""
        count = num_disparities or self.num_disparities
        if count <= 0:
            raise ValueError("EdgeMatch(0) takes its disparity count per call")
        return count

    def count_for(self, disparity: np.ndarray) -> int:
        """The disparity count a frame's matching runs with: the stage's fixed one, or
        "auto"'s from the network's final `disparity` (`disparities_for`)."""
        return self.num_disparities or disparities_for(disparity, disparity.shape[1])

    def beyond_px(self, disparity: np.ndarray, num_disparities: int = 0) -> int:
        """Pixels whose disparity StereoBM cannot reach (≥ the count − 1): a count too small
        for the scene fails there without a sound, so the daemon counts it."""
        return int(np.count_nonzero(disparity >= self._count(num_disparities) - 1))

    def matched(self, left: np.ndarray, right: np.ndarray,
                num_disparities: int = 0, matcher: str = "") -> np.ndarray:
        """The block matcher's disparity in px (StereoBM's, or SGBM's with `matcher` "sgbm"),
        (H, W) float32; 0 where it found no checked match.
        `num_disparities`: this call's count (required when the stage has none fixed). With
        `row_step` 2 it matches every other row (the columns, the disparity's own axis, at
        full resolution) and each value also stands for the row below. `matcher`: "bm" or
        "sgbm" instead of the stage's."""
        left, right = as_grey8(left), as_grey8(right)
        height = left.shape[0]
        if self.row_step > 1:
            left, right = left[::self.row_step], right[::self.row_step]
        raw = self._matcher(self._count(num_disparities), matcher).compute(left, right)
        out = raw.astype(np.float32) * (1.0 / 16.0)
        out[raw <= 0] = 0.0
        if self.row_step > 1:
            out = np.repeat(out, self.row_step, axis=0)[:height]
        return out

    def apply(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
              confidence: np.ndarray, sparse: np.ndarray | None = None,
              matched: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """(disparity with the matched values swapped in, how many pixels were swapped).
        `sparse`: the LiDAR's disparity (px, 0 = no point), or None. `matched`:
        `matched(left, right)` if already computed. `prepare` then `finish`: the engine runs
        the first while StereoBM is still matching."""
        if matched is None:
            matched = self.matched(left, right)
        prepared = self.prepare(left, right, disparity, confidence, sparse)
        far = self.far_matched(left, right, prepared, self.count_for(disparity))
        out, taken = self.finish(prepared, disparity, matched, far)
        return self.smooth(out, prepared), taken

    def prepare(self, left: np.ndarray, right: np.ndarray, disparity: np.ndarray,
                confidence: np.ndarray, sparse: np.ndarray | None = None,
                terms: PairTerms | None = None) -> Prepared | None:
        """Everything of the choice that does not need StereoBM's answer: where the network
        is unsure at its edges (the gate), its own warp cost, and where the LiDAR's nearest
        point would do for a hole. None when nothing is gated. `terms`: `pair_terms(left,
        right, sparse)` if already computed (the engine's matching thread does)."""
        gate = unsure_edges(disparity, confidence, self.max_confidence, self.min_range_px,
                            self.window_px)
        if not gate.any():
            return None
        if terms is None:
            terms = self.pair_terms(left, right, sparse)
        network_cost = warped_cost(*terms.grey, disparity, (self.photo_window_px,))[0]
        point_ok = far = None
        if terms.point is not None and terms.texture is not None \
                and terms.point_cost is not None:
            point_ok = gate & (terms.texture > float(self.min_texture or 0.0)) & \
                (terms.point_cost < float(self.point_margin or 0.0) * network_cost)
        if self.far_px > 0 and self.matcher != "sgbm":  # without points: far everywhere
            far = gate if terms.distance is None else gate & (terms.distance > self.far_px)
            far = far if np.count_nonzero(far) >= FAR_MIN_SHARE * far.size else None
        return Prepared(gate, terms.grey, network_cost, terms.point, point_ok, far,
                        far_smooth_only=terms.distance is None)

    def pair_terms(self, left: np.ndarray, right: np.ndarray,
                   sparse: np.ndarray | None = None) -> PairTerms:
        """The choice's terms that need only the pair and the LiDAR, not the network: the grey
        pair (float32), the nearest point's map, its 5×5 warp cost, the left image's
        texture and each pixel's distance to that point (the last four None without
        points)."""
        grey = [np.asarray(im, np.float32) for im in (left, right)]
        if sparse is None or not (sparse > 0).any():
            return PairTerms(grey)
        window = (self.photo_window_px,)
        point, distance = nearest_point(sparse, sparse > 0)
        gradient = np.abs(cv2.Sobel(grey[0], cv2.CV_32F, 1, 0, ksize=1, scale=0.5))
        texture = cv2.blur(gradient, window * 2)  # mean |d/dx| in the window
        return PairTerms(grey, point, warped_cost(*grey, point, window)[0], texture, distance)

    def far_matched(self, left: np.ndarray, right: np.ndarray, prepared: Prepared | None,
                    num_disparities: int) -> np.ndarray | None:
        """SGBM's checked disparity (0: no match) over the rows and columns the gate's far
        pixels span (`Prepared.far`), zeros elsewhere; None where there are none. The
        columns reach `num_disparities` further left, so each far pixel sees its whole
        range."""
        if prepared is None or prepared.far is None:
            return None
        rows, cols = np.flatnonzero(prepared.far.any(1)), np.flatnonzero(prepared.far.any(0))
        top = rows[0] - rows[0] % self.row_step  # on the row grid `matched` keeps
        x0, x1 = max(0, int(cols[0]) - num_disparities), int(cols[-1]) + 1
        if x1 - x0 <= num_disparities:  # SGBM needs columns beyond its count
            x0, x1 = 0, left.shape[1]
        box = (slice(top, int(rows[-1]) + 1), slice(x0, x1))
        out = np.zeros(left.shape, np.float32)
        out[box] = self.matched(left[box], right[box], num_disparities, "sgbm")
        return out

    def finish(self, prepared: Prepared | None, disparity: np.ndarray, matched: np.ndarray,
               far_matched: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """The choice: `prepare`'s gate and costs with StereoBM's answer, and far from the
        LiDAR SGBM's (`far_matched`) instead (the median, a stage of its own, is
        `smooth`)."""
        if prepared is None:
            return disparity.astype(np.float32, copy=True), 0
        found = matched > 0
        # only where the matched value explains the pair better
        take = prepared.gate & found & \
            (warped_cost(*prepared.grey, matched, (self.photo_window_px,))[0] <
             prepared.network_cost)
        out = np.where(take, matched, disparity).astype(np.float32)
        if prepared.point is not None and prepared.point_ok is not None:  # StereoBM's holes:
            # the nearest point, where it does
            hole_take = prepared.point_ok & ~found
            out[hole_take] = prepared.point[hole_take]
            take |= hole_take
        if prepared.far is not None and far_matched is not None:  # far from every point
            far_take = prepared.far & (far_matched > 0) & \
                (warped_cost(*prepared.grey, far_matched, (self.photo_window_px,))[0] <
                 prepared.network_cost)
            if prepared.far_smooth_only:
                far_take &= local_range(far_matched, self.window_px) <= FAR_SMOOTH_PX
            out[far_take] = far_matched[far_take]
            take |= far_take
        return out, int(take.sum())

    def smooth(self, disparity: np.ndarray, prepared: Prepared | None) -> np.ndarray:
        """The gate's grey-guided weighted median (`median`; `edge.runtime.edge_median`):
        after the choice, its pixel-by-pixel mix of sources made one surface with the image's
        edges. As it is when the median is off or nothing was gated."""
        if self._median is None or prepared is None:
            return disparity
        return self._median.apply(disparity, prepared.grey[0], prepared.gate)


@dataclass
class PairTerms:
    """`EdgeMatch.pair_terms`' answer."""

    grey: list[np.ndarray]
    point: np.ndarray | None = None
    point_cost: np.ndarray | None = None
    texture: np.ndarray | None = None
    distance: np.ndarray | None = None  # px to the nearest point


@dataclass
class Prepared:
    """`EdgeMatch.prepare`'s answer: the gate, the grey pair (float32), the network's 5×5
    warp cost, the nearest point's map with where it may fill a hole (None without LiDAR),
    and the gate's pixels far from every point (None: under FAR_MIN_SHARE of the frame, or
    `far_px` off)."""

    gate: np.ndarray
    grey: list[np.ndarray]
    network_cost: np.ndarray
    point: np.ndarray | None
    point_ok: np.ndarray | None
    far: np.ndarray | None = None
    far_smooth_only: bool = False  # no points: SGBM's match only where it is smooth


def unsure_edges(disparity: np.ndarray, confidence: np.ndarray,
                 max_confidence: float = MAX_CONFIDENCE, min_range_px: float = MIN_RANGE_PX,
                 window_px: int = WINDOW_PX) -> np.ndarray:
    """The gate: where the network is unsure (`confidence` under `max_confidence`) at an edge
    (the disparity's range over `window_px`² above `min_range_px`)."""
    return (confidence < max_confidence) & \
        (local_range(disparity, window_px) > min_range_px)


def check_matcher(matcher: str) -> None:
    """`[engine] edge_matcher`: ConfigError unless one of MATCHERS."""
    if matcher not in MATCHERS:
        raise ConfigError("edge_matcher", " or ".join(f'"{m}"' for m in MATCHERS) + " (OpenCV's "
                          "StereoBM, or its SGBM: fewer holes, about SGBM's time)", matcher)


def check_row_step(row_step: int) -> None:
    """`[engine] edge_match_rows`: ConfigError unless one of ROW_STEPS."""
    if row_step not in ROW_STEPS:
        raise ConfigError("edge_match_rows", " or ".join(map(str, ROW_STEPS)) + " (every "
                          "row, or every other row: half StereoBM's time)", row_step)


def parse_count(text: str) -> int | str:
    """A command line's `--edge-match`: "auto", or 0 (off) / a positive multiple of 16
    (ValueError otherwise, with what is accepted)."""
    if text.strip().lower() == AUTO:
        return AUTO
    try:
        count = int(text)
    except ValueError:
        raise ValueError(f"{AUTO!r} or a disparity count (0 = off), not {text!r}") from None
    EdgeMatch(count)  # ConfigError (a ValueError) unless 0 or a multiple of 16
    return count


def count_argument(text: str) -> int | str:
    """`parse_count` as an argparse type: the command line's one clear line."""
    try:
        return parse_count(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def disparities_for(disparity: np.ndarray, width: int) -> int:
    """StereoBM's disparity count for a frame from the network's own disparity there: its
    largest value plus `AUTO_MARGIN_PX`, rounded up to a multiple of 16 — at least 16, below
    `width` (StereoBM matches nothing with a count as wide as the image)."""
    largest = float(np.nanmax(disparity, initial=0.0))
    largest = largest if np.isfinite(largest) else float(width)  # inf: as wide as allowed
    count = 16 * int(np.ceil((largest + AUTO_MARGIN_PX) / 16.0))
    return int(min(max(count, 16), 16 * ((width - 1) // 16)))


def as_grey8(image: np.ndarray) -> np.ndarray:
    """StereoBM needs 8-bit grey: float images (the engine's buffers) are rounded and clipped."""
    if image.dtype == np.uint8:
        return image
    return np.clip(np.rint(image), 0, 255).astype(np.uint8)
