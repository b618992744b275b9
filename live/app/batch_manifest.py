"""``batch.json``: one record per item (status, key, outputs and their hashes, frames, fps,
accuracy, error), the totals of the last run, and what a resumed batch reads back to skip the
items already done. Rewritten as results arrive (at most every WRITE_INTERVAL_S, and at the
end), so a killed batch loses only the last seconds of its records (those items are made again,
to the same bytes)."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field

from live import __version__
from live.app import batch_storage as storage
from live.app.batch_items import ItemResult
from live.core.errors import UserInputError

WRITE_INTERVAL_S = 2.0
#: The records' key in the file, per command.
RECORDS = {"replay": "sessions", "synth": "items"}


def manifest_name(shard: tuple[int, int] | None) -> str:
    """``batch.json``, or one file per shard (shards of one batch run at the same time)."""
    return "batch.json" if shard is None else f"batch-shard-{shard[0]}-of-{shard[1]}.json"


def read_previous(location: str, command: str) -> dict[str, dict]:
    """The records of an earlier run into the same folder (empty when there is none)."""
    text = storage.read_text(location)
    if text is None:
        return {}
    try:
        data = json.loads(text)
    except json.JSONDecodeError:
        raise UserInputError(f"{location} is not a batch record (not JSON): move it away or use another --out") from None
    if not isinstance(data, dict) or data.get("command") != command:
        raise UserInputError(f"{location} records a batch of another command "
                             f"({data.get('command') if isinstance(data, dict) else '?'}): use another --out")
    records = data.get(RECORDS[command])
    return records if isinstance(records, dict) else {}


@dataclass
class Manifest:
    location: str
    command: str
    options: list[str]
    records: dict[str, dict] = field(default_factory=dict)
    run: list[ItemResult] = field(default_factory=list)
    #: When the command started, and when its executor was ready (a Ray started or joined).
    started: float = field(default_factory=time.perf_counter)
    ready: float = field(default_factory=time.perf_counter)
    executor: str = ""
    workers: int = 0
    _last_write: float = 0.0

    def add(self, result: ItemResult) -> None:
        self.run.append(result)
        self.records[result.name] = result.record()
        if time.perf_counter() - self._last_write >= WRITE_INTERVAL_S:
            self.write()

    def totals(self) -> dict:
        """This run's counts, frames, wall time (of the whole command, the executor's startup
        included) and throughput; mean accuracy over the items
        with ground truth (weighted by the frames scored)."""
        wall = time.perf_counter() - self.started
        counts = {s: sum(r.status == s for r in self.run) for s in ("done", "skipped", "failed")}
        scored = [r.accuracy for r in self.run if r.accuracy and r.status != "failed"]
        frames_scored = sum(a["frames_scored"] for a in scored)
        accuracy = None
        if frames_scored:
            accuracy = {"sessions": len(scored), "frames_scored": frames_scored}
            for k in ("mpjpe_mm", "pa_mpjpe_mm"):
                accuracy[k] = round(sum(a[k] * a["frames_scored"] for a in scored) / frames_scored, 2)
        return {"items": len(self.run), **counts, "with_warnings": sum(bool(r.warning) for r in self.run),
                "frames": sum(r.frames or 0 for r in self.run if r.status != "failed"),
                "wall_s": round(wall, 3), "startup_s": round(self.ready - self.started, 3), "items_per_s": round(len(self.run) / wall, 3) if wall > 0 else None,
                "executor": self.executor, "workers": self.workers, "accuracy": accuracy}

    def write(self) -> None:
        data = {"livecap": __version__, "command": self.command, "options": self.options,
                RECORDS[self.command]: dict(sorted(self.records.items())), "totals": self.totals()}
        storage.write_text(self.location, json.dumps(data, indent=2, default=str) + "\n")
        self._last_write = time.perf_counter()
