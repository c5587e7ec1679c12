"""Live processing: list-cameras, live (a camera or a file at camera rate), replay."""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

from camwhisker.cli.common import (
    CommandError,
    feature_hints,
    features_arg,
    mode_arg,
    sensor_arg,
    springs_arg,
    springs_of,
)
from camwhisker.sensor.file import load_sensor

__all__ = ["add_list_cameras", "add_live", "add_replay"]

#: Port of ``--view`` given without one.
VIEW_PORT = 8765


def _contact_args(p, live: bool) -> None:
    """--calib, --eta-deg and the base positions' options (live: UDP; replay: the log)."""
    p.add_argument("--calib", metavar="CALIB",
                   help="contact calibration (camwhisker calibrate): adds per row the contact "
                        "belief (eq. 1), MF's r and spread and the forces (--springs, default "
                        "the spring model of Table I); with base positions, GM, Z, the fused "
                        "estimate and the contact point (docs/sensor.md, section 6.4)")
    p.add_argument("--eta-deg", type=float, metavar="X",
                   help="the belief's eta as given; default: from the first rest frames")
    if live:
        p.add_argument("--base-udp", type=int, metavar="PORT",
                       help="receive the base position, one JSON datagram {t_s, x_mm} each")
        p.add_argument("--base-host", default="127.0.0.1",
                       help="interface to receive base positions on (default: this host)")
        p.add_argument("--base-poses", action="store_true",
                       help="with --base-udp: the datagrams are poses in space {t_s, x_mm, "
                            "y_mm, z_mm, qw, qx, qy, qz} (docs/sensor.md, section 9): the rows "
                            "add the contact point px_mm..nz; written as OUT.pose.csv")
        p.add_argument("--base-lsl", metavar="NAME",
                       help="instead of --base-udp: the base from the Lab Streaming Layer "
                            "stream NAME, 1 channel (x_mm) or 7 (a pose, as --base-poses), "
                            "stamped on the sender's LSL clock (docs/robots.md)")
    else:
        base = p.add_mutually_exclusive_group()
        base.add_argument("--base-log", metavar="L.csv",
                          help="the base positions: OUT.base.csv of the live session (or a "
                               "stage log t_s,x_mm)")
        base.add_argument("--pose-log", metavar="P.csv",
                          help="the base poses: OUT.pose.csv of the live session (or a pose "
                               "log of section 9): the rows add the contact point in space")
    p.add_argument("--mount", metavar="X,Y,Z,QW,QX,QY,QZ",
                   help="with poses: they are a carrier's (a robot's flange), and this is the "
                        "sensor's pose in its frame")
    p.add_argument("--base-offset-s", type=float, metavar="X",
                   help="t_camera = t_base + X; default: " + (
                       "the sender stamps with this machine's monotonic clock" if live
                       else "0 (the session's base log is on the camera clock)"))


def _mcap_arg(p, live: bool) -> None:
    images = ("the recording's JPEG bytes with --record, the camera's as sent (--raw-mjpg), else "
              "the frames at JPEG quality 90" if live else "the recording's JPEG bytes")
    p.add_argument("--mcap", metavar="FILE.mcap",
                   help="also the rows as ROS 2 messages in an MCAP file, streamed: "
                        "/whisker/signals, /whisker/wrench (forces), /whisker/contact (base "
                        f"poses) and /whisker/image ({images}); docs/robots.md, "
                        "pip install 'camwhisker[ros]'")  # fmt: skip


def _mcap_of(args) -> Path | None:
    """--mcap as a path, checked before the session starts (the extra installed, not the
    table's name)."""
    if not args.mcap:
        return None
    from camwhisker.io.bag import ros_modules

    ros_modules(CommandError)  # a missing extra stops the command before the session
    if Path(args.mcap).resolve() == Path(args.out).resolve():
        raise CommandError(f"--mcap {args.mcap} would overwrite the table --out")
    return Path(args.mcap)


def _lsl_arg(p) -> None:
    p.add_argument("--lsl", metavar="NAME",
                   help="also the rows to a Lab Streaming Layer outlet NAME (one channel per "
                        "numeric column, stamped with the frames' capture times on LSL's "
                        "clock) and the events to NAME-events; docs/robots.md, "
                        "pip install 'camwhisker[lsl]'")


def _check_lsl(args) -> None:
    """pylsl installed where --lsl or --base-lsl is given (before the capture opens)."""
    if args.lsl is not None or args.base_lsl is not None:
        from camwhisker.live.lsl import lsl_module

        lsl_module(CommandError)
    if args.lsl is not None and not args.lsl.strip():
        raise CommandError("--lsl: the stream's name is empty")


def _calib_of(args):
    """The --calib file's calibration (or None), with the checks of its options."""
    if args.eta_deg is not None and not args.eta_deg > 0:
        raise CommandError(f"--eta-deg must be > 0, got {args.eta_deg}")
    lsl = getattr(args, "base_lsl", None)
    base = (getattr(args, "base_udp", None) is not None or getattr(args, "base_log", None)
            or getattr(args, "pose_log", None) or lsl)
    # An LSL stream's channel count says whether it gives poses: checked when it is found.
    poses = getattr(args, "base_poses", False) or getattr(args, "pose_log", None) or lsl
    if getattr(args, "base_poses", False) and args.base_udp is None:
        raise CommandError("--base-poses goes with --base-udp PORT")
    if lsl and (args.base_udp is not None or args.base_offset_s is not None):
        raise CommandError("--base-lsl takes the place of --base-udp, and LSL corrects the "
                           "clocks: no --base-udp or --base-offset-s with it")
    if args.mount and not poses:
        raise CommandError("--mount goes with base poses (" + (
            "--base-poses" if hasattr(args, "base_poses") else "--pose-log") + ")")
    if args.calib is None:
        if base or args.eta_deg is not None:
            raise CommandError("--eta-deg and the base positions need --calib")
        return None
    from camwhisker.contact.calibrate import read_calibration

    return read_calibration(args.calib)


def _mount_of(args):
    """--mount as a Mount (None without it)."""
    if not args.mount:
        return None
    from camwhisker.io.poses import Mount

    return Mount.parse(args.mount)


def _springs_with(args, calib):
    """--springs; with --calib and none given, the spring model of Table I."""
    springs = springs_of(args)
    if springs is None and calib is not None:
        from camwhisker.sensor.springs import suspension_stiffness

        springs = suspension_stiffness()
    return springs


def add_list_cameras(sub) -> None:
    p = sub.add_parser("list-cameras", help="capture devices (V4L2), their stable names and "
                                            "the formats, sizes and frame rates each lists")
    p.add_argument("--all", action="store_true", help="also the nodes that cannot capture")
    p.add_argument(
        "--sysfs",
        default="/sys/class/video4linux",
        metavar="DIR",
        help="video4linux class folder (another tree for tests)",
    )
    p.add_argument("--dev", default="/dev", metavar="DIR", help="device folder (with v4l/by-id)")
    p.set_defaults(func=_run_list_cameras)


def _run_list_cameras(args) -> int:
    from camwhisker.live.cameras import format_camera_list, list_cameras
    from camwhisker.live.modes import camera_modes, format_modes

    cameras = list_cameras(Path(args.sysfs), Path(args.dev), include_metadata=args.all)
    modes = {c.node: format_modes(camera_modes(c.node)) for c in cameras if c.captures}
    print(format_camera_list(cameras, modes))
    return 0 if cameras else 1


def add_live(sub) -> None:
    p = sub.add_parser("live", help="camera (or file at camera rate) -> signals within ms")
    p.add_argument(
        "source", nargs="?", help="camera index, /dev/videoN or by-id name; or a video / folder"
    )
    p.add_argument("--out", metavar="OUT.csv", help="signal table, flushed per row (+ OUT.json)")
    p.add_argument(
        "--keep",
        choices=("latest", "every"),
        default="latest",
        help="latest: only the newest frame, stale ones dropped (control); every: keep all",
    )
    p.add_argument("--record", metavar="SESSION.avi", help="record the frames (MJPG + timestamps)")
    p.add_argument("--udp", type=int, metavar="PORT", help="one JSON datagram per frame")
    p.add_argument("--udp-host", default="127.0.0.1", help="UDP destination (default: this host)")
    p.add_argument("--jsonl", action="store_true", help="one JSON line per frame on stdout")
    p.add_argument(
        "--view",
        type=int,
        nargs="?",
        const=VIEW_PORT,
        metavar="PORT",
        help=f"serve a live view to a browser (port {VIEW_PORT} if none given; 0: any free one)",
    )
    p.add_argument("--view-host", default="127.0.0.1",
                   help="view address (default: this host; off it, the page's URL printed "
                        "at start holds the token it needs)")
    p.add_argument(
        "--playback-fps", type=float, metavar="FPS", help="play a file at this rate, like a camera"
    )
    p.add_argument("--loop", action="store_true", help="loop a played-back file")
    p.add_argument("--frames", type=int, metavar="N", help="stop after N rows (bench: clip length)")
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds")
    p.add_argument("--no-keys", action="store_true", help="no r/d/q keys even on a terminal")
    p.add_argument("--raw-mjpg", action=argparse.BooleanOptionalAction, default=True,
                   help="take the camera's JPEG bytes as sent and decode them with "
                        "libjpeg-turbo (default; OpenCV decodes where the camera sends "
                        "no JPEG)")
    p.add_argument(
        "--no-lock",
        action="store_true",
        help="leave auto white balance and exposure as the camera has them",
    )
    p.add_argument("--exposure", type=float, help="manual exposure (driver units)")
    p.add_argument("--size", metavar="WxH", help="camera: ask for this frame size (default "
                   "1280x720); an error where the camera does not take it")  # fmt: skip
    p.add_argument("--fps", type=float, metavar="F", help="camera: ask for this frame rate "
                   "(default 30); an error where the camera does not take it")  # fmt: skip
    p.add_argument("--bench", action="store_true", help="latency benchmark (one core), then exit")
    _mcap_arg(p, live=True)
    _lsl_arg(p)
    mode_arg(p)
    sensor_arg(p)
    features_arg(p)
    springs_arg(p)
    _contact_args(p, live=True)
    p.set_defaults(func=_run_live)


def _mode_of(args, profile):
    """``profile`` with the size and rate of ``--size WxH`` and ``--fps F``."""
    from dataclasses import replace

    if args.size is not None:
        w, _, h = args.size.lower().partition("x")
        if not (w.isdigit() and h.isdigit() and int(w) > 0 and int(h) > 0):
            raise CommandError(f"--size must be WIDTHxHEIGHT in px, e.g. 1280x720, got "
                               f"{args.size!r}")  # fmt: skip
        profile = replace(profile, width_px=int(w), height_px=int(h))
    if args.fps is not None:
        if not (math.isfinite(args.fps) and args.fps > 0):
            raise CommandError(f"--fps must be positive, got {args.fps}")
        profile = replace(profile, fps=args.fps)
    return profile


def _run_live(args) -> int:
    import logging
    from dataclasses import replace

    from camwhisker.live.cameras import C310_PROFILE
    from camwhisker.live.capture import open_capture
    from camwhisker.live.loop import LiveConfig, LiveSession
    from camwhisker.vision import FrontEndOptions

    if args.bench:
        from camwhisker.bench.live import run_bench

        print(run_bench(args.frames or 150).text())
        return 0
    if not args.source or not args.out:
        raise CommandError("live needs a SOURCE and --out (or --bench)")
    # Replaces the command's warning handler: live logs its own progress at INFO.
    logging.basicConfig(level=logging.INFO, format="camwhisker live: %(message)s", force=True)
    profile = C310_PROFILE
    if args.no_lock:
        profile = replace(profile, auto_wb=None, auto_exposure=None)
    if args.exposure is not None:
        profile = replace(profile, exposure=args.exposure)
    profile = _mode_of(args, profile)
    sensor = load_sensor(args.sensor)
    options = FrontEndOptions(mode=args.mode, features=feature_hints(args, sensor))
    calib = _calib_of(args)
    mount = _mount_of(args)  # before the capture opens: a bad one leaves nothing open
    mcap = _mcap_of(args)
    _check_lsl(args)
    try:
        capture = open_capture(args.source, profile, args.playback_fps, raw_mjpg=args.raw_mjpg,
                               require_mode=args.size is not None or args.fps is not None)
    except OSError as exc:  # a camera that does not take the mode asked for
        raise CommandError(str(exc)) from None
    if args.loop and hasattr(capture, "loop"):
        capture.loop = True
    config = LiveConfig(
        mode=args.keep,
        options=options,
        record=Path(args.record) if args.record else None,
        record_rate_fps=args.playback_fps or profile.fps,
        udp_port=args.udp,
        udp_host=args.udp_host,
        jsonl=args.jsonl,
        controls=False if args.no_keys else None,
        max_frames=args.frames,
        duration_s=args.duration,
        springs=_springs_with(args, calib),
        calib=calib,
        calib_path=args.calib,
        eta_deg=args.eta_deg,
        base_port=args.base_udp,
        base_host=args.base_host,
        base_offset_s=args.base_offset_s,
        base_poses=args.base_poses,
        mount=mount,
        view_port=args.view,
        view_host=args.view_host,
        mcap=mcap,
        lsl=args.lsl,
        base_lsl=args.base_lsl,
    )
    from camwhisker.live.lsl import LslError

    try:
        session = LiveSession(capture, sensor, args.out, config)
    except (OSError, LslError) as exc:
        raise CommandError(str(exc)) from None
    report = session.run()
    print(LiveSession.summary(report), file=sys.stderr)
    for problem in report.problems:
        print(f"camwhisker live: problem: {problem}", file=sys.stderr)
    return 1 if report.failed else 0


def add_replay(sub) -> None:
    p = sub.add_parser("replay", help="a recorded live session -> its signal table again")
    p.add_argument("session", help="SESSION.avi recorded by 'camwhisker live --record'")
    p.add_argument("--out", required=True, metavar="OUT.csv",
                   help="signal table to write (OUT.json beside it)")
    _mcap_arg(p, live=False)
    mode_arg(p)
    sensor_arg(p)
    features_arg(p)
    springs_arg(p)
    _contact_args(p, live=False)
    p.set_defaults(func=_run_replay)


def _run_replay(args) -> int:
    from camwhisker.live.loop import reprocess_session
    from camwhisker.vision import FrontEndOptions

    sensor = load_sensor(args.sensor)
    options = FrontEndOptions(mode=args.mode, features=feature_hints(args, sensor))
    calib = _calib_of(args)
    mcap = _mcap_of(args)
    contact = None
    if calib is not None:
        from camwhisker.live.base import read_base_log, read_pose_log_samples
        from camwhisker.live.contact import RowContact

        mount = _mount_of(args)
        offset = args.base_offset_s or 0.0
        samples = (read_pose_log_samples(args.pose_log, offset) if args.pose_log else
                   read_base_log(args.base_log, offset) if args.base_log else None)

        def contact(frame_s):
            rc = RowContact(calib, frame_s, args.eta_deg, base=samples is not None,
                            poses=bool(args.pose_log), mount=mount)
            for sample in samples or ():
                rc.put(*sample)
            return rc

    elif args.base_offset_s is not None:
        raise CommandError("--base-offset-s needs --calib and --base-log or --pose-log")
    out = reprocess_session(args.session, sensor, args.out, options,
                            _springs_with(args, calib), contact, mcap)
    print(out if mcap is None else f"{out}, {mcap}")
    return 0
