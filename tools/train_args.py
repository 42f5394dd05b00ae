"""tools/train.py's command line: its flags, their checks, and `--resume`'s restoring of the
flags a run was started with (kept apart so that the training loop reads on its own)."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from edge_depth.model.device import resolve_device

DIMS = ("feature", "context", "hidden", "motion", "head")


def parse_dims(text: str) -> dict[str, int]:
    """`--dims feature=48,hidden=48` -> {"feature_dim": 48, "hidden_dim": 48}."""
    dims = {}
    for item in filter(None, (t.strip() for t in text.split(","))):
        name, _, value = item.partition("=")
        if name not in DIMS or not value.isdigit() or int(value) < 1:
            raise argparse.ArgumentTypeError(f"expected NAME=N with NAME one of "
                                             f"{', '.join(DIMS)} and N ≥ 1, got {item!r}")
        dims[f"{name}_dim"] = int(value)
    return dims


def parse_args(argv, description: str = "") -> argparse.Namespace:
    """tools/train.py's command line, checked (one clear line for each bad combination)."""
    p = argparse.ArgumentParser(description=description)
    run_flags(p)
    network_flags(p)
    data_flags(p)
    args = p.parse_args(argv)
    if args.resume:
        restore_run_args(p, args, argv)
    if args.freeze_trunk and args.init is None:
        p.error("--freeze-trunk needs --init (the trunk's weights come from it)")
    if args.dims and args.init is not None:
        p.error("--dims is for a network from scratch: with --init the widths are the "
                "checkpoint's (experiments/prune.py cuts them)")
    if args.teacher is not None and args.mode != "supervised":
        p.error("--teacher distils in supervised mode")
    if args.fresh_lr_mult != 1.0 and args.init is None:
        p.error("--fresh-lr-mult needs --init (fresh tensors are those the checkpoint lacks)")
    if args.freeze_trunk and not args.refine:
        p.error("--freeze-trunk trains the confidence head only: give --refine 10")
    for name in ("stereo_only_share", "rig_stereo_only_share", "asymmetric_share"):
        share, flag = getattr(args, name), "--" + name.replace("_", "-")
        if share is None:  # not given: the things stream's default
            continue
        if not 0.0 <= share <= 1.0:
            p.error(f"{flag} must be within 0-1, got {share}")
        if not (args.data or "").startswith("things:"):
            p.error(f"{flag} applies to --data things:DIR only")
    args.device = training_device(p, args.device)
    return args


def run_flags(p: argparse.ArgumentParser) -> None:
    """How long, how fast and from where the run goes."""
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--steps", type=int, default=6000)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--crop", default="320x192")
    p.add_argument("--lr", type=float, default=2e-4)
    p.add_argument("--iters", type=int, default=6, help="GRU iterations while training")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--workers", type=int, default=1,
                   help="data-generation processes (0: in the training process)")
    p.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    p.add_argument("--device", default="auto",
                   help="where the network trains: auto (the GPU when torch sees one, else "
                        "the CPU), cpu, cuda or cuda:N; data are made on the CPU either way")
    p.add_argument("--ckpt-every", type=int, default=250)
    p.add_argument("--val-every", type=int, default=0, help="validate every N steps (0: off)")
    p.add_argument("--resume", action="store_true", help="continue from OUT/last.pt")
    p.add_argument("--init", type=Path, default=None, help="start from a checkpoint's weights")


def network_flags(p: argparse.ArgumentParser) -> None:
    """What network is trained, and which of its parts learn at what rate."""
    p.add_argument("--no-cspn", action="store_true")
    p.add_argument("--no-sparse", action="store_true")
    p.add_argument("--no-half-res-block", action="store_true",
                   help="drop the backbone's 1/2-resolution residual block (faster encoder)")
    p.add_argument("--refine", type=int, nargs="?", const=10, default=0, choices=(0, 10),
                   help="10: the confidence head (edge.model.refine; a bare --refine: 10), "
                        "0: none")
    p.add_argument("--dims", type=parse_dims, default={}, metavar="NAME=N,...",
                   help="from scratch: the network's widths (feature, context, hidden, motion, "
                        "head; ModelConfig's *_dim), e.g. the shipped network's "
                        "feature=48,context=32,hidden=48,motion=48,head=32 (default: "
                        "ModelConfig's 64 / 48 / 64 / 64 / 64)")
    p.add_argument("--refine-lr-mult", type=float, default=1.0,
                   help="the confidence head's learning rate as a multiple of --lr")
    p.add_argument("--fresh-lr-mult", type=float, default=1.0,
                   help="with --init: the learning rate of the tensors the checkpoint lacks "
                        "(a new stage's, which start at or near zero) as a multiple of the "
                        "confidence head's")
    p.add_argument("--freeze-trunk", action="store_true",
                   help="with --init: train only the confidence head; the encoders and the "
                        "update block keep the checkpoint's weights and run as deployed "
                        "(batch norm on its running statistics)")


def data_flags(p: argparse.ArgumentParser) -> None:
    """What it learns from: the data, the loss and its teacher."""
    p.add_argument("--mode", choices=["supervised", "self"], default="supervised")
    p.add_argument("--split", choices=["all", "half1", "half2"], default="half2")
    p.add_argument("--patterns", default="beams16")
    p.add_argument("--data", default=None,
                   help="scene folders, REC.mcap, kitti:DIR, sceneflow:DIR or things:DIR "
                        "(rendered by `edge-depth synth --world things`; default: the rig)")
    p.add_argument("--stereo-only-share", type=float, default=None,
                   help="things data: the share of samples without LiDAR (default 0.12)")
    p.add_argument("--rig-stereo-only-share", type=float, default=None,
                   help="things data: the share of its rig samples without LiDAR (default 0)")
    p.add_argument("--asymmetric-share", type=float, default=None,
                   help="things data: how often each camera draws its own photometric "
                        "augmentation (default 0.2, RAFT-Stereo's)")
    p.add_argument("--edge-weight", type=float, default=0.0,
                   help="supervised: pixels at GT depth edges weigh 1 + W in the loss")
    p.add_argument("--teacher", type=Path, default=None,
                   help="supervised: a trained checkpoint whose final disparity (frozen, after "
                   "--iters iterations) the network also learns to reproduce: distillation "
                   "into a lighter network")
    p.add_argument("--teacher-weight", type=float, default=1.0,
                   help="with --teacher: the weight of the L1 towards the teacher's disparity "
                   "beside the ground truth's")


def training_device(p: argparse.ArgumentParser, name: str) -> torch.device:
    """--device as a torch device; a GPU asked for but absent is one clear line."""
    try:
        return resolve_device(name)
    except ValueError as exc:
        p.error(str(exc))


# where and how a resumed run trains now: never taken from the run (the machine may be new:
# a run trained on a GPU resumes on a CPU); given, or the parser's defaults
RESUME_FROM_THIS_MACHINE = {"out", "resume", "threads", "workers", "ckpt_every", "val_every",
                            "device"}


def restore_run_args(p: argparse.ArgumentParser, args: argparse.Namespace, argv) -> None:
    """--resume continues the run as it was started: the flags not given again take the values
    saved in OUT/last.pt (--init and --refine among them: without them the model and its
    optimizer groups would not match the checkpoint; --steps too, so a run resumed without it
    goes on to the end it was started for); one given again with another value is an error,
    except --steps. Those in RESUME_FROM_THIS_MACHINE are left as given."""
    last = args.out / "last.pt"
    if not last.exists():
        return
    saved = torch.load(last, weights_only=False, map_location="cpu").get("args") or {}
    unset = object()  # argparse fills in a default only where the namespace has no value
    parsed = vars(p.parse_args(argv, argparse.Namespace(**dict.fromkeys(vars(args), unset))))
    given = {k: v for k, v in parsed.items() if v is not unset}  # on the command line
    restored, clashes = [], []
    for key, value in saved.items():
        if key in RESUME_FROM_THIS_MACHINE or not hasattr(args, key):
            continue
        if key == "init":
            value = None if value in (None, "None") else Path(value)
        flag = f"--{key.replace('_', '-')}"
        if key not in given:
            if value != getattr(args, key):
                restored.append(flag if value is True else f"{flag} {value}")
            setattr(args, key, value)
        elif key != "steps" and str(given[key]) != str(value):  # how long it runs may change
            clashes.append(f"{flag} {given[key]} (the run: {value})")
    if clashes:
        p.error(f"--resume continues {last} as it was started; these differ from it: "
                + "; ".join(clashes))
    if restored:
        print(f"--resume: as the run was started, {', '.join(restored)}")
