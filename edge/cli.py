"""The `edge-depth` command. Each subcommand maps its arguments into configs and calls a module."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from edge.errors import EdgeError


def parse_size(text: str) -> tuple[int, int]:
    """'640x400' -> (640, 400); raises argparse.ArgumentTypeError otherwise."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 640x400, got {text!r}")
    w, h = int(parts[0]), int(parts[1])
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"size must be at least 16x16, got {text!r}")
    return w, h


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


class _Parser(argparse.ArgumentParser):
    """argparse that reports errors on one line and exits with status 2."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from edge.sim.lidar import PATTERNS

    parser = _Parser(prog="edge-depth", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    synth = sub.add_parser("synth", help="write synthetic scene folders with exact ground truth")
    synth.add_argument("--out", required=True, type=Path, help="output directory")
    synth.add_argument("--count", type=_positive_int, default=1, help="number of scenes")
    synth.add_argument("--seed", type=int, default=0, help="seed of the first scene")
    synth.add_argument("--size", type=parse_size, default=(640, 400), help="WxH (640x400)")
    synth.add_argument("--lidar", choices=sorted(PATTERNS), default="beams16")

    demo = sub.add_parser("demo", help="the embedded default: the synthetic rig, end to end")
    demo.add_argument("--out", type=Path, default=Path("out"))
    demo.add_argument("--frames", type=_positive_int, default=3)
    demo.add_argument("--seed", type=int, default=1000)
    from calibration.cli import add_parsers

    add_parsers(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "synth":
            from edge.sim.export import synth_command

            return synth_command(args.out, args.count, args.seed, args.size, args.lidar)
        if args.command == "calibrate":
            from calibration.cli import run

            return run(args)
        if args.command == "demo":
            from edge.demo import demo_command

            return demo_command(args.out, args.frames, args.seed)
    except (EdgeError, OSError) as exc:
        print(f"edge-depth {args.command}: error: {exc}", file=sys.stderr)
        return 1
    parser.error(f"unknown command {args.command}")
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
