"""Live processing: a camera (or a file at camera rate) -> the front end -> results within ms.

Modules, in the order the data flows:

- :mod:`~camwhisker.live.cameras`   listing capture devices, stable names, the settings profile
- :mod:`~camwhisker.live.capture`   one source interface: camera, video file, image folder
- :mod:`~camwhisker.live.playback`  a file released on a real-time clock (a camera stand-in)
- :mod:`~camwhisker.live.grabber`   the grabber thread: "latest" / "every", reconnects, fps
- :mod:`~camwhisker.live.record`    recording a session (MJPG AVI + timestamps) for batch
- :mod:`~camwhisker.live.outputs`   JSON lines, UDP (the table: :mod:`camwhisker.io.signals`)
- :mod:`~camwhisker.live.view`      the page in a browser (``--view``): picture, plots, buttons
- :mod:`~camwhisker.live.base`      the robot's base positions over UDP, and their log
- :mod:`~camwhisker.live.contact`   contact fields per row (:mod:`camwhisker.contact.online`)
- :mod:`~camwhisker.live.loop`      the session, reprocessing
  (the core: :mod:`camwhisker.vision.stream`)
"""

from camwhisker.live.loop import LiveConfig, LiveProcessor, LiveSession, reprocess_session, run_live

__all__ = ["LiveConfig", "LiveProcessor", "LiveSession", "reprocess_session", "run_live"]
