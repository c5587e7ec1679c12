"""The compiled loops of :mod:`camwhisker.vision.blobs` (see :mod:`camwhisker.kernels`)."""

import numpy as np

from camwhisker.kernels import kernel


@kernel("i4[:, ::1], i8")
def stats(labels, n):
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
