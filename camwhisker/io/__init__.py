"""Data in and out: frame sources, video out, the signal table, pose and force logs.

- :mod:`~camwhisker.io.sources`: video files, image folders and recorded sessions as frames.
- :mod:`~camwhisker.io.video_out`: annotated video written through a real encoder.
- :mod:`~camwhisker.io.signals`: the signal table (docs/sensor.md section 6) and its sidecar.
- :mod:`~camwhisker.io.poses`: pose logs (docs/sensor.md section 9) and mounts.
- :mod:`~camwhisker.io.bag`: ROS 2 messages in MCAP files: the signal table out, pose
  and stage logs in (docs/robots.md).
- :mod:`~camwhisker.io.forcelog`: a force-torque sensor's log (the paper's test 2).
"""
