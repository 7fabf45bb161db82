"""Jobs on a Ray cluster: the engine ``workers.run_jobs`` hands its jobs to when given a
cluster address (``reproduce``, ``study data`` and ``study size`` take ``--cluster``).

Each job is one Ray task with declared resources (``cpus`` CPU threads, ``gpus`` GPUs), retried
up to ``retries`` times when its worker or node dies (a training job then resumes from its
``last.ckpt``: ``lab.reproduce.TrainingJob``). The jobs' inputs and outputs are paths: the package,
the dataset and the output folder must be on every node at the same path (a shared
filesystem); results come back as the small objects the jobs return. Ray is an optional
dependency (``pip install slungload[cluster]``), imported only here and only when a cluster is
asked for, so local runs start as fast as without it. docs/cluster.md says how to start one.

Addresses: ``auto`` (the cluster ``RAY_ADDRESS`` names, or the one ``ray start`` left on this
machine), ``local`` (a Ray instance started for this command on this machine, stopped at the
end), or ``ray://HOST:PORT`` (a remote cluster's client server).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from typing import TypeVar

from tqdm.auto import tqdm

J = TypeVar("J")
R = TypeVar("R")

LOCAL = "local"


def require_ray():
    """The ``ray`` module, or an error that says how to install it."""
    try:
        import ray
    except ImportError as exc:  # an optional extra
        raise ValueError(
            "--cluster needs Ray: pip install 'slungload[cluster]' (or pip install 'ray[tune]')"
        ) from exc
    return ray


def connect(address: str) -> bool:
    """Connect this process to the cluster at ``address`` (see the module); True when this call
    started Ray (the caller shuts it down), False when it was already connected."""
    ray = require_ray()
    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    # Ray starts its workers at niceness 15; a training task then waits behind every other
    # process of the machine. At 0 it runs as the local process pool's workers do.
    os.environ.setdefault("RAY_worker_niceness", "0")
    options = {"include_dashboard": False, "log_to_driver": False}
    if address == LOCAL:
        ray.init(**options)
    else:
        ray.init(address=address, **options)
    return True


def check_reachable(address: str | None) -> None:
    """Fail before any work when ``address`` names a cluster that cannot be reached (``auto``
    with none running, a wrong ``ray://`` address): a ``ValueError`` naming it, so a command
    does not simulate for a minute and then die. None and ``local`` need only Ray installed."""
    if address is None:
        return
    ray = require_ray()
    if address == LOCAL or ray.is_initialized():
        return
    try:
        started = connect(address)
    except ConnectionError as exc:
        raise ValueError(
            f"--cluster {address}: no Ray cluster reachable ({exc}); start one (docs/cluster.md), "
            "or use --cluster local, or leave --cluster out"
        ) from None
    if started:
        ray.shutdown()


def run_on_ray(
    fn: Callable[[J], R],
    jobs: Sequence[J],
    *,
    address: str,
    cpus: float = 1.0,
    gpus: float = 0.0,
    retries: int = 3,
    progress: bool = True,
    desc: str = "jobs",
    unit: str = "job",
) -> Iterator[R]:
    """``fn(job)`` for every job as a Ray task on the cluster at ``address``, yielded as each
    finishes; a job that fails raises here (after ``retries`` retries of a dead worker)."""
    ray = require_ray()
    started = connect(address)
    bar = tqdm(
        total=len(jobs), desc=f"{desc} on Ray", unit=unit, disable=None if progress else True
    )
    try:
        task = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=retries)(fn)
        pending = [task.remote(job) for job in jobs]
        while pending:
            done, pending = ray.wait(pending, num_returns=1)
            yield ray.get(done[0])
            bar.update()
    finally:
        bar.close()
        if started:
            ray.shutdown()
