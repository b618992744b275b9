"""``livecap batch replay`` and ``livecap batch synth``: many items through the single commands'
own code, on Ray or a local process pool, resumable, with one record file (docs/batch.md).

The plan (which items, their names, their command lines) is made here, in the driver; each item
runs in a worker through live.app.batch_items.run_item; live.app.batch_manifest keeps the
records. Ray is imported only by live.app.batch_ray, and only when a batch runs on it."""

from __future__ import annotations

import os
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from live.app import batch_storage as storage
from live.app.batch_args import REPLAY_OPTIONS, SYNTH_OPTIONS, passthrough
from live.app.batch_items import REPLAY, SYNTH, BatchItem, ItemResult, run_item
from live.app.batch_manifest import Manifest, manifest_name, read_previous
from live.app.running import EXIT_DATA_LOSS
from live.core.errors import UserInputError
from live.core.text import printable, safe_filename


@dataclass
class BatchPlan:
    command: str
    out_dir: str
    items: list[BatchItem]
    options: list[str]
    manifest: str
    cpus_per_task: float = 1.0


def parse_shard(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    first, sep, count = text.partition("/")
    if not (sep and first.isdigit() and count.isdigit() and 0 <= int(first) < int(count)):
        raise UserInputError(f"--shard wants I/N with 0 <= I < N (e.g. 0/4), not {text!r}")
    return int(first), int(count)


def read_list(path: Path) -> list[str]:
    """Sessions named in a list file, one a line; relative paths are relative to the file's folder."""
    if not path.is_file():
        raise UserInputError(f"no such list file: {path}")
    names = []
    for line in path.read_text().splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            names.append(line if storage.is_url(line) or Path(line).is_absolute() else str(path.parent / line))
    return names


def _base_name(source: str) -> str:
    name = source.rstrip("/").rsplit("/", 1)[-1]
    return name[: -len(".mcap")] if name.lower().endswith(".mcap") and len(name) > 5 else name


def session_names(sources: list[str]) -> list[str]:
    """An output folder name per session: its file name without ``.mcap``; when two share one,
    their parent folder's name goes before it (``day1__take``)."""
    names = [safe_filename(_base_name(s)) for s in sources]
    for i, name in enumerate(names):
        if names.count(name) > 1:
            parent = _base_name(sources[i].rstrip("/").rsplit("/", 1)[0]) if "/" in sources[i].rstrip("/") else ""
            names[i] = safe_filename(f"{parent}__{_base_name(sources[i])}")
    for i, name in enumerate(names):
        if names.count(name) > 1:
            j = names.index(name)
            raise UserInputError(f"two sessions would write the same folder {name}: {sources[j]} and {sources[i]} "
                                 "(rename one, or run them into different --out folders)")
    return names


def _depends_on(paths: list) -> tuple[str, ...]:
    """Option values that are files: their content goes into each item's key."""
    return tuple(storage.absolute(str(p)) for p in paths if p is not None and Path(str(p)).exists())


def _check_locations(out: str, sources: list[str]) -> None:
    """The output folder is a folder; every URL's protocol can be used here (fsspec and the
    protocol's package installed): one line now rather than one failure per item."""
    if storage.is_url(out):
        storage.exists(out)
    elif Path(out).exists() and not Path(out).is_dir():
        raise UserInputError(f"--out {out} is a file; give a folder for the batch")
    protocols = {s.split("://", 1)[0]: s for s in sources if storage.is_url(s)}
    for url in protocols.values():
        storage.check_protocol(url)


def plan_replay(args) -> BatchPlan:
    sources = list(args.sessions) + (read_list(args.list) if args.list is not None else [])
    sources = list(dict.fromkeys(storage.absolute(s) for s in sources))  # one replay of a session named twice
    if not sources:
        raise UserInputError("no sessions: give .mcap files or depth folders, or --list FILE")
    for flag in ("model", "calibration"):
        value = getattr(args, flag)
        if value is not None and not Path(value).is_file():
            raise UserInputError(f"no such file: --{flag} {value}")
        setattr(args, flag, None if value is None else Path(storage.absolute(value)))
    if args.avatar:
        from live.body.avatar import load_avatar

        load_avatar(args.avatar)  # a typo is one line now, not one failure per session
    options = passthrough(args, REPLAY_OPTIONS)
    entries = [(source, name, tuple(options)) for source, name in zip(sources, session_names(sources))]
    return _plan(REPLAY, args, entries, options, _depends_on([args.model, args.calibration, args.avatar]),
                 cpus_per_task=args.threads or 1)


def parse_seeds(text: str) -> list[int]:
    try:
        if "," in text:
            seeds = [int(s) for s in text.split(",") if s.strip()]
        elif "-" in text.strip("-"):
            low, high = (int(s) for s in text.split("-", 1))
            seeds = list(range(low, high + 1))
        else:
            seeds = list(range(int(text)))
    except ValueError:
        seeds = []
    if not seeds or min(seeds) < 0:
        raise UserInputError(f"--seeds wants N (0..N-1), A-B or a list A,B,... of seeds >= 0, not {text!r}")
    return list(dict.fromkeys(seeds))


def _clips(motions: list[str]) -> list[str]:
    clips: list[str] = []
    for m in motions:
        p = Path(m)
        if p.is_dir():
            clips += sorted(storage.absolute(c) for c in p.glob("*.bvh"))
        elif p.is_file() or storage.is_url(m):
            clips.append(storage.absolute(m))
        else:
            raise UserInputError(f"no such motion file or folder: {m}")
    if not clips:
        raise UserInputError(f"no .bvh clips in {' '.join(motions)}")
    return list(dict.fromkeys(clips))


def plan_synth(args) -> BatchPlan:
    from live.body.library import load_body
    from sim.depth_camera import get_preset

    clips, seeds = _clips(args.motion), parse_seeds(args.seeds)
    for body in args.body:
        load_body(body)  # a typo is one line now, not one failure per item
    for camera in args.camera:
        get_preset(camera)
    shared = passthrough(args, SYNTH_OPTIONS)
    entries = []
    for clip in clips:
        for body in args.body:
            body_file = Path(body).is_file()
            body_name, body_arg = (Path(body).stem, storage.absolute(body)) if body_file else (body, body)
            for camera in args.camera:
                for seed in seeds:
                    name = safe_filename(f"{_base_name(clip).removesuffix('.bvh')}__{body_name}__{camera}__s{seed}")
                    entries.append((clip, name, ("--body", body_arg, "--camera", camera, "--seed", str(seed), *shared)))
    if len({name for _, name, _ in entries}) < len(entries):
        raise UserInputError("two items would write the same file (clips or bodies with the same name): "
                             "give them different names")
    return _plan(SYNTH, args, entries, shared, _depends_on(list(args.body)))


def _plan(command: str, args, entries: list[tuple[str, str, tuple[str, ...]]], options: list[str],
          depends_on: tuple[str, ...], cpus_per_task: float = 1.0) -> BatchPlan:
    """The plan of a batch: one item per (source, name, command options) entry in this shard."""
    args.out = storage.absolute(args.out)
    _check_locations(args.out, [source for source, _, _ in entries])
    shard = parse_shard(args.shard)
    location = storage.join(args.out, manifest_name(shard))
    previous = read_previous(location, command)
    if shard is not None:  # a shard also skips what an unsharded run of the batch made
        previous = {**read_previous(storage.join(args.out, manifest_name(None)), command), **previous}
    items = [BatchItem(name=name, kind=command, source=source, out_dir=args.out, options=opts,
                       depends_on=depends_on, previous=previous.get(name))
             for i, (source, name, opts) in enumerate(entries) if shard is None or i % shard[1] == shard[0]]
    return BatchPlan(command, args.out, items, options, location, cpus_per_task)


def choose_executor(args, cpus_per_task: float = 1.0):
    """Ray when asked for (or installed and nothing else asked for); else a process pool."""
    from live.app.batch_executors import InlineExecutor, ProcessPoolBatchExecutor
    from live.app.batch_ray import INSTALL_HINT, RayExecutor, ray_installed

    if args.ray is not None:
        address = None if args.ray == "local" else args.ray
        if address is not None and args.workers is not None:
            raise UserInputError("--workers sets the CPUs of a local Ray (--ray local); a cluster has its own")
        return RayExecutor(address, cpus=args.workers, cpus_per_task=cpus_per_task, retries=args.retries)
    if args.workers is not None:
        return InlineExecutor() if args.workers == 1 else ProcessPoolBatchExecutor(args.workers, args.retries)
    if ray_installed():
        return RayExecutor(None, cpus=None, cpus_per_task=cpus_per_task, retries=args.retries)
    workers = os.cpu_count() or 1
    if not args.quiet:
        print(f"livecap batch: Ray is not installed: a local pool of {workers} processes (for Ray and clusters: "
              f"{INSTALL_HINT})", file=sys.stderr)
    return ProcessPoolBatchExecutor(workers, args.retries)


def run_batch(plan: BatchPlan, executor, *, progress: bool = True, work=run_item,
              started: float | None = None) -> Manifest:
    """Run every item of the plan on the executor; the records go to the plan's batch.json as
    they arrive. Ctrl-C stops the batch with the records so far written. ``started``: when the
    command started (perf_counter), for the wall time; default now."""
    manifest = Manifest(plan.manifest, plan.command, plan.options, executor=executor.name, workers=executor.workers,
                        records=read_previous(plan.manifest, plan.command))
    if started is not None:
        manifest.started = started
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(plan.items), desc=f"batch {plan.command}", unit="item", leave=False, file=sys.stderr,
                   disable=None, dynamic_ncols=True)

    def on_result(result: ItemResult) -> None:
        manifest.add(result)
        if bar is not None:
            bar.update(1)
            failed = sum(r.status == "failed" for r in manifest.run)
            if failed:
                bar.set_postfix(failed=failed)

    try:
        executor.run(plan.items, on_result, work)
    finally:
        if bar is not None:
            bar.close()
        manifest.write()
        storage.remove_empty_scratch_folder(plan.out_dir)
    return manifest


def _count(n: int, noun: str) -> str:
    return f"{n} {noun}" + ("" if n == 1 else "s")


def cmd_batch(args) -> int:
    started = time.perf_counter()
    plan = plan_replay(args) if args.what == REPLAY else plan_synth(args)
    executor = choose_executor(args, plan.cpus_per_task)
    try:
        manifest = run_batch(plan, executor, progress=not args.quiet, started=started)
    finally:
        executor.close()
    totals = manifest.totals()
    failed = [r for r in manifest.run if r.status == "failed"]
    if not args.quiet:
        noun = _count(totals["items"], "session" if plan.command == REPLAY else "item")
        print(f"livecap batch {plan.command}: {noun} in {totals['wall_s']:.1f} s ({totals['items_per_s'] or 0:.2f}/s; "
              f"{executor.name}, {_count(executor.workers, 'worker')}): {totals['done']} done, "
              f"{totals['skipped']} skipped (done before), {totals['failed']} failed")
        acc = totals["accuracy"]
        if acc:
            print(f"  skeleton MPJPE / PA-MPJPE {acc['mpjpe_mm']:.1f} / {acc['pa_mpjpe_mm']:.1f} mm over "
                  f"{_count(acc['sessions'], 'session')} with ground truth")
        print(f"  records: {plan.manifest}")
    for r in manifest.run:
        if r.warning and r.status != "failed":
            print(f"livecap batch: {r.name}: {printable(r.warning)}", file=sys.stderr)
    for r in failed:
        print(f"livecap batch: {r.name} failed: {printable(r.error)}", file=sys.stderr)
    return EXIT_DATA_LOSS if failed else 0
