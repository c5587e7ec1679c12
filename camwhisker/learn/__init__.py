"""A learned time-series estimator: windows of a table's input columns -> its target columns.

- :mod:`~camwhisker.learn.series`: tables read and checked, targets encoded (angles on the
  circle), normalisation, windows that never span two tables, the split by table.
- :mod:`~camwhisker.learn.net`: the network (torch, imported only here).
- :mod:`~camwhisker.learn.train`: the training loop, the best epoch kept.
- :mod:`~camwhisker.learn.modeldir`: the model directory (docs/learn.md): weights (npz, no
  pickle) with their SHA-256, and a JSON config.
- :mod:`~camwhisker.learn.predict`: a table's predictions, one row per input row; rows with
  gaps, each run of usable rows on its own.
- :mod:`~camwhisker.learn.sensor`: our sensor's runs as tables (phi, dz, theta, base travel
  -> r), and a model's r for a contact table (``contact --learned``).

The core package imports without torch; this package needs it only to train and predict
(``pip install 'camwhisker[learn]'``).
"""
