"""A build's geometry from its own footage: bundle adjustment of the sensor file.

:mod:`~camwhisker.geometry.adjust` fits the camera intrinsics and the plate
geometry to tracked image points over a sweep; :mod:`~camwhisker.geometry.sweep`
tracks the points in videos and iterates tracking and adjustment;
:mod:`~camwhisker.geometry.report` writes the fitted sensor file and its report.
"""
