"""Puppeteering outputs (sinks): VMC protocol to Unity-style avatars, the Rerun viewer, video.

Every sink has ``send(result: FrameResult)`` and ``close()`` and never raises from ``send``.
``rerun`` (the ``viewer`` extra) is imported only when a RerunSink is made.
"""
