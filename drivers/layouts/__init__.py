"""IMU suit layouts: which canonical joint (segment) each sensor id is strapped to.

A layout file is JSON ``{"sensors": {"<id>": "<segment>", ...}}`` (optional "name",
"description"). A segment is named by the canonical joint whose global rotation moves it
(``left_elbow`` = the left forearm) or by one of the aliases below.
"""

from __future__ import annotations

from pathlib import Path

from live.core.errors import FormatError
from live.core.skeleton import JOINT_INDEX
from live.core import assets

LAYOUT_DIR = assets.layouts_dir()
DEFAULT_LAYOUT = LAYOUT_DIR / "full_body.json"

#: Segment names people use for suits -> canonical joint.
SEGMENT_ALIASES: dict[str, str] = {
    "chest": "spine3", "sternum": "spine3",
    "left_upper_arm": "left_shoulder", "right_upper_arm": "right_shoulder",
    "left_forearm": "left_elbow", "right_forearm": "right_elbow",
    "left_hand": "left_wrist", "right_hand": "right_wrist",
    "left_thigh": "left_hip", "right_thigh": "right_hip",
    "left_shin": "left_knee", "right_shin": "right_knee",
    "left_foot_segment": "left_ankle", "right_foot_segment": "right_ankle",
}


def parse_layout(obj: object, *, path: str | None = None) -> dict[int, int]:
    """A layout object -> {sensor id: joint index}, in ascending sensor id order."""
    if not isinstance(obj, dict) or not isinstance(obj.get("sensors"), dict) or not obj["sensors"]:
        raise FormatError('a layout is {"sensors": {"<id>": "<segment>", ...}}', path=path)
    out: dict[int, int] = {}
    for key, segment in obj["sensors"].items():
        try:
            sensor = int(key)
        except ValueError:
            raise FormatError(f"sensor id {key!r} is not an integer", path=path) from None
        name = SEGMENT_ALIASES.get(segment, segment) if isinstance(segment, str) else None
        if name not in JOINT_INDEX:
            raise FormatError(f"sensor {sensor}: unknown segment {segment!r}", path=path)
        out[sensor] = JOINT_INDEX[name]
    return dict(sorted(out.items()))


def load_layout(path: str | Path | None = None) -> dict[int, int]:
    """Read a layout file (default: the 15-sensor full body) -> {sensor id: joint index}."""
    from live.core.jsonfile import read_json

    p = Path(path) if path is not None else DEFAULT_LAYOUT
    return parse_layout(read_json(p), path=str(p))
