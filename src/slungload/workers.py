"""Jobs in parallel processes: the one process pool of the package.

Simulated flights (``sim.dataset``), training runs (``lab.reproduce``, ``lab.study``) and the
control study's closed-loop flights (``lab.control.study``) run through ``run_jobs``:
``fn(job)`` for every job, ``workers`` at a time, a progress bar, the results as they finish.
Each worker watches the process that started it and stops when that one goes (a ``kill`` of
``reproduce`` reaches the parent only; its workers would otherwise train on as orphans, using
the cores and writing into the output folder).

Workers are spawned by default: a forked child would inherit the parent's torch thread pools
and locks. ``start="fork"`` (where the platform has it) starts in milliseconds and is for jobs
that never touch torch, such as the simulator's (numpy and MuJoCo only).
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Literal, TypeVar

from tqdm.auto import tqdm

J = TypeVar("J")
R = TypeVar("R")

Start = Literal["spawn", "fork"]


def run_jobs(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    *,
    workers: int,
    progress: bool = True,
    desc: str = "jobs",
    unit: str = "job",
    start: Start = "spawn",
    cluster: str | None = None,
) -> Iterator[R]:
    """``fn(job)`` for every job, ``workers`` at a time (in this process when ``workers`` <= 1
    or there is one job), yielded as each finishes; a failed job raises here. ``fn`` and the
    jobs must pickle (module-level functions, dataclasses, tuples). ``cluster``: a Ray address
    (``cluster.run_on_ray``): every job a task there, one CPU each, ``workers`` unused."""
    if cluster is not None:
        from .cluster import run_on_ray  # Ray only when a cluster is asked for

        yield from run_on_ray(fn, jobs, address=cluster, progress=progress, desc=desc, unit=unit)
        return
    bar = tqdm(total=len(jobs), desc=desc, unit=unit, disable=None if progress else True)
    try:
        if workers <= 1 or len(jobs) <= 1:
            for job in jobs:
                yield fn(job)
                bar.update()
            return
        with process_pool(min(workers, len(jobs)), start=start) as pool:
            futures = [pool.submit(run_watched, fn, job, os.getpid()) for job in jobs]
            for future in as_completed(futures):
                yield future.result()
                bar.update()
    finally:
        bar.close()


def process_pool(workers: int, *, start: Start = "spawn") -> ProcessPoolExecutor:
    """A pool whose workers watch this process from their start (``watch_parent``); ``fork``
    falls back to ``spawn`` where the platform has no fork."""
    method = start if start in multiprocessing.get_all_start_methods() else "spawn"
    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=multiprocessing.get_context(method),
        initializer=watch_parent,
        initargs=(os.getpid(),),
    )


def run_watched(fn: Callable[[J], R], job: J, parent: int) -> R:
    """``fn(job)`` in a pool worker that stops when its parent goes.

    ``watch_parent`` sends the worker SIGTERM once the parent is gone, which makes a training
    run save last.ckpt and stop; the worker then exits here rather than wait for work from a
    parent that is gone.
    """
    try:
        return fn(job)
    finally:
        if os.getppid() != parent:
            os._exit(128 + signal.SIGTERM)


def watch_parent(parent: int, interval: float = 1.0) -> threading.Thread:
    """Send this process SIGTERM once it is no longer the child of process ``parent`` (checked
    every ``interval`` seconds, in a daemon thread; at once if that is already so)."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(interval)
        os.kill(os.getpid(), signal.SIGTERM)

    thread = threading.Thread(target=watch, name="watch-parent", daemon=True)
    thread.start()
    return thread
