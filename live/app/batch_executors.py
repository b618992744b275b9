"""Where a batch's items run without Ray: in this process one after the other (``--workers 1``),
or in a local pool of worker processes (``--workers N``). Ray's executor (live.app.batch_ray)
has the same two methods: ``run(items, on_result, work)`` and ``close()``.

A pool worker is a fresh interpreter (spawn: nothing of the parent's state, threads or locks
comes along) that lives for the whole batch, so it imports livecap and loads the avatar once.
A worker that dies (the OOM killer, a crash in native code) breaks the pool: the items it took
down with it run again in a new pool, up to ``retries`` times."""

from __future__ import annotations

import logging
import os
import signal
from collections.abc import Callable, Iterable
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from live.app.batch_items import BatchItem, ItemResult, run_item

Work = Callable[[BatchItem], ItemResult]
OnResult = Callable[[ItemResult], None]
#: BLAS / OpenMP pools at one thread in every worker, as the CLI runs (live.app.cli.limit_blas_threads).
WORKER_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def died(item: BatchItem, why: str) -> ItemResult:
    """The record of an item whose worker process died under it every time it ran."""
    return ItemResult(name=item.name, status="failed", source=item.source, error=why)


class InlineExecutor:
    """The items one after the other in this process: the sequential baseline, and the simplest
    way to debug one item."""

    name = "inline"
    workers = 1

    def run(self, items: Iterable[BatchItem], on_result: OnResult, work: Work = run_item) -> None:
        for item in items:
            on_result(work(item))

    def close(self) -> None:
        pass


def _init_pool_worker() -> None:
    for var, value in WORKER_ENVIRONMENT.items():
        os.environ.setdefault(var, value)
    # Ctrl-C reaches every process of the terminal's group: the parent decides what stops. A
    # replay running when it comes still stops (its own handler), and is recorded as failed.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    logging.basicConfig(level=logging.ERROR)


class ProcessPoolBatchExecutor:
    """``--workers N`` local processes, each running whole items."""

    name = "process pool"

    def __init__(self, workers: int, retries: int = 2):
        self.workers = max(int(workers), 1)
        self.retries = retries

    def run(self, items: Iterable[BatchItem], on_result: OnResult, work: Work = run_item) -> None:
        import multiprocessing

        pending = list(items)
        for attempt in range(self.retries + 1):
            if not pending:
                return
            broken: list[BatchItem] = []
            with ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                     initializer=_init_pool_worker) as pool:
                futures: dict[Future, BatchItem] = {pool.submit(work, item): item for item in pending}
                try:
                    while futures:
                        done, _ = wait(futures, return_when=FIRST_COMPLETED)
                        for fut in done:
                            item = futures.pop(fut)
                            try:
                                on_result(fut.result())
                            except BrokenProcessPool:
                                broken.append(item)
                except KeyboardInterrupt:
                    pool.shutdown(wait=True, cancel_futures=True)
                    raise
            if attempt == self.retries:
                for item in broken:
                    on_result(died(item, f"a worker process died while making it ({attempt + 1} attempts)"))
            pending = broken

    def close(self) -> None:
        pass
