"""A build's own numbers: its geometry, its springs, and the paper's accuracy tests.

- :mod:`~camwhisker.calibration.adjust`: bundle adjustment of camera intrinsics and plate geometry.
- :mod:`~camwhisker.calibration.sweep`: tracking a sweep's videos, iterated with the adjustment.
- :mod:`~camwhisker.calibration.report`: the fitted sensor file and its report.
- :mod:`~camwhisker.calibration.springs_fit`: k_z and k_phi against a force-torque log.
- :mod:`~camwhisker.calibration.springfile`: the springs file written and read.
- :mod:`~camwhisker.calibration.validate`: applied against measured phi or dz (Fig. 6 A/B).

The contact calibration (GM, sigma_GM, the MF table) is :mod:`camwhisker.contact.calibrate`.
"""

__all__ = ["MAX_ROUNDS"]

#: Rounds of tracking and adjustment at most (calibration.sweep): the tip's measurement places
#: the model's rim and rod, so each round's fit measures it better (~0.6x the error). Here, so
#: that the command line reads it without importing the adjustment.
MAX_ROUNDS = 6
