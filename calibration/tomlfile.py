"""Reading the project's TOML files (calibration, robot config, topics) so that any damage ends
in one line: a syntax error, nesting deep enough to exhaust the parser's recursion, bytes that
are not UTF-8, or a file far larger than any settings file."""

from __future__ import annotations

import tomllib
from pathlib import Path

MAX_TOML_BYTES = 1 << 20  # settings files are a few kB; a larger one is not one of ours


class TomlReadError(ValueError):
    """A TOML file could not be read; the message says why, without the file's name (the
    caller's error names the file and what it is for)."""


def read_toml(path: str | Path, max_bytes: int = MAX_TOML_BYTES) -> dict:
    """Parse the TOML file at `path`; FileNotFoundError and IsADirectoryError pass through
    (callers word them), every other failure is a TomlReadError."""
    with open(path, "rb") as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise TomlReadError(f"larger than {max_bytes >> 10} KiB: not a settings file")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise TomlReadError(f"not UTF-8 text (byte {exc.start} is not)") from None
    return parse_toml(text)


def parse_toml(text: str) -> dict:
    """tomllib.loads, every failure a TomlReadError."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise TomlReadError(f"not valid TOML ({exc})") from None
    except RecursionError:
        raise TomlReadError("not valid TOML (nested too deeply to read)") from None
