"""Ray checks, run by ``test_cluster.py`` inside a private network namespace whose only
interface is loopback (never collected on their own: Ray binds to the machine's address even
when asked for 127.0.0.1). They start one local Ray instance of two CPUs for the module."""

from __future__ import annotations

import os
from pathlib import Path

import flights
import pytest
from flights import SMALL, TINY

from slungload.cluster import run_on_ray
from slungload.evaluation.evaluator import evaluate
from slungload.lab.reproduce import _training_jobs, run_training_jobs
from slungload.run_config import RunConfig

ray = pytest.importorskip("ray")


@pytest.fixture(scope="module", autouse=True)
def local_cluster():
    os.environ["RAY_USAGE_STATS_ENABLED"] = "0"
    os.environ["RAY_worker_niceness"] = "0"  # as cluster.connect: not behind every process
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    names = [f"{split}_{i}" for i, split in enumerate(["train", "train", "val", "test"])]
    splits = {s: [n for n in names if n.startswith(s)] for s in ("train", "val", "test")}
    return flights.write_dataset(tmp_path_factory.mktemp("ray") / "data",
                                 {n: 40 + 3 * i for i, n in enumerate(names)}, splits,
                                 physics=True)  # fmt: skip


def _runs() -> list[RunConfig]:
    return [RunConfig.from_preset(preset="quick", variant=v, model=TINY, window=SMALL, seed=s,
                                  max_epochs=1)
            for v in ("proposed", "no-physics") for s in (0, 1)]  # fmt: skip


def _rmse_table(out: Path, data: Path) -> list[tuple]:
    """Every row of the RMSE table (label, horizon, mean and std per group)."""
    report = evaluate(sorted(out.glob("runs/*")), data=data, horizons=(SMALL.horizon,),
                      include_physics=False, progress=False)  # fmt: skip
    return sorted((r.label, r.horizon, sorted(r.mean.items()), sorted(r.std.items()))
                  for r in report.table)  # fmt: skip


def test_a_grid_on_ray_gives_the_local_runners_table_and_a_rerun_trains_nothing(data, tmp_path):
    tables = []
    for engine in ("local", "ray"):
        out = tmp_path / engine
        jobs = _training_jobs(out, data, _runs(), device="cpu")
        assert len(jobs) == 4
        run_training_jobs(jobs, workers=1, progress=False,
                          cluster=None if engine == "local" else "auto")  # fmt: skip
        tables.append(_rmse_table(out, data))
        assert _training_jobs(out, data, _runs(), device="cpu") == []  # all finished
    assert tables[0] == tables[1]


def _dies_once(marker: Path) -> str:
    """A task whose first attempt loses its worker process (as a node going down would)."""
    if not marker.exists():
        marker.write_text("first attempt")
        os._exit(1)
    return marker.read_text()


def test_a_task_whose_worker_dies_is_retried_and_finishes(tmp_path):
    markers = [tmp_path / f"m{i}" for i in range(3)]
    results = list(run_on_ray(_dies_once, markers, address="auto", progress=False))
    assert sorted(results) == ["first attempt"] * 3


def test_tune_searches_and_its_best_configuration_trains(tmp_path):
    from slungload.cli import main
    from slungload.lab.study.config import SearchSpace, TuneSettings
    from slungload.lab.study.tune import run_tune

    names = [f"{split}_{i}" for i, split in enumerate(["train", "train", "val", "test"])]
    splits = {s: [n for n in names if n.startswith(s)] for s in ("train", "val", "test")}
    data = flights.write_dataset(tmp_path / "long", {n: 60 for n in names}, splits, physics=True)
    space = SearchSpace(architecture=("lstm-attention",), variant=("proposed", "no-physics"),
                        steps=("paper",), horizon=(SMALL.horizon,), load_estimate=("difference",),
                        size=("tiny",), batch_size=(32,), lr=(1e-3, 3e-3))  # fmt: skip
    settings = TuneSettings(
        trials=3, preset="quick", epochs=2, final_preset="quick",
        horizon=SMALL.horizon, grace_epochs=1, history=SMALL.history,
    )  # fmt: skip
    rows = run_tune(data, tmp_path / "tune", settings, space, cluster="auto")
    assert len(rows) == 3 and sorted(r["order"] for r in rows) == [1, 2, 3]  # as they started
    assert all(1 <= r["epochs"] <= 2 and r["val_rmse"] > 0 for r in rows)  # every epoch reported
    assert (tmp_path / "tune" / "trials.csv").read_text().count("\n") == 4
    text = (tmp_path / "tune" / "tune.md").read_text()
    assert "outside this search space" in text  # the tiny space excludes reproduce's choice
    best = tmp_path / "tune" / "best.toml"
    assert best.is_file() and (tmp_path / "tune" / "tune.png").stat().st_size > 0
    # no TensorBoard logger (it warns on every stopped trial's +inf objective); CSV/JSON kept
    assert not list((tmp_path / "tune" / "ray").rglob("events.out.tfevents*"))
    assert list((tmp_path / "tune" / "ray").rglob("progress.csv"))
    assert main(["train", "--data", str(data), "--config", str(best), "--epochs", "1",
                 "--out", str(tmp_path / "retrained"), "--quiet"]) == 0  # fmt: skip
    assert (tmp_path / "retrained" / "run.json").is_file()
