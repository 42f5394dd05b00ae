"""What a run's frames say, from their per-frame timings (`Pipeline.finish`'s dicts): the
stages' median / p95 latency (`summarise`) and the closing lines about the LiDAR selection,
the band refinement and the LiDAR map's checks (`selection_summary`); the daemon,
`replay` and the demo print them, `/diagnostics` carries the per-frame values
(`replaced_shares`). Also the closing lines from a pipeline's counters: the LiDAR's
pairing (`lidar_summary`), the calibration watch's (`watch_summary`) and the camera rate's
(`rate_summary`)."""

from __future__ import annotations

import numpy as np

from edge_depth.calibration_verdict import fixes
from edge_depth.runtime.lidar_align import jump_px
from edge_depth.runtime.lidar_denoise import THRESHOLD_PX as NOISE_THRESHOLD_PX

# per-frame values in the timings that are not ms
NOT_LATENCY = ("iterations", "replaced_pct", "refined_pct", "band_skipped", "lidar_put_back",
               "lidar_dx_px", "lidar_dy_px", "lidar_turn_deg", "lidar_noise_px", "lidar_smoothed")
# the selections' per-frame shares: timings key -> the closing line's name
SELECTIONS = {"replaced_pct": "LiDAR selection", "refined_pct": "Band refinement"}


def replaced_shares(timings: list[dict], key: str = "replaced_pct") -> list[float]:
    """Per frame that ran the stage, its share (%) under `key`: one of SELECTIONS' (the % of
    the frame's pixels the stage replaced; default the LiDAR selection's), or the pair's
    "lidar_noise_px", or "lidar_put_back" (1: the LiDAR map was put back)."""
    return [t[key] for t in timings if key in t]


def rate_summary(propagator) -> str | None:
    """The closing line of `[engine] rate = "camera"` (None otherwise): key frames and the
    frames carried between them."""
    if propagator is None:
        return None
    lost = f" ({propagator.lost} of the key frames where the flow was lost)" \
        if propagator.lost else ""
    return (f"Camera rate: {propagator.keys} key frames (the engine) on {propagator.scans} "
            f"scans{lost}, "
            f"{propagator.carried} carried along the optical flow between scans "
            f"({propagator.scaled} scaled by the camera's motion fitted to it"
            + (f"; {propagator.ahead} without waiting for their scans" if propagator.ahead
               else "") + ")")


def selection_summary(timings: list[dict]) -> str | None:
    """The closing lines about the selections, one each: the share of each frame's pixels
    it replaced (None when the engine ran none)."""
    lines = []
    for key, name in SELECTIONS.items():
        shares = replaced_shares(timings, key)
        if shares:
            none = sum(1 for s in shares if s == 0)
            lines.append(f"{name}: replaced a median {np.median(shares):.1f} % of each "
                         f"frame's pixels (p95 {np.percentile(shares, 95):.1f} %; none in "
                         f"{none} of {len(shares)} frames)")
    if skipped := int(sum(replaced_shares(timings, "band_skipped"))):
        engine_frames = sum(1 for t in timings if "band_refine" in t or "band_skipped" in t)
        lines.append(f"Band refinement: skipped in {skipped} of {engine_frames} frames the "
                     "engine ran on, where it would have ended after the deadline")
    if line := noise_line(timings):
        lines.append(line)
    if (put_back := replaced_shares(timings, "lidar_put_back")) and any(put_back):
        moves = [(t["lidar_dx_px"], t["lidar_dy_px"], t["lidar_turn_deg"]) for t in timings
                 if t.get("lidar_put_back")]
        dx, dy, turn = (float(np.median(m)) for m in zip(*moves, strict=True))
        lines.append(f"LiDAR map: put back onto the image's edges in {len(moves)} of "
                     f"{len(put_back)} frames (it sat turned {turn:+.2f}° and moved "
                     f"({dx:+.0f}, {dy:+.0f}) px off them, medians): the LiDAR–camera "
                     "calibration looks off; refine it (edge-depth calibrate lidar --refine, "
                     "as the calibration watch's line says)")
    return "\n".join(lines) or None


def noise_line(timings: list[dict]) -> str | None:
    """The closing line about the LiDAR map's range noise, where frames measured it above
    NOISE_THRESHOLD_PX: smoothed (`denoise_lidar`), or only said (the map's own noise then
    sets which jumps between row neighbours the alignment reads as depth edges)."""
    levels = replaced_shares(timings, "lidar_noise_px")
    noisy = [v for v in levels if v > NOISE_THRESHOLD_PX]
    if not noisy:
        return None
    median = float(np.median(noisy))
    if smoothed := int(sum(replaced_shares(timings, "lidar_smoothed"))):
        return (f"LiDAR noise: smoothed along the rows in {smoothed} of {len(levels)} frames "
                f"(noise median {median:.2f} px, smoothed above {NOISE_THRESHOLD_PX} px)")
    return (f"LiDAR noise: {len(noisy)} of {len(levels)} frames' maps above "
            f"{NOISE_THRESHOLD_PX} px of range noise (median {median:.2f} px; the real "
            f"pairs' maps read 0.1-0.15): their depth edges are read from jumps above "
            f"{jump_px(median):.1f} px only. Check the LiDAR's range noise and its "
            "timing; [engine] denoise_lidar = true smooths such a map (docs/results.md: where "
            "that helps)")


def summarise(timings: list[dict]) -> dict[str, dict[str, float]]:
    """Median and p95 ms per stage, over the frames that ran it (the two selections run on
    different frames)."""
    keys = list(dict.fromkeys(k for t in timings for k in t if k not in NOT_LATENCY))
    out = {}
    for k in keys:
        values = [t[k] for t in timings if k in t]
        out[k] = dict(median=float(np.median(values)), p95=float(np.percentile(values, 95)))
    return out


def format_latency(summary: dict[str, dict[str, float]]) -> str:
    """'encoder 9.1/10.2, steps ...': median / p95 ms of each stage of a `summarise`."""
    return ", ".join(f"{k} {v['median']:.1f}/{v['p95']:.1f}" for k, v in summary.items()
                     if k != "step_mean")


def watch_summary(pipeline, recording: str | None = None,
                  calibration: str | None = None) -> str | None:
    """The closing line about the calibration watch (None when it did not run), with the
    command that fixes it when the level is not OK."""
    watch = pipeline.watch
    if watch is None:
        return None
    estimate = watch.estimate()
    line = f"LiDAR-camera calibration watch: {estimate.describe()}"
    if samples := pipeline.stats.watch_ms:
        line += (f" ({len(samples)} samples, median {np.median(samples):.0f} ms each, between "
                 "frames)")
    offset = 0 if pipeline.lidar is None else pipeline.lidar.time_offset_ns
    if todo := fixes(estimate, recording, calibration, offset):
        line += f"; {todo}"
    return line


def lidar_summary(pipeline) -> str:
    """The closing line about the LiDAR: how many frames had it, or why none did. Counted
    over the frames that were paired with scans (pipelined, some of those are dropped before
    the engine: the frames processed are fewer)."""
    counters, stats = pipeline.sync.counters(), pipeline.stats
    paired = counters["frames_with_lidar"]
    frames = paired + counters["frames_without_lidar"]
    ahead = pipeline.ahead_frames  # the camera's rate: gone on before their scans, not paired
    if pipeline.lidar is None:
        return "no LiDAR extrinsics: stereo only (add a [lidar] section to the calibration)"
    if stats.scans == 0:
        return f"frames with LiDAR: 0 of {frames} (no scan arrived: stereo only)"
    line = f"frames with LiDAR: {paired} of {frames}"
    dropped = frames + ahead - stats.frames  # pipelined: frames paired, then dropped
    if ahead:
        line += (f"{' paired' if dropped > 0 else ''}, and {ahead} more gone on at the "
                 f"camera's rate before their scans (" +
                 (f"{dropped} of the {frames + ahead} dropped before the engine)"
                  if dropped > 0 else "not paired)"))
    elif dropped > 0:
        line += f" paired ({dropped} of them dropped before the engine)"
    if paired < frames and pipeline.sync.median_gap_ms() is not None:
        line += (f" (unpaired frames: median nearest-scan minus frame stamp "
                 f"{pipeline.sync.median_gap_ms():+.0f} ms)")
    if counters["frames_gone_before_their_scans"]:
        line += f"; {counters['frames_gone_before_their_scans']} went on before their scans arrived"
    if stats.deskewed:
        line += (f"; deskewed by the camera's turn in {len(stats.deskewed)} frames (points "
                 f"moved up to a median {np.median(stats.deskewed):.1f} px)")
    return line
