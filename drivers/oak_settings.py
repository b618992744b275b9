"""OAK-D stereo settings: presets and the pure settings -> depthai configuration mapping.

depthai 3.x cannot create device nodes (Camera, StereoDepth) without a device, so the mapping is
split in two host-testable parts: ``stereo_config(settings) -> dict`` (plain data, what the
device code applies) and ``apply_stereo_config(dai.StereoDepthConfig, settings)`` (the message
object, which depthai does build on the host). drivers/oak.py applies both to the real nodes.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from live.core.errors import UserInputError

#: Stereo sensor modes of the OAK-D mono pair (OV9282): size -> highest frame rate.
SENSOR_MODES: dict[tuple[int, int], float] = {(640, 400): 120.0, (1280, 720): 120.0, (1280, 800): 120.0}
MEDIAN_KERNELS = ("off", "3x3", "5x5", "7x7")
PRESET_MODES = ("DEFAULT", "FAST_ACCURACY", "FAST_DENSITY", "ACCURACY", "DENSITY", "HIGH_DETAIL", "ROBOTICS", "FACE")


@dataclass(frozen=True)
class OakSettings:
    """How the OAK-D computes depth.

    width/height/fps: stereo resolution (one of SENSOR_MODES) and frame rate.
    preset_mode: depthai StereoDepth.PresetMode name, the base the fields below refine.
    confidence_threshold: depthai's raw 0..255 value; None keeps the preset's own.
    median: "off" | "3x3" | "5x5" | "7x7". spatial_filter / temporal_filter: depthai's
    edge-preserving hole filling / temporal smoothing. min_depth_m / max_depth_m: threshold
    filter (pixels outside become 0 = no data). imu: stream the device IMU when it has one.
    on_device_pointcloud: unproject on the device (PointCloud node) instead of on the host.
    ir_dot_intensity: 0..1 dot projector power (OAK-D Pro only; ignored without one).
    """

    name: str = "default"
    width: int = 640
    height: int = 400
    fps: float = 30.0
    preset_mode: str = "DEFAULT"
    subpixel: bool = True
    extended_disparity: bool = False
    left_right_check: bool = True
    confidence_threshold: int | None = None
    median: str = "5x5"
    spatial_filter: bool = False
    temporal_filter: bool = False
    min_depth_m: float = 0.2
    max_depth_m: float = 8.0
    imu: bool = True
    imu_rate_hz: int = 200
    on_device_pointcloud: bool = False
    ir_dot_intensity: float = 0.0

    def __post_init__(self) -> None:
        size = (self.width, self.height)
        if size not in SENSOR_MODES:
            modes = ", ".join(f"{w}x{h}" for w, h in SENSOR_MODES)
            raise UserInputError(f"OAK stereo size {self.width}x{self.height} is not supported; use one of {modes}")
        if not 0 < self.fps <= SENSOR_MODES[size]:
            raise UserInputError(f"OAK fps {self.fps} out of range (0, {SENSOR_MODES[size]:g}] at {self.width}x{self.height}")
        if self.preset_mode not in PRESET_MODES:
            raise UserInputError(f"unknown OAK preset mode {self.preset_mode!r}; use one of {', '.join(PRESET_MODES)}")
        if self.median not in MEDIAN_KERNELS:
            raise UserInputError(f"unknown median filter {self.median!r}; use one of {', '.join(MEDIAN_KERNELS)}")
        if self.confidence_threshold is not None and not 0 <= self.confidence_threshold <= 255:
            raise UserInputError(f"OAK confidence threshold {self.confidence_threshold} not in 0..255")
        if not 0.0 <= self.min_depth_m < self.max_depth_m <= 65.535:
            raise UserInputError(f"OAK depth range [{self.min_depth_m}, {self.max_depth_m}] m is invalid")
        if not 0.0 <= self.ir_dot_intensity <= 1.0:
            raise UserInputError(f"OAK IR dot intensity {self.ir_dot_intensity} not in [0, 1]")
        if self.imu_rate_hz <= 0:
            raise UserInputError(f"OAK IMU rate {self.imu_rate_hz} must be positive")


PRESETS: dict[str, OakSettings] = {
    # Lowest latency: 400p at up to 120 fps, no subpixel (doubles the stereo engine's work).
    "fast": OakSettings(name="fast", fps=120.0, preset_mode="FAST_DENSITY", subpixel=False, median="3x3"),
    "default": OakSettings(),
    # Best geometry for bodies at 1-4 m: 800p, subpixel, spatial + temporal filtering.
    "accurate": OakSettings(
        name="accurate", width=1280, height=800, fps=15.0, preset_mode="ACCURACY", median="7x7",
        spatial_filter=True, temporal_filter=True,
    ),
}


def oak_settings(preset: str = "default", **overrides: Any) -> OakSettings:
    """A preset by name ("fast" | "default" | "accurate") with fields overridden."""
    if preset not in PRESETS:
        raise UserInputError(f"unknown OAK preset {preset!r}; use one of {', '.join(PRESETS)}")
    unknown = set(overrides) - set(OakSettings.__dataclass_fields__)
    if unknown:
        raise UserInputError(f"unknown OAK setting(s) {', '.join(sorted(unknown))}")
    return replace(PRESETS[preset], **overrides)


def stereo_config(settings: OakSettings) -> dict[str, Any]:
    """Settings -> the plain configuration the device code applies (JSON-serialisable).

    Depth is aligned to the rectified right camera, whose intrinsics depthai reports as those of
    CAM_C (the right mono camera); depth is uint16 millimetres.
    """
    median = "MEDIAN_OFF" if settings.median == "off" else f"KERNEL_{settings.median}"
    return {
        "size": [settings.width, settings.height],
        "fps": float(settings.fps),
        "preset_mode": settings.preset_mode,
        "left_right_check": settings.left_right_check,
        "subpixel": settings.subpixel,
        "extended_disparity": settings.extended_disparity,
        "confidence_threshold": settings.confidence_threshold,
        "median": median,
        "spatial_filter": settings.spatial_filter,
        "temporal_filter": settings.temporal_filter,
        "threshold_mm": [int(round(settings.min_depth_m * 1000)), int(round(settings.max_depth_m * 1000))],
        "depth_align": "RECTIFIED_RIGHT",
        "depth_socket": "CAM_C",
        "depth_unit": "MILLIMETER",
        "imu_rate_hz": settings.imu_rate_hz if settings.imu else 0,
        "on_device_pointcloud": settings.on_device_pointcloud,
        "ir_dot_intensity": settings.ir_dot_intensity,
    }


def apply_stereo_config(cfg, settings: OakSettings):
    """Write the settings into a depthai StereoDepthConfig (e.g. ``stereo.initialConfig``).

    cfg: dai.StereoDepthConfig, modified in place and returned. Fields the settings leave at
    None keep the value the preset mode gave them.
    """
    import depthai as dai

    conf = stereo_config(settings)
    cfg.setLeftRightCheck(conf["left_right_check"])
    cfg.setSubpixel(conf["subpixel"])
    cfg.setExtendedDisparity(conf["extended_disparity"])
    cfg.setMedianFilter(getattr(dai.MedianFilter, conf["median"]))
    cfg.setDepthAlign(getattr(dai.StereoDepthConfig.AlgorithmControl.DepthAlign, conf["depth_align"]))
    cfg.setDepthUnit(getattr(dai.StereoDepthConfig.AlgorithmControl.DepthUnit, conf["depth_unit"]))
    if conf["confidence_threshold"] is not None:
        cfg.setConfidenceThreshold(conf["confidence_threshold"])
    post = cfg.postProcessing
    post.spatialFilter.enable = conf["spatial_filter"]
    post.temporalFilter.enable = conf["temporal_filter"]
    post.thresholdFilter.minRange, post.thresholdFilter.maxRange = conf["threshold_mm"]
    return cfg
