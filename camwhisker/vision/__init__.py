"""The vision front end: frames -> tracked features -> plate pose (dz, phi, theta).

Modules, in the order the data flows:

- :mod:`~camwhisker.vision.colour`  white balance from the cloth, eq. (1), colour unmixing
- :mod:`~camwhisker.vision.detect`  finding the features without help
- :mod:`~camwhisker.vision.hints`   the user's rough positions, where detection needs help
- :mod:`~camwhisker.vision.blobs`   connected components and their statistics
- :mod:`~camwhisker.vision.lk`      Lucas-Kanade with template update and drift correction
- :mod:`~camwhisker.vision.tip`     the magnifier tip by colour and edge
- :mod:`~camwhisker.vision.pose`    the pose fit through the exact camera model
- :mod:`~camwhisker.vision.paper`   the paper's eqs. (2)-(7) as printed
- :mod:`~camwhisker.vision.tracker` the stateful front end (start, update)

The per-pixel loops (the corners' LK and template warp, the colour-share
patches, the tip's brightness, ray edges and rim fit, blob statistics) are
numba kernels in :mod:`camwhisker.kernels`, compiled when the package installs,
each called by the Python function here that states its contract; everything
else is numpy and OpenCV.
"""

from camwhisker.vision.detect import FeaturesNotFound
from camwhisker.vision.tracker import FrameResult, FrontEnd, FrontEndOptions

__all__ = ["FeaturesNotFound", "FrameResult", "FrontEnd", "FrontEndOptions"]
