"""What the contacts add up to: surfels, the object behind them, texture.

- :mod:`~camwhisker.percept.surfels`: contact rows as oriented surface points.
- :mod:`~camwhisker.percept.percepts`: wall, cylinder, box corner or nothing, with intervals.
- :mod:`~camwhisker.percept.solids`: plane, sphere, cylinder or nothing in 3-D (section 9).
- :mod:`~camwhisker.percept.texture`: a texture's gap and amplitude from sliding over it.
- :mod:`~camwhisker.percept.ringing`: the whisker's first mode from its free ringing.
"""
