"""ROS `camera_info` YAML (as written by camera_calibration) to and from StereoCalibration.

ROS stores, per camera, K, D, the rectification rotation R and the projection P; the right
camera's P holds Tx = -f' B. The stereo extrinsics follow: X_r = R2ᵀ R1 X_l - R2ᵀ (B, 0, 0).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from edge_depth.calibration.errors import CalibrationFileError
from edge_depth.calibration.model import StereoCalibration


def _matrix(path: str, info: dict, key: str, shape: tuple[int, int]) -> np.ndarray:
    try:
        data = np.asarray(info[key]["data"], np.float64)
    except KeyError:
        raise CalibrationFileError("missing key", path, f"{key}.data") from None
    except (TypeError, ValueError):
        raise CalibrationFileError("expected a list of numbers", path, f"{key}.data") from None
    if key == "distortion_coefficients":
        return data.ravel()
    if data.size != shape[0] * shape[1]:
        raise CalibrationFileError(f"expected {shape[0] * shape[1]} numbers, got {data.size}",
                                   path, f"{key}.data")
    return data.reshape(shape)


def load_camera_info(path: Path | str) -> dict:
    """One camera_info YAML -> dict(K, D, R, P, size)."""
    path = str(path)
    try:
        with open(path) as f:
            info = yaml.safe_load(f)
    except FileNotFoundError:
        raise CalibrationFileError("file not found", path) from None
    except yaml.YAMLError as exc:
        raise CalibrationFileError(f"not valid YAML ({exc})", path) from None
    if not isinstance(info, dict):
        raise CalibrationFileError("expected a mapping at the top level", path)
    for key in ("image_width", "image_height"):
        if not isinstance(info.get(key), int) or info[key] <= 0:
            raise CalibrationFileError("expected a positive integer", path, key)
    model = info.get("distortion_model", "plumb_bob")
    if model not in ("plumb_bob", "rational_polynomial"):
        raise CalibrationFileError(f"distortion model {model!r} is not supported", path,
                                   "distortion_model")
    return dict(K=_matrix(path, info, "camera_matrix", (3, 3)),
                D=_matrix(path, info, "distortion_coefficients", (1, 0)),
                R=_matrix(path, info, "rectification_matrix", (3, 3)),
                P=_matrix(path, info, "projection_matrix", (3, 4)),
                size=(info["image_width"], info["image_height"]))


def load_camera_info_pair(left: Path | str, right: Path | str) -> StereoCalibration:
    return stereo_from_camera_infos(load_camera_info(left), load_camera_info(right),
                                    str(right))


def stereo_from_camera_infos(cl: dict, cr: dict, where: str,
                             rectified: bool = False) -> StereoCalibration:
    """The stereo calibration of a left/right pair of camera infos (dicts of K, D, R, P,
    size). `rectified`: the images are already rectified (a ROS image_rect pair), so the
    pair is the ideal one their P matrices describe — no distortion, no rotation."""
    if cl["size"] != cr["size"]:
        raise CalibrationFileError(f"image size {cr['size']} differs from left {cl['size']}",
                                   where, "image_width")
    baseline = -cr["P"][0, 3] / cr["P"][0, 0] if cr["P"][0, 0] > 0 else 0.0
    if baseline <= 0:
        raise CalibrationFileError("expected P[0,3] = -f * baseline < 0 in the right camera",
                                   where, "projection_matrix")
    if rectified:
        K_left, K_right = cl["P"][:, :3], cr["P"][:, :3]
        no_distortion = np.zeros(5)
        return StereoCalibration(K_left, no_distortion, K_right, no_distortion, np.eye(3),
                                 np.array([-baseline, 0.0, 0.0]), cl["size"])
    R = cr["R"].T @ cl["R"]
    T = -cr["R"].T @ np.array([baseline, 0.0, 0.0])
    return StereoCalibration(cl["K"], cl["D"], cr["K"], cr["D"], R, T, cl["size"])


def transform_matrix(translation, rotation_xyzw) -> np.ndarray:
    """4×4 from a ROS Transform (translation x y z, quaternion x y z w)."""
    from scipy.spatial.transform import Rotation

    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(np.asarray(rotation_xyzw, float)).as_matrix()
    T[:3, 3] = np.asarray(translation, float)
    return T


def chain_transform(edges: list[tuple[str, str, np.ndarray]], target: str, source: str
                    ) -> tuple[np.ndarray, list[str]] | None:
    """T_target_source through a TF tree given as (parent, child, T_parent_child) edges
    (X_parent = T X_child), walking edges either way; (T, the frames passed through), or
    None where no chain joins the two frames."""
    links: dict[str, list[tuple[str, np.ndarray]]] = {}
    for parent, child, T in edges:
        links.setdefault(child, []).append((parent, T))
        links.setdefault(parent, []).append((child, np.linalg.inv(T)))
    # breadth-first from the source: each frame's pose as T_frame_source
    found = {source: (np.eye(4), [source])}
    queue = [source]
    while queue:
        frame = queue.pop(0)
        T_frame, path = found[frame]
        if frame == target:
            return T_frame, path
        for nxt, T_next_frame in links.get(frame, []):
            if nxt not in found:
                found[nxt] = (T_next_frame @ T_frame, [*path, nxt])
                queue.append(nxt)
    return None


def _block(rows: int, cols: int, data: np.ndarray) -> dict:
    return {"rows": rows, "cols": cols, "data": [float(v) for v in np.ravel(data)]}


def save_camera_info_pair(stereo: StereoCalibration, out_dir: Path | str) -> list[Path]:
    """Write left.yaml and right.yaml in camera_calibration's format."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    r = stereo.rect
    paths = []
    for name, K, D, R, P in (("left", stereo.K_left, stereo.dist_left, r["R1"], r["P1"]),
                             ("right", stereo.K_right, stereo.dist_right, r["R2"], r["P2"])):
        info = {
            "image_width": stereo.image_size[0], "image_height": stereo.image_size[1],
            "camera_name": name, "camera_matrix": _block(3, 3, K),
            "distortion_model": "plumb_bob" if D.size <= 5 else "rational_polynomial",
            "distortion_coefficients": _block(1, D.size, D),
            "rectification_matrix": _block(3, 3, R), "projection_matrix": _block(3, 4, P),
        }
        path = out_dir / f"{name}.yaml"
        path.write_text(yaml.safe_dump(info, sort_keys=False))
        paths.append(path)
    return paths
