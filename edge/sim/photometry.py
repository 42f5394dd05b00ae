"""Camera response for rendered views: what makes two real cameras see the same surface
differently — exposure and gain, gamma, vignetting, defocus blur, noise (read + shot) and JPEG.
The pair shares a base response; each view departs from it a little, as two real sensors do.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np


@dataclass(frozen=True)
class CameraResponse:
    """exposure: the mean grey level the pair's auto-exposure aims at (radiance is scaled so
    that the left view's mean lands there; the right view's gain differs a little); gamma:
    output = 255 (x / 255)^(1 / gamma);
    vignetting: relative fall-off at the corners; blur_sigma_px; read_noise (grey levels);
    shot_noise (grey levels at full scale); jpeg_quality 0 = none."""

    exposure: float
    gamma: float
    vignetting: float
    blur_sigma_px: float
    read_noise: float
    shot_noise: float
    jpeg_quality: int

    @classmethod
    def random(cls, rng: np.random.Generator) -> CameraResponse:
        return cls(exposure=float(rng.uniform(60, 160)), gamma=float(rng.uniform(0.8, 1.4)),
                   vignetting=float(rng.uniform(0, 0.35)),
                   blur_sigma_px=float(rng.uniform(0, 1.0)),
                   read_noise=float(rng.uniform(0.3, 3.0)), shot_noise=float(rng.uniform(0, 3)),
                   jpeg_quality=int(rng.integers(50, 96)) if rng.random() < 0.3 else 0)

    def clean(self) -> CameraResponse:
        """This response at its cleanest: gamma 1, no vignetting, blur or JPEG, read noise
        0.5 (the exposure kept)."""
        return replace(self, gamma=1.0, vignetting=0.0, blur_sigma_px=0.0, read_noise=0.5,
                       shot_noise=0.0, jpeg_quality=0)

    def for_view(self, view: str, rng: np.random.Generator,
                 spread: float = 1.0) -> CameraResponse:
        """This response as one camera of the pair sees it: gain within ±12 %, gamma ±6 %,
        blur ±0.3 px, vignetting ±0.05, each range times `spread` (left and right draw
        independently; the same draws for any spread, so a seed keeps its scene)."""
        def draw(low: float, high: float, centre: float) -> float:
            value = float(rng.uniform(low, high))  # as rendered before `spread` (bit-exact)
            return value if spread == 1.0 else centre + (value - centre) * spread

        return replace(self, exposure=self.exposure * draw(0.88, 1.12, 1.0),
                       gamma=self.gamma * draw(0.94, 1.06, 1.0),
                       blur_sigma_px=max(0.0, self.blur_sigma_px + draw(-.3, .3, 0.0)),
                       vignetting=max(0.0, self.vignetting + draw(-.05, .05, 0.0)))


def apply_camera(radiance: np.ndarray, response: CameraResponse, rng: np.random.Generator,
                 reference_mean: float) -> np.ndarray:
    """(H, W) radiance → (H, W) uint8 image through the camera's response; `reference_mean`
    is the mean radiance the auto-exposure metered (the left view's, for both)."""
    h, w = radiance.shape
    v, u = np.mgrid[0:h, 0:w].astype(np.float32)
    r2 = ((u - w / 2) ** 2 + (v - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    gain = response.exposure / max(reference_mean, 1e-3)
    image = radiance.astype(np.float32) * gain * (1 - response.vignetting * r2)
    if response.blur_sigma_px > 0.05:
        image = cv2.GaussianBlur(image, (0, 0), response.blur_sigma_px)
    image = 255.0 * (np.clip(image, 0, 255) / 255.0) ** (1.0 / response.gamma)
    shot = response.shot_noise * np.sqrt(image / 255.0)
    image = image + rng.standard_normal(image.shape).astype(np.float32) \
        * np.sqrt(response.read_noise ** 2 + shot ** 2)
    image = np.clip(np.rint(image), 0, 255).astype(np.uint8)
    if response.jpeg_quality:
        ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, response.jpeg_quality])
        image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    return image
