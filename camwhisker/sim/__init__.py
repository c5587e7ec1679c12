"""Simulators with known truth: the whisker's mechanics and the camera's renderer.

They may import any package of the library; no package of the library imports them.

- :mod:`~camwhisker.sim.mechanics`: quasi-static stage experiments, objects, texture.
- :mod:`~camwhisker.sim.render`: scenarios and builds rendered to webcam video with truth.
"""
