"""Puppeteering outputs (sinks): VMC protocol to Unity-style avatars, the Rerun viewer, video.

Every sink has ``send(result: FrameResult)`` and ``close()`` and never raises from ``send``.
``rerun`` (the ``viewer`` extra) is imported only when a RerunSink is made.
"""

from live.outputs.render import RenderOptions, VideoSink, compose_frame, frames_to_video
from live.outputs.viewer import RerunSink
from live.outputs.vmc import VmcSink

__all__ = ["RenderOptions", "RerunSink", "VideoSink", "VmcSink", "compose_frame", "frames_to_video"]
