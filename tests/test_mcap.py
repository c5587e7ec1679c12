"""MCAP with ROS 2 messages (docs/robots.md): batch --mcap writes the signal table as
messages that decode to the table's values, and pose and stage logs read from a bag's
topic give what their CSVs give, with errors that name the file, topic and type."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer as McapWriter
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer

from camwhisker.cli import main
from camwhisker.contact.stage import StageLogError, read_stage_log
from camwhisker.files.tables import read_columns
from camwhisker.io.bag import write_signal_bag
from camwhisker.io.poses import PoseLogError, read_pose_log

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT / "sample_frames"
SPACE = SAMPLES / "space"

_SEP = "=" * 80
_TAIL = f"""{_SEP}
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
{_SEP}
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
{_SEP}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{_SEP}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""
POSE_STAMPED = f"""std_msgs/Header header
geometry_msgs/Pose pose
{_SEP}
MSG: geometry_msgs/Pose
geometry_msgs/Point position
geometry_msgs/Quaternion orientation
{_TAIL}"""
POINT_STAMPED = f"std_msgs/Header header\ngeometry_msgs/Point point\n{_TAIL}"
TRANSFORM_STAMPED = f"""std_msgs/Header header
string child_frame_id
geometry_msgs/Transform transform
{_SEP}
MSG: geometry_msgs/Transform
geometry_msgs/Point translation
geometry_msgs/Quaternion rotation
{_TAIL}"""
DEFINITIONS = {"pose": ("PoseStamped", POSE_STAMPED), "point": ("PointStamped", POINT_STAMPED),
               "transform": ("TransformStamped", TRANSFORM_STAMPED)}


def _messages(path: Path) -> dict[str, list]:
    """Each topic's (schema name, log time, decoded message), in log-time order."""
    out: dict[str, list] = {}
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        for schema, channel, message, msg in reader.iter_decoded_messages():
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            out.setdefault(channel.topic, []).append((schema.name, message.log_time, msg))
    return out


def _ns(stamp) -> int:
    return stamp.sec * 10**9 + stamp.nanosec


def _bag_of_log(path: Path, log: Path, topic: str, kind: str = "pose", swap: int = -1) -> Path:
    """A bag of PoseStamped (``kind`` "pose"), TransformStamped or PointStamped messages
    from a CSV log in mm: metres in the bag, the stamp from round(t_s * 1e9); ``swap`` >= 0
    swaps that message's stamp with the next one's (a bag out of order)."""
    cols = read_columns(log)
    ns = [round(t * 1e9) for t in cols["t_s"]]
    if swap >= 0:
        ns[swap], ns[swap + 1] = ns[swap + 1], ns[swap]
    with open(path, "wb") as fh:
        w = Writer(fh)
        name, definition = DEFINITIONS[kind]
        schema = w.register_msgdef(f"geometry_msgs/msg/{name}", definition)
        for i, t in enumerate(ns):
            header = {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "world"}
            xyz = {k: cols[f"{k}_mm"][i] / 1000.0 if f"{k}_mm" in cols else 0.0 for k in "xyz"}
            q = {k: cols[f"q{k}"][i] for k in "wxyz"} if kind != "point" else None
            body = {"point": {"point": xyz}, "pose": {"pose": {"position": xyz, "orientation": q}},
                    "transform": {"child_frame_id": "flange", "transform": {
                        "translation": xyz, "rotation": q}}}[kind]  # fmt: skip
            w.write_message(topic, schema, {"header": header, **body}, log_time=i, sequence=i)
        w.finish()
    return path


def test_batch_writes_the_table_as_ros2_messages(tmp_path, capsys):
    springs = tmp_path / "springs.toml"
    springs.write_text("[stiffness]\nk_z_n_per_mm = 0.05\nk_phi_nmm_per_rad = 20.0\n")
    out, bag = tmp_path / "T.csv", tmp_path / "T.mcap"
    assert main(["batch", str(SAMPLES / "nominal_mjpg.avi"), "--sensor",
                 str(SAMPLES / "nominal_mjpg.sensor.toml"), "--out", str(out), "--mcap", str(bag),
                 "--springs", str(springs), "--quiet"]) == 0  # fmt: skip
    assert str(bag) in capsys.readouterr().out
    header = out.read_text().splitlines()[0].split(",")
    table = read_columns(out, tuple(c for c in header if c != "note"))
    n = table["t_s"].size
    assert n == 12  # the sample's 12 frames
    topics = _messages(bag)
    assert sorted(topics) == ["/whisker/signals", "/whisker/wrench"]
    signals = topics["/whisker/signals"]
    assert len(signals) == n and {s for s, _, _ in signals} == {"camwhisker_msgs/msg/Signals"}
    for i, (_, log_ns, msg) in enumerate(signals):
        # Exact: the stamp is integer nanoseconds, the table's t_s has 6 decimals.
        assert _ns(msg.header.stamp) == log_ns == round(table["t_s"][i] * 1e9)
        assert _ns(msg.header.stamp) / 10**9 == table["t_s"][i]
        assert msg.header.frame_id == "whisker"
        assert msg.frame == int(table["frame"][i]) and msg.ok == (table["ok"][i] == 1)
        for c in header:
            if c not in ("frame", "ok", "t_s", "note"):
                # Exact, NaN to NaN: the bag holds the CSV's printed values (fz_mN as fz_mn).
                np.testing.assert_array_equal(getattr(msg, c.lower()), table[c][i], err_msg=c)
    assert sum(math.isnan(m.theta_deg) for _, _, m in signals) == 3  # frames 0-2 at rest
    wrench = topics["/whisker/wrench"]
    have = np.isfinite(table["fz_mN"]) & np.isfinite(table["mb_Nmm"])
    assert len(wrench) == int(have.sum()) == 12  # every row is trusted here
    for (s, log_ns, msg), i in zip(wrench, np.flatnonzero(have), strict=True):
        assert s == "geometry_msgs/msg/WrenchStamped" and log_ns == signals[i][1]
        f, m = msg.wrench.force, msg.wrench.torque
        # force.z is the printed -fz_mN / 1000 exactly (the load pushes along -z_S): the same
        # division of the same value.
        assert (f.x, f.y, f.z) == (0.0, 0.0, -table["fz_mN"][i] / 1000.0)
        th = math.radians(table["theta_deg"][i])
        if math.isnan(th):
            assert (m.x, m.y, m.z) == (0.0, 0.0, 0.0)  # no direction at phi under 0.6 deg
            continue
        # 1e-12 relative: only cos^2 + sin^2 rounding; the axis is z x (cos psi, sin psi, 0),
        # psi = theta + 180 deg, the way the load leans the whisker: (sin, -cos, 0).
        assert math.hypot(m.x, m.y) == pytest.approx(table["mb_Nmm"][i] / 1000.0, rel=1e-12)
        assert math.sin(th) * m.x - math.cos(th) * m.y == pytest.approx(math.hypot(m.x, m.y),
                                                                        rel=1e-12)
        assert m.z == 0.0


def test_contact_from_a_pose_bag_equals_the_csv(tmp_path, capsys):
    log = SPACE / "h+0run0.pose.csv"
    bag = _bag_of_log(tmp_path / "poses.mcap", log, "/base")
    common = ["contact", "--signals", str(SPACE / "h+0run0.signals.csv"), "--calib",
              str(SPACE / "calib.toml")]  # fmt: skip
    assert main([*common, "--pose", str(log), "--out", str(tmp_path / "csv.csv")]) == 0
    assert main([*common, "--pose", f"{bag}:/base", "--out", str(tmp_path / "bag.csv")]) == 0
    # Exact text: mm -> m -> mm returns every position of this log to its bits (x / 1000
    # * 1000 == x for all 3 x 1848 values) and the stamps are its 8 decimals in ns.
    text = (tmp_path / "csv.csv").read_text()
    assert (tmp_path / "bag.csv").read_text() == text
    assert len(text.splitlines()) == 2713  # a row per signal row, and the header
    poses, ref = read_pose_log(f"{bag}:/base"), read_pose_log(log)
    assert poses.source == f"{bag}:/base"
    np.testing.assert_array_equal(poses.t_s, ref.t_s)
    np.testing.assert_array_equal(poses.p_mm, ref.p_mm)
    tf = _bag_of_log(tmp_path / "tf.mcap", log, "/flange", "transform")
    poses = read_pose_log(f"{tf}:/flange")
    # Exact, as above; the quaternions pass through unchanged, then normalised as a CSV's.
    for a, b in ((poses.t_s, ref.t_s), (poses.p_mm, ref.p_mm), (poses.quat, ref.quat)):
        np.testing.assert_array_equal(a, b)


def test_a_stage_log_from_a_bag_of_points(tmp_path):
    log = SAMPLES / "experiment" / "bottle_left.stage.csv"
    bag = _bag_of_log(tmp_path / "stage.mcap", log, "/stage/x", "point")
    got, ref = read_stage_log(f"{bag}:/stage/x"), read_stage_log(log)
    assert got.t_s.size == ref.t_s.size == 1192
    np.testing.assert_array_equal(got.t_s, ref.t_s)  # the stamps are the 8 decimals in ns
    # 1e-12 mm: metres and back may move the last bit of a position, nothing more.
    np.testing.assert_allclose(got.x_mm, ref.x_mm, rtol=0, atol=1e-12)
    assert got.source == f"{bag}:/stage/x"


def test_bad_bags_are_named(tmp_path, capsys):
    log = SPACE / "h+0run0.pose.csv"
    bag = _bag_of_log(tmp_path / "poses.mcap", log, "/base")
    rc = main(["contact", "--signals", str(SPACE / "h+0run0.signals.csv"), "--calib",
               str(SPACE / "calib.toml"), "--pose", f"{bag}:/nope", "--out",
               str(tmp_path / "c.csv")])  # fmt: skip
    assert rc == 2
    assert f"{bag}:/nope: no topic /nope in the bag; it has: /base" in capsys.readouterr().err
    signals = write_signal_bag(tmp_path / "s.mcap", {"t_s": np.array([0.0, 0.5]),
                                                     "phi_deg": np.array([1.0, np.nan])})
    with pytest.raises(PoseLogError, match="messages of type camwhisker_msgs/msg/Signals, "
                       "expected one of geometry_msgs/msg/PoseStamped, "
                       "geometry_msgs/msg/TransformStamped"):  # fmt: skip
        read_pose_log(f"{signals}:/whisker/signals")
    with pytest.raises(StageLogError, match="geometry_msgs/msg/PointStamped"):
        read_stage_log(f"{signals}:/whisker/signals")
    with pytest.raises(PoseLogError, match=r"poses\.mcap: an MCAP bag: name the topic"):
        read_pose_log(bag)
    # Two stamps swapped: the CSV's check, naming the bag, the topic and the message.
    swapped = _bag_of_log(tmp_path / "swapped.mcap", log, "/base", swap=4)
    with pytest.raises(PoseLogError, match=r"swapped\.mcap:/base: row 6, column t_s: time "
                       "goes backwards"):  # fmt: skip
        read_pose_log(f"{swapped}:/base")
    empty = tmp_path / "empty.mcap"
    with open(empty, "wb") as fh:
        w = McapWriter(fh)
        w.start(profile="ros2")
        sid = w.register_schema("geometry_msgs/msg/PoseStamped", "ros2msg",
                                POSE_STAMPED.encode())  # fmt: skip
        w.register_channel("/base", "cdr", sid)
        w.finish()
    with pytest.raises(PoseLogError, match=r"empty\.mcap:/base: the topic has no messages"):
        read_pose_log(f"{empty}:/base")
    not_a_bag = tmp_path / "text.mcap"
    not_a_bag.write_text("t_s,x_mm\n0,0\n")
    with pytest.raises(PoseLogError, match=r"text\.mcap:/base: not a readable MCAP bag"):
        read_pose_log(f"{not_a_bag}:/base")
    rc = main(["batch", "a.avi", "b.avi", "--mcap", str(tmp_path / "x.mcap")])
    assert rc == 2 and "--mcap goes with --out" in capsys.readouterr().err


def test_the_package_runs_without_mcap(tmp_path):
    """Importing the package loads no mcap; with mcap blocked, a bag's error names the
    extra, and batch --mcap stops before the video."""
    out = tmp_path / "T.csv"
    code = f"""
import sys
import camwhisker.cli, camwhisker.io.poses, camwhisker.io.bag, camwhisker.contact.stage
print("loaded:", sorted(m for m in sys.modules if m.split(".")[0] in ("mcap", "mcap_ros2")))
for m in ("mcap", "mcap_ros2"):
    sys.modules[m] = None
from camwhisker.io.poses import read_pose_log
try:
    read_pose_log("poses.mcap:/base")
except ValueError as exc:
    print(type(exc).__name__, exc)
rc = camwhisker.cli.main(["batch", {str(SAMPLES / "nominal_mjpg.avi")!r}, "--sensor",
                          {str(SAMPLES / "nominal_mjpg.sensor.toml")!r}, "--out", {str(out)!r},
                          "--mcap", {str(tmp_path / "T.mcap")!r}])
print("rc", rc)
"""
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         cwd=ROOT, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"},
                         timeout=60)  # fmt: skip
    lines = run.stdout.splitlines()
    assert lines[0] == "loaded: []", run.stderr
    assert lines[1] == ("PoseLogError MCAP bags need the packages mcap and mcap-ros2-support, "
                        "which are not installed: pip install 'camwhisker[ros]'")  # fmt: skip
    assert lines[2] == "rc 2"
    assert "pip install 'camwhisker[ros]'" in run.stderr
    assert not out.exists()  # stopped before the video
