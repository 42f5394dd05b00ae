"""`edge-depth compare BASE.mcap NEW.mcap`: two replay outputs of one recording, side by side.

For robot teams' CI: keep a golden replay of a recording, replay it again with another bundle,
version or setting, and compare. Frames are paired by stamp. Per frame and overall: the mean
|Δ disparity| over pixels both call valid, the share of pixels beyond `tolerance_px` (a pixel
valid in one output and not the other counts as beyond), and — where the recordings carry
ground truth (/sim/gt_disparity) — EPE and bad-3 of each; the latency of each from its
/diagnostics windows. The verdict (exit 1 on a regression):

- NEW lost frames that BASE has: regression;
- with ground truth: NEW's EPE is more than `tolerance_px` / 10 worse than BASE's, or its bad-3
  more than `max_share` worse (a change that makes things better passes);
- without: the share of pixels beyond the tolerance exceeds `max_share` (nothing says which
  output is right, so a change beyond the limits is one).

Both profiles' outputs are read (foxglove RawImage and ROS 2 DisparityImage / Image).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from edge_depth.capture.decode import decode_image, decode_message, header_stamp, message_decoders
from edge_depth.errors import EdgeError
from edge_depth.topics import ROS2_TOPICS, TOPICS

BAD_PX = 3.0


class CompareError(EdgeError):
    pass


@dataclass
class ReplayOutput:
    """What `compare` needs of one replay output: disparity and GT per stamp, latencies."""

    path: Path
    disparity: dict[int, np.ndarray] = field(default_factory=dict)
    gt: dict[int, np.ndarray] = field(default_factory=dict)
    engine_ms: list[float] = field(default_factory=list)  # per-window medians
    frame_ms: list[float] = field(default_factory=list)
    skipped: int = 0  # messages that did not decode


def _role(topic: str) -> str | None:
    for role in ("disparity", "gt_disparity", "diagnostics"):
        if topic == TOPICS[role] or topic.endswith("/" + ROS2_TOPICS[role].lstrip("/")):
            return role
    return None


def _latencies(values: dict, out: ReplayOutput) -> None:
    latency = values.get("latency_ms") or {}
    if isinstance(latency, str):  # ros2 profile: each value is JSON text
        latency = json.loads(latency)
    for key, dest in (("engine", out.engine_ms), ("frame", out.frame_ms)):
        stat = latency.get(key)
        if isinstance(stat, dict) and "median" in stat:
            dest.append(float(stat["median"]))


def read_replay_output(path: Path | str) -> ReplayOutput:
    """Disparity (and GT) images by stamp and the latency windows of one replay output."""
    from edge_depth.capture.mcap_tolerant import ReadReport, iter_messages

    out = ReplayOutput(Path(path))
    if not out.path.is_file():
        raise CompareError(f"{path}: no such file")
    factories = message_decoders()
    decoders: dict = {}
    try:
        for schema, channel, message in iter_messages(out.path, ReadReport()):
            role = _role(channel.topic)
            if role is None:
                continue
            try:
                msg = decode_message(schema, channel, message, factories, decoders)
                if role == "diagnostics":
                    if isinstance(msg, dict):
                        _latencies(msg, out)
                    else:  # DiagnosticArray
                        for status in msg.status:
                            _latencies({v.key: v.value for v in status.values}, out)
                    continue
                image_msg = getattr(msg, "image", msg)  # DisparityImage wraps an Image
                stamp = header_stamp(image_msg, int(message.log_time))
                if hasattr(image_msg, "timestamp"):  # foxglove RawImage
                    ts = image_msg.timestamp
                    stamp = int(ts.seconds) * 1_000_000_000 + int(ts.nanos)
                image = decode_image(image_msg).astype(np.float32)
                (out.disparity if role == "disparity" else out.gt)[stamp] = image
            except Exception:  # noqa: BLE001 - counted and reported, never fatal
                out.skipped += 1
    except ValueError as exc:
        raise CompareError(f"{path}: not a readable MCAP file ({exc})") from None
    if not out.disparity:
        raise CompareError(f"{path}: no disparity messages ({TOPICS['disparity']} or "
                           f".../{ROS2_TOPICS['disparity']}): is it a replay output?")
    return out


def _valid(d: np.ndarray) -> np.ndarray:
    return np.isfinite(d) & (d > 0)


def frame_difference(base: np.ndarray, new: np.ndarray, tolerance_px: float) -> dict:
    if base.shape != new.shape:
        raise CompareError(f"disparity sizes differ: {base.shape[::-1]} vs {new.shape[::-1]}")
    vb, vn = _valid(base), _valid(new)
    both = vb & vn
    delta = np.abs(base - new)[both]
    beyond = int((delta > tolerance_px).sum()) + int((vb ^ vn).sum())
    return dict(mean_abs_px=float(delta.mean()) if delta.size else 0.0,
                beyond=beyond, pixels=int(base.size))


def accuracy(pred: np.ndarray, gt: np.ndarray) -> tuple[float, float, int]:
    """(sum of |error|, count beyond BAD_PX, pixels) over GT-valid pixels; a hole is an error
    of the whole GT value."""
    mask = _valid(gt)
    err = np.abs(np.where(_valid(pred), pred, 0.0) - gt)[mask]
    return float(err.sum()), int((err > BAD_PX).sum()), int(mask.sum())


def compare(base_path, new_path, tolerance_px: float = 0.25, max_share: float = 0.01) -> dict:
    base, new = read_replay_output(base_path), read_replay_output(new_path)
    common = sorted(set(base.disparity) & set(new.disparity))
    if not common:
        raise CompareError(f"{base_path} and {new_path} share no frame stamps: are they "
                           "replays of the same recording?")
    frames, beyond, pixels = [], 0, 0
    acc: dict[str, list[float]] = {"base": [0.0, 0.0, 0.0], "new": [0.0, 0.0, 0.0]}
    for stamp in common:
        diff = frame_difference(base.disparity[stamp], new.disparity[stamp], tolerance_px)
        row = dict(stamp_ns=stamp, mean_abs_px=diff["mean_abs_px"],
                   beyond_share=diff["beyond"] / diff["pixels"])
        beyond += diff["beyond"]
        pixels += diff["pixels"]
        gt = base.gt.get(stamp, new.gt.get(stamp))
        if gt is not None:
            for name, out in (("base", base), ("new", new)):
                total, bad, n = accuracy(out.disparity[stamp], gt)
                acc[name] = [a + b for a, b in zip(acc[name], (total, bad, n), strict=True)]
                if n:
                    row[f"{name}_epe"] = total / n
        frames.append(row)
    result = dict(base=str(base_path), new=str(new_path), tolerance_px=tolerance_px,
                  max_share=max_share, frames_compared=len(common),
                  frames_only_in_base=len(set(base.disparity) - set(new.disparity)),
                  frames_only_in_new=len(set(new.disparity) - set(base.disparity)),
                  mean_abs_px=float(np.mean([f["mean_abs_px"] for f in frames])),
                  beyond_share=beyond / pixels, skipped_messages=base.skipped + new.skipped,
                  per_frame=frames)
    for name, out in (("base", base), ("new", new)):
        result[f"{name}_latency_ms"] = dict(
            engine=float(np.median(out.engine_ms)) if out.engine_ms else None,
            frame=float(np.median(out.frame_ms)) if out.frame_ms else None)
    if acc["base"][2]:
        for name in ("base", "new"):
            total, bad, count = acc[name]
            result[f"{name}_accuracy"] = dict(epe=total / count, bad3=100.0 * bad / count)
    result["regressions"] = regressions(result)
    return result


def regressions(r: dict) -> list[str]:
    """Why NEW fails against BASE (empty: it passes); the rules are the module's."""
    found = []
    if r["frames_only_in_base"]:
        found.append(f"NEW lacks {r['frames_only_in_base']} of BASE's frames")
    if "base_accuracy" in r:
        b, n = r["base_accuracy"], r["new_accuracy"]
        if n["epe"] > b["epe"] + r["tolerance_px"] / 10:
            found.append(f"EPE {b['epe']:.3f} -> {n['epe']:.3f} px (limit +"
                         f"{r['tolerance_px'] / 10:.3f})")
        if n["bad3"] > b["bad3"] + 100 * r["max_share"]:
            found.append(f"bad-3 {b['bad3']:.2f} -> {n['bad3']:.2f} % (limit +"
                         f"{100 * r['max_share']:.2f})")
    elif r["beyond_share"] > r["max_share"]:
        found.append(f"{100 * r['beyond_share']:.2f} % of pixels differ by more than "
                     f"{r['tolerance_px']} px (limit {100 * r['max_share']:.2f} %; no ground "
                     "truth to say which is right)")
    return found


def format_report(r: dict) -> str:
    def ms(v):
        return "n/a" if v is None else f"{v:.1f}"

    lines = [f"compared {r['frames_compared']} frames ({r['frames_only_in_base']} only in BASE,"
             f" {r['frames_only_in_new']} only in NEW, {r['skipped_messages']} messages "
             "skipped)",
             f"mean |Δ| {r['mean_abs_px']:.3f} px; {100 * r['beyond_share']:.3f} % of pixels "
             f"beyond {r['tolerance_px']} px",
             f"latency median ms, engine / frame: BASE {ms(r['base_latency_ms']['engine'])} / "
             f"{ms(r['base_latency_ms']['frame'])}, NEW {ms(r['new_latency_ms']['engine'])} / "
             f"{ms(r['new_latency_ms']['frame'])}"]
    if "base_accuracy" in r:
        b, n = r["base_accuracy"], r["new_accuracy"]
        lines.append(f"against ground truth: BASE EPE {b['epe']:.3f} px, bad-3 {b['bad3']:.2f} %"
                     f"; NEW EPE {n['epe']:.3f} px, bad-3 {n['bad3']:.2f} %")
    worst = sorted(r["per_frame"], key=lambda f: -f["beyond_share"])[:3]
    lines.append("most changed frames: " + ", ".join(
        f"{f['stamp_ns']} ({100 * f['beyond_share']:.2f} %)" for f in worst))
    lines.append("REGRESSION: " + "; ".join(r["regressions"]) if r["regressions"]
                 else "OK: within the limits")
    return "\n".join(lines)


def compare_command(base, new, tolerance_px: float, max_share: float, json_out=None) -> int:
    result = compare(base, new, tolerance_px, max_share)
    print(format_report(result))
    if json_out:
        Path(json_out).write_text(json.dumps(result, indent=2))
    return 1 if result["regressions"] else 0
