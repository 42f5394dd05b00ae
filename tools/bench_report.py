"""`tools/bench.py`'s report: the stage table, the ratios and the machine it ran on, in
Markdown; the host line every benchmark starts with (ratios are only comparable per ISA)."""

from __future__ import annotations

import os

import numpy as np

BUSY_SHARE = 0.10  # other processes' share of the CPU above which a run is flagged busy
# SGBM's p90 / p10 above which its times are flagged: steady it spreads 1.03–1.09; with a
# spinning thread of the bench's own process taking a core half the time, 1.5–1.8 (its
# calls bimodal, 14 or 25 ms; docs/speed.md, 2026-12-06 18:10)
SGBM_SPREAD = 1.3


def markdown(summary: dict) -> str:
    w, h = summary["size"]
    st = summary["stages"]
    lines = [f"| stage ({w}x{h}, {summary['threads']} threads, {summary['runtime']}"
             f"{', bf16 encoder' if summary.get('bf16_encoder') else ''}"
             f"{', int8 encoder' if summary.get('int8_encoder') else ''}) | median ms | p95 ms |",
             "|---|---|---|"]
    names = ["rectify", "project_filter", "encoder", "step", "upsample", "log", "frame", "sgbm",
             "band_refine", "edge_median"]
    names += sorted(k for k in st if k.startswith("engine_"))
    for name in names:
        if name in st:
            lines.append(f"| {name} | {st[name]['median_ms']:.1f} | {st[name]['p95_ms']:.1f} |")
    if "ratios" in summary:
        lines += ratio_lines(summary["ratios"])
    if "outside_engine" in summary:
        o = summary["outside_engine"]
        lines.append(f"the daemon's frame outside the engine (rectify, projection, logging; the "
                     f"same {o['frames']} frames): {o['ms']:.1f} ms, {o['share_pct']:.1f} %")
    if "calibration_watch" in summary:
        c = summary["calibration_watch"]
        lines.append(f"calibration watch: {c['sample_ms']:.1f} ms a sample, one in {c['every']} "
                     f"frames with LiDAR: {c['per_frame_ms']:.2f} ms a frame, "
                     f"{c['share_of_frame_pct']:.1f} % of the daemon's frame")
    if "replay_peak_rss_mb" in summary:
        lines.append(f"peak RSS of `edge-depth replay`: {summary['replay_peak_rss_mb']:.0f} MB")
    if "engine" in summary:
        lines.append(f"engine: {summary['engine']}")
    lines.append(f"(project_filter: 64-beam scans, {summary['points_64_beams']} points; "
                 f"{summary['scenes']} test scenes)")
    lines.append(machine_line(summary["machine"]))
    if "runs" in summary:
        lines += runs_lines(summary)
    return "\n".join(lines)


def ratio_lines(r: dict) -> list[str]:
    """The engine's ratios against SGBM (plain, paired frame by frame, the matching's)."""
    lines = ["", f"int8 engine / SGBM: **{r['int8_vs_sgbm']:.2f}x** (fp32 "
                 f"{r['fp32_vs_sgbm']:.2f}x; int8 speed-up x{r['int8_speedup']:.2f}); "
                 f"daemon frame / engine: {r['frame_vs_engine']:.2f}x"]
    if "int8_vs_sgbm_paired" in r:
        lo, hi = r["int8_vs_sgbm_paired_p10_p90"]
        lines.append(f"paired, frame by frame (engine and SGBM back to back): median "
                     f"{r['int8_vs_sgbm_paired']:.2f}x (p10-p90 {lo:.2f}-{hi:.2f}x)")
    if "band_refine_vs_sgbm" in r:
        lines.append(f"the engine's band_refine stage / SGBM: {r['band_refine_vs_sgbm']:.2f}x "
                     "(inside the engine rows)")
    return lines


def runs_lines(summary: dict) -> list[str]:
    """A --runs summary: the ratio per run and its median, paired and the matching's too, and
    which runs a busy machine spoiled."""
    runs = summary["runs"]
    ratios = [r["int8_vs_sgbm"] for r in runs]
    lines = ["", f"{len(ratios)} runs: int8 engine / SGBM per run "
                 f"{', '.join(f'{r:.2f}x' for r in ratios)}; median "
                 f"**{summary['ratio_median']:.2f}x** (range {min(ratios):.2f}-"
                 f"{max(ratios):.2f}x)"]
    for key, label in (("int8_vs_sgbm_paired", "paired"),
                       ("band_refine_vs_sgbm", "the engine's band_refine stage / SGBM")):
        values = [r[key] for r in runs if key in r]
        if values:
            lines.append(f"{label} per run {', '.join(f'{v:.2f}x' for v in values)}; median "
                         f"{float(np.median(values)):.2f}x")
    busy = [i + 1 for i, r in enumerate(runs) if r["busy"]]
    if busy:
        lines.append(f"**busy machine in run(s) {busy}: other processes took over "
                     f"{BUSY_SHARE:.0%} of the CPU; do not trust this ratio, rerun on a "
                     "quiet machine**")
    return lines


def host_line(cpu: dict) -> str:
    """'host: AMD EPYC 7B13; ISA AVX2, AVX-512, AVX512-VNNI; int8 dot product: yes': the
    benchmark's first line."""
    dot = {True: "yes", False: "no", None: "unknown"}[cpu["int8_dot_product"]]
    line = (f"host: {cpu['model']}; ISA {', '.join(cpu['isa']) or 'unknown'}; int8 dot "
            f"product: {dot}; {os.cpu_count()} cores")
    # another CPU's instruction sets emulated here: its kernels' share, not that CPU's times
    limits = [f"{name} {os.environ[var]}" for var, name in KERNEL_LIMITS if os.environ.get(var)]
    if limits:
        line += f"; kernels limited: {', '.join(limits)}"
    return line


# the environment variables that keep a library's kernels off instruction sets this CPU has
# (`experiments/avx2_kernels.sh` sets them all: an AVX2-only CPU's kernels, docs/speed.md)
KERNEL_LIMITS = (("ONEDNN_MAX_CPU_ISA", "OpenVINO/oneDNN up to"),
                 ("OPENCV_CPU_DISABLE", "OpenCV without"),
                 ("NPY_DISABLE_CPU_FEATURES", "NumPy without"),
                 ("OPENBLAS_CORETYPE", "OpenBLAS as"))


def machine_line(m: dict) -> str:
    others = "n/a" if m["others_cpu_share"] is None else f"{m['others_cpu_share']:.0%}"
    load = "n/a" if m["load_avg_1min"] is None else f"{m['load_avg_1min']:.2f}"
    flag = " — BUSY" if m["busy"] else ""
    if m["sgbm_p90_over_p10"] > SGBM_SPREAD:
        flag += (" — SGBM UNSTEADY: something in or beside this process took a core from it "
                 "part of the time; do not trust the ratio")
    line = (f"machine: other processes {others} of the CPU during the run, load average "
            f"{load} before it, SGBM p90/p10 {m['sgbm_p90_over_p10']:.2f}{flag}")
    if "cpu" in m:  # ratios from CPUs with and without int8 dot products differ ~2x
        dot = {True: "yes", False: "no", None: "unknown"}[m["cpu"]["int8_dot_product"]]
        isa = ", ".join(m["cpu"].get("isa") or []) or "unknown"
        line += f"; CPU {m['cpu']['model']} ({isa}), int8 dot product (VNNI/AMX): {dot}"
    return line
