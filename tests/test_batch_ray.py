"""`livecap batch` on Ray: a two-node cluster on this machine gives the outputs of sequential
`livecap replay`, byte for byte; a worker killed mid-batch leaves the batch complete after Ray
runs its task again. Marked ``ray`` (about 20 s together): ``-m 'not ray'`` leaves them out."""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path

import pytest
from test_batch import assert_same_results, make_sessions, records, reference_replays

from live.app.cli import main

ray = pytest.importorskip("ray")
pytestmark = pytest.mark.ray
NODE = {"num_cpus": 1, "object_store_memory": 80 * 1024 * 1024}


@pytest.fixture(scope="module")
def cluster():
    from ray.cluster_utils import Cluster

    c = Cluster(initialize_head=True, head_node_args={**NODE, "include_dashboard": False})
    c.add_node(**NODE)
    c.wait_for_nodes()
    yield c
    ray.shutdown()
    c.shutdown()


@pytest.fixture(scope="module")
def sessions(tmp_path_factory, shared_bvh) -> list[Path]:
    return make_sessions(tmp_path_factory.mktemp("sessions"), shared_bvh, count=3)


@pytest.fixture(scope="module")
def reference(sessions, tmp_path_factory) -> dict[str, Path]:
    return reference_replays(sessions, tmp_path_factory.mktemp("reference"), "--avatar", "default")


def test_two_node_cluster_matches_sequential_replay(cluster, sessions, reference, tmp_path):
    out = tmp_path / "batch"
    assert main(["batch", "replay", *map(str, sessions), "--out", str(out), "--avatar", "default",
                 "--ray", cluster.address, "--quiet"]) == 0
    assert_same_results(out, reference)
    recs = records(out)
    assert {r["status"] for r in recs.values()} == {"done"}
    assert len({r["worker"] for r in recs.values()}) >= 2  # both nodes' workers took sessions


def kill_first_attempt(item):
    """Run the item, then kill this worker process before its result leaves, once (a marker file
    beside the batch says it happened): Ray must run the task again."""
    from live.app.batch_items import run_item

    result = run_item(item)
    marker = Path(item.out_dir).parent / f"killed-{item.name}"
    if item.name == "take1" and not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return result


def test_a_worker_killed_mid_batch_leaves_the_batch_complete(cluster, sessions, reference, tmp_path):
    from live.app.batch import plan_replay, run_batch
    from live.app.batch_ray import RayExecutor
    from live.app.cli import build_parser

    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # Ray workers cannot import test modules
    out = tmp_path / "batch"
    args = build_parser().parse_args(["batch", "replay", *map(str, sessions), "--out", str(out),
                                      "--avatar", "default"])
    executor = RayExecutor(cluster.address, retries=2)
    try:
        manifest = run_batch(plan_replay(args), executor, progress=False, work=kill_first_attempt)
    finally:
        executor.close()
    killed_pid = (tmp_path / "killed-take1").read_text()
    assert [r.status for r in manifest.run] == ["done"] * 3
    recs = records(out)
    assert {r["status"] for r in recs.values()} == {"done"}
    assert not recs["take1"]["worker"].endswith(f":{killed_pid}")  # the retry ran in another process
    assert_same_results(out, reference)
