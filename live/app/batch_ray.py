"""Batch items as Ray Core tasks (the ``cluster`` extra: ``pip install 'livecap[cluster]'``).

Ray is imported here only, and only when a batch runs on it. Without an address a local Ray
starts in this process with this machine's cores; ``auto`` or an address (``HOST:6379``,
``ray://HOST:10001``) joins a running cluster, whose workers need livecap installed and the
batch's inputs and outputs within reach (docs/batch.md). Each task is one item (``run_item``);
Ray reuses its worker processes, so a worker imports livecap and loads the avatar once. A task
whose worker or node dies is run again by Ray up to ``retries`` times (``max_retries``); an
item's own failure is not an exception (run_item records it), so it is never retried."""

from __future__ import annotations

import importlib.util
import logging
import os
from collections.abc import Iterable

from live.app.batch_executors import WORKER_ENVIRONMENT, OnResult, Work, died
from live.app.batch_items import BatchItem, run_item
from live.core.errors import UserInputError

INSTALL_HINT = "pip install 'livecap[cluster]'"
#: Object store of a local Ray: items and results are small records, not arrays.
LOCAL_OBJECT_STORE_BYTES = 256 * 1024 * 1024
#: Tasks in flight per worker: enough to keep every worker busy, few enough that a batch of
#: 100,000 items does not hold 100,000 task records in the driver.
IN_FLIGHT_PER_WORKER = 4


def ray_installed() -> bool:
    return importlib.util.find_spec("ray") is not None


class RayExecutor:
    """Items as Ray tasks on a local Ray (``address`` None) or a cluster."""

    name = "ray"

    def __init__(self, address: str | None = None, *, cpus: int | None = None, cpus_per_task: float = 1.0,
                 retries: int = 3):
        if not ray_installed():
            raise UserInputError(f"--ray needs Ray: {INSTALL_HINT} (or run a local process pool with --workers N)")
        import ray

        self.cpus_per_task = float(cpus_per_task)
        self.retries = int(retries)
        self.started = False
        if not ray.is_initialized():
            options: dict = {"include_dashboard": False, "logging_level": logging.ERROR, "log_to_driver": False}
            if address is None:
                # A local Ray's workers inherit this environment (a runtime_env would start new
                # workers for it, ~1 s later).
                for var, value in WORKER_ENVIRONMENT.items():
                    os.environ.setdefault(var, value)
                options.update(num_cpus=cpus, object_store_memory=LOCAL_OBJECT_STORE_BYTES)
            else:
                options.update(address=address, runtime_env={"env_vars": dict(WORKER_ENVIRONMENT)})
            try:
                ray.init(**options)
            except (ConnectionError, ValueError, RuntimeError) as exc:
                raise UserInputError(f"cannot join the Ray cluster at {address}: {exc}") from None
            self.started = True
        self.workers = max(int(ray.cluster_resources().get("CPU", 1) // self.cpus_per_task), 1)
        self.name = "ray (local)" if address is None else f"ray ({address})"

    def run(self, items: Iterable[BatchItem], on_result: OnResult, work: Work = run_item) -> None:
        import ray

        task = ray.remote(work).options(num_cpus=self.cpus_per_task, max_retries=self.retries,
                                        retry_exceptions=False)
        queue = iter(items)
        in_flight: dict = {}
        window = self.workers * IN_FLIGHT_PER_WORKER
        try:
            while True:
                for item in queue:
                    in_flight[task.remote(item)] = item
                    if len(in_flight) >= window:
                        break
                if not in_flight:
                    return
                done, _ = ray.wait(list(in_flight), num_returns=1)
                for ref in done:
                    item = in_flight.pop(ref)
                    try:
                        result = ray.get(ref)
                    except ray.exceptions.RayError as exc:  # its worker or node died every time
                        result = died(item, f"its Ray worker died {self.retries + 1} times "
                                      f"({type(exc).__name__})")
                    on_result(result)
        except KeyboardInterrupt:
            for ref in in_flight:
                ray.cancel(ref, force=True)
            raise

    def close(self) -> None:
        if self.started:
            import ray

            ray.shutdown()
