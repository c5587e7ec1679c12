"""camwhisker: plate pose, contact distance and shape from a camera-based whisker sensor."""

__version__ = "0.1.0"
