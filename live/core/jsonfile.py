"""Reading a user's JSON file with one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

from live.core.errors import FormatError, UserInputError

#: Largest JSON file read (settings, intrinsics, calibrations, layouts are a few kB).
MAX_JSON_BYTES = 64 * 1024 * 1024


def read_json(path: str | Path, *, max_bytes: int = MAX_JSON_BYTES):
    """The parsed JSON of a file: UserInputError when it is missing or a folder, FormatError when
    it is too large, not UTF-8 or not JSON (NaN and Infinity are read as JSON numbers, like
    Python's json; callers check finiteness)."""
    p = Path(path)
    if not p.is_file():
        raise UserInputError(f"file not found: {p}" if not p.exists() else f"{p} is not a file")
    try:
        if p.stat().st_size > max_bytes:
            raise FormatError(f"larger than {max_bytes // (1024 * 1024)} MiB: not a settings file", path=str(p))
        return json.loads(p.read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise UserInputError(f"file not found: {p}") from None
    except UnicodeDecodeError as e:
        raise FormatError(f"not UTF-8 text (byte {e.start})", path=str(p)) from None
    except json.JSONDecodeError as e:
        raise FormatError(f"not JSON: {e.msg}", path=str(p), line=e.lineno) from None
    except RecursionError:
        raise FormatError("not JSON: nested too deeply", path=str(p)) from None
