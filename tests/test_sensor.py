"""The sensor file: defaults from Table I, and one clear error per kind of bad input."""

import math

import pytest

from camwhisker.sensor.file import Sensor, SensorFileError, dump_sensor, load_sensor


def write(tmp_path, text):
    path = tmp_path / "sensor.toml"
    path.write_text(text)
    return path


def test_defaults_are_table_one():
    s = load_sensor(None)
    # Half angles of view of Table I over half the resolution.
    assert s.camera.fx_px == pytest.approx(640 / math.tan(math.radians(26.95)), abs=0.005)
    assert s.camera.fy_px == pytest.approx(360 / math.tan(math.radians(16.26)), abs=0.005)
    assert s.camera.fx_px / s.camera.fy_px == pytest.approx(1.02, abs=0.005)  # eq. 5's mu
    assert (s.plate.z_i_mm, s.plate.h_r_mm, s.whisker.length_mm) == (25.0, 7.5, 150.0)


def test_missing_keys_take_defaults(tmp_path):
    s = load_sensor(write(tmp_path, "[plate]\nh_r_mm = 8\n"))
    assert s.plate.h_r_mm == 8.0
    assert s.plate.z_i_mm == 25.0
    assert s.camera == Sensor().camera


def test_round_trip_through_toml(tmp_path):
    s = Sensor().replace(camera={"distortion": [-0.2, 0.05, 0.001, 0.0, 0.0], "cx_px": 600.5})
    back = load_sensor(write(tmp_path, dump_sensor(s)))
    assert back.camera == s.camera and back.plate == s.plate and back.whisker == s.whisker


@pytest.mark.parametrize(
    ("text", "names"),
    [
        ("[camera]\nfocal = 3\n", ["[camera] focal", "unknown key"]),
        ("[lens]\nk1 = 0\n", ["unknown table [lens]"]),
        ("[plate]\nh_r_mm = -1\n", ["[plate] h_r_mm", "positive"]),
        ("[plate]\nz_i_mm = 7\n", ["[plate] z_i_mm", "h_r_mm"]),
        ("[plate]\nz_i_mm = nan\n", ["[plate] z_i_mm", "finite"]),
        ('[plate]\nz_i_mm = "25"\n', ["[plate] z_i_mm", "expected a number"]),
        ("[camera]\nwidth_px = 1280.5\n", ["[camera] width_px", "integer"]),
        ("[camera]\nfx_px = true\n", ["[camera] fx_px", "expected a number"]),
        ("[camera]\ndistortion = [0, 0]\n", ["[camera] distortion", "5 numbers"]),
        ("[camera]\ncx_px = 2000\n", ["[camera] cx_px", "outside the image"]),
        ("[whisker]\nlength_mm = 0\n", ["[whisker] length_mm", "positive"]),
        ("[plate\n", ["not valid TOML"]),
    ],
)
def test_bad_values_name_file_and_key(tmp_path, text, names):
    path = write(tmp_path, text)
    with pytest.raises(SensorFileError) as err:
        load_sensor(path)
    message = str(err.value)
    assert str(path) in message
    for name in names:
        assert name in message


def test_missing_file_is_named(tmp_path):
    with pytest.raises(SensorFileError, match="nope.toml"):
        load_sensor(tmp_path / "nope.toml")


def test_bundled_default_file_equals_the_built_in_defaults():
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "calib" / "sensor_default.toml"
    s = load_sensor(path)
    assert (s.camera, s.plate, s.whisker) == (Sensor().camera, Sensor().plate, Sensor().whisker)
