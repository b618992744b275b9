"""Reading a user's JSON file with one-line errors."""

from __future__ import annotations

import json
from pathlib import Path

from live.core.errors import FormatError, UserInputError


def read_json(path: str | Path):
    p = Path(path)
    try:
        return json.loads(p.read_text())
    except FileNotFoundError:
        raise UserInputError(f"file not found: {p}") from None
    except json.JSONDecodeError as e:
        raise FormatError(f"not JSON: {e.msg}", path=str(p), line=e.lineno) from None
