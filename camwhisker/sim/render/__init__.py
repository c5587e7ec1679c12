"""The renderer: a build's frames with their truth, as its webcam would film them.

- :mod:`~camwhisker.sim.render.render`: one frame of a pose; :mod:`~camwhisker.sim.render.video`
  writes frames through a real encoder.
- :mod:`~camwhisker.sim.render.builds`: hand builds that differ from the nominal file.
- :mod:`~camwhisker.sim.render.scenarios`, :mod:`~camwhisker.sim.render.samples`: the bundled
  sample videos; :mod:`~camwhisker.sim.render.experiment`: a stage experiment filmed.
- :mod:`~camwhisker.sim.render.artefacts`: a webcam's artefacts.
- :mod:`~camwhisker.sim.render.bound`: the Cramer-Rao bound on the pose.
"""
