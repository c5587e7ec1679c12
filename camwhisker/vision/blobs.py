"""Connected components of a binary mask with their statistics.

OpenCV labels the components (cv2.connectedComponents); their area, centroid
and bounding box are gathered in one compiled pass over the labels: the same
numbers as cv2.connectedComponentsWithStats, whose statistics cost more than
the labelling.
"""

from __future__ import annotations

import cv2
import numpy as np

from camwhisker.kernels import blobs as kernels

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
    return Blobs(labels, *kernels.stats(labels, n))
