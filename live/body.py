"""Bodies: rest mesh, rest skeleton and skinning weights, loaded with numpy alone.

A body spec is a preset name (``list_presets()``; files in models/bodies, made by
``python -m models.train.export_bodies``), a path to a body file (.npz, contract in
CONVENTIONS.md), or ``anny:gender=0.3,age=0.6,...`` built on demand with the ``train`` extra.
"""

from __future__ import annotations

import functools
import io
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from live.errors import FormatError, UserInputError
from live.skeleton import NUM_JOINTS, PARENTS

BODIES_DIR = Path(__file__).resolve().parent.parent / "models" / "bodies"


@dataclass(frozen=True)
class Body:
    """vertices (V,3) float32 T-pose mesh, y up, feet on y=0, facing +z; faces (F,3) int32;
    rest_joints (22,3) float32; weights (V,22) float32 rows summing to 1; parents (22,) int32."""

    vertices: np.ndarray
    faces: np.ndarray
    rest_joints: np.ndarray
    weights: np.ndarray
    parents: np.ndarray
    name: str
    phenotype: dict | None = None

    @property
    def height(self) -> float:
        return float(self.vertices[:, 1].max() - self.vertices[:, 1].min())


def _library() -> dict:
    path = BODIES_DIR / "library.json"
    return json.loads(path.read_text()) if path.is_file() else {"aliases": {}, "bodies": {}}


def list_presets() -> list[str]:
    """Preset body names (aliases such as ``default`` and ``performer`` not included)."""
    return sorted(p.stem for p in BODIES_DIR.glob("*.npz"))


def aliases() -> dict[str, str]:
    return dict(_library().get("aliases", {}))


def save_body(path: str | Path, body: Body) -> None:
    np.savez_compressed(
        path, vertices=body.vertices.astype(np.float32), faces=body.faces.astype(np.int32),
        rest_joints=body.rest_joints.astype(np.float32), weights=body.weights.astype(np.float32),
        parents=np.asarray(body.parents, np.int32), name=np.array(body.name),
        phenotype=np.array(json.dumps(body.phenotype) if body.phenotype else ""),
    )


def body_from_arrays(arrays: dict, source: str = "body") -> Body:
    """Validate the body-file contract and build a Body (FormatError naming what is wrong)."""
    def need(key: str) -> np.ndarray:
        if key not in arrays:
            raise FormatError(f"body file has no '{key}' array", path=source)
        return np.asarray(arrays[key])

    v, f, j, w = need("vertices"), need("faces"), need("rest_joints"), need("weights")
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise FormatError(f"vertices must be (V, 3), got {v.shape}", path=source)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise FormatError(f"faces must be (F, 3) integers, got {f.shape} {f.dtype}", path=source)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise FormatError("faces index vertices that do not exist", path=source)
    if j.shape != (NUM_JOINTS, 3):
        raise FormatError(f"rest_joints must be (22, 3), got {j.shape}", path=source)
    if w.shape != (len(v), NUM_JOINTS):
        raise FormatError(f"weights must be (V, 22) = ({len(v)}, 22), got {w.shape}", path=source)
    for key, arr in (("vertices", v), ("rest_joints", j), ("weights", w)):
        if not np.all(np.isfinite(arr)):
            raise FormatError(f"{key} holds NaN or infinite values", path=source)
    if np.abs(w.sum(axis=1) - 1.0).max() > 1e-3 or w.min() < -1e-6:
        raise FormatError("weights rows must be non-negative and sum to 1", path=source)
    parents = np.asarray(arrays.get("parents", PARENTS), np.int32)
    if not np.array_equal(parents, PARENTS):
        raise FormatError("parents differ from the canonical 22-joint skeleton", path=source)
    name = str(np.asarray(arrays.get("name", Path(source).stem)))
    pheno_text = str(np.asarray(arrays.get("phenotype", "")))
    try:
        phenotype = json.loads(pheno_text) if pheno_text else None
    except json.JSONDecodeError:
        raise FormatError("phenotype is not a JSON string", path=source) from None
    return Body(vertices=v.astype(np.float32), faces=f.astype(np.int32), rest_joints=j.astype(np.float32),
                weights=w.astype(np.float32), parents=parents, name=name, phenotype=phenotype)


def _load_file(path: Path) -> Body:
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as exc:
        raise FormatError(f"not a readable body file ({type(exc).__name__}: {exc})", path=str(path)) from None
    return body_from_arrays(arrays, source=str(path))


def body_from_npz_bytes(data: bytes, source: str = "body.npz") -> Body:
    with np.load(io.BytesIO(data), allow_pickle=False) as z:
        return body_from_arrays({k: z[k] for k in z.files}, source=source)


@functools.lru_cache(maxsize=32)
def _load_cached(spec: str) -> Body:
    if spec.startswith("anny:"):
        try:
            from models.train.export_bodies import build_from_spec
            import torch  # noqa: F401 - the train extra is what makes anny: specs work
        except ImportError:
            raise UserInputError("building an anny: body needs the train extra: pip install 'livecap[train]'") from None
        return build_from_spec(spec)
    name = aliases().get(spec, spec)
    preset = BODIES_DIR / f"{name}.npz"
    if preset.is_file() and "/" not in spec and not spec.endswith(".npz"):
        return _load_file(preset)
    path = Path(spec)
    if path.suffix == ".npz" or path.exists():
        if not path.is_file():
            raise UserInputError(f"no such body file: {path}")
        return _load_file(path)
    raise UserInputError(f"unknown body {spec!r}: use a preset ({', '.join(list_presets() + sorted(aliases()))}), "
                         "a body .npz file, or anny:gender=..,age=..")


def load_body(spec: str | Path) -> Body:
    """A body from a preset name, a .npz path, or an anny: phenotype (cached per spec)."""
    return _load_cached(str(spec))
