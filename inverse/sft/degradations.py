"""Camera-like degradations of rendered frames: illumination drift, blur, noise, JPEG.

Applied in the order light reaches a camera: scene illumination (gain and offset drifting
linearly over the sequence), optical blur, sensor noise, then compression.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np


@dataclass(frozen=True)
class Degradations:
    """noise_sigma: Gaussian noise std as a fraction of full scale (2/255 ≈ 0.0078);
    blur_sigma: Gaussian blur std [px] (0: none); jpeg_quality: JPEG round trip quality in
    [1, 100] or None; gain_drift: image gain goes from 1 to 1 + gain_drift over the sequence;
    offset_drift: intensity offset goes from 0 to offset_drift (fraction of full scale).
    """

    noise_sigma: float = 2.0 / 255.0
    blur_sigma: float = 0.5
    jpeg_quality: int | None = 80
    gain_drift: float = 0.1
    offset_drift: float = 0.02

    def __post_init__(self):
        if self.noise_sigma < 0:
            raise ValueError(f"noise_sigma must be >= 0, got {self.noise_sigma}")
        if self.blur_sigma < 0:
            raise ValueError(f"blur_sigma must be >= 0, got {self.blur_sigma}")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            raise ValueError(f"jpeg_quality must be in [1, 100] or None, got {self.jpeg_quality}")
        if self.gain_drift <= -1:
            raise ValueError(f"gain_drift must be > -1, got {self.gain_drift}")

    def apply(
        self, image: np.ndarray, t: float, rng: np.random.Generator
    ) -> tuple[np.ndarray, bytes | None]:
        """Degrade a BGR uint8 frame at sequence time t ∈ [0, 1].

        Returns the degraded uint8 frame and, with JPEG, the encoded bytes it was decoded from
        (so a .jpg file can hold exactly this frame).
        """
        x = image.astype(np.float32) / 255.0
        x = (1.0 + t * self.gain_drift) * x + t * self.offset_drift
        if self.blur_sigma > 0:
            x = cv2.GaussianBlur(x, (0, 0), self.blur_sigma)
        if self.noise_sigma > 0:
            x = x + rng.normal(0.0, self.noise_sigma, size=x.shape).astype(np.float32)
        out = np.clip(np.rint(x * 255.0), 0, 255).astype(np.uint8)
        if self.jpeg_quality is None:
            return out, None
        ok, encoded = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, int(self.jpeg_quality)])
        if not ok:
            raise RuntimeError("OpenCV failed to encode a JPEG frame")
        return cv2.imdecode(encoded, cv2.IMREAD_COLOR), encoded.tobytes()


CLEAN = Degradations(noise_sigma=0.0, blur_sigma=0.0, jpeg_quality=None, gain_drift=0.0,
                     offset_drift=0.0)
