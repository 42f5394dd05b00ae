"""Build the real evaluation pair (Middlebury Aloe, from Debian's opencv-doc) as a scene folder,
and copy opencv-doc's training photos (never Aloe, never a stereo pair) to data/textures; or,
with --motorcycle, the real validation pair (Middlebury 2014 Motorcycle, which scikit-image
ships) as a scene folder.

    python tools/real_pairs.py [--out data/aloe] [--deb opencv-doc_*.deb | --from DIR]
        [--textures data/textures] [--rows 16] [--seed 0]
    python tools/real_pairs.py --motorcycle [--out data/motorcycle] [--rows 16] [--seed 0]

The recipe: aloeL/R.jpg halved with INTER_AREA, aloeGT.png (pixels at full size,
0 = unknown) with INTER_NEAREST and ×0.5, centre-cropped to 640x400; the LiDAR is `--rows`
rows of the GT at the centres of equal horizontal bands, every 2nd column, plus N(0, 0.1 px)
(`edge.sim.gt_lidar.GtLidarPattern.evenly`). Without --deb or --from it runs
`apt-get download opencv-doc` in a temporary folder and unpacks it with `dpkg -x`.
Aloe is for evaluation only: never train on it or pick a checkpoint by it.

The motorcycle pair (`skimage.data.stereo_motorcycle`: 741x500, GT in pixels, inf = unknown)
is converted to grey and centre-cropped to 640x400 at its own scale (disparities 7-60 px),
with the same LiDAR rows. It is the pair on which runs may be compared and chosen (never
trained on), so that Aloe stays a pair no decision has seen.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import tempfile
from pathlib import Path

import cv2
import numpy as np

from edge_depth.sim.folder import write_pfm
from edge_depth.sim.gt_lidar import GtLidarPattern
from edge_depth.sim.textures import OPENCV_DOC_PHOTOS

DATA_IN_DEB = "usr/share/doc/opencv-doc/examples/data"
SIZE = (640, 400)


def unpack_opencv_doc(deb: Path | None, workdir: Path) -> Path:
    """The opencv-doc examples' data folder, from a .deb (downloaded if None)."""
    if deb is None:
        run = subprocess.run(["apt-get", "download", "opencv-doc"], cwd=workdir,
                             capture_output=True, text=True)
        debs = sorted(workdir.glob("opencv-doc_*.deb"))
        if run.returncode != 0 or not debs:
            raise SystemExit("apt-get download opencv-doc failed (run `apt-get update` first, "
                             f"or pass --deb / --from): {run.stderr.strip()[-200:]}")
        deb = debs[0]
    subprocess.run(["dpkg", "-x", str(deb), str(workdir / "x")], check=True)
    return workdir / "x" / DATA_IN_DEB


def centre_crop(image: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    h, w = image.shape[:2]
    cw, ch = size
    if w < cw or h < ch:
        raise SystemExit(f"image {w}x{h} is smaller than the crop {cw}x{ch}")
    x0, y0 = (w - cw) // 2, (h - ch) // 2
    return image[y0:y0 + ch, x0:x0 + cw]


def build_aloe(src: Path, out: Path, rows: int = 16, seed: int = 0) -> dict:
    """Write the Aloe scene folder; returns its meta.json contents."""
    left = cv2.imread(str(src / "aloeL.jpg"), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(src / "aloeR.jpg"), cv2.IMREAD_GRAYSCALE)
    gt = cv2.imread(str(src / "aloeGT.png"), cv2.IMREAD_UNCHANGED)
    if left is None or right is None or gt is None:
        raise SystemExit(f"{src}: aloeL.jpg, aloeR.jpg and aloeGT.png are needed")
    if gt.ndim == 3:
        gt = gt[..., 0]
    half = (left.shape[1] // 2, left.shape[0] // 2)
    left = centre_crop(cv2.resize(left, half, interpolation=cv2.INTER_AREA), SIZE)
    right = centre_crop(cv2.resize(right, half, interpolation=cv2.INTER_AREA), SIZE)
    gt = centre_crop(cv2.resize(gt.astype(np.float32), half, interpolation=cv2.INTER_NEAREST)
                     * 0.5, SIZE)
    source = "Middlebury Aloe (Debian opencv-doc), halved, centre-cropped 640x400"
    return write_pair(out, left, right, gt, rows, seed, source, evaluation_only=True)


def build_motorcycle(out: Path, rows: int = 16, seed: int = 0) -> dict:
    """Write the motorcycle scene folder from scikit-image's copy; returns its meta.json."""
    from skimage import data

    try:
        left, right, disp = data.stereo_motorcycle()
    except Exception as exc:   # a scikit-image without the files would try to download them
        raise SystemExit(f"scikit-image's stereo_motorcycle is not available here ({exc}); "
                         "scikit-image 0.26 ships it in its wheel") from exc
    left = centre_crop(cv2.cvtColor(left, cv2.COLOR_RGB2GRAY), SIZE)
    right = centre_crop(cv2.cvtColor(right, cv2.COLOR_RGB2GRAY), SIZE)
    gt = centre_crop(np.where(np.isfinite(disp), disp, 0).astype(np.float32), SIZE)
    source = "Middlebury 2014 Motorcycle (scikit-image), grey, centre-cropped 640x400"
    return write_pair(out, left, right, gt, rows, seed, source, evaluation_only=False)


def write_pair(out: Path, left: np.ndarray, right: np.ndarray, gt: np.ndarray, rows: int,
               seed: int, source: str, evaluation_only: bool) -> dict:
    """A scene folder from grey images and GT (0 = unknown), with `rows` LiDAR rows of GT."""
    pattern = GtLidarPattern.evenly(SIZE[1], rows, column_step=2, noise_px=0.1)
    sparse = pattern.sample(gt, np.random.default_rng(seed))
    out.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(out / "left.png"), left)
    cv2.imwrite(str(out / "right.png"), right)
    write_pfm(out / "disp.pfm", np.where(gt > 0, gt, np.inf).astype(np.float32))
    write_pfm(out / "sparse.pfm", sparse)
    meta = dict(source=source,
                lidar=f"{rows} rows of GT, every 2nd column, N(0, 0.1 px), seed {seed}",
                max_gt_disparity_px=float(gt.max()), lidar_points=int((sparse > 0).sum()),
                evaluation_only=evaluation_only)
    (out / "meta.json").write_text(json.dumps(meta, indent=2))
    return meta


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", type=Path, default=None,
                   help="the scene folder (default data/aloe, with --motorcycle data/motorcycle)")
    p.add_argument("--motorcycle", action="store_true",
                   help="build the validation pair from scikit-image instead of Aloe")
    p.add_argument("--deb", type=Path, default=None, help="a downloaded opencv-doc .deb")
    p.add_argument("--from", dest="src", type=Path, default=None,
                   help="an unpacked opencv-doc examples/data folder")
    p.add_argument("--textures", type=Path, default=Path("data/textures"))
    p.add_argument("--rows", type=int, default=16)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    if args.rows < 1:
        p.error("--rows: at least 1")
    if args.motorcycle:
        out = args.out or Path("data/motorcycle")
        meta = build_motorcycle(out, args.rows, args.seed)
        print(f"{out}: Motorcycle 640x400, GT up to {meta['max_gt_disparity_px']:.1f} px, "
              f"{meta['lidar_points']} LiDAR points")
        return 0
    args.out = args.out or Path("data/aloe")
    with tempfile.TemporaryDirectory() as tmp:
        src = args.src or unpack_opencv_doc(args.deb, Path(tmp))
        meta = build_aloe(src, args.out, args.rows, args.seed)
        args.textures.mkdir(parents=True, exist_ok=True)
        copied = 0
        for name in OPENCV_DOC_PHOTOS:
            if (src / name).exists():
                shutil.copy(src / name, args.textures / name)
                copied += 1
    print(f"{args.out}: Aloe 640x400, GT up to {meta['max_gt_disparity_px']:.1f} px, "
          f"{meta['lidar_points']} LiDAR points; {copied} texture photos in {args.textures}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
