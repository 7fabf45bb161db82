"""Training data from the MPC's own flights (``record``): the recorded flights are
what ``simulate`` would write of the same flight, they join the base's train split only, and
bad bases and seeds are refused before anything is written."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from slungload.control.closed_loop import fly
from slungload.data.dataset import load_dataset
from slungload.data.folder import read_splits
from slungload.lab.control.config import BENCHMARK_SEEDS, RecordConfig
from slungload.lab.control.record import record_flights
from slungload.sim import Effects, SimConfig, simulate_dataset, simulate_flight
from slungload.sim.controller import PIDController

SMALL = RecordConfig(flights=(("xy_step", 2), ("roll_35", 1)), samples=32, horizon=10, steps=120)


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    out = tmp_path_factory.mktemp("record") / "base"
    simulate_dataset(out, flights=3, seed=5, workers=1, progress=False, maneuvers=("roll_35",))
    return out


def test_a_logged_flight_is_published_as_simulate_writes_it():
    cfg = SimConfig()
    want = simulate_flight("roll_35", seed=3, config=cfg, steps=90).arrays
    log = fly("roll_35", 3, PIDController(cfg.nominal), label="pid", config=cfg, steps=90)
    got = log.published(cfg.control_dt)
    assert set(got) == set(want)
    for key in want:
        np.testing.assert_array_equal(got[key], want[key], err_msg=key)


def test_recorded_flights_join_the_train_split_only(base, tmp_path):
    out = tmp_path / "recorded"
    # Two processes: the split lists the flights in the plan's order, not as they finish.
    done = record_flights("physics", base, out, SMALL, workers=2, progress=False)
    names = ("mpc_xy_step_1000", "mpc_xy_step_1001", "mpc_roll_35_1000")
    assert done.folder == out and done.flights == names and not done.skipped
    before, after = read_splits(base), read_splits(out)
    assert after["val"] == before["val"] and after["test"] == before["test"]
    assert after["train"] == [*before["train"], *names]
    ds = load_dataset(out, use_cache=False)
    for name in names:
        flight = ds.flights[name]
        assert len(flight.states) == SMALL.steps
        assert np.isfinite(flight.states).all() and np.isfinite(flight.inputs).all()
    made = json.loads((out / "vehicle.json").read_text())
    assert made["recorded"]["first_seed"] == SMALL.first_seed and made["base"] == str(base)
    # A second round on the recorded data needs other seeds: the names would collide.
    with pytest.raises(ValueError, match="another first seed"):
        record_flights("physics", out, tmp_path / "again", SMALL, progress=False)
    assert not (tmp_path / "again").exists()


def test_flights_stopped_before_one_training_window_are_left_out(tiny_run, base, tmp_path):
    # One epoch of the tiny network: its MPC leaves the arena within a second.
    config = replace(SMALL, flights=(("roll_35", 1),))
    done = record_flights(tiny_run.out, base, tmp_path / "r", config, progress=False)
    assert done.skipped == ("mpc_roll_35_1000",) and not done.flights
    assert read_splits(tmp_path / "r") == read_splits(base)
    assert not (tmp_path / "r" / "mpc_roll_35_1000.npz").exists()


def test_only_flights_of_the_nominal_simulator_make_a_base(tiny_run, tmp_path):
    # Files without the simulator's config (the paper's constants alike), another load, another
    # effect: each refused, naming the file, before anything is written.
    heavier, windless = tmp_path / "heavier", tmp_path / "windless"
    for folder, config in ((heavier, SimConfig().with_load(load_mass=0.2)),
                           (windless, SimConfig(effects=Effects().without("wind")))):  # fmt: skip
        simulate_dataset(folder, flights=1, seed=1, workers=1, progress=False, config=config,
                         maneuvers=("roll_35",))  # fmt: skip
    for folder, why in ((tiny_run.data, "nominal vehicle"), (heavier, "nominal vehicle"),
                        (windless, "another simulator config")):  # fmt: skip
        with pytest.raises(ValueError, match=why) as err:
            record_flights("physics", folder, tmp_path / "x", SMALL, progress=False)
        assert str(folder / "vehicle.json") in str(err.value)
        assert not (tmp_path / "x").exists()


def test_recorded_flights_never_fly_a_benchmarks_seeds():
    assert 100 in BENCHMARK_SEEDS and 200 in BENCHMARK_SEEDS
    with pytest.raises(ValueError, match="benchmarks' sim seeds"):
        RecordConfig(first_seed=98)
    for bad in ((("xy_step", 0),), (("xy_step", 1), ("xy_step", 2)), ()):
        with pytest.raises(ValueError, match="each maneuver once"):
            RecordConfig(flights=bad)
    with pytest.raises(ValueError, match="unknown maneuvers"):
        RecordConfig(flights=(("xy_stepp", 1),))


def test_the_command_line_records(run_cli, tiny_run, base, tmp_path, capsys):
    code, out, err = run_cli("record", "--model", str(tiny_run.out),
                             "--base", str(base), "--flights", "roll_35:1", "--samples", "8",
                             "--horizon", "5", "--steps", "110", "--out", str(tmp_path / "r"),
                             "--quiet")  # fmt: skip
    assert code == 0, err
    assert "recorded flights added to the train split" in out
    with pytest.raises(SystemExit) as exit_:  # argparse: a required option missing
        run_cli("record", "--model", str(tiny_run.out), "--out", str(tmp_path / "q"))
    assert exit_.value.code == 2 and "--base" in capsys.readouterr().err
