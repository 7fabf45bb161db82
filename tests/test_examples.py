"""The measuring scripts of ``examples/`` that BENCHMARKS quotes, on the tiny ensemble: they
agree with the package's own evaluation."""

from __future__ import annotations

import re
import runpy
import sys
from pathlib import Path

import pytest
from flights import SMALL

from slungload.evaluation.evaluator import evaluate
from slungload.evaluation.metrics import COMBINED

EXAMPLES = Path(__file__).parents[1] / "examples"


def run_example(name: str, *argv: str | Path, monkeypatch, capsys) -> str:
    """``python examples/NAME ARGV...`` in this process; its stdout."""
    monkeypatch.setattr(sys, "argv", [name, *map(str, argv)])
    runpy.run_path(str(EXAMPLES / name), run_name="__main__")
    return capsys.readouterr().out


def test_ensemble_per_flight_pools_to_evaluates_rmse(trained_ensemble, tiny_run, monkeypatch,
                                                     capsys, tmp_path):  # fmt: skip
    """Every test flight gets a line, the count covers them all, and the pooled mean is the
    RMSE `evaluate` reports for the ensemble."""
    n = SMALL.horizon
    out = run_example("ensemble_per_flight.py", trained_ensemble, "--data", tiny_run.data,
                      "--horizon", n, monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    tested = tiny_run.dataset.splits["test"].names
    assert sorted(line.split(":")[0] for line in out.splitlines()[: len(tested)]) == sorted(tested)
    assert re.search(rf"below every member on \d of {len(tested)} flights", out)
    pooled = float(re.search(r"pooled: mean ([\d.]+), members [\d.]+ [\d.]+$", out, re.M)[1])
    report = evaluate([trained_ensemble], data=tiny_run.data, out=tmp_path / "r", horizons=(n,),
                      include_physics=False, progress=False)  # fmt: skip
    (label,) = report.labels
    assert pooled == pytest.approx(report.row(label, n).mean[COMBINED], abs=6e-4)


def test_ensemble_per_step_names_the_steps_behind_physics(trained_ensemble, tiny_run,
                                                          monkeypatch, capsys):  # fmt: skip
    n = SMALL.horizon
    out = run_example("ensemble_per_step.py", trained_ensemble, "--data", tiny_run.data,
                      "--horizon", n, monkeypatch=monkeypatch, capsys=capsys)  # fmt: skip
    assert "steps where the mean is not below physics:" in out
    assert re.search(rf"^step {n}: physics [\d.]+, mean [\d.]+ \([\d.]+x\)$", out, re.M)
    assert re.search(rf"^members at step {n} : [\d.]+ [\d.]+$", out, re.M)
