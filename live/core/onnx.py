"""One way to open an ONNX model with onnxruntime for the live path."""

from __future__ import annotations

import json
from pathlib import Path

from live.core.errors import ModelError


def open_session(path: Path, *, threads: int = 1, what: str = "model", retrain: str = ""):
    """(InferenceSession, model card dict) for ``path``; a clear ModelError when it is missing or
    unreadable. Sequential execution and one inter-op thread: the models are small and the
    pipeline's own threads share two cores with them."""
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        hint = f" (train one: {retrain})" if retrain else ""
        raise ModelError(f"no {what} at {path}{hint}")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = max(int(threads), 1)
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    if opts.intra_op_num_threads > 1:
        # Idle pool threads spin by default: with two sessions per frame (regressor, temporal
        # model) on two cores, each one's spinning threads starve the other (the skeleton stage
        # at threads=2 took 2.6x longer than at 1, benchmarks/bench_skeleton.py --threads 2).
        opts.add_session_config_entry("session.intra_op.allow_spinning", "0")
    try:
        session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own types for unreadable graphs
        raise ModelError(f"cannot load {what} {path}: {exc}") from exc
    card_path = path.with_suffix(".json")
    card = json.loads(card_path.read_text()) if card_path.is_file() else {}
    return session, card
