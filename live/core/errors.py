"""The one exception tree of livecap.

Every error raised on purpose by livecap derives from ``LivecapError`` so that the CLI can turn
it into a single line. Device errors are also ``OSError`` (like pyserial's SerialException);
bad user input is also ``ValueError``.
"""


class LivecapError(Exception):
    """Base class of every livecap error."""


class UserInputError(LivecapError, ValueError):
    """A user mistake: unknown option value, bad source string, missing file."""


class FormatError(LivecapError, ValueError):
    """A file or byte stream does not follow its format (BVH, body file, session, depth folder)."""

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None):
        where = ""
        if path is not None:
            where = f"{path}"
            if line is not None:
                where += f":{line}"
            where += ": "
        super().__init__(f"{where}{message}")
        self.path = path
        self.line = line


class SessionError(FormatError):
    """A recorded session is truncated, corrupted or not a livecap session."""


class DeviceError(LivecapError, OSError):
    """A sensor could not be opened, went away, or answered wrongly."""


class DeviceNotFoundError(DeviceError):
    """No device matches what the user asked for."""


class ModelError(LivecapError):
    """A model file is missing or does not match what the code expects."""
