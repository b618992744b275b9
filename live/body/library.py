"""Bodies: rest mesh, rest skeleton and skinning weights, loaded with numpy alone.

A body spec is a preset name (``list_presets()`` and the aliases ``performer`` / ``default``;
files in models/bodies, made by ``python -m models.train.export_bodies``), a path to a body file
(.npz, contract in CONVENTIONS.md), or ``anny:gender=0.3,age=0.6,...``: a body built once with the
``train`` extra (``livecap train bodies --anny SPEC``, models.train.anny_bodies) into the body
cache, and read from there. models/bodies/library.json is the one table of the presets'
phenotypes and the aliases: the exporter builds the bodies it lists.
"""

from __future__ import annotations

import functools
import hashlib
import io
import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from live.body.body import Body
from live.core import assets
from live.core.errors import FormatError, UserInputError
from live.core.skeleton import NUM_JOINTS, PARENTS

BODIES_DIR = assets.bodies_dir()

#: Anny's phenotype parameters, each in [0, 1] (gender 0 = male, 1 = female; age 0.75 = young
#: adult, 1 = old; the others 0.5 = average); a missing one takes 0.5.
ANNY_KEYS = ("gender", "age", "muscle", "weight", "height", "proportions")

#: Array names of a body file, in the order save_body writes them.
_FIELDS = ("vertices", "faces", "rest_joints", "weights", "parents", "name", "phenotype")


def _library() -> dict:
    path = BODIES_DIR / "library.json"
    return json.loads(path.read_text()) if path.is_file() else {"aliases": {}, "bodies": {}}


def list_presets() -> list[str]:
    """Preset body names (aliases such as ``default`` and ``performer`` not included)."""
    return sorted(p.stem for p in BODIES_DIR.glob("*.npz"))


def aliases() -> dict[str, str]:
    """Alias -> preset: ``performer`` (synthetic sessions' default body), ``default`` (demo avatar)."""
    return dict(_library().get("aliases", {}))


def preset_phenotypes() -> dict[str, dict[str, float]]:
    """Preset name -> its Anny phenotype ({key: value} for ANNY_KEYS), in library.json's order.

    Values are in [0, 1] as Anny defines them: gender 0 is male and 1 female; age blends Anny's
    newborn/baby/child/young/old targets at -1/3, 0, 1/3, 2/3, 1, which Anny's own calibration
    reads as 4 y at 0.215, 11 y at 0.415, 16 y at 0.67, 18 y at 0.77, 64 y at 0.83 (the names
    say what the bodies look like, e.g. child_boy_4y is 1.05 m tall). Renaming or adding bodies
    changes the train/val body splits of the learned models (sim.skeleton_data.split_bodies):
    retrain them after such a change."""
    return {name: {k: float(v) for k, v in entry["phenotype"].items()}
            for name, entry in _library().get("bodies", {}).items()}


def parse_anny_spec(spec: str) -> dict[str, float]:
    """``[anny:]gender=0.3,age=0.6,...`` -> {key: value} for all of ANNY_KEYS (missing ones 0.5)."""
    text = spec[len("anny:"):] if spec.startswith("anny:") else spec
    values = {k: 0.5 for k in ANNY_KEYS}
    for part in filter(None, (p.strip() for p in text.split(","))):
        key, sep, value = (s.strip() for s in part.partition("="))
        if not sep or key not in ANNY_KEYS:
            raise UserInputError(f"bad anny phenotype {part!r}: use key=value with key in {', '.join(ANNY_KEYS)}")
        try:
            v = float(value)
        except ValueError:
            raise UserInputError(f"bad anny phenotype value {value!r} for {key}") from None
        if not 0.0 <= v <= 1.0:  # also rejects nan
            raise UserInputError(f"anny phenotype {key}={value} is outside [0, 1]")
        values[key] = v
    return values


def format_anny_spec(phenotype: dict[str, float]) -> str:
    """{key: value} -> the canonical ``anny:gender=..,age=..,...`` spec (ANNY_KEYS order; the
    inverse of ``parse_anny_spec``), which also names the body."""
    return "anny:" + ",".join(f"{k}={phenotype[k]:g}" for k in ANNY_KEYS)


def anny_body_path(spec: str) -> Path:
    """Where the built body of an ``anny:`` spec is kept (the body cache; models.train.anny_bodies
    builds it, ``livecap train bodies --anny SPEC``): one file per canonical phenotype."""
    canonical = format_anny_spec(parse_anny_spec(spec))
    return assets.cache_dir("anny_bodies") / f"{hashlib.sha1(canonical.encode()).hexdigest()[:16]}.npz"


def save_body(path: str | Path, body: Body) -> None:
    """Write a body file (compressed .npz). Byte-for-byte deterministic: fixed zip timestamps,
    so re-exporting the library reproduces the committed files exactly."""
    arrays = {
        "vertices": np.asarray(body.vertices, np.float32), "faces": np.asarray(body.faces, np.int32),
        "rest_joints": np.asarray(body.rest_joints, np.float32), "weights": np.asarray(body.weights, np.float32),
        "parents": np.asarray(body.parents, np.int32), "name": np.array(str(body.name)),
        "phenotype": np.array(json.dumps(body.phenotype) if body.phenotype else ""),
    }
    with zipfile.ZipFile(path, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for key in _FIELDS:
            info = zipfile.ZipInfo(f"{key}.npy", date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            buf = io.BytesIO()
            # np.ascontiguousarray would turn the 0-d name/phenotype into (1,) arrays.
            np.lib.format.write_array(buf, np.require(arrays[key], requirements="C"), allow_pickle=False)
            zf.writestr(info, buf.getvalue())


def _float_array(arrays: dict, key: str, source: str) -> np.ndarray:
    a = np.asarray(arrays[key])
    if not np.issubdtype(a.dtype, np.floating):
        raise FormatError(f"{key} must be floating point, got {a.dtype}", path=source)
    if not np.all(np.isfinite(a)):
        raise FormatError(f"{key} holds NaN or infinite values", path=source)
    return a


def _text(arrays: dict, key: str, source: str) -> str:
    a = np.asarray(arrays[key])
    if a.ndim != 0 or a.dtype.kind != "U":
        raise FormatError(f"{key} must be a text scalar, got {a.dtype} {a.shape}", path=source)
    return str(a)


def body_from_arrays(arrays: dict, source: str = "body") -> Body:
    """Validate every field of the body-file contract and build a Body (FormatError naming what is
    wrong). ``phenotype`` is optional; the other fields are required."""
    missing = [k for k in _FIELDS[:-1] if k not in arrays]
    if missing:
        raise FormatError(f"body file has no {', '.join(repr(k) for k in missing)} array", path=source)
    v = _float_array(arrays, "vertices", source)
    j = _float_array(arrays, "rest_joints", source)
    w = _float_array(arrays, "weights", source)
    f, parents = np.asarray(arrays["faces"]), np.asarray(arrays["parents"])
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4:
        raise FormatError(f"vertices must be (V, 3) with V >= 4, got {v.shape}", path=source)
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer):
        raise FormatError(f"faces must be (F, 3) integers, got {f.shape} {f.dtype}", path=source)
    if len(f) and (f.min() < 0 or f.max() >= len(v)):
        raise FormatError("faces index vertices that do not exist", path=source)
    if j.shape != (NUM_JOINTS, 3):
        raise FormatError(f"rest_joints must be (22, 3), got {j.shape}", path=source)
    if w.shape != (len(v), NUM_JOINTS):
        raise FormatError(f"weights must be (V, 22) = ({len(v)}, 22), got {w.shape}", path=source)
    if w.min() < -1e-6 or np.abs(w.sum(axis=1) - 1.0).max() > 1e-3:
        raise FormatError("weights rows must be non-negative and sum to 1", path=source)
    if not np.issubdtype(parents.dtype, np.integer) or not np.array_equal(parents, PARENTS):
        raise FormatError("parents differ from the canonical 22-joint skeleton", path=source)
    name = _text(arrays, "name", source)
    pheno_text = _text(arrays, "phenotype", source) if "phenotype" in arrays else ""
    try:
        phenotype = json.loads(pheno_text) if pheno_text else None
    except json.JSONDecodeError:
        raise FormatError("phenotype is not a JSON string", path=source) from None
    if phenotype is not None and not isinstance(phenotype, dict):
        raise FormatError("phenotype must be a JSON object", path=source)
    out = dict(vertices=v.astype(np.float32), faces=f.astype(np.int32), rest_joints=j.astype(np.float32),
               weights=w.astype(np.float32), parents=parents.astype(np.int32))
    for a in out.values():
        a.flags.writeable = False  # shared by the load cache: nobody may edit them in place
    return Body(**out, name=name, phenotype=phenotype)


#: Ceilings of a body file, checked on the arrays' headers before anything is read
#: (docs/reliability.md): 128 MiB per array (a million vertices' weights are 88 MB), 256 MiB in
#: all. A 200-byte file may declare a (2^40, 3) array; numpy would try to allocate 12 TiB.
MAX_BODY_ARRAY_BYTES = 128 * 1024 * 1024
MAX_BODY_BYTES = 256 * 1024 * 1024
#: dtype kinds a body file may hold: floats, integers, booleans, unicode text (no objects, no bytes).
_BODY_KINDS = "fiubU"


def _member_header(zf: zipfile.ZipFile, member: str, where: str) -> int:
    """Check one .npy member's header (version, dtype, declared shape) and return its data size in
    bytes, without reading the data."""
    with zf.open(member) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise FormatError(f"{member}: unsupported .npy version {version}", path=where)
    if dtype.hasobject or dtype.kind not in _BODY_KINDS:
        raise FormatError(f"{member}: dtype {dtype} is not allowed in a body file", path=where)
    count = 1
    for n in shape:
        count *= int(n)
    size = count * dtype.itemsize
    if size > MAX_BODY_ARRAY_BYTES:
        raise FormatError(f"{member} declares shape {tuple(shape)} {dtype} ({size / 2**20:.3g} MiB), more than "
                          f"the {MAX_BODY_ARRAY_BYTES >> 20} MiB a body array may hold", path=where)
    return size


def _npz_arrays(source, where: str) -> dict:
    """The body-file arrays of an .npz (a path or a binary file), each member's header checked
    against the ceilings above before its data is read; members that are not body fields are
    not read at all."""
    try:
        with zipfile.ZipFile(source) as zf:
            names = {n[:-4]: n for n in zf.namelist() if n.endswith(".npy") and n[:-4] in _FIELDS}
            total = sum(_member_header(zf, member, where) for member in names.values())
            if total > MAX_BODY_BYTES:
                raise FormatError(f"the arrays declare {total / 2**20:.3g} MiB, more than the "
                                  f"{MAX_BODY_BYTES >> 20} MiB a body file may hold", path=where)
            arrays = {}
            for key, member in names.items():
                with zf.open(member) as f:
                    arrays[key] = np.lib.format.read_array(f, allow_pickle=False)
            return arrays
    except FormatError:
        raise
    except zipfile.BadZipFile as exc:
        head = b""
        try:
            if hasattr(source, "seek"):
                source.seek(0)
                head = source.read(6)
            else:
                with open(source, "rb") as f:
                    head = f.read(6)
        except OSError:
            pass
        if head == b"\x93NUMPY":
            raise FormatError("a body file is an .npz archive, not a single .npy array", path=where) from None
        if head.startswith(b"PK"):
            raise FormatError(f"not a readable body file (a damaged zip archive: {exc})", path=where) from None
        raise FormatError("not a readable body file (not a zip archive)", path=where) from None
    except (OSError, ValueError, EOFError, zlib.error, zipfile.LargeZipFile, NotImplementedError, RuntimeError) as exc:
        # ValueError covers bad headers and pickled (object) arrays; zlib.error a damaged
        # compressed member; NotImplementedError and RuntimeError unsupported or encrypted ones.
        raise FormatError(f"not a readable body file ({type(exc).__name__}: {exc})", path=where) from None


def body_from_npz_bytes(data: bytes, source: str = "body.npz") -> Body:
    """A body from the bytes of a body file (e.g. embedded in a session)."""
    return body_from_arrays(_npz_arrays(io.BytesIO(data), source), source=source)


@functools.lru_cache(maxsize=32)
def _load_cached(spec: str) -> Body:
    if spec.startswith("anny:"):
        path = anny_body_path(spec)  # a bad spec fails here, built or not
        if not path.is_file():
            canonical = format_anny_spec(parse_anny_spec(spec))
            raise UserInputError(f"the body {canonical} is not built yet: `livecap train bodies --anny '{canonical}'` "
                                 "builds it once (train extra: pip install 'livecap[train]')")
        return body_from_arrays(_npz_arrays(path, str(path)), source=str(path))
    name = aliases().get(spec, spec)
    preset = BODIES_DIR / f"{name}.npz"
    if "/" not in spec and not spec.endswith(".npz") and preset.is_file():
        return body_from_arrays(_npz_arrays(preset, str(preset)), source=str(preset))
    path = Path(spec)
    if path.suffix == ".npz" or path.exists():
        if not path.is_file():
            raise UserInputError(f"no such body file: {path}")
        return body_from_arrays(_npz_arrays(path, str(path)), source=str(path))
    raise UserInputError(f"unknown body {spec!r}: use a preset ({', '.join(list_presets() + sorted(aliases()))}), "
                         "a body .npz file, or anny:gender=..,age=..,muscle=..,weight=..,height=..,proportions=..")


@functools.lru_cache(maxsize=4)
def mean_rest_template(names: tuple[str, ...] | None = None) -> np.ndarray | None:
    """(22, 3) mean T-pose of library bodies (``names``, default all presets), each scaled to a
    unit pelvis height: the bone directions of real bodies, for estimating a performer's T-pose
    from bone lengths (the default of live.retarget.analytic.estimate_rest_joints). None when
    there is no library."""
    from live.core.skeleton import pelvis_height

    names = tuple(list_presets()) if names is None else names
    if not names:
        return None
    rests = [np.asarray(load_body(n).rest_joints, np.float64) for n in names]
    return np.mean([r / pelvis_height(r) for r in rests], axis=0)


def load_body(spec: str | Path) -> Body:
    """A body from a preset name, a .npz path, or an anny: phenotype (cached per spec; the arrays
    are read-only and shared: copy them to edit)."""
    return _load_cached(str(spec))
