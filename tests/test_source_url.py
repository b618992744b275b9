"""Source-string parsing: every accepted form, round trips, and one-line errors."""

import pytest

from drivers.source_url import SourceSpec, format_source, open_camera_source, parse_source
from live.core.errors import UserInputError


@pytest.mark.parametrize(
    "text, kind, target, options",
    [
        ("oak", "oak", "", {}),
        ("oak:18443010C1B2D41200", "oak", "18443010C1B2D41200", {}),
        ("oak:1.3", "oak", "1.3", {}),
        ("realsense", "realsense", "", {}),
        ("realsense:213622078112", "realsense", "213622078112", {}),
        ("realsense-bag:rec/take1.bag", "realsense-bag", "rec/take1.bag", {}),
        ("serial:/dev/ttyUSB0:xbus", "serial", "/dev/ttyUSB0", {"protocol": "xbus"}),
        ("serial:/dev/ttyUSB0:lines:115200", "serial", "/dev/ttyUSB0", {"protocol": "lines", "baud": 115200}),
        ("serial:COM3:xbus:921600", "serial", "COM3", {"protocol": "xbus", "baud": 921600}),
        ("serial:socket://localhost:1234:xbus", "serial", "socket://localhost:1234", {"protocol": "xbus"}),
        ("serial:socket://10.0.0.2:7000:lines:9600", "serial", "socket://10.0.0.2:7000", {"protocol": "lines", "baud": 9600}),
        ("serial:rfc2217://host:2217?timeout=1:xbus", "serial", "rfc2217://host:2217?timeout=1", {"protocol": "xbus"}),
        ("serial:loop://:lines", "serial", "loop://", {"protocol": "lines"}),
        ("replay:sessions/a.mcap", "replay", "sessions/a.mcap", {}),
        ("folder:data/depth", "folder", "data/depth", {}),
        ("sim:clips/walk.bvh", "sim", "clips/walk.bvh", {}),
        ("sim:clips/walk.bvh?body=slim&seed=3", "sim", "clips/walk.bvh", {"body": "slim", "seed": "3"}),
        ("take.mcap", "replay", "take.mcap", {}),
        ("C:/x/take.MCAP", "replay", "C:/x/take.MCAP", {}),
        ("take.bag", "realsense-bag", "take.bag", {}),
    ],
)
def test_accepted_forms(text, kind, target, options):
    spec = parse_source(text)
    assert spec == SourceSpec(kind, target, options)
    assert parse_source(format_source(spec)) == spec


def test_bare_directory_is_a_folder(tmp_path):
    assert parse_source(str(tmp_path)) == SourceSpec("folder", str(tmp_path))


def test_specs_are_frozen():
    spec = parse_source("oak")
    with pytest.raises(AttributeError):
        spec.kind = "realsense"


@pytest.mark.parametrize(
    "text",
    [
        "",
        "kinect",
        "oak:",
        "replay:",
        "folder:",
        "sim:",
        "sim:walk.bvh?body",
        "serial:/dev/ttyUSB0",
        "serial:/dev/ttyUSB0:nmea",
        "serial::xbus",
        "serial:socket://host:1234",
        "serial:/dev/ttyUSB0:xbus:0",
        "serial:/dev/ttyUSB0:xbus:16000001",
        "serial:/dev/ttyUSB0:xbus:100000000000000000000",
        "serial:/dev/ttyUSB0:xbus:\u00b2",
        "realsense-bag:take.mcap",
        "no/such/dir",
    ],
)
def test_bad_strings_raise_one_line(text):
    with pytest.raises(UserInputError) as info:
        parse_source(text)
    message = str(info.value)
    assert "\n" not in message
    assert "oak[:MXID|NAME]" in message and "serial:PORT|URL:xbus|lines[:BAUD]" in message


def test_user_input_error_is_a_value_error():
    with pytest.raises(ValueError):
        parse_source("nope:x")


def test_open_camera_source_rejects_other_kinds():
    with pytest.raises(UserInputError, match="not a camera source"):
        open_camera_source(parse_source("replay:a.mcap"))


def test_open_camera_source_missing_bag(tmp_path):
    with pytest.raises(UserInputError, match="does not exist"):
        open_camera_source(parse_source(f"realsense-bag:{tmp_path / 'missing.bag'}"))
