"""Contact back end: GM (eq. 8), MF (eqs. 9-10), Z (eq. 11), fusion, shape (eq. 12).

Also the stage log and its clock (:mod:`~camwhisker.contact.stage`,
:mod:`~camwhisker.contact.clock`), the contact calibration
(:mod:`~camwhisker.contact.calibrate`), the per-row pipeline and its online form, and the
contact belief without a stage log; :mod:`~camwhisker.contact.space` places contacts in 3-D
from a pose log (docs/sensor.md section 9).
"""
