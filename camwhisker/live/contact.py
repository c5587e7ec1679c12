"""Contact in the live rows: the per-frame fields, their table cells and message values.

:class:`RowContact` wraps :class:`~camwhisker.contact.online.OnlineContact` for a
session (live) or a recording (replay): it feeds it the base positions received
by each frame's capture time and the session's first rest reference, and formats
the fields for the table and the JSON message alike, so a message and its row agree.
"""

from __future__ import annotations

import math

from camwhisker.contact.online import BaseFeed, BaseTrack, OnlineContact, PoseTrack
from camwhisker.vision.stream import Frame
from camwhisker.vision.tracker import FrameResult

__all__ = ["FORMATS", "RowContact"]

#: Cell format of each field (the message rounds to the same digits).
FORMATS = {"contact_b": ".4f", "z_score": ".3f", "z_combined": ".3f", "p_gm_good": ".4f",
           "nx": ".6f", "ny": ".6f", "nz": ".6f"}  # a unit vector: 1e-6 is 0.00006 deg
_DEFAULT_FORMAT = ".4f"  # mm and mm/s: 0.1 um, far below any estimate's noise


class RowContact:
    """Per-row contact fields for a stream of (frame, result) rows.

    Parameters
    ----------
    calib : Calibration, optional
    frame_s : float
        The camera's frame period (s).
    eta_deg : float, optional
        Given eta; default from the first rest reference's frames.
    base : bool
        Whether base positions come (:meth:`put`).
    poses : bool
        With ``base``: they are poses in space (the rows add the contact point in W).
    mount : camwhisker.io.poses.Mount, optional
        With ``poses``: the sensor's pose in the frame of the carrier the poses are of.
    """

    def __init__(self, calib, frame_s: float, eta_deg: float | None = None, base: bool = False,
                 poses: bool = False, mount=None):  # fmt: skip
        track = (PoseTrack(mount) if poses else BaseTrack()) if base else None
        self.feed = BaseFeed(track) if base else None
        self.online = OnlineContact(calib, frame_s, eta_deg, track)
        self.fields = self.online.fields()

    def put(self, t_s: float, value, received_s: float) -> None:
        """A base position x_mm, or pose (its seven numbers), at t_s (camera clock, s) and
        when it was received (camera clock)."""
        self.feed.put(t_s, value, received_s)

    def update(self, frame: Frame, r: FrameResult, rest_log: list) -> dict:
        """The fields for one row; ``rest_log`` the stream's rest references so far."""
        t = round(frame.t_s, 6)  # as the table and the timestamps file hold it
        if self.feed is not None:
            self.feed.advance(t)
        rest = (rest_log[0].frame, rest_log[0].frames_used) if rest_log else None
        # The pose as the table holds it, so a command run on the table sees the same numbers.
        phi, dz = (float(format(v, ".5f")) for v in (r.phi_deg, r.dz_mm))
        theta = float(format(r.theta_deg, ".3f"))
        return self.online.update(frame.index, t, phi, dz, bool(r.ok), rest, theta)

    def cells(self, values: dict) -> list[str]:
        """The fields as table cells (NaN: empty)."""
        return [_cell(name, values[name]) for name in self.fields]

    def message(self, values: dict, cells: list[str] | None = None) -> dict:
        """The fields as message values (NaN: null), rounded as the cells; ``cells``: the
        row's :meth:`cells` where they are made already (each is formatted once)."""
        out = {}
        for name, cell in zip(self.fields, self.cells(values) if cells is None else cells,
                              strict=True):
            out[name] = cell if name == "doubt" else (None if cell == "" else
                                                      (int(cell) if name == "contact"
                                                       else float(cell)))
        return out

    def describe(self) -> dict:
        """For the sidecar: eta and where it came from, the fields, base counts."""
        out = {"eta_deg": self.online.eta_deg, "eta_from": self.online.eta_from,
               "smooth_half_frames": self.online.half_frames, "fields": list(self.fields)}
        if self.feed is not None:
            out["base_positions"] = len(self.feed.samples)
            out["base_out_of_order"] = self.feed.out_of_order
        if self.feed is not None and isinstance(self.feed.track, PoseTrack):
            out["base_turn_deg"] = self.feed.track.turn_deg
        return out


def _cell(name: str, value) -> str:
    if name == "doubt":
        return value
    if name == "contact":
        return str(int(value))
    if value is None or not math.isfinite(value):
        return ""
    return format(value, FORMATS.get(name, _DEFAULT_FORMAT))
