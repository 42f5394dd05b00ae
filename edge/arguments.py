"""Argument types and shared flags of the `edge-depth` commands, for `edge.cli`, the
`calibrate` subcommands and the tools alike (below all of them: it imports none)."""

from __future__ import annotations

import argparse
from pathlib import Path


def parse_size(text: str) -> tuple[int, int]:
    """'640x400' -> (640, 400); raises argparse.ArgumentTypeError otherwise."""
    parts = text.lower().split("x")
    if len(parts) != 2 or not all(p.isdigit() for p in parts):
        raise argparse.ArgumentTypeError(f"size must be WxH, e.g. 640x400, got {text!r}")
    w, h = int(parts[0]), int(parts[1])
    if w < 16 or h < 16:
        raise argparse.ArgumentTypeError(f"size must be at least 16x16, got {text!r}")
    return w, h


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def load_topic_map(path: Path) -> dict:
    from edge_depth.calibration.tomlfile import TomlReadError, read_toml
    from edge_depth.errors import ConfigError

    try:
        data = read_toml(path)
    except (OSError, TomlReadError) as exc:
        raise ConfigError("topics", "a readable TOML file", str(exc), str(path)) from None
    if not isinstance(data.get("topics"), dict):
        raise ConfigError("topics", "a [topics] table", sorted(data), str(path))
    return data["topics"]


def parse_host_port(text: str) -> tuple[str, int]:
    """'8765', ':8765' or 'HOST:8765' -> (host, port); the host defaults to 127.0.0.1."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT, got {text!r}")
    return host or "127.0.0.1", number


def share(text: str) -> float:
    try:
        value = float(text[:-1]) / 100 if text.endswith("%") else float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a share like 1% or 0.01, got {text!r}"
                                         ) from None
    if not 0 <= value <= 1:
        raise argparse.ArgumentTypeError(f"expected a share in 0 … 100 %, got {text!r}")
    return value
