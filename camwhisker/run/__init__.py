"""Driving the library over recordings: batch, campaigns of many inputs, overlays.

- :mod:`~camwhisker.run.batch`: a video -> its signal table, sidecar and rest check.
- :mod:`~camwhisker.run.campaign`: many inputs, resumable, skipping finished outputs.
- :mod:`~camwhisker.run.workers`: local processes and the stop signals they share.
- :mod:`~camwhisker.run.overlay`: a video -> the same video annotated.
"""
