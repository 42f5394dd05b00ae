"""`edge-depth` with the camera rate's fitted depth change switched off (a carried frame keeps
the key frame's disparity as it was), for an A/B of its cost in a live run.

    python experiments/without_depth_change.py run --config experiments/sim_robot_camera_rate.toml
"""

import sys

from edge_depth.runtime import propagate

propagate.depth_change = lambda *args, **kwargs: None  # type: ignore[assignment]

from edge_depth.cli import main  # noqa: E402

sys.exit(main(sys.argv[1:]))
