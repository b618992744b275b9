"""The body library and numpy LBS: the file contract, the T-pose, skinning consistent with FK."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from live.body.library import (
    BODIES_DIR,
    Body,
    aliases,
    list_presets,
    load_body,
    parse_anny_spec,
    preset_phenotypes,
    save_body,
)
from live.body.skinning import lbs, skinning_transforms
from live.core.errors import FormatError, UserInputError
from live.core.kinematics import forward_kinematics, global_rotations
from live.core.rotations import quat_identity, quat_normalize, quat_to_matrix
from live.core.skeleton import JOINT_INDEX, NUM_JOINTS, PARENTS

J = JOINT_INDEX
ROOT = Path(__file__).resolve().parent.parent
FEET = [J["left_ankle"], J["right_ankle"], J["left_foot"], J["right_foot"]]


def _random_pose(n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    q = quat_normalize(np.concatenate([np.full((n, NUM_JOINTS, 1), 3.0), rng.normal(size=(n, NUM_JOINTS, 3))], -1))
    return q, rng.normal(size=(n, 3))


def test_library_has_varied_bodies():
    names = list_presets()
    assert len(names) >= 16
    heights = [load_body(n).height for n in names]
    assert min(heights) <= 1.1 and max(heights) >= 1.95
    assert set(aliases()) == {"default", "performer"} and set(aliases().values()) <= set(names)
    assert load_body("default").name != load_body("performer").name
    assert load_body("default").height < load_body("performer").height - 0.2  # clearly different


@pytest.mark.parametrize("name", list_presets())
def test_preset_follows_the_contract_and_the_tpose(name):
    b = load_body(name)
    assert b.name == name and set(b.phenotype) == {"gender", "age", "muscle", "weight", "height", "proportions"}
    assert b.vertices.dtype == np.float32 and b.vertices.shape[1] == 3 and 5000 <= len(b.vertices) <= 10000
    assert b.faces.dtype == np.int32 and b.faces.max() < len(b.vertices)
    assert b.rest_joints.dtype == np.float32 and b.weights.dtype == np.float32
    assert b.rest_joints.shape == (NUM_JOINTS, 3) and b.weights.shape == (len(b.vertices), NUM_JOINTS)
    np.testing.assert_allclose(b.weights.sum(axis=1), 1.0, atol=1e-4)
    np.testing.assert_array_equal(b.parents, PARENTS)
    assert (BODIES_DIR / f"{name}.npz").stat().st_size < 600_000
    # Feet on the floor: the lowest point is at y = 0 and everything within 1 cm of it is foot.
    assert abs(float(b.vertices[:, 1].min())) < 0.01
    assert b.weights[b.vertices[:, 1] < 0.01][:, FEET].sum(axis=1).min() > 0.95
    r = b.rest_joints
    # Facing +z: toes ahead of ankles, the face further ahead of the head joint than the skull behind it.
    assert r[J["left_foot"], 2] > r[J["left_ankle"], 2] and r[J["right_foot"], 2] > r[J["right_ankle"], 2]
    head = b.vertices[b.weights[:, J["head"]] > 0.9]
    assert head[:, 2].max() - r[J["head"], 2] > r[J["head"], 2] - head[:, 2].min() + 0.01
    # Subject's left on +x; arms horizontal; legs straight down.
    assert r[J["left_wrist"], 0] > 0.25 * b.height and r[J["right_wrist"], 0] < -0.25 * b.height
    for side, sign in (("left", 1.0), ("right", -1.0)):
        arm = r[J[f"{side}_wrist"]] - r[J[f"{side}_shoulder"]]
        leg = r[J[f"{side}_ankle"]] - r[J[f"{side}_hip"]]
        assert abs(arm[1]) < 0.02 * np.linalg.norm(arm) and abs(arm[2]) < 0.05 * np.linalg.norm(arm)
        assert abs(leg[0]) < 0.02 * np.linalg.norm(leg) and leg[1] < 0
        # Palms down: the hand is flat in the xz plane (within 25 deg), its thumb forward.
        wrist = r[J[f"{side}_wrist"]]
        hand = b.vertices[(b.weights[:, J[f"{side}_wrist"]] > 0.9) & (sign * (b.vertices[:, 0] - wrist[0]) > 0.03)]
        centred = hand - hand.mean(axis=0)
        normal = np.linalg.eigh(centred.T @ centred)[1][:, 0]
        assert abs(normal[1]) > np.cos(np.radians(25))
        assert hand[:, 2].max() - wrist[2] > wrist[2] - hand[:, 2].min()
    assert r[J["head"], 1] > r[J["neck"], 1] > r[J["pelvis"], 1] > r[J["left_knee"], 1]


def test_committed_files_are_what_save_body_writes(tmp_path):
    """The export is reproducible byte for byte: save_body is deterministic (fixed zip times)."""
    for name in (aliases()["performer"], aliases()["default"]):
        save_body(tmp_path / "again.npz", load_body(name))
        assert (tmp_path / "again.npz").read_bytes() == (BODIES_DIR / f"{name}.npz").read_bytes()


def test_loaded_bodies_are_shared_and_read_only():
    b = load_body("performer")
    assert load_body("adult_male_average") is not None and load_body("performer") is b
    with pytest.raises(ValueError):
        b.vertices[0, 0] = 1.0


def test_lbs_identity_is_rest_and_matches_fk():
    b = load_body("performer")
    rest = lbs(b.vertices, b.weights, b.rest_joints, quat_identity((NUM_JOINTS,)), b.rest_joints[0])
    assert rest.shape == (1, len(b.vertices), 3) and rest.dtype == np.float32
    np.testing.assert_allclose(rest[0], b.vertices, atol=1e-5)
    q, root = _random_pose(4)
    joints, _ = forward_kinematics(q, root, b.rest_joints)
    # Skinning the rest joints themselves, each bound to its parent bone, gives FK's joints.
    onehot = np.zeros((NUM_JOINTS, NUM_JOINTS), np.float32)
    onehot[0, 0] = 1
    onehot[np.arange(1, NUM_JOINTS), PARENTS[1:]] = 1
    np.testing.assert_allclose(lbs(b.rest_joints, onehot, b.rest_joints, q, root), joints, atol=1e-5)
    # ... and bound to their own joint too (a joint's transform fixes its own rest position).
    np.testing.assert_allclose(lbs(b.rest_joints, np.eye(NUM_JOINTS, dtype=np.float32), b.rest_joints, q, root),
                               joints, atol=1e-5)


def test_lbs_against_a_slow_reference():
    b = load_body("performer")
    q, root = _random_pose(3, seed=1)
    joints, _ = forward_kinematics(q, root, b.rest_joints)
    g = quat_to_matrix(global_rotations(q))
    sel = np.random.default_rng(2).choice(len(b.vertices), 200, replace=False)
    posed = lbs(b.vertices[sel], b.weights[sel], b.rest_joints, q, root)
    for t in range(3):
        ref = np.zeros((len(sel), 3))
        for i, v in enumerate(sel):
            for j in range(NUM_JOINTS):
                ref[i] += b.weights[v, j] * (joints[t, j] + g[t, j] @ (b.vertices[v] - b.rest_joints[j]))
        np.testing.assert_allclose(posed[t], ref, atol=1e-4)


def test_lbs_single_frame_equals_batched_and_ignores_the_layout_memo():
    b = load_body("performer")
    q, root = _random_pose(5, seed=3)
    batched = lbs(b.vertices, b.weights, b.rest_joints, q, root)
    for t in range(5):
        np.testing.assert_allclose(lbs(b.vertices, b.weights, b.rest_joints, q[t], root[t])[0], batched[t], atol=2e-5)
    # Writable (not memoised) copies give the same result, and editing them in place is seen.
    v, w = b.vertices.copy(), b.weights.copy()
    np.testing.assert_allclose(lbs(v, w, b.rest_joints, q, root), batched, atol=2e-5)
    v += np.float32(1.0)
    np.testing.assert_allclose(lbs(v, w, b.rest_joints, q[0], root[0]), lbs(b.vertices + 1, w, b.rest_joints, q[0], root[0]),
                               atol=1e-5)
    tr = skinning_transforms(q, root, b.rest_joints)
    assert tr.shape == (5, NUM_JOINTS, 3, 4)
    np.testing.assert_allclose(skinning_transforms(q[2], root[2], b.rest_joints)[0], tr[2], atol=1e-9)


def test_save_and_load_round_trip(tmp_path):
    good = load_body("performer")
    save_body(tmp_path / "b.npz", good)
    back = load_body(tmp_path / "b.npz")
    assert back.name == good.name and back.phenotype == good.phenotype
    for key in ("vertices", "faces", "rest_joints", "weights", "parents"):
        np.testing.assert_array_equal(getattr(back, key), getattr(good, key))
    plain = Body(good.vertices, good.faces, good.rest_joints, good.weights, good.parents, "plain")
    save_body(tmp_path / "plain.npz", plain)
    assert load_body(str(tmp_path / "plain.npz")).phenotype is None


def _arrays(body: Body) -> dict:
    return dict(vertices=body.vertices, faces=body.faces, rest_joints=body.rest_joints, weights=body.weights,
                parents=body.parents, name=np.array(body.name), phenotype=np.array(json.dumps(body.phenotype)))


@pytest.mark.parametrize("change, message", [
    (dict(weights="double"), "sum to 1"),
    (dict(vertices="text"), "floating point"),
    (dict(rest_joints="nan"), "NaN"),
    (dict(faces="out_of_range"), "do not exist"),
    (dict(parents="wrong"), "parents"),
    (dict(name="drop"), "'name'"),
    (dict(faces="drop"), "'faces'"),
    (dict(phenotype="not_json"), "JSON"),
    (dict(weights="pickled"), "dtype object is not allowed"),
])
def test_bad_body_files_raise_format_errors(tmp_path, change, message):
    arrays = _arrays(load_body("performer"))
    (key, how), = change.items()
    if how == "drop":
        del arrays[key]
    else:
        arrays[key] = {
            "double": lambda a: a * 2, "text": lambda a: a.astype(str), "nan": lambda a: np.where(a > 1, np.nan, a),
            "out_of_range": lambda a: a + 10**6, "wrong": lambda a: a[::-1].copy(), "not_json": lambda a: np.array("{oops"),
            "pickled": lambda a: np.array([None, a], dtype=object),
        }[how](arrays[key])
    np.savez(tmp_path / "bad.npz", **arrays, allow_pickle=True)
    with pytest.raises(FormatError, match=message):
        load_body(tmp_path / "bad.npz")


def test_garbage_and_missing_files(tmp_path):
    (tmp_path / "garbage.npz").write_bytes(b"PK\x03\x04 definitely not a zip")
    with pytest.raises(FormatError, match="garbage.npz"):
        load_body(tmp_path / "garbage.npz")
    np.save(tmp_path / "single.npy", np.zeros((4, 3), np.float32))
    with pytest.raises(FormatError, match="npz"):
        load_body(tmp_path / "single.npy")
    with pytest.raises(UserInputError, match="adult_male_average"):  # lists the presets
        load_body("no_such_body")
    with pytest.raises(UserInputError):
        load_body(tmp_path / "missing.npz")


def test_anny_spec_parsing():
    assert parse_anny_spec("anny:gender=0.3, age=1") == dict(gender=0.3, age=1.0, muscle=0.5, weight=0.5,
                                                              height=0.5, proportions=0.5)
    for bad in ("anny:gender=1.5", "anny:size=0.5", "anny:gender", "anny:age=old", "anny:age=nan"):
        with pytest.raises(UserInputError):
            load_body(bad)  # fails on the spec itself, with or without the train extra


def test_an_anny_body_not_built_says_how_to_build_it(tmp_path, monkeypatch):
    monkeypatch.setenv("LIVECAP_CACHE", str(tmp_path))
    with pytest.raises(UserInputError, match="livecap train bodies --anny 'anny:gender=0.123,"):
        load_body("anny:gender=0.123")


def test_a_built_anny_body_loads_from_the_cache_without_torch(tmp_path, monkeypatch):
    from live.body.library import anny_body_path, format_anny_spec, save_body

    monkeypatch.setenv("LIVECAP_CACHE", str(tmp_path))
    performer = load_body("performer")
    spec = format_anny_spec(performer.phenotype)
    path = anny_body_path("anny:" + ",".join(f"{k}={v}" for k, v in performer.phenotype.items()))
    assert path.parent == tmp_path / "anny_bodies"  # any spelling of the phenotype, one file
    path.parent.mkdir()
    save_body(path, performer)
    loaded = load_body(spec + " ")  # another spelling: not this process's cached object
    np.testing.assert_array_equal(loaded.vertices, performer.vertices)


def _anny_ready() -> bool:
    if importlib.util.find_spec("torch") is None or importlib.util.find_spec("anny") is None:
        return False
    # Without Anny's cache the first build takes over a minute: run the export once to make it.
    return any((ROOT / ".cache" / "anny").glob("**/*.safetensors"))


@pytest.mark.skipif(not _anny_ready(), reason="needs the train extra and Anny's cache (run models.train.export_bodies)")
def test_anny_spec_builds_the_same_body_as_its_preset():
    from live.body.library import anny_body_path
    from models.train.anny_bodies import ensure_built

    performer = load_body("performer")
    spec = "anny:" + ",".join(f"{k}={v}" for k, v in performer.phenotype.items())
    anny_body_path(spec).unlink(missing_ok=True)
    assert ensure_built([spec]) == [spec] and ensure_built([spec]) == []  # built once, then cached
    built = load_body(spec)
    assert built.name.startswith("anny:") and built.phenotype == performer.phenotype
    np.testing.assert_allclose(built.rest_joints, performer.rest_joints, atol=1e-6)
    assert built.vertices.shape == performer.vertices.shape and built.faces.shape == performer.faces.shape
    # The same surface: byte for byte where the presets were exported; elsewhere (another CPU,
    # another build of torch) the mesh decimation may order and place a few vertices differently
    # (measured: within 5 mm).
    from scipy.spatial import cKDTree

    for a, b in ((built.vertices, performer.vertices), (performer.vertices, built.vertices)):
        assert cKDTree(b).query(a)[0].max() < 0.01


def test_library_json_is_the_phenotype_table():
    phenotypes = preset_phenotypes()
    assert sorted(phenotypes) == list_presets()
    for name, phenotype in phenotypes.items():
        assert load_body(name).phenotype == phenotype


def test_exporter_builds_the_bodies_library_json_lists(tmp_path, monkeypatch):
    # The Anny build itself needs the train extra; here each preset stands in for its own build,
    # so the command's reading and writing of the library is checked byte for byte.
    import models.train.anny_bodies
    from models.train.export_bodies import main

    built = []

    def build_body(phenotype, name):
        built.append(name)
        assert load_body(name).phenotype == phenotype
        return load_body(name)

    monkeypatch.setattr(models.train.anny_bodies, "build_body", build_body)
    assert main(["--out", str(tmp_path)]) == 0
    assert built == list(preset_phenotypes())
    for path in sorted(BODIES_DIR.glob("*.npz")) + [BODIES_DIR / "library.json"]:
        assert (tmp_path / path.name).read_bytes() == path.read_bytes(), path.name
