"""The sensor as built: its file, camera, plate, forward model and springs.

- :mod:`~camwhisker.sensor.file`: the sensor file (docs/sensor.md section 3), typed and checked.
- :mod:`~camwhisker.sensor.camera`: pinhole and distortion: project, unproject.
- :mod:`~camwhisker.sensor.plate`: pose -> the features' 3-D points -> pixels.
- :mod:`~camwhisker.sensor.model`: the forward model and its Jacobians for the pose fit.
- :mod:`~camwhisker.sensor.polygon`: image polygons' area and centroid, and its derivative.
- :mod:`~camwhisker.sensor.springs`: the serpentine springs' stiffness and its value type.
"""
