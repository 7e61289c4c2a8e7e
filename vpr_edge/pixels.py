"""SeqSLAM's own front end: grey images downsampled to 64x32 and patch-normalised, compared by the mean
absolute difference (sum of absolute differences in the paper). No model, no codebook."""
from __future__ import annotations

import cv2
import numpy as np

SIZE = (64, 32)     # width, height (SeqSLAM's Nordland setting)
PATCH = 8           # patch normalisation: PATCH x PATCH blocks


def pixel_descriptor(rgb: np.ndarray, size: tuple[int, int] = SIZE, patch: int = PATCH) -> np.ndarray:
    """RGB uint8 (H, W, 3) -> float32 (h*w,): grey, resized (area), every patch x patch block z-scored."""
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    interp = cv2.INTER_AREA if grey.shape[1] >= size[0] else cv2.INTER_LINEAR
    x = cv2.resize(grey, size, interpolation=interp).astype(np.float32)
    h, w = size[1] // patch, size[0] // patch
    blocks = x[: h * patch, : w * patch].reshape(h, patch, w, patch)
    mean = blocks.mean(axis=(1, 3), keepdims=True)
    std = blocks.std(axis=(1, 3), keepdims=True)
    return ((blocks - mean) / np.maximum(std, 1e-3)).reshape(-1).astype(np.float32)


def sad_similarity(queries: np.ndarray, refs: np.ndarray, chunk: int = 16) -> np.ndarray:
    """(Q, D) and (R, D) descriptors -> (Q, R) similarity = minus the mean absolute difference."""
    out = np.empty((len(queries), len(refs)), np.float32)
    for i in range(0, len(queries), chunk):
        out[i:i + chunk] = -np.abs(queries[i:i + chunk, None, :] - refs[None, :, :]).mean(axis=2)
    return out
