"""What an aarch64 install computes and says against x86-64's, for `.ci/arm_check.sh`.

`prepare` writes the bad inputs both CPUs get: the sim recording cut off at 60 % of its bytes
and its calibration with the left camera's fx = -5 px. `compare X86 ARM` reads two folders
the check filled with the same runs and fails, naming each, where they differ:

- the engine's graphs on one sim scene (`ort_on_avx2.py run`: per runtime and precision, the
  network's disparity without the stages after it): fp32 within FP32_MAX_PX everywhere, int8
  within INT8_MEAN_PX on average (int8 kernels with and without dot products may round a
  product differently; the x86 and emulated-AVX2 runs differed by 0.012 px on average);
- the whole pipeline's `replay` of a sim recording, per precision: the mean |Δ| within the
  same limits and `edge-depth compare`'s share rule (`compare_replays` says why not the max);
- the bad inputs: the same exit status and the same lines on stderr (log time stamps, INFO
  lines and the emulator's EMULATOR_LINES aside: INFO lines name the precision, which
  differs by CPU);
- `calibrate check` of an 8-frame recording: the same exit status and verdict (`check` runs
  it on x86 with ONNX Runtime, as ARM runs it);
- with `--precision`, the precision `auto` chose in the ARM demo's first line.

    python experiments/arm_compare.py prepare out/arm-check/inputs/sim8.mcap out/arm-check/inputs
    python experiments/arm_compare.py compare out/arm-check/x86 out/arm-check/cortex-a76 \
        --precision int8
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import numpy as np
from ort_on_avx2 import compare as print_graph_table  # this folder's script: same comparison

FP32_MAX_PX = 1e-3  # fp32: the same arithmetic up to the order of float sums
INT8_MEAN_PX = 0.05  # int8: mean |Δ| px
# two replays' agreement as `edge-depth compare` judges it without ground truth (its defaults)
REPLAY_TOLERANCE_PX, REPLAY_MAX_SHARE = 0.25, 0.01
BAD_INPUTS = ("replay-damaged", "check-damaged", "check-bad-calib", "replay-bad-calib")
REPLAYS = ("fp32", "int8")
LOG_STAMP = re.compile(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d+ ")
# what ONNX Runtime's CPU library says under QEMU's user mode, where it finds neither an ARM
# /proc/cpuinfo nor /sys (.ci/arm_check.sh): the emulator's, not a board's
EMULATOR_LINES = re.compile(r"^(Error in cpuinfo: |onnxruntime (cpuid_info )?warning: "
                            r"(Failed to initialize PyTorch cpuinfo|Unknown CPU vendor|"
                            r"cpuinfo_initialize failed))")


def prepare(recording: Path, out: Path) -> None:
    """damaged.mcap (`recording` cut at 60 % of its bytes) and bad_calib.toml (its calibration,
    the left camera's fx = -5) in `out`."""
    from edge_depth.calibration.io import dumps_calibration, loads_calibration
    from edge_depth.capture.replay import McapSource

    data = recording.read_bytes()
    (out / "damaged.mcap").write_bytes(data[:len(data) * 6 // 10])
    stereo, lidar = loads_calibration(McapSource(recording).scan_calibration().toml)
    text = dumps_calibration(stereo, lidar)
    fx = f"K = [[{float(stereo.K_left[0, 0])!r},"
    assert fx in text, f"{fx} not in the calibration's text"
    (out / "bad_calib.toml").write_text(text.replace(fx, "K = [[-5.0,", 1))


def check_on_onnxruntime(recording: str) -> int:
    """`edge-depth calibrate check RECORDING` with OpenVINO hidden, so that its engine runs on
    ONNX Runtime as on ARM (the command has no --runtime; `auto` takes OpenVINO on x86-64)."""
    sys.modules["openvino"] = None  # type: ignore[assignment]  # import openvino: ImportError
    from edge_depth.cli import main as edge_depth

    return edge_depth(["calibrate", "check", recording])


def compare_check(x86: Path, arm: Path) -> list[str]:
    """calibrate check's exit status and verdict (its last line's last word) on both CPUs; its
    numbers move with int8's rounding, so they are shown, not compared."""
    failures = []
    lines = {}
    for name, folder in (("x86", x86), ("ARM", arm)):
        status = (folder / "check.rc").read_text().strip()
        last = [line for line in (folder / "check.out").read_text().splitlines()
                if line and not EMULATOR_LINES.match(line)][-1]
        lines[name] = (status, last.rsplit(" ", 1)[-1], last)
        print(f"calibrate check on {name}: exit {status}, {last}")
    if lines["x86"][:2] != lines["ARM"][:2]:
        failures.append(f"calibrate check: exit {lines['x86'][0]} {lines['x86'][1]} on x86, "
                        f"exit {lines['ARM'][0]} {lines['ARM'][1]} on ARM")
    return failures


def _verdict(key: str, max_px: float, mean_px: float) -> str | None:
    """Why the graphs' `key` (RUNTIME/PRECISION) differ beyond its limit, or None."""
    if key.endswith("fp32") and max_px > FP32_MAX_PX:
        return f"{key}: max |Δ| {max_px:.3g} px > {FP32_MAX_PX:g}"
    if key.endswith("int8") and mean_px > INT8_MEAN_PX:
        return f"{key}: mean |Δ| {mean_px:.3g} px > {INT8_MEAN_PX:g}"
    return None


def compare_graphs(x86: Path, arm: Path) -> tuple[list[str], list[str]]:
    """(table rows, failures) of graphs.npz (and graphs-openvino.npz where x86 has one), per
    runtime/precision both ran."""
    a, b = {}, {}
    for name in ("graphs.npz", "graphs-openvino.npz"):
        if (x86 / name).exists():
            a.update(np.load(x86 / name))
            b.update(np.load(arm / name) if (arm / name).exists() else {})
    rows, failures = [], []
    for key in sorted(a):
        if key not in b:
            failures.append(f"graphs {key}: not run on ARM")
            continue
        diff = np.abs(a[key] - b[key])
        rows.append(f"| graphs {key} | {diff.max():.3g} | {diff.mean():.3g} | "
                    f"{int((diff > FP32_MAX_PX).sum())} | – |")
        failures += [f"graphs {v}" for v in [_verdict(key, diff.max(), diff.mean())] if v]
    return rows, failures


def compare_replays(x86: Path, arm: Path) -> tuple[list[str], list[str]]:
    """(table rows, failures) of replay-PRECISION.mcap, frames paired by stamp: the mean |Δ|
    over the pixels both call valid within the precision's limit, and `edge-depth compare`'s
    rule for two replays without a judge of which is right: at most REPLAY_MAX_SHARE of the
    pixels beyond REPLAY_TOLERANCE_PX or valid on one CPU only. The stages after the network
    make discrete choices (a 1/16 px step of the block matcher, a cell's LiDAR-or-network
    pick), so a difference below the rounding can move a few pixels by a step: counted and
    shown, not failed on."""
    from edge_depth.compare import frame_difference, read_replay_output

    rows, failures = [], []
    for precision in REPLAYS:
        name = f"replay-{precision}.mcap"
        a, b = read_replay_output(x86 / name), read_replay_output(arm / name)
        if set(a.disparity) != set(b.disparity):
            failures.append(f"replay {precision}: frames {sorted(a.disparity)} on x86, "
                            f"{sorted(b.disparity)} on ARM")
        common = sorted(set(a.disparity) & set(b.disparity))
        diffs = [frame_difference(a.disparity[s], b.disparity[s], REPLAY_TOLERANCE_PX)
                 for s in common]
        deltas = [np.nan_to_num(np.abs(a.disparity[s] - b.disparity[s])) for s in common]
        peak = max((float(d.max()) for d in deltas), default=0.0)
        stepped = sum(int((d > FP32_MAX_PX).sum()) for d in deltas)
        mean = float(np.mean([d["mean_abs_px"] for d in diffs])) if diffs else 0.0
        share = sum(d["beyond"] for d in diffs) / max(1, sum(d["pixels"] for d in diffs))
        rows.append(f"| replay {precision}, {len(common)} frames | {peak:.3g} | {mean:.3g} | "
                    f"{stepped} | {100 * share:.3f} % |")
        limit = FP32_MAX_PX if precision == "fp32" else INT8_MEAN_PX
        if mean > limit:
            failures.append(f"replay {precision}: mean |Δ| {mean:.3g} px > {limit:g}")
        if share > REPLAY_MAX_SHARE:
            failures.append(f"replay {precision}: {100 * share:.2f} % of pixels beyond "
                            f"{REPLAY_TOLERANCE_PX} px or valid on one CPU only")
    return rows, failures


def said(folder: Path, case: str) -> tuple[str, list[str]]:
    """A bad-input run's exit status and its stderr lines, log stamps and INFO lines aside."""
    status = (folder / f"{case}.rc").read_text().strip()
    lines = [LOG_STAMP.sub("", line) for line in
             (folder / f"{case}.err").read_text().splitlines()]
    return status, [line for line in lines if line and not line.startswith("INFO ")
                    and not EMULATOR_LINES.match(line)]


def compare_errors(x86: Path, arm: Path) -> list[str]:
    failures = []
    for case in BAD_INPUTS:
        (rc_x86, err_x86), (rc_arm, err_arm) = said(x86, case), said(arm, case)
        if not err_x86:
            failures.append(f"{case}: nothing said on x86 (exit {rc_x86})")
        if (rc_x86, err_x86) != (rc_arm, err_arm):
            failures.append(f"{case}: exit {rc_x86} {err_x86} on x86, "
                            f"exit {rc_arm} {err_arm} on ARM")
        else:
            print(f"{case}: exit {rc_arm}, {err_arm[-1] if err_arm else ''}")
    return failures


def chosen_precision(arm: Path) -> str:
    """The precision the ARM demo's first line names ('…, int8 on onnxruntime, …')."""
    first = next(line for line in (arm / "demo.out").read_text().splitlines()
                 if not EMULATOR_LINES.match(line))
    found = re.search(r"(\w+) on (onnxruntime|openvino)", first)
    return found.group(1) if found else f"none in {first!r}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare")
    p.add_argument("recording", type=Path)
    p.add_argument("out", type=Path)
    k = sub.add_parser("check", help="calibrate check on ONNX Runtime (x86's reference)")
    k.add_argument("recording")
    c = sub.add_parser("compare")
    c.add_argument("x86", type=Path)
    c.add_argument("arm", type=Path)
    c.add_argument("--precision", help="what `auto` must have chosen in the ARM demo")
    args = parser.parse_args(argv)
    if args.command == "prepare":
        prepare(args.recording, args.out)
        return 0
    if args.command == "check":
        return check_on_onnxruntime(args.recording)
    print_graph_table(str(args.x86 / "graphs.npz"), str(args.arm / "graphs.npz"))
    graph_rows, failures = compare_graphs(args.x86, args.arm)
    replay_rows, replay_failures = compare_replays(args.x86, args.arm)
    print(f"\n{args.arm.name} against x86-64\n| what | max |Δ| px | mean |Δ| px | "
          f"pixels > {FP32_MAX_PX:g} px | beyond {REPLAY_TOLERANCE_PX} px or valid on one only |"
          "\n|---|---|---|---|---|")
    print("\n".join(graph_rows + replay_rows))
    failures += replay_failures + compare_check(args.x86, args.arm)
    failures += compare_errors(args.x86, args.arm)
    if args.precision and chosen_precision(args.arm) != args.precision:
        failures.append(f"precision auto: {chosen_precision(args.arm)}, not {args.precision}")
    for failure in failures:
        print(f"arm-check {args.arm.name}: DIFFERS: {failure}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
