"""Train the sparse-LiDAR stereo network on the synthetic rig (supervised or self-supervised).

    python tools/train.py --out runs/sup --steps 6000 [--mode supervised|self]
        [--split half2] [--resume] [--init CHECKPOINT] [--data SPEC]
    torchrun --nproc_per_node=N tools/train.py ...      # DistributedDataParallel

--data: scene folders, a .mcap recording (self-supervised fine-tuning on the robot's own
data), kitti:DIR or sceneflow:DIR (edge/model/datasets.py); default: the synthetic rig.
Under torchrun every rank trains on its own shard of the data (gloo on CPU, nccl on GPU);
rank 0 logs and checkpoints, and at the end all ranks compare a checksum of their weights.

Checkpoints (`last.pt`, every --ckpt-every steps) make long runs resumable; metrics go to
`metrics.csv` and `loss.png` in the output folder. `--out DIR --resume [--steps N]` continues
a run as it was started: the flags not given again (--init, --refine, --lr, ...) come from its
checkpoint, and one given with another value is an error.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from torch.utils.data import DataLoader

from edge_depth.calibration.atomic import atomic_write
from edge_depth.model.config import ModelConfig
from edge_depth.model.data import (
    VAL_SEED0,
    FixedSplit,
    RecordedTrainSet,
    SyntheticTrainSet,
)
from edge_depth.model.device import on_cpu, to_device
from edge_depth.model.losses import (
    CONFIDENCE_WEIGHT,
    confidence_loss,
    depth_edges,
    self_supervised_loss,
    sequence_loss,
    split_sparse,
    view_loss,
)
from edge_depth.model.network import SparseStereoNet
from edge_depth.tools.train_args import parse_args
from edge_depth.workers import one_thread_each


def self_supervised_step(net, batch, split: str, iters: int):
    """The paper's loss on the left view and on the flipped, swapped pair for the right. Both
    go through the network as one stacked batch: one forward per step, as DDP expects."""
    inp_l, sup_l = split_sparse(batch["valid"], split)
    inp_r, sup_r = split_sparse(batch["valid_right"], split)
    flip = lambda t: torch.flip(t, [-1])  # noqa: E731
    b = batch["left"].shape[0]
    preds = net(torch.cat([batch["left"], flip(batch["right"])]),
                torch.cat([batch["right"], flip(batch["left"])]),
                torch.cat([batch["sparse"] * inp_l, flip(batch["sparse_right"] * inp_r)]),
                torch.cat([inp_l, flip(inp_r)]), iters)
    total, terms = 0.0, {}
    n = len(preds)
    for i, pred in enumerate(preds):
        d_l, d_r = pred[:b], flip(pred[b:])
        t_l = view_loss(batch["left"], batch["right"], d_l, d_r, batch["sparse"], sup_l, -1.0)
        t_r = view_loss(batch["right"], batch["left"], d_r, d_l, batch["sparse_right"], sup_r,
                        1.0)
        loss, terms = self_supervised_loss(t_l, t_r)
        total = total + 0.9 ** (n - 1 - i) * loss
    return total, {k: float(v.detach()) for k, v in terms.items()}, preds[-1][:b]


def setup_distributed() -> tuple[int, int]:
    """(rank, world size); under torchrun, joins the process group (gloo on CPU)."""
    import os

    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world == 1:
        return 0, 1
    import torch.distributed as dist

    backend = "nccl" if torch.cuda.is_available() else "gloo"
    dist.init_process_group(backend)
    return dist.get_rank(), world


def weights_checksum(model) -> float:
    return float(sum(p.detach().double().sum() * (i + 1)
                     for i, p in enumerate(model.parameters())))


def validate(net, iters: int, count: int = 8) -> dict[str, float]:
    net.eval()
    epes, bad3 = [], []
    device = next(net.parameters()).device
    with torch.no_grad():
        for item in FixedSplit(VAL_SEED0, count):
            batch = to_device({k: v[None] for k, v in item.items()}, device)
            pred = net(batch["left"], batch["right"], batch["sparse"], batch["valid"], iters)[-1]
            err = (pred - batch["gt"]).abs()
            epes.append(float(err.mean()))
            bad3.append(float((err > 3).float().mean() * 100))
    net.train()
    return dict(val_epe=sum(epes) / len(epes), val_bad3=sum(bad3) / len(bad3))


def plot_metrics(csv_path: Path, png_path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(csv_path) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return
    steps = [int(r["step"]) for r in rows]
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    ax[0].plot(steps, [float(r["loss"]) for r in rows])
    ax[0].set(xlabel="step", ylabel="loss", yscale="log", title="training loss")
    val = [(int(r["step"]), float(r["val_epe"])) for r in rows if r.get("val_epe")]
    if val:
        ax[1].plot(*zip(*val, strict=True), marker="o")
    ax[1].set(xlabel="step", ylabel="EPE (px)", title="validation EPE (8 scenes)")
    fig.tight_layout()
    fig.savefig(png_path, dpi=80)
    plt.close(fig)


def init_weights(init: dict, refine: int) -> dict:
    """The --init checkpoint's weights in the form the net loads: without its confidence
    head when the run asks for one the checkpoint lacks (it starts fresh)."""
    weights = init["model"]
    before = ModelConfig.from_dict(init["config"]).refine
    if refine and before != refine:
        return {k: v for k, v in weights.items() if not k.startswith("refine.")}
    return weights


def set_train_mode(net, freeze_trunk: bool) -> None:
    """Training mode, but a frozen trunk runs as deployed (batch norm on its running
    statistics), so the refinement learns on the features the engine will give it."""
    net.train()
    if freeze_trunk:
        net.encoders.eval()
        net.update.eval()


def main(argv: list[str] | None = None) -> int:
    # denormal floats (early training, tiny activations) make CPU convolutions crawl; the
    # setting is the whole process's (a caller's subnormals read as 0 after it), so it is
    # undone on the way out
    torch.set_flush_denormal(True)
    try:
        return _train(argv)
    finally:
        torch.set_flush_denormal(False)


LOG_FIELDS = ["step", "loss", "appearance", "sparse", "lr", "smooth", "confidence", "teacher",
              "epe", "val_epe", "val_bad3", "lr_now", "seconds"]
HEADS = ("refine.",)  # the confidence head: may start fresh, at its own learning rate


def model_config(args, init: dict | None) -> ModelConfig:
    """The flags' architecture, or with --init the checkpoint's except what the flags change."""
    if init is None:
        return ModelConfig(gru_iters=args.iters, use_cspn=not args.no_cspn,
                           use_sparse=not args.no_sparse,
                           half_res_block=not args.no_half_res_block, refine=args.refine,
                           **args.dims)
    changes = {"gru_iters": args.iters}
    if args.no_half_res_block:
        changes["half_res_block"] = False
    if args.refine:
        changes["refine"] = args.refine
    return ModelConfig.from_dict({**init["config"], **changes})


def training_device(args) -> torch.device:
    device = args.device
    if device.type == "cuda" and device.index is None:
        # under torchrun each process takes its own GPU (one process per GPU)
        device = torch.device("cuda", int(os.environ.get("LOCAL_RANK", "0")))
    if device.type == "cuda":
        torch.cuda.set_device(device)
    return device


def optimizer(net, args, weights: dict | None):
    """AdamW over three groups — the trunk, the head carried over, the head's tensors the
    checkpoint lacks (kept apart even on --resume so --fresh-lr-mult can move them faster) —
    and its one-cycle schedule."""
    fresh = {n for n, _ in net.named_parameters()
             if weights is not None and n.startswith(HEADS) and n not in weights}
    if args.freeze_trunk:
        for n, p in net.named_parameters():
            p.requires_grad_(n.startswith(HEADS))
    named = list(net.named_parameters())
    groups = [([p for n, p in named if not n.startswith(HEADS)], args.lr),
              ([p for n, p in named if n.startswith(HEADS) and n not in fresh],
               args.lr * args.refine_lr_mult),
              ([p for n, p in named if n in fresh],
               args.lr * args.refine_lr_mult * args.fresh_lr_mult)]
    groups = [(ps, lr) for ps, lr in groups if ps and ps[0].requires_grad]
    opt = torch.optim.AdamW([dict(params=ps) for ps, _ in groups], lr=args.lr,
                            weight_decay=1e-5)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, [lr for _, lr in groups],
                                                total_steps=args.steps + 100,
                                                pct_start=0.05, anneal_strategy="linear")
    return opt, sched


def load_start(net, opt, sched, args, weights: dict | None) -> int:
    """The step to start from: --resume's last.pt (weights, optimizer, schedule), else the
    --init weights (a head the checkpoint lacks starts fresh, said so), else 0."""
    last = args.out / "last.pt"
    if args.resume and last.exists():
        ckpt = torch.load(last, weights_only=False, map_location="cpu")
        net.load_state_dict(ckpt["model"])
        opt.load_state_dict(ckpt["optimizer"])
        sched.load_state_dict(ckpt["scheduler"])
        print(f"resumed from {last} at step {ckpt['step']}")
        return int(ckpt["step"])
    if weights is None:
        return 0
    result = net.load_state_dict(weights, strict=False)
    new = [k for k in result.missing_keys if k.startswith(HEADS)]
    if new and args.refine:  # a head the checkpoint lacks: fresh
        print(f"--init {args.init}: {len(new)} tensors of the refinement stages start "
              f"fresh ({', '.join(sorted(new)[:4])}{', ...' if len(new) > 4 else ''})")
        result.missing_keys[:] = [k for k in result.missing_keys if k not in new]
    if result.missing_keys:
        raise SystemExit(f"--init {args.init}: the model needs weights the checkpoint "
                         f"lacks: {result.missing_keys[:5]}")
    print(f"initialised from {args.init}"
          + (f" (dropped {len(result.unexpected_keys)} tensors the model no longer has)"
             if result.unexpected_keys else ""))
    return 0


def training_data(args, crop: tuple[int, int], step: int, rank: int, world: int):
    """The --data stream (things world, recordings, or the rig), seeded per rank and step."""
    if args.data is not None and args.data.startswith("things:"):
        from edge_depth.model.things_data import ThingsTrainSet

        return ThingsTrainSet(args.data[len("things:"):], crop,
                              seed=(args.seed * 1000 + step) * world + rank,
                              stereo_only_share=args.stereo_only_share,
                              rig_stereo_only_share=args.rig_stereo_only_share or 0.0,
                              **({} if args.asymmetric_share is None
                                 else dict(asymmetric_share=args.asymmetric_share)))
    if args.data is None:
        return SyntheticTrainSet(seed=(args.seed * 1000 + step) * world + rank, crop=crop,
                                 patterns=tuple(args.patterns.split(",")))
    return RecordedTrainSet(args.data, crop, seed=args.seed * 1000 + step, shard=rank,
                            shards=world)


def open_log(path: Path, step: int, main_rank: bool):
    """metrics.csv (appended in its own columns when a run resumes) and its writer."""
    fields = list(LOG_FIELDS)
    new_log = not path.exists() or step == 0
    if not new_log and main_rank:  # resumed: append in the columns the file already has
        with open(path, newline="") as f:
            fields = next(csv.reader(f), None) or fields
    log = open(path if main_rank else os.devnull, "w" if new_log else "a", newline="")  # noqa: SIM115
    writer = csv.DictWriter(log, fieldnames=fields, extrasaction="ignore")
    if new_log:
        writer.writeheader()
    return log, writer


def load_teacher(path: Path, device: torch.device):
    """The frozen network distilled from (`--teacher`): eval mode, no gradients."""
    from edge_depth.tools.export import load_checkpoint

    teacher, ckpt = load_checkpoint(path)
    for param in teacher.parameters():
        param.requires_grad_(False)
    print(f"teacher {path}: step {ckpt.get('step')}")
    return teacher.to(device)


def batch_loss(net, batch: dict, args, teacher=None):
    """(loss, its logged terms, the final disparity) of one batch, supervised or not; with a
    `teacher`, plus `--teacher-weight` × the same sequence loss towards its final disparity
    after as many iterations (on every pixel: the teacher answers where the ground truth is
    unknown too)."""
    if args.mode != "supervised":
        return self_supervised_step(net, batch, args.split, args.iters)
    preds, logit = net(batch["left"], batch["right"], batch["sparse"], batch["valid"],
                       args.iters, with_confidence=True)
    has_gt = (batch["gt"] > 0).float()
    weight = (1 + args.edge_weight * depth_edges(batch["gt"], has_gt)
              if args.edge_weight else None)  # the plain mean: no edge map to make
    loss = sequence_loss(preds, batch["gt"], has_gt, weight=weight)
    terms, final = {}, preds[-1]
    if teacher is not None:
        with torch.no_grad():
            taught = teacher(batch["left"], batch["right"], batch["sparse"], batch["valid"],
                             args.iters)[-1]
        distil = sequence_loss(preds, taught, torch.ones_like(has_gt))
        loss = loss + args.teacher_weight * distil
        terms["teacher"] = float(distil.detach())
    if logit is not None:
        conf = confidence_loss(logit, final.detach(), batch["gt"], has_gt)
        loss = loss + CONFIDENCE_WEIGHT * conf
        terms["confidence"] = float(conf.detach())
    return loss, terms, final


def finish_distributed(model, args, main_rank: bool, world: int) -> None:
    """Every rank's weights checksummed (they must be identical), then the group closed."""
    sums = [None] * world
    torch.distributed.all_gather_object(sums, weights_checksum(model))
    if main_rank:
        (args.out / "replicas.json").write_text(json.dumps(sums))
        print(f"replica weight checksums: {sums} "
              f"({'identical' if len(set(sums)) == 1 else 'DIFFERENT'})")
    # every rank leaves the group together: a rank tearing it down while another still
    # wrote its files aborted at exit now and then under load (docs/experiments.md)
    torch.distributed.barrier()
    torch.distributed.destroy_process_group()


def batches(args, crop: tuple[int, int], step: int, rank: int, world: int,
            device: torch.device):
    """The endless batch iterator (`--workers` processes start here, each with one BLAS /
    OpenCV thread), from `step` on, this rank's shard."""
    with one_thread_each():
        return iter(DataLoader(training_data(args, crop, step, rank, world),
                               batch_size=args.batch, num_workers=args.workers,
                               pin_memory=device.type == "cuda"))


def optimise(net, opt, sched, loss) -> None:
    """One optimiser step on `loss`, its gradients clipped to norm 1."""
    opt.zero_grad()
    loss.backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 1.0)
    opt.step()
    sched.step()


def batch_epe(final: torch.Tensor, gt: torch.Tensor) -> float:
    """The final disparity's mean error where the ground truth is known (NaN: nowhere)."""
    has_gt = gt > 0
    return float((final.detach() - gt).abs()[has_gt].mean()) if has_gt.any() else float("nan")


def save_checkpoint(path: Path, model: torch.nn.Module, opt, sched, step: int, config,
                    args: argparse.Namespace, device: torch.device) -> None:
    """The resumable checkpoint (weights and optimiser state on the CPU, the schedule, the
    step, the network's config and the run's flags), written whole or not at all."""
    with atomic_write(path) as tmp:
        torch.save(dict(model=on_cpu(model.state_dict()), optimizer=on_cpu(opt.state_dict()),
                        scheduler=sched.state_dict(), step=step, config=config.to_dict(),
                        args=vars(args) | {"out": str(args.out), "init": str(args.init),
                                           "device": str(device)}),
                   tmp)


def finite_on_every_rank(loss: torch.Tensor, world: int, device: torch.device) -> bool:
    """Whether the batch's loss is finite on every rank: every rank skips the batch, or
    none does (a lone skip would hang the all-reduce)."""
    bad = torch.tensor(0.0 if math.isfinite(float(loss.detach())) else 1.0, device=device)
    if world > 1:
        torch.distributed.all_reduce(bad)
    return float(bad) == 0


@dataclass
class _Run:
    """A training run's network, optimiser and place, from its start to its last step."""

    args: argparse.Namespace
    net: torch.nn.Module  # what the steps call: the network, wrapped on several ranks
    model: SparseStereoNet  # the network itself
    opt: torch.optim.Optimizer
    sched: torch.optim.lr_scheduler.LRScheduler
    step: int
    config: ModelConfig
    device: torch.device
    rank: int
    world: int

    @property
    def main_rank(self) -> bool:
        return self.rank == 0

    def save(self, path: Path) -> None:
        if self.main_rank:
            save_checkpoint(path, self.model, self.opt, self.sched, self.step, self.config,
                            self.args, self.device)


def _start(args: argparse.Namespace) -> _Run:
    """The network (from --init or --resume), its optimiser and schedule at the step the run
    starts from, on this rank's device."""
    rank, world = setup_distributed()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.threads:
        torch.set_num_threads(args.threads)
    init = None if args.init is None else \
        torch.load(args.init, weights_only=False, map_location="cpu")
    config = model_config(args, init)
    device = training_device(args)
    net = SparseStereoNet(config).to(device)
    weights = init_weights(init, args.refine) if init is not None else None
    opt, sched = optimizer(net, args, weights)
    step = load_start(net, opt, sched, args, weights)
    model = net
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(
            net, device_ids=[device.index] if device.type == "cuda" else None)
    return _Run(args, net, model, opt, sched, step, config, device, rank, world)


def _train(argv: list[str] | None) -> int:
    args = parse_args(argv, __doc__.splitlines()[0])
    from tqdm import tqdm

    run = _start(args)
    cw, ch = (int(v) for v in args.crop.split("x"))
    loader = batches(args, (cw, ch), run.step, run.rank, run.world, run.device)
    log_path = args.out / "metrics.csv"
    log, writer = open_log(log_path, run.step, run.main_rank)
    set_train_mode(run.model, args.freeze_trunk)
    teacher = None if args.teacher is None else load_teacher(args.teacher, run.device)
    bar = tqdm(total=args.steps, initial=run.step, desc="train", dynamic_ncols=True,
               disable=not run.main_rank)
    start = time.time()
    while run.step < args.steps:
        batch = to_device(next(loader), run.device)
        loss, terms, final = batch_loss(run.net, batch, args, teacher)
        if not finite_on_every_rank(loss, run.world, run.device):
            print(f"step {run.step}: non-finite loss, batch skipped", file=sys.stderr)
            continue
        optimise(run.net, run.opt, run.sched, loss)
        run.step += 1
        epe = batch_epe(final, batch["gt"])
        row = dict(step=run.step, loss=float(loss.detach()), epe=epe,
                   lr_now=run.sched.get_last_lr()[0], seconds=round(time.time() - start, 1),
                   **terms)
        if args.val_every and (run.step % args.val_every == 0 or run.step == args.steps):
            row.update(validate(run.model, 4))
            set_train_mode(run.model, args.freeze_trunk)
        writer.writerow(row)
        log.flush()
        bar.update(1)
        bar.set_postfix(loss=f"{float(loss.detach()):.3f}", epe=f"{epe:.2f}",
                        **{k: f"{v:.3f}" for k, v in terms.items()})
        if run.step % args.ckpt_every == 0 or run.step == args.steps:
            run.save(args.out / "last.pt")
    bar.close()
    log.close()
    run.save(args.out / "final.pt")
    if run.world > 1:
        finish_distributed(run.model, args, run.main_rank, run.world)
    if run.main_rank:
        plot_metrics(log_path, args.out / "loss.png")
        print(f"done: {run.step} steps, checkpoint {args.out / 'final.pt'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
