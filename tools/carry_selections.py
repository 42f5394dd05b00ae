"""Carry the LiDAR selection of one bundle's model.json into another bundle.

    python tools/carry_selections.py FROM_MODEL_JSON_OR_BUNDLE BUNDLE_DIR

For a new checkpoint whose trunk was frozen (the network's estimate before its refinement is
the old one's): the selections fitted on the old bundle may serve it as they are, and whether
they do is measured, not assumed (`docs/experiments.md`: stage 16 ships with stage
15's because the refitted ones lost on motorcycle). `make bundle SELECTIONS=carry` runs this
with the bundle being replaced; the default, `SELECTIONS=fit`, fits new ones.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from edge_depth.tools.fit_select import store

KEYS = ("lidar_select",)  # an older bundle's "edge_select": no stage of the engine now


def carry(source: Path, bundle: Path) -> list[str]:
    """Copy every selection `source` (a model.json or a bundle folder) has into `bundle`;
    returns the keys carried. ValueError (one line) when the source has none."""
    path = source / "model.json" if source.is_dir() else source
    try:
        meta = json.loads(path.read_text())
    except ValueError as e:  # not JSON, or not text at all
        raise ValueError(f"{path}: not a bundle's model.json ({e})") from None
    keys = [k for k in KEYS if k in meta]
    if not keys:
        raise ValueError(f"{path}: no {' or '.join(KEYS)} to carry")
    for key in keys:
        store(bundle, key, meta[key])
    return keys


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("source", type=Path, help="a bundle folder or its model.json")
    p.add_argument("bundle", type=Path, help="the bundle that receives them")
    args = p.parse_args(argv)
    for path in (args.source, args.bundle / "model.json"):
        if not path.exists():
            p.error(f"{path}: not found")
    try:
        carry(args.source, args.bundle)
    except ValueError as e:
        print(f"carry_selections: {e}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
