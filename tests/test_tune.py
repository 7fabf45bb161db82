"""The configuration search's parts that need no Ray (``lab.study.config``, ``lab.study.tune``) and
``train --config``; the search itself runs in ``ray_cases.py`` (``test_cluster.py``)."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from slungload.lab.reproduce import BEYOND_PAPER
from slungload.lab.study.config import SearchSpace, TuneSettings
from slungload.lab.study.tune import choice_run, hand_chosen, within
from slungload.run_config import read_toml


def test_the_first_trial_is_reproduces_configuration():
    settings = TuneSettings()
    first = hand_chosen(settings.preset)
    assert within(first, SearchSpace())
    run = choice_run(first, settings.preset, 0, None)
    assert run == BEYOND_PAPER[0].scheduled(settings.preset, seed=0)
    assert not within({**first, "size": "huge"}, SearchSpace())
    assert not within({**first, "lr": 1.0}, SearchSpace())


def test_train_config_reads_a_run_file_and_refuses_options_beside_it(run_cli, tiny_run, tmp_path):
    toml = tiny_run.out / "run.toml"
    code, out, err = run_cli("train", "--data", tiny_run.data, "--config", toml, "--epochs", "1",
                             "--seed", "3", "--out", tmp_path / "again", "--quiet")  # fmt: skip
    assert code == 0, err
    again = read_toml(tmp_path / "again" / "run.toml")
    first = read_toml(toml)
    assert again.train.seed == 3 and again.model == first.model and again.window == first.window
    code, _, err = run_cli("train", "--data", tiny_run.data, "--config", toml, "--variant",
                           "no-slack", "--out", tmp_path / "x")  # fmt: skip
    assert code == 2 and "drop --variant" in err


def test_tune_help_is_light():
    code = (
        "import sys\nfrom slungload.cli import build_parser\n"
        "try:\n    build_parser().parse_args(['tune', '--help'])\nexcept SystemExit:\n    pass\n"
        "assert not {'torch', 'ray', 'optuna'} & set(sys.modules), sorted(sys.modules)\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_a_trial_without_a_physics_step_trains_the_default_load_estimate():
    choice = {**hand_chosen("quick"), "architecture": "lstm-attention", "load_estimate": "smoothed"}
    run = choice_run(choice, "quick", 0, 1)  # no error: the estimate has no meaning there
    assert run.model.architecture == "lstm-attention"
    assert run.model.load_estimate == "difference"
    kept = choice_run({**choice, "architecture": "physics-step"}, "quick", 0, 1)
    assert kept.model.load_estimate == "smoothed"


def test_trials_are_numbered_in_the_order_they_started(tmp_path):
    from slungload.lab.study.tune import OBJECTIVE, STARTED, _in_start_order, write_tune

    choice = hand_chosen("quick")
    rows = [{"trial": trial, STARTED: started, **choice, "epochs": 2, "val_rmse": 1.0,
             OBJECTIVE: objective}
            for trial, started, objective in (("f0", 30.0, 0.9), ("a1", 10.0, math.inf),
                                              ("c2", 20.0, 1.2))]  # fmt: skip
    numbered = _in_start_order(rows)  # Ray's trial ids are random: the start time orders them
    assert [(r["trial"], r["order"]) for r in numbered] == [("a1", 1), ("c2", 2), ("f0", 3)]
    assert all(STARTED not in r for r in numbered)
    best_first = sorted(numbered, key=lambda r: r[OBJECTIVE])
    write_tune(best_first, choice, TuneSettings(), tmp_path)
    lines = (tmp_path / "trials.csv").read_text().splitlines()
    assert lines[0].startswith("trial,order,") and lines[1].startswith("f0,3,")
    assert (tmp_path / "tune.png").stat().st_size > 0 and (tmp_path / "best.toml").is_file()


def test_a_budget_no_longer_than_the_grace_period_is_refused(run_cli, tmp_path):
    with pytest.raises(ValueError, match="exceed ASHA's grace period of 2 epochs"):
        TuneSettings(epochs=2)
    assert TuneSettings(epochs=3).epochs == 3 and TuneSettings(epochs=None).epochs is None
    code, _, err = run_cli("tune", "--data", tmp_path, "--out", tmp_path / "t", "--epochs", "2")
    assert code == 2 and "--epochs 3 or more" in err and not (tmp_path / "t").exists()


def test_a_preset_no_longer_than_the_grace_period_is_refused_before_anything(tmp_path):
    pytest.importorskip("ray")
    from slungload.lab.study.tune import run_tune

    with pytest.raises(ValueError, match="preset 'quick' trains 2 epochs"):
        run_tune(tmp_path, tmp_path / "t", TuneSettings(preset="quick", epochs=None))
    assert not (tmp_path / "t").exists()
