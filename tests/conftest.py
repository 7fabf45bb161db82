"""Shared fixtures: synthetic flights and dataset folders, the command line, quick training.

The fixtures serve the plain helpers of ``flights.py`` (one implementation of each); the
factories are session-scoped, so module-scoped fixtures may use them too.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import flights
import pytest
import torch
from flights import ADAPTIVE, ADAPTIVE_WINDOW, SMALL, TINY, VARIED_LOADS, WINDOW_ARGS

from slungload.config import ModelConfig, VehicleParams, WindowConfig
from slungload.data.dataset import Dataset, load_dataset
from slungload.data.windows import make_windows


@pytest.fixture(scope="session")
def physics_flight() -> Callable[..., flights.Flight]:
    """Factory ``physics_flight(name, seed=0, steps=40) -> Flight``: a flight of the paper's
    discrete model (``flights.physics_flight``)."""
    return flights.physics_flight


@pytest.fixture(scope="session")
def write_dataset() -> Callable[..., Path]:
    """Factory ``write_dataset(folder, lengths=None, splits=None, *, physics=False,
    vehicle=True) -> folder``: flights, split lists and vehicle.json
    (``flights.write_dataset``)."""
    return flights.write_dataset


@pytest.fixture
def run_cli(capsys: pytest.CaptureFixture[str]) -> Callable[..., tuple[int, str, str]]:
    """``run_cli(*argv) -> (exit code, stdout, stderr)``: ``slungload.cli.main`` in this
    process; the arguments may be paths."""
    from slungload.cli import main

    def run(*argv: str | Path) -> tuple[int, str, str]:
        code = main([str(a) for a in argv])
        out, err = capsys.readouterr()
        return code, out, err

    return run


@pytest.fixture(scope="session")
def train_tiny() -> Callable[..., Any]:
    """Factory ``train_tiny(data, out, *, resume=False, device="auto", **run) -> Run``:
    ``train`` of ``RunConfig.from_preset(**run)`` with the quick preset, the TINY network and
    SMALL windows unless ``run`` says otherwise; one thread, no progress bar."""
    from slungload.run_config import RunConfig
    from slungload.training.trainer import train

    def run(
        data: Path | Dataset, out: Path, *, resume: bool = False, device: str = "auto", **what: Any
    ):
        config = RunConfig.from_preset(**{"preset": "quick", "model": TINY, "window": SMALL,
                                          **what})  # fmt: skip
        return train(data, config, out=out, resume=resume, device=device, progress=False,
                     num_threads=1)  # fmt: skip

    return run


class TinyRun(NamedTuple):
    data: Path  # the dataset folder
    dataset: Dataset  # that folder loaded with SMALL windows
    out: Path  # the run folder


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory: pytest.TempPathFactory, train_tiny) -> TinyRun:
    """One quick epoch of the TINY network on physics flights in the file schema: train_0
    (40 steps), train_1 (43), val_2 (46), test_3 (49), test_4 (52). Shared by every module
    that needs a trained run: use it read-only."""
    root = tmp_path_factory.mktemp("tiny_run")
    names = [f"{split}_{i}" for i, split in enumerate(["train", "train", "val", "test", "test"])]
    lengths = {name: 40 + 3 * i for i, name in enumerate(names)}
    splits = {s: [n for n in names if n.startswith(s)] for s in ("train", "val", "test")}
    data = flights.write_dataset(root / "data", lengths, splits, physics=True)
    dataset = load_dataset(data, window=SMALL, cache_dir=root / "cache")
    train_tiny(dataset, root / "run", max_epochs=1)
    return TinyRun(data, dataset, root / "run")


@pytest.fixture(scope="session")
def untrained_predictor() -> Callable[..., Any]:
    """Factory ``untrained_predictor(config=ModelConfig(), seed=0) -> Predictor``: the
    network of ``config`` with random weights (torch seed ``seed``), its normalisation (if
    any) fitted on windows of three physics flights; the paper's M = 50, N = 25."""
    from slungload.deploy.predictor import Predictor
    from slungload.models.lstm_attention import SlungLoadNet

    paper = WindowConfig(history=50, horizon=25)
    fitting = [flights.physics_flight(f"f{i}", i, 150) for i in range(3)]
    windows = make_windows(fitting, paper)

    def make(config: ModelConfig = ModelConfig(), seed: int = 0) -> Predictor:  # noqa: B008
        torch.manual_seed(seed)
        model = SlungLoadNet(config)
        if config.normalize:
            model.fit_normalization(windows.states, windows.inputs, origin_step=paper.history - 1)
        return Predictor(model.eval(), paper, VehicleParams(), "proposed")

    return make


@pytest.fixture(scope="session")
def subprocess_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment of a ``slungload`` subprocess: its own dataset cache, one thread."""
    cache = tmp_path_factory.mktemp("cache")
    return {**os.environ, "SLUNGLOAD_CACHE": str(cache), "OMP_NUM_THREADS": "1"}


@pytest.fixture(scope="session")
def train_command() -> Callable[..., list[str]]:
    """Factory ``train_command(data, out, *extra) -> argv``: ``python -m slungload.cli train``
    with the quick preset on the CPU, one thread, SMALL windows, quiet."""

    def command(data: Path, out: Path, *extra: str) -> list[str]:
        return [
            sys.executable, "-m", "slungload.cli", "train", "--data", str(data), "--out",
            str(out), "--preset", "quick", "--device", "cpu", "--threads", "1", "--quiet",
            *WINDOW_ARGS, *extra,
        ]  # fmt: skip

    return command


@pytest.fixture(scope="session")
def weights_of() -> Callable[[Path], dict[str, torch.Tensor]]:
    """``weights_of(checkpoint) -> state_dict``: a checkpoint's network weights, on the CPU."""

    def weights(path: Path) -> dict[str, torch.Tensor]:
        return torch.load(path, map_location="cpu", weights_only=True)["state_dict"]

    return weights


@pytest.fixture(scope="module")
def varied(tmp_path_factory: pytest.TempPathFactory) -> tuple[Dataset, Any]:
    """Four simulated flights of loads drawn from ``flights.VARIED_LOADS``: the dataset read
    with ``ADAPTIVE_WINDOW`` and every window of its flights."""
    from slungload.sim import SimConfig, simulate_dataset

    out = tmp_path_factory.mktemp("adaptive") / "d"
    simulate_dataset(out, flights=4, seed=11, config=SimConfig().with_loads(**VARIED_LOADS),
                     workers=1, progress=False,
                     maneuvers=("roll_35", "xy_step", "baf_fast"))  # fmt: skip
    ds = load_dataset(out, window=ADAPTIVE_WINDOW, use_cache=False)
    return ds, make_windows(list(ds.flights.values()), ADAPTIVE_WINDOW, ds.params)


@pytest.fixture(scope="module")
def adaptive_run(varied, train_tiny, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One quick epoch of the adaptive network on the ``varied`` flights (a run folder)."""
    ds, _ = varied
    out = tmp_path_factory.mktemp("adaptive_run") / "run"
    train_tiny(ds, out, variant="no-physics", model=ADAPTIVE, window=ADAPTIVE_WINDOW,
               max_epochs=1)  # fmt: skip
    return out


@pytest.fixture(scope="session")
def trained_ensemble(tmp_path_factory: pytest.TempPathFactory, tiny_run) -> Path:
    """``train --ensemble 2`` of the tiny network on the tiny run's dataset (calibrated)."""
    from slungload.cli import main

    out = tmp_path_factory.mktemp("ensemble") / "E"
    code = main(["train", "--data", str(tiny_run.data), "--out", str(out), "--preset", "quick",
                 "--size", "tiny", "--device", "cpu", "--threads", "1", "--quiet",
                 "--ensemble", "2", "--epochs", "1", *WINDOW_ARGS])  # fmt: skip
    assert code == 0
    return out
