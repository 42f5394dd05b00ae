"""`tools/evaluate.py` with the edge matching's gate opened far from the LiDAR (a probe).

The matching's gate is where the network is unsure at its own edges. With sparse LiDAR (8
rows), the engine's bad-3 away from depth edges triples, in pixels 12+ px from the nearest
point, and SGBM gets half of them right (`experiments/low_density_headroom.py`). This adds to
the gate every pixel farther than `--far-px` from the nearest LiDAR point (with
`--far-confidence`, only where the network's confidence is also below the gate's 0.9); the
rest of the choice is the shipped one (StereoBM's checked match where it warps the right view
onto the left better, then the weighted median over the gate). The other arguments are
`tools/evaluate.py`'s.
    python experiments/far_gate_probe.py --far-px 12 data/aloe_r8 --methods net --json out.json
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from edge_depth.baselines import nearest_valid_index
from edge_depth.runtime import edge_match
from edge_depth.runtime.cells import local_range

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tools"))
import evaluate  # noqa: E402


def far_gate(far_px: float, with_confidence: bool):
    """EdgeMatch.prepare whose gate also holds the pixels over `far_px` from every point."""
    shipped = edge_match.EdgeMatch.prepare

    def prepare(self, left, right, disparity, confidence, sparse=None, terms=None):
        original = edge_match.local_range
        if sparse is not None and (sparse > 0).any():
            _, distance = nearest_valid_index(sparse > 0)
            far = distance > far_px
            if with_confidence:
                far &= confidence < self.max_confidence

            def widened(values, window):
                """The gate's range test, passed wherever the pixel is far."""
                return np.where(far, np.inf, local_range(values, window))
            edge_match.local_range = widened
        try:
            return shipped(self, left, right, disparity, confidence, sparse, terms)
        finally:
            edge_match.local_range = original
    return prepare


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0], add_help=False)
    p.add_argument("--far-px", type=float, required=True)
    p.add_argument("--far-confidence", action="store_true")
    args, rest = p.parse_known_args()
    edge_match.EdgeMatch.prepare = far_gate(args.far_px, args.far_confidence)
    sys.exit(evaluate.main(rest))


if __name__ == "__main__":
    main()
