"""Adapt the model to a robot's own recordings: self-supervised fine-tuning, an int8 bundle at
the recordings' camera size, and a report that says whether it got better.

    edge-depth adapt REC.mcap [REC2.mcap ...] --out BUNDLE_DIR [--minutes M | --steps N]
        [--topics topics.toml] [--calib calib.toml] [--from BUNDLE_OR_CKPT] [--work DIR]
        [--resume] [--force]

1. The recordings' synced frames (LiDAR projected into both views; `replay`'s calibration
   order: --calib, the recording's own) are split by time: the last --check-share of each
   recording are the check frames, never trained on.
2. Fine-tuning from --from (default: the shipped checkpoint) with the paper's self-supervised
   losses (Sparse-half2: half the LiDAR points in, the other half supervise), bounded by
   --steps and/or --minutes, checkpointed in --work (--resume continues).
3. Export at the recordings' camera size (rounded up to the network's multiple of 8; the
   engine pads) and int8 quantization calibrated on the adapt frames.
4. The old bundle and the new one on the check frames, by measures that need no ground truth
   (`edge.selfcheck`: photometric error on visible pixels, error against held-out LiDAR
   points, left-right inconsistency) and EPE / bad-3 where the recording carries ground truth
   (/sim/gt_disparity). Report: --work/report.md, report.json, report.png (check frames,
   before | after).
5. The new bundle goes to --out only if it is better on the check frames — lower photometric
   error and lower held-out LiDAR error than the old bundle, and than its weights run at the
   camera's size where those ran; a measure that is NaN or missing never passes (without
   LiDAR on the check frames, --photometric-only decides on the photometric error alone) —
   unless --force. Exit status 0 when
   it was written, 3 when the old one is kept, 2 for bad arguments or recordings.

Python: `adapt(["rec.mcap"], "bundles/robot", minutes=20)` returns an `AdaptResult`.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from edge_depth.calibration.atomic import atomic_write
from edge_depth.runtime.engine import DEFAULT_BUNDLE, Engine
from edge_depth.tools.adapt_check import check, decide, format_report, picture
from edge_depth.tools.adapt_frames import Frame, load_frames, split_by_time

log = logging.getLogger(__name__)
DEFAULT_CHECKPOINT = Path(DEFAULT_BUNDLE).parent / "sparse_stereo.pt"
BUNDLE_CHECKPOINT = "checkpoint.pt"  # an adapted bundle carries its weights: adapt it again
MAX_SKIPPED_IN_A_ROW = 20
TERM_NAMES = {"lr": "left_right"}  # the loss terms' short names, as the bar shows them


@dataclass
class FineTune:
    """How the fine-tuning runs; steps and/or minutes bound it (at least one)."""

    steps: int | None = None
    minutes: float | None = None
    lr: float = 5e-5
    batch: int = 4
    crop: tuple[int, int] = (320, 192)
    iters: int = 4
    split: str = "half2"
    ckpt_every: int = 50
    seed: int = 0
    supervised: bool = False  # the comparison the paper makes: GT instead of the self losses
    device: str = "auto"  # where it trains: auto (the GPU when torch sees one), cpu, cuda[:N]

    def __post_init__(self) -> None:
        if self.steps is None and self.minutes is None:
            raise ValueError("fine-tuning needs --steps or --minutes")
        if self.steps is not None and self.steps < 1:
            raise ValueError(f"steps must be >= 1, got {self.steps}")
        if self.minutes is not None and not self.minutes > 0:
            raise ValueError(f"minutes must be > 0, got {self.minutes}")

    def progress(self, step: int, seconds: float) -> float:
        """0 → 1 along whichever bound comes first."""
        parts = []
        if self.steps is not None:
            parts.append(step / self.steps)
        if self.minutes is not None:
            parts.append(seconds / (60 * self.minutes))
        return min(1.0, max(parts))


def adapt_and_check_frames(recordings: list[Path | str], calib: Path | None, topics: dict | None,
                           max_frames: int, check_share: float, test_time: bool
                           ) -> tuple[list[Frame], list[Frame]]:
    """The recordings' frames (at most `max_frames` in all), split by time into the frames
    adapted on and the later ones checked on (the same frames with `test_time`); one camera
    size, or a clear error."""
    per_recording = [load_frames(r, calib, topics, max_frames // len(recordings))
                     for r in recordings]
    if test_time:
        adapt_frames = check_frames = [f for frames in per_recording for f in frames]
        if not adapt_frames:
            raise ValueError("no frames to adapt on")
    else:
        adapt_frames, check_frames = split_by_time(per_recording, check_share)
    sizes = sorted({f.left.shape[::-1] for f in adapt_frames + check_frames})
    if len(sizes) > 1:
        raise ValueError(f"the recordings hold more than one camera size {sizes}: adapt one "
                         "camera at a time")
    print(f"{len(adapt_frames)} adapt frames, {len(check_frames)} check frames"
          + (" (test-time: the same frames)" if test_time else ""))
    return adapt_frames, check_frames


def unadapted_engine(before: Engine, old_bundle: Path, init: Path, start: Path | None,
                     work: Path, adapt_frames: list[Frame], node_search: bool) -> Engine:
    """The starting weights at the camera's size: what adaptation gained apart from the
    resolution the old bundle ran at. A bundle with any-size graphs holding those weights
    runs there itself; others are exported at that size."""
    if before.any_size and (start is None or Path(start).is_dir()):
        return Engine(old_bundle, precision="int8", scale="native")
    start_bundle = work / "start_bundle"
    build_bundle(init, start_bundle, bundle_size(adapt_frames), adapt_frames,
                 node_search=node_search)
    return Engine(start_bundle, precision="int8")


def install(candidate: Path, out: Path, files: list[Path]) -> None:
    """The candidate bundle (with the report's `files`) becomes `out`: copied beside it
    first, the old one kept as `out.previous`, then renamed into place."""
    for f in files:
        shutil.copy(f, candidate / f.name)
    staging = out.with_name(out.name + ".new")
    if staging.exists():
        shutil.rmtree(staging)
    shutil.copytree(candidate, staging)
    if out.exists():
        previous = out.with_name(out.name + ".previous")
        if previous.exists():
            shutil.rmtree(previous)
        out.rename(previous)
    staging.rename(out)


@dataclass
class _Adapting:
    """A fine-tuning run's network and optimiser and how far it has got."""

    init: Path
    net: Any
    opt: Any
    ckpt: dict
    plan: FineTune
    frames: int
    crop: tuple[int, int]
    device: Any
    step: int = 0
    seconds: float = 0.0
    skipped: int = 0

    def summary(self) -> dict:
        plan = self.plan
        return dict(init=str(self.init), steps=self.step, minutes=round(self.seconds / 60, 2),
                    frames=self.frames, lr=plan.lr, batch=plan.batch, crop=list(self.crop),
                    iters=plan.iters, mode="supervised" if plan.supervised else "self",
                    split=plan.split, skipped_batches=self.skipped, device=str(self.device))

    def save(self, path: Path, optimizer: bool = True) -> None:
        """A checkpoint: resumable with `optimizer`; the one that ships with the bundle
        stays small."""
        import torch

        from edge_depth.model.device import on_cpu

        state = dict(model=on_cpu(self.net.state_dict()), step=self.step,
                     seconds=self.seconds, config=self.ckpt["config"],
                     training=dict(self.ckpt.get("training") or {}, adapted=self.summary()))
        if optimizer:
            state["optimizer"] = on_cpu(self.opt.state_dict())
        with atomic_write(path) as tmp:
            torch.save(state, tmp)


def finetune(init: Path, frames: list[Frame], work: Path, plan: FineTune,
             resume: bool = False) -> tuple[Path, dict]:
    """Self-supervised fine-tuning of `init` on `frames`; (checkpoint path, summary). The
    learning rate warms up over the first 5 % and falls linearly to 0 at the bound."""
    import torch

    from edge_depth.model.device import resolve_device
    from edge_depth.tools.export import load_checkpoint

    if not frames:
        raise ValueError("no adapt frames")
    device = resolve_device(plan.device)
    work.mkdir(parents=True, exist_ok=True)
    net, ckpt = load_checkpoint(init)
    net.to(device)
    h, w = frames[0].left.shape
    crop = (min(plan.crop[0], w // 8 * 8), min(plan.crop[1], h // 8 * 8))
    opt = torch.optim.AdamW(net.parameters(), lr=plan.lr, weight_decay=1e-5)
    run = _Adapting(init, net, opt, ckpt, plan, len(frames), crop, device)
    last = work / "last.pt"
    if resume and last.exists():
        run.step, run.seconds = _resume(last, net, opt)
    rng = np.random.default_rng([plan.seed, run.step])
    torch.manual_seed(plan.seed + run.step)
    net.train()
    by_time = plan.steps is None
    bar = _progress_bar(plan, run.step, run.seconds)
    started = time.time() - run.seconds
    skipped_in_a_row = 0
    while plan.progress(run.step, run.seconds) < 1.0:
        frac = plan.progress(run.step, run.seconds)
        loss, terms = _loss(net, _batch(frames, crop, rng, plan.batch, device), plan)
        run.seconds = time.time() - started
        if not math.isfinite(float(loss.detach())):
            run.skipped, skipped_in_a_row = run.skipped + 1, skipped_in_a_row + 1
            _say_skipped(run.step, run.skipped, skipped_in_a_row)
            continue
        skipped_in_a_row = 0
        # warm-up over 5 %, then linearly down to 0
        _optimise(net, opt, loss, plan.lr * min(1.0, frac / 0.05 + 0.01) * (1.0 - frac))
        run.step += 1
        run.seconds = time.time() - started
        bar.update(min(round(run.seconds), bar.total) - bar.n if by_time else 1)
        bar.set_postfix(step=run.step, loss=f"{float(loss.detach()):.4f}",
                        **{TERM_NAMES.get(k, k): f"{v:.4f}" for k, v in terms.items()})
        if run.step % plan.ckpt_every == 0:
            run.save(last)
    bar.close()
    run.save(last)
    out = work / "adapted.pt"
    run.save(out, optimizer=False)
    return out, run.summary()


def _say_skipped(step: int, skipped: int, in_a_row: int) -> None:
    """A batch skipped for its non-finite loss: said, and an error once MAX_SKIPPED_IN_A_ROW
    come in a row."""
    log.warning("step %d: non-finite loss, batch skipped (%d so far)", step, skipped)
    if in_a_row >= MAX_SKIPPED_IN_A_ROW:
        raise ValueError(f"{in_a_row} batches in a row gave a non-finite loss "
                         "(check the recordings' LiDAR and calibration)")


def _optimise(net, opt, loss, lr: float) -> None:
    """One optimiser step at `lr`, the gradient's norm clipped to 1."""
    import torch

    for group in opt.param_groups:
        group["lr"] = lr
    opt.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
    opt.step()


def _progress_bar(plan: FineTune, step: int, seconds: float):
    """The run's bar: it counts steps, or seconds when only a time bounds the run."""
    from tqdm import tqdm

    by_time = plan.steps is None
    return tqdm(total=round(60 * (plan.minutes or 0.0)) if by_time else plan.steps,
                initial=round(seconds) if by_time else step, desc="adapt",
                unit="s" if by_time else "it", dynamic_ncols=True)


def _batch(frames: list[Frame], crop: tuple[int, int], rng: np.random.Generator, size: int,
           device) -> dict:
    """`size` frames drawn at random, cropped and augmented, stacked on `device`."""
    import torch

    from edge_depth.model.data import to_tensors

    items = [to_tensors(frames[int(i)].arrays(), crop, rng, augment=True)
             for i in rng.integers(0, len(frames), size)]
    return {k: torch.stack([item[k] for item in items]).to(device) for k in items[0]}


def _resume(last: Path, net, opt) -> tuple[int, float]:
    """The network and optimizer as `last` left them; (its step, its seconds)."""
    import torch

    state = torch.load(last, weights_only=False, map_location="cpu")
    net.load_state_dict(state["model"])
    opt.load_state_dict(state["optimizer"])
    print(f"resumed from {last} at step {state['step']} ({state['seconds'] / 60:.1f} min)")
    return state["step"], state["seconds"]


def _loss(net, batch: dict, plan: FineTune):
    """(loss, its logged terms): the sequence loss against the ground truth (supervised), or
    the paper's self-supervised loss."""
    from edge_depth.model.losses import sequence_loss
    from edge_depth.tools.train import self_supervised_step

    if plan.supervised:
        preds = net(batch["left"], batch["right"], batch["sparse"], batch["valid"], plan.iters)
        return sequence_loss(preds, batch["gt"], (batch["gt"] > 0).float()), {}
    loss, terms, _ = self_supervised_step(net, batch, plan.split, plan.iters)
    return loss, terms


def bundle_size(frames: list[Frame], multiple: int = 8) -> tuple[int, int]:
    """The camera's (w, h) rounded up to the network's multiple (the engine pads)."""
    h, w = frames[0].left.shape
    return (-(-w // multiple) * multiple, -(-h // multiple) * multiple)


def build_bundle(checkpoint: Path, bundle: Path, size: tuple[int, int], frames: list[Frame],
                 calib_frames: int = 16, node_search: bool = True) -> dict:
    """Export at `size`, then int8 quantization calibrated on up to `calib_frames` frames."""
    from edge_depth.tools.export import export
    from edge_depth.tools.quantize import quantize_bundle

    if bundle.exists():
        shutil.rmtree(bundle)
    export(checkpoint, bundle, size)
    pick = np.linspace(0, len(frames) - 1, min(calib_frames, len(frames))).round().astype(int)
    feeds = [(frames[i].left, frames[i].right, frames[i].sparse("left")) for i in pick]
    shutil.copy(checkpoint, bundle / BUNDLE_CHECKPOINT)
    return quantize_bundle(bundle, feeds, node_search=node_search,
                           calib_label=f"{len(feeds)} adapt frames of the recordings")


@dataclass
class AdaptResult:
    written: bool  # the new bundle went to `out`
    report: dict
    work: Path
    files: list[Path] = field(default_factory=list)


def resolve_start(start: Path | None) -> tuple[Path, Path]:
    """(checkpoint to fine-tune, bundle to compare against) for --from."""
    if start is None:
        return DEFAULT_CHECKPOINT, Path(DEFAULT_BUNDLE)
    if start.is_dir():
        if not (start / BUNDLE_CHECKPOINT).is_file():
            raise ValueError(f"--from {start}: a bundle without {BUNDLE_CHECKPOINT} (only "
                             "bundles written by adapt carry their weights); give the .pt "
                             "checkpoint it was exported from")
        return start / BUNDLE_CHECKPOINT, start
    if not start.is_file():
        raise ValueError(f"--from {start}: no such checkpoint or bundle")
    return start, Path(DEFAULT_BUNDLE)


def adapt(recordings: list[Path | str], out: Path | str, *, steps: int | None = None,
          minutes: float | None = None, topics: dict | None = None, calib: Path | None = None,
          start: Path | None = None, work: Path | None = None, resume: bool = False,
          force: bool = False, check_share: float = 0.2, max_frames: int = 300,
          plan: FineTune | None = None, node_search: bool = True,
          test_time: bool = False, unadapted: bool = True,
          photometric_only: bool = False) -> AdaptResult:
    """The whole job (module docstring); the Python entry for scheduled adaptation.
    test_time: adapt on every frame and check on the same frames (test-time adaptation: the
    frames are the ones to be measured, e.g. one real pair with its LiDAR)."""
    recordings = [Path(r) for r in recordings]
    out = Path(out)
    work = Path(work) if work else out.with_name(out.name + ".adapt")
    init, old_bundle = resolve_start(Path(start) if start else None)
    plan = plan or FineTune(steps=steps, minutes=minutes)
    from edge_depth.model.device import resolve_device

    resolve_device(plan.device)  # a GPU asked for but absent: one line before any work
    adapt_frames, check_frames = adapt_and_check_frames(
        recordings, calib, topics, max_frames, check_share, test_time)
    if plan.supervised and any(f.gt is None for f in adapt_frames):
        raise ValueError("supervised fine-tuning needs ground truth on every adapt frame")
    checkpoint, training = finetune(init, adapt_frames, work, plan, resume)
    candidate = work / "bundle"
    quant = build_bundle(checkpoint, candidate, bundle_size(adapt_frames), adapt_frames,
                         node_search=node_search)
    engines = {"before": Engine(old_bundle, precision="int8")}
    if unadapted and tuple(engines["before"].size) != bundle_size(adapt_frames):
        engines["unadapted"] = unadapted_engine(engines["before"], old_bundle, init, start,
                                                work, adapt_frames, node_search)
    engines["after"] = Engine(candidate, precision="int8")
    means, rows, shown = check(engines, check_frames)
    better, why = decide(means, photometric_only)
    if not np.isfinite(means["after"].get("held_out_px", np.nan)):
        print("adapt: the check frames have no held-out LiDAR error (no LiDAR paired with "
              "them): " + ("deciding on the photometric error alone (--photometric-only)"
                           if photometric_only else "the decision needs --photometric-only"),
              flush=True)
    written = better or force
    verdict = ("better on the check frames: the new bundle is written" if better else
               "not better on the check frames: " + ("written anyway (--force)" if force
                                                     else "the old bundle is kept"))
    report = dict(recordings=[str(r) for r in recordings], out=str(out), test_time=test_time,
                  check_share=0.0 if test_time else check_share,
                  frames=dict(adapt=len(adapt_frames), check=len(check_frames)),
                  bundles=dict(before=str(old_bundle), after=str(out) if written else
                               str(candidate)),
                  training=training, quantization=dict(
                      mean_abs_px_vs_fp32=quant["mean_abs_px_vs_fp32"],
                      int8={k: v["int8"] for k, v in quant["graphs"].items()}),
                  check=means, per_frame=rows, better=better, written=written,
                  verdict=verdict, why=why)
    files = [work / "report.json", work / "report.md", work / "report.png"]
    files[0].write_text(json.dumps(report, indent=2))
    files[1].write_text(format_report(report))
    picture(shown, files[2])
    if written:
        install(candidate, out, files)
    print(format_report(report))
    return AdaptResult(written, report, work, files)


def build_parser() -> argparse.ArgumentParser:
    """`edge-depth adapt`'s flags."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("recordings", type=Path, nargs="+",
                   help="MCAP recordings (or folders of scene folders)")
    p.add_argument("--out", type=Path, required=True, help="the adapted bundle's folder")
    p.add_argument("--steps", type=int, default=None)
    p.add_argument("--minutes", type=float, default=None)
    p.add_argument("--topics", type=Path, default=None, help="TOML [topics] map (as replay)")
    p.add_argument("--calib", type=Path, default=None, help="calibration TOML (as replay)")
    p.add_argument("--from", dest="start", type=Path, default=None,
                   help="checkpoint (.pt) or adapted bundle to start from (default: shipped)")
    p.add_argument("--work", type=Path, default=None,
                   help="checkpoints, candidate bundle and report (default: OUT.adapt)")
    p.add_argument("--resume", action="store_true", help="continue WORK/last.pt")
    p.add_argument("--force", action="store_true",
                   help="write the new bundle even when it is not better")
    p.add_argument("--photometric-only", action="store_true",
                   help="where the check frames have no LiDAR: decide on the photometric "
                        "error alone (without it such a run keeps the old bundle)")
    p.add_argument("--check-share", type=float, default=0.2)
    p.add_argument("--max-frames", type=int, default=300,
                   help="frames kept in memory, evenly spread over the recordings' time")
    p.add_argument("--lr", type=float, default=5e-5)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--iters", type=int, default=4, help="GRU iterations while training")
    p.add_argument("--device", default="auto",
                   help="where the fine-tuning runs: auto (the GPU when torch sees one), cpu, "
                        "cuda or cuda:N")
    p.add_argument("--supervised", action="store_true",
                   help="train on the recordings' ground truth instead (for comparison)")
    p.add_argument("--test-time", action="store_true",
                   help="adapt on all frames and check on the same ones (test-time "
                        "adaptation, e.g. on one real pair)")
    p.add_argument("--no-unadapted", action="store_true",
                   help="skip scoring the starting weights at the camera's size")
    p.add_argument("--no-node-search", action="store_true",
                   help="quantize without the per-convolution pass (faster)")
    return p


def main(argv: list[str] | None = None) -> int:
    import torch  # noqa: F401  (the train extra: said in one line before any work)
    import tqdm  # noqa: F401

    from edge_depth.arguments import load_topic_map

    p = build_parser()
    args = p.parse_args(argv)
    if args.steps is None and args.minutes is None:
        p.error("give --steps N and/or --minutes M")
    if not 0 < args.check_share < 1:
        p.error(f"--check-share must be within (0, 1), got {args.check_share}")
    for r in args.recordings:
        if not r.exists():
            p.error(f"{r}: no such recording")
    try:
        plan = FineTune(steps=args.steps, minutes=args.minutes, lr=args.lr, batch=args.batch,
                        iters=args.iters, supervised=args.supervised, device=args.device)
        result = adapt(args.recordings, args.out,
                       topics=load_topic_map(args.topics) if args.topics else None,
                       calib=args.calib, start=args.start, work=args.work, resume=args.resume,
                       force=args.force, check_share=args.check_share,
                       max_frames=args.max_frames, plan=plan,
                       node_search=not args.no_node_search, test_time=args.test_time,
                       unadapted=not args.no_unadapted,
                       photometric_only=args.photometric_only)
    except ValueError as exc:
        print(f"edge-depth adapt: {exc}")
        return 2
    print(f"report: {', '.join(str(f) for f in result.files)}")
    return 0 if result.written else 3


if __name__ == "__main__":
    raise SystemExit(main())
