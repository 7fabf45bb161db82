"""What a configuration search (``slungload tune``, ``study.tune``) may choose and on what
budget, without importing torch or Ray (the command line's help reads it)."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SearchSpace:
    """What a trial may choose (each tuple: the choices; ``lr``: a log-uniform range)."""

    architecture: tuple[str, ...] = ("lstm-attention", "physics-step")
    variant: tuple[str, ...] = ("proposed", "no-slack", "no-physics")
    steps: tuple[str, ...] = ("paper", "physics-relative", "mixed")
    horizon: tuple[int, ...] = (25, 50)  # training horizon N
    load_estimate: tuple[str, ...] = ("difference", "smoothed")
    size: tuple[str, ...] = ("paper", "medium", "small", "tiny")
    batch_size: tuple[int, ...] = (32, 64, 128)
    lr: tuple[float, float] = (2e-4, 3e-3)  # 1/step, log-uniform


@dataclass(frozen=True)
class TuneSettings:
    """The search: how many trials, on what budget, with which seeds."""

    trials: int = 24
    preset: str = "default"  # the search budget's schedule ...
    epochs: int | None = 10  # ... cut to this many epochs (its cosine fitted to them)
    final_preset: str = "default"  # best.toml's schedule: what the chosen run retrains with
    seeds: tuple[int, int] = (0, 1)  # the objective is their mean
    horizon: int = 50  # N of the objective
    concurrent: int = 2  # trials at a time (one CPU each)
    grace_epochs: int = 2  # ASHA: epochs every trial gets before it may be stopped
    search_seed: int = 0  # TPE's random seed
    history: int = 50  # M of every trial
