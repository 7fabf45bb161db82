"""``train_ensemble``: K runs of one recipe, differing by seed, saved as one ensemble folder.

Member i trains with seed ``run.train.seed + i`` into ``out/member-i`` (``training.train``,
one after another on the same loaded dataset), and ``out/ensemble.json`` names them
(``models.ensemble``). With ``resume`` a member whose ``run.json`` exists is kept as it is and
one with only ``last.ckpt`` continues, so an interrupted ensemble resumes where it stopped.
Members can also train elsewhere (e.g. in parallel, as separate ``train`` runs) and be named
afterwards (``slungload ensemble``, ``models.ensemble.write_manifest``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

from ..config import VehicleParams
from ..data.dataset import Dataset, load_dataset
from ..models.checkpoints import LAST
from ..models.ensemble import MEMBER_PREFIX, write_manifest
from ..run_config import RunConfig
from .trainer import RUN_JSON, Run, train


def train_ensemble(
    data: str | Path | Dataset,
    run: RunConfig,
    *,
    out: str | Path,
    members: int,
    resume: bool = False,
    params: VehicleParams | None = None,
    progress: bool = True,
    **train_options: Any,
) -> list[Run | None]:
    """Train ``members`` (>= 2) seeds of ``run`` into ``out/member-i`` and write the manifest.

    Returns each member's ``Run``, or None for a member kept as finished (``resume``).
    ``train_options`` go to ``training.train`` (device, num_threads, ...)."""
    if members < 2:
        raise ValueError(f"an ensemble needs at least 2 members, got {members}")
    out = Path(out).expanduser()
    if not resume and out.exists() and any(out.iterdir()):
        raise FileExistsError(
            f"{out} is not empty: continue the ensemble with --resume (resume=True) or choose "
            "another --out (out=)"
        )
    dataset = (
        data if isinstance(data, Dataset) else load_dataset(data, window=run.window, params=params)
    )
    folders = [out / f"{MEMBER_PREFIX}{i}" for i in range(members)]
    results: list[Run | None] = []
    for i, folder in enumerate(folders):
        if resume and (folder / RUN_JSON).is_file():
            results.append(None)
            continue
        member = replace(run, train=replace(run.train, seed=run.train.seed + i))
        if progress:
            print(f"member {i + 1} of {members} (seed {member.train.seed}) -> {folder}")
        results.append(
            train(
                dataset,
                member,
                out=folder,
                resume=resume and (folder / LAST).is_file(),
                progress=progress,
                **train_options,
            )
        )
    write_manifest(out, folders)
    return results
