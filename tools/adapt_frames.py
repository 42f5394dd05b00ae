"""The frames `edge-depth adapt` trains and checks on: a recording's synced frames (or scene
folders) with their LiDAR projected into both views, kept compact, and split by time."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass
class Frame:
    """One synced frame of a recording: rectified grey images (H, W) uint8, its LiDAR as
    disparity in each view kept compact (flat pixel indices, px), GT disparity or None."""

    recording: str
    stamp_ns: int
    left: np.ndarray
    right: np.ndarray
    lidar_left: tuple[np.ndarray, np.ndarray]
    lidar_right: tuple[np.ndarray, np.ndarray]
    gt: np.ndarray | None = None

    def sparse(self, side: str = "left") -> np.ndarray:
        """(H, W) float32 disparity of the LiDAR in one view, 0 = no point."""
        index, value = self.lidar_left if side == "left" else self.lidar_right
        out = np.zeros(self.left.size, np.float32)
        out[index] = value
        return out.reshape(self.left.shape)

    def arrays(self) -> dict[str, np.ndarray]:
        """The training dict of `edge.model.data.sample_to_arrays`."""
        sparse_l, sparse_r = self.sparse("left"), self.sparse("right")
        zeros = np.zeros(self.left.shape, np.float32)
        return dict(left=self.left, right=self.right,
                    gt=self.gt if self.gt is not None else zeros, gt_right=zeros,
                    sparse=sparse_l, valid=sparse_l > 0, sparse_right=sparse_r,
                    valid_right=sparse_r > 0)


def _compact(sparse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    index = np.flatnonzero(sparse > 0)
    return index.astype(np.int32), sparse.ravel()[index].astype(np.float32)


def folder_frames(root: Path) -> list[Frame]:
    """Scene folders (left.png, right.png, sparse.pfm, disp.pfm as GT if there) as frames, in
    name order (one a "second")."""
    from edge_depth.model.datasets import scene_folder_arrays
    from edge_depth.sim.folder import list_scene_folders

    frames = []
    for i, folder in enumerate(list_scene_folders(root)):
        a = scene_folder_arrays(folder)
        frames.append(Frame(str(folder), i * 1_000_000_000, a["left"], a["right"],
                            _compact(a["sparse"]), _compact(a["sparse_right"]),
                            a["gt"] if (a["gt"] > 0).any() else None))
    return frames


def load_frames(recording: Path, calib: Path | None = None, topics: dict | None = None,
                max_frames: int = 300) -> list[Frame]:
    """A recording's synced frames in time order, at most `max_frames` evenly spread (the
    stride doubles whenever the kept frames pass the limit, so memory stays bounded). A
    directory is read as scene folders (`folder_frames`)."""
    from edge_depth.calibration.projection import project_to_disparity
    from edge_depth.capture.replay import McapSource, TopicMap
    from edge_depth.capture.synced import deskewed_note, synced_frames
    from edge_depth.commands import replay_calibration

    if Path(recording).is_dir():
        return folder_frames(Path(recording))[:max_frames]
    topic_map = TopicMap.from_dict(topics or {})
    source = McapSource(recording, topic_map)
    source.check_topics()
    stereo, lidar = replay_calibration(source, calib)
    offset = lidar.time_offset_ns if lidar else 0
    frames: list[Frame] = []
    stride = 1
    counts: dict[str, int] = {}
    for i, (event, left, right, points, gt) in enumerate(
            synced_frames(recording, stereo, offset, topics=topic_map, counters=counts,
                          deskew_with=None if lidar is None else lidar.T_cam_lidar)):
        if i % stride:
            continue
        sparse = {side: np.zeros(left.shape, np.float32) for side in ("left", "right")}
        if lidar is not None and len(points):
            for side in sparse:
                sparse[side], _ = project_to_disparity(points, stereo, lidar.T_cam_lidar, side)
        frames.append(Frame(str(recording), int(event.stamp_ns), left, right,
                            _compact(sparse["left"]), _compact(sparse["right"]),
                            None if gt is None else np.asarray(gt, np.float32)))
        if len(frames) > max_frames:
            frames, stride = frames[::2], stride * 2
    paired = counts.get("frames_with_lidar", 0)
    print(f"{recording}: frames with LiDAR: {paired} of "
          f"{paired + counts.get('frames_without_lidar', 0)}"
          + ("" if lidar is not None else " (no LiDAR extrinsics: stereo only)")
          + deskewed_note(counts), flush=True)
    return sorted(frames, key=lambda f: f.stamp_ns)


def split_by_time(recordings: list[list[Frame]], check_share: float = 0.2
                  ) -> tuple[list[Frame], list[Frame]]:
    """(adapt, check): the last `check_share` of each recording's frames (at least one) are
    check frames."""
    adapt_frames, check_frames = [], []
    for frames in recordings:
        if len(frames) < 2:
            raise ValueError(f"{frames[0].recording if frames else 'a recording'}: "
                             f"{len(frames)} synced frame(s); adapting needs at least 2")
        n_check = max(1, int(math.ceil(check_share * len(frames))))
        adapt_frames += frames[:-n_check]
        check_frames += frames[-n_check:]
    return adapt_frames, check_frames
