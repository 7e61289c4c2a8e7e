"""Bringing a frame to a model's input size: the policies (stretch, pad, crop) and which tap cells see the image."""
from __future__ import annotations

import cv2
import numpy as np

RESIZE = {
    "stretch": "resize to the model's input whatever the image's aspect (the default)",
    "pad": "keep the aspect: resize to fit inside the input, pad the rest with the normalisation mean (zero input)",
    "crop": "keep the aspect: resize to cover the input, cut the centre",
}


def _scaled(shape: tuple[int, ...], size: tuple[int, int], policy: str) -> tuple[int, int]:
    """(width, height) an image of ``shape`` (H, W, ...) is resized to before padding or cropping."""
    (w, h), (iw, ih) = size, (shape[1], shape[0])
    if policy == "stretch" or iw * h == ih * w:
        return w, h
    if (policy == "pad") == (iw * h > ih * w):   # pad a wide image / crop a tall one: match the widths
        return w, max(1, round(ih * w / iw))
    return max(1, round(iw * h / ih)), h


def fit_to_input(rgb: np.ndarray, size: tuple[int, int], policy: str, fill: np.ndarray) -> np.ndarray:
    """RGB uint8 (H, W, 3) -> uint8 (height, width, 3) at ``size`` = (width, height) by ``policy`` (``RESIZE``):
    area-averaged when shrinking, bilinear when enlarging; ``pad`` fills with ``fill`` (3,) uint8."""
    (w, h), iw = size, rgb.shape[1]
    tw, th = _scaled(rgb.shape, size, policy)
    x = cv2.resize(rgb, (tw, th), interpolation=cv2.INTER_AREA if iw > tw else cv2.INTER_LINEAR)
    if (tw, th) == (w, h):
        return x
    if policy == "crop":
        top, left = (th - h) // 2, (tw - w) // 2
        return np.ascontiguousarray(x[top:top + h, left:left + w])
    top, left = (h - th) // 2, (w - tw) // 2
    return cv2.copyMakeBorder(x, top, h - th - top, left, w - tw - left, cv2.BORDER_CONSTANT,
                              value=[int(v) for v in fill])


def content_cells(shape: tuple[int, ...], size: tuple[int, int], grid: tuple[int, int]) -> np.ndarray:
    """Which cells of a (grid_width x grid_height) tap grid see the image under ``pad`` -> (N,) bool in
    row-major grid order: cells whose centre lies in the resized image, not in the padding (at least the
    cell at the image's centre)."""
    (w, h), (gw, gh) = size, grid
    tw, th = _scaled(shape, size, "pad")
    left, top = (w - tw) // 2, (h - th) // 2
    cx = (np.arange(gw) + 0.5) * w / gw
    cy = (np.arange(gh) + 0.5) * h / gh
    inside = ((cy >= top) & (cy < top + th))[:, None] & ((cx >= left) & (cx < left + tw))[None, :]
    if not inside.any():
        inside[min(int((top + th / 2) * gh / h), gh - 1), min(int((left + tw / 2) * gw / w), gw - 1)] = True
    return inside.reshape(-1)
