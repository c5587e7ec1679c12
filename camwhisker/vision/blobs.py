"""Connected components of a binary mask with their statistics.

OpenCV labels the components (cv2.connectedComponents); their area, centroid
and bounding box are gathered in one compiled pass over the labels: the same
numbers as cv2.connectedComponentsWithStats, whose statistics cost more than
the labelling.
"""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit

__all__ = ["Blobs", "blobs"]


class Blobs:
    """Components 1..n of a mask: ``labels`` (h, w) int32 (0 = background),
    ``area`` (n,), ``centroid`` (n, 2) as (x, y), ``box`` (n, 4) as (x, y,
    width, height); row k describes label k + 1."""

    def __init__(self, labels, area, centroid, box):
        self.labels, self.area, self.centroid, self.box = labels, area, centroid, box

    def __len__(self) -> int:
        return len(self.area)


def blobs(mask: np.ndarray) -> Blobs:
    """8-connected components of a uint8 mask (non-zero = inside)."""
    n, labels = cv2.connectedComponents(mask, connectivity=8)
    return Blobs(labels, *_stats(labels, n))


@njit(cache=True, nogil=True, error_model="numpy")
def _stats(labels, n):
    area = np.zeros(n - 1)
    sx = np.zeros(n - 1)
    sy = np.zeros(n - 1)
    box = np.empty((n - 1, 4), np.int64)
    box[:, :2] = labels.shape[1] + labels.shape[0]
    box[:, 2:] = -1
    for i in range(labels.shape[0]):
        for j in range(labels.shape[1]):
            k = labels[i, j] - 1
            if k >= 0:
                area[k] += 1
                sx[k] += j
                sy[k] += i
                box[k, 0] = min(box[k, 0], j)
                box[k, 1] = min(box[k, 1], i)
                box[k, 2] = max(box[k, 2], j)
                box[k, 3] = max(box[k, 3], i)
    centroid = np.empty((n - 1, 2))
    centroid[:, 0], centroid[:, 1] = sx / area, sy / area
    box[:, 2:] -= box[:, :2] - 1
    return area, centroid, box
