"""What a new user meets first: fast help, split lists, the maneuver list, and ablations that
give every variant its training budget whatever the machine's load."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import pytest

from slungload.cli import main
from slungload.config import LossWeights, ModelConfig, WindowConfig
from slungload.evaluation.report import _budget_warnings, _epochs
from slungload.lab.reproduce import BEYOND_PAPER, _training_jobs, stopped_by_time_cap
from slungload.run_config import PRESETS, RunConfig
from slungload.sim.dataset import flight_plan
from slungload.sim.maneuvers import MANEUVER_DESCRIPTIONS, MANEUVERS


def test_help_loads_neither_torch_nor_mujoco():
    # Every subcommand's --help is built from name tables in light modules.
    code = (
        "import sys\n"
        "from slungload.cli import build_parser\n"
        "p = build_parser()\n"
        "for c in ('simulate', 'train', 'evaluate', 'reproduce', 'split', 'export'):\n"
        "    try:\n"
        "        p.parse_args([c, '--help'])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "heavy = [m for m in ('torch', 'mujoco', 'lightning') if m in sys.modules]\n"
        "assert not heavy, heavy\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_every_maneuver_says_what_it_flies(capsys):
    assert set(MANEUVER_DESCRIPTIONS) == set(MANEUVERS)
    assert main(["maneuvers"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == len(MANEUVERS)
    assert any(line.startswith("roll_35") and "roll" in line.split(None, 1)[1] for line in lines)


def test_simulate_can_fly_chosen_maneuvers():
    plan = flight_plan(5, ["roll_35", "baf_fast"])
    assert [family for family, _ in plan] == ["roll_35", "baf_fast"] * 2 + ["roll_35"]
    with pytest.raises(ValueError, match="unknown maneuvers"):
        flight_plan(2, ["no_such_maneuver"])


def flights(folder, count: int):
    folder.mkdir()
    for i in range(count):
        (folder / f"f{i:02d}.npz").write_bytes(b"")  # listing only: split reads no flight
    return folder


def read(folder, split: str) -> list[str]:
    """Flight names of a split list (written with the authors' ``.npz`` suffix)."""
    return [n.removesuffix(".npz") for n in (folder / f"{split}.txt").read_text().split()]


def test_split_draws_shares_by_flight(capsys, tmp_path):
    data = flights(tmp_path / "d", 12)
    assert main(["split", str(data), "--val", "0.25", "--test", "0.25", "--seed", "3"]) == 0
    names = {s: read(data, s) for s in ("train", "val", "test")}
    assert [len(names[s]) for s in ("train", "val", "test")] == [6, 3, 3]
    assert sorted(sum(names.values(), [])) == [f"f{i:02d}" for i in range(12)]  # each once
    # Seeded: the same draw again; existing lists are kept unless --overwrite.
    code = main(["split", str(data)])
    assert code == 2 and "--overwrite" in capsys.readouterr().err
    assert main(["split", str(data), "--val", "0.25", "--test", "0.25", "--seed", "3",
                 "--overwrite"]) == 0  # fmt: skip
    assert {s: read(data, s) for s in names} == names


def test_split_takes_named_flights(capsys, tmp_path):
    data = flights(tmp_path / "d", 4)
    assert main(["split", str(data), "--val", "f01", "--test", "f02,f03.npz"]) == 0
    assert (read(data, "train"), read(data, "val"), read(data, "test")) == (
        ["f00"],
        ["f01"],
        ["f02", "f03"],
    )
    code = main(["split", str(data), "--val", "nope", "--overwrite"])
    assert code == 2 and "nope" in capsys.readouterr().err


def write_run(folder, *, epochs: int, reason: str, budget: int = 45):
    folder.mkdir(parents=True)
    summary = {"epochs": epochs, "stop_reason": reason, "config": {"train": {"max_epochs": budget}}}
    (folder / "run.json").write_text(json.dumps(summary))
    (folder / "last.ckpt").write_bytes(b"")


def test_reproduce_resumes_runs_the_time_cap_stopped(tmp_path):
    runs = tmp_path / "runs"
    write_run(runs / "proposed-s0", epochs=24, reason="max_time")
    write_run(runs / "no-slack-s0", epochs=45, reason="max_epochs")
    write_run(runs / "no-physics-s0", epochs=30, reason="early_stopping")
    assert stopped_by_time_cap(runs / "proposed-s0")
    assert not stopped_by_time_cap(runs / "no-slack-s0")
    runs = [RunConfig(v) for v in ("proposed", "no-slack", "no-physics")]
    jobs = _training_jobs(tmp_path, tmp_path / "data", runs, device="cpu")
    # Only the capped run trains again: resumed from last.ckpt, without the cap.
    assert [(j.run.variant, j.resume, j.run.train.max_time) for j in jobs] == [
        ("proposed", True, None)
    ]
    assert jobs[0].run == runs[0].uncapped() and runs[0].train.max_time is not None


def test_the_report_says_loudly_when_the_time_cap_cut_a_run_short():
    capped = {"label": "proposed", "seed": 0, "epochs": 24, "stop_reason": "max_time",
              "configs": {"train": {"max_epochs": 45}}}  # fmt: skip
    full = {"label": "no-slack", "seed": 0, "epochs": 45, "stop_reason": "max_epochs"}
    text = "\n".join(_budget_warnings(SimpleNamespace(models=(capped, full))))
    assert "stopped by the time cap at epoch 24 of 45" in text and "no-slack" not in text
    assert _budget_warnings(SimpleNamespace(models=(full,))) == []
    assert "24 of 45" in _epochs(capped) and _epochs(full) == "45"


def test_the_default_budget_is_epochs_with_the_clock_only_a_safety_net():
    config = PRESETS["default"].config
    # 45 epochs take ~5-8 min on this machine; the cap is far beyond a loaded machine's time.
    assert config.max_epochs == 45 and config.max_time >= 6 * 600


def test_a_missing_vehicle_json_is_one_readable_line(write_dataset, tmp_path):
    # In its own process: pytest records warnings instead of printing them.
    folder = write_dataset(tmp_path / "d", vehicle=False)
    command = [sys.executable, "-m", "slungload.cli", "inspect", str(folder)]
    done = subprocess.run(command, capture_output=True, text=True)
    assert done.returncode == 0 and "flights" in done.stdout
    notes = [line for line in done.stderr.splitlines() if "vehicle.json" in line]
    assert notes and all(line.startswith("slungload: note: ") for line in notes)
    assert "warnings.warn" not in done.stderr and "DataWarning" not in done.stderr


def test_run_folders_name_the_architecture_and_the_fit():
    assert RunConfig("proposed").folder() == "proposed-s0"  # the paper's network, as before
    step = ModelConfig(architecture="physics-step")
    run = RunConfig.from_preset("quick", variant="no-physics", model=step, fit_constants=True,
                                seed=2)  # fmt: skip
    assert run.folder() == "physics-step-no-physics-fitted-s2"
    run = RunConfig("no-physics", model=step, loss=LossWeights(steps="physics-relative"),
                    window=WindowConfig(horizon=50))  # fmt: skip
    assert run.folder() == "physics-step-no-physics-relative-N50-s0"
    (job,) = _training_jobs(Path("/o"), Path("/d"), [run], device="cpu")
    assert job.out == Path("/o/runs") / run.folder() and job.run == run
    smoothed = replace(step, load_estimate="smoothed")
    run = RunConfig("no-physics", model=smoothed).scheduled("quick", seed=1)
    assert run.folder() == "physics-step-no-physics-smoothed-s1"
    assert run.preset == "quick" and run.train == replace(PRESETS["quick"].config, seed=1)
    # reproduce's configuration beyond the paper keeps the folder name of its earlier runs
    (beyond,) = BEYOND_PAPER
    assert beyond.folder() == "physics-step-no-physics-mixed-N50-smoothed-s0"


# The public names of slungload 0.1.0 as released before the foundations (issue 21) moved
# their homes; each must still be importable from the package, but for the lab's, which the
# package root no longer exports (the product never loads the lab; CHANGELOG.md): those are
# importable from their homes in ``slungload.lab``.
# Removed before 0.1.0 was released (CHANGELOG.md): the evaluation's deprecated predictors.
GONE = {"NetworkPredictor", "PhysicsPredictor"}
LAB_NAMES = {
    "BenchmarkResult": "slungload.lab.bench.report",
    "benchmark": "slungload.lab.bench.benchmarks",
    "Reproduction": "slungload.lab.reproduce",
    "reproduce": "slungload.lab.reproduce",
}
RELEASED_NAMES = tuple(
    name
    for name in (
        "BenchmarkResult CompiledPredictor Controller Dataset DatasetError DatasetSummary Effects "
        "ExportResult Flight FlightFormatError FlightWindow GROUPS INPUT_DIM LOSS_VARIANTS "
        "LoadedModel LossTerms LossWeights MANEUVERS MODELS Measurement ModelConfig "
        "NetworkPredictor OnnxModelError OnnxPredictor PIDController PRESETS PhysicsPredictor "
        "PhysicsStepNet Prediction Predictor Preset READERS Report Reproduction Run STATE_DIM "
        "SimConfig SimulatedDataset SlungLoadNet TrainConfig TrainingDiverged TrainingInterrupted "
        "VehicleParams WindowConfig Windows benchmark build compute_loss count_parameters "
        "estimate_load_state evaluate evaluate_runs export flight_window load_checkpoint "
        "load_dataset load_vehicle make_windows model_config_for quat_error read_flight "
        "read_splits "
        "reproduce rollout simulate_dataset simulate_flight step summarize time_inference train "
        "write_report __version__"
    ).split()
    if name not in LAB_NAMES and name not in GONE
)


def test_every_public_name_resolves_and_the_released_ones_are_kept():
    import slungload

    assert set(RELEASED_NAMES) <= set(slungload.__all__)
    for name in slungload.__all__:
        assert getattr(slungload, name) is not None, name
    import importlib

    assert not GONE & set(slungload.__all__)
    # the MPC a vehicle's loop calls, from the root (numpy only: ``control.mppi``)
    assert {"Command", "InputLimits", "MPCConfig", "MPPIController", "ReferenceAhead"} <= set(
        slungload.__all__
    )
    for name, module in LAB_NAMES.items():
        assert name not in slungload.__all__
        assert getattr(importlib.import_module(module), name) is not None, name
