"""Varied loads in the simulator: per-flight vehicle and load constants drawn from ranges,
recorded in each flight's file, read back as ``Flight.constants``; without ranges nothing
changes."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace

import numpy as np
import pytest

from slungload.cli import build_parser
from slungload.config import VehicleParams, WindowConfig, to_dict
from slungload.data import load_dataset
from slungload.data.flight import FlightFormatError, recorded_constants
from slungload.data.readers import read_flight
from slungload.fileio import CONSTANT_KEYS, read_npz, write_npz
from slungload.sim import SimConfig, simulate_dataset, simulate_flight
from slungload.sim.config import LoadRanges
from slungload.sim.plant import Plant

VARIED = SimConfig().with_loads(load_mass=(0.05, 0.30), cable_length=(0.5, 1.0))
MANEUVERS = ("xy_step", "roll_35", "baf_very_fast")  # short flights


def _hashes(folder):
    return {p.name: hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def varied(tmp_path_factory):
    out = tmp_path_factory.mktemp("varied") / "d"
    simulate_dataset(out, flights=3, seed=4, config=VARIED, workers=1, progress=False,
                     maneuvers=MANEUVERS)  # fmt: skip
    return out


def test_with_loads_sets_values_and_ranges():
    assert SimConfig().with_loads() == SimConfig()
    assert SimConfig().with_loads(load_mass=None) == SimConfig()
    one = SimConfig().with_loads(load_mass=0.2, cable_length=0.9)
    assert not one.loads.active
    assert one.load_mass == 0.2 and one.cable_length == pytest.approx(0.9)
    assert one.string_length == pytest.approx(0.8)  # less the attachment and half the cube
    assert SimConfig().with_loads(load_mass=(0.2, 0.2)) == SimConfig().with_loads(load_mass=0.2)
    assert VARIED.loads == LoadRanges(load_mass=(0.05, 0.30), cable_length=(0.5, 1.0))
    nominal = VARIED.nominal
    assert not nominal.loads.active
    assert nominal.load_mass == pytest.approx(0.175)
    assert nominal.cable_length == pytest.approx(0.75)
    assert nominal.mass_quad == SimConfig().mass_quad  # no range: the single value
    assert SimConfig().nominal == SimConfig()


def test_bad_ranges_are_refused():
    with pytest.raises(ValueError, match="low <= high"):
        LoadRanges(load_mass=(0.3, 0.1))
    with pytest.raises(ValueError, match="low <= high"):
        LoadRanges(mass_quad=(0.0, 1.0))
    with pytest.raises(ValueError, match="attachment and half the load"):
        SimConfig().with_loads(cable_length=(0.05, 0.8))


def test_draws_are_uniform_within_the_ranges_and_independent_of_each_other():
    rng = np.random.default_rng(0)
    draws = [VARIED.drawn(rng) for _ in range(200)]
    masses = np.array([c.load_mass for c in draws])
    lengths = np.array([c.cable_length for c in draws])
    assert masses.min() >= 0.05 and masses.max() <= 0.30 and np.ptp(masses) > 0.2
    assert lengths.min() >= 0.5 - 1e-9 and lengths.max() <= 1.0 + 1e-9
    assert all(c.mass_quad == SimConfig().mass_quad and not c.loads.active for c in draws)
    # A range on the cable does not move the mass drawn from the same stream.
    masses_only = SimConfig().with_loads(load_mass=(0.05, 0.30))
    again = [masses_only.drawn(np.random.default_rng(7)).load_mass for _ in range(2)]
    assert again[0] == VARIED.drawn(np.random.default_rng(7)).load_mass == again[1]
    untouched = np.random.default_rng(3)
    assert SimConfig().drawn(untouched) == SimConfig()
    assert untouched.uniform() == np.random.default_rng(3).uniform()


def test_the_plant_flies_the_drawn_load():
    flown = VARIED.drawn(np.random.default_rng(1))
    plant = Plant(flown)
    assert plant.model.body("load").mass[0] == pytest.approx(flown.load_mass)
    assert plant.model.tendon_range[plant.cable, 1] == pytest.approx(flown.string_length)
    assert np.linalg.norm(plant.p_load - plant.p) == pytest.approx(flown.cable_length)


def test_a_flight_records_its_constants_and_keeps_its_other_streams():
    plain = simulate_flight("roll_35", seed=11, steps=40)
    varied = simulate_flight("roll_35", seed=11, steps=40, config=VARIED)
    assert not set(CONSTANT_KEYS) & set(plain.arrays)
    assert plain.config == SimConfig()
    for key in CONSTANT_KEYS:
        assert varied.arrays[key].shape == ()
    assert float(varied.arrays["mass_load"]) == varied.config.load_mass
    assert float(varied.arrays["cable_length"]) == pytest.approx(varied.config.cable_length)
    assert float(varied.arrays["mass_quad"]) == SimConfig().mass_quad
    assert varied.params == plain.params  # the thrust error and offset draws are the same
    # The load hangs at its own cable length.
    r = np.linalg.norm(varied.truth["p_load"] - varied.truth["p"], axis=1)
    assert np.median(r) == pytest.approx(varied.config.cable_length, abs=0.01)


def test_a_varied_dataset_records_truth_and_nominal(varied):
    meta = json.loads((varied / "vehicle.json").read_text())
    assert meta["vehicle"]["mass_load"] == pytest.approx(0.175)
    assert meta["vehicle"]["cable_length"] == pytest.approx(0.75)
    assert SimConfig.from_dict(meta["sim"]) == VARIED
    files = sorted(varied.glob("*.npz"))
    masses = {float(read_npz(p)["mass_load"]) for p in files}
    assert len(masses) == len(files)  # one draw per flight
    ds = load_dataset(varied, window=WindowConfig(20, 5, 10), use_cache=False)
    assert not [n for n in ds.notes if "unknown keys" in n]  # the keys are known, not noted
    for name, flight in ds.flights.items():
        raw = read_npz(varied / f"{name}.npz")
        assert flight.constants == replace(
            ds.params, mass_load=float(raw["mass_load"]), cable_length=float(raw["cable_length"])
        )


def test_the_cache_keeps_the_constants(varied, tmp_path):
    window = WindowConfig(20, 5, 10)
    first = load_dataset(varied, window=window, cache_dir=tmp_path)
    second = load_dataset(varied, window=window, cache_dir=tmp_path)
    assert second.from_cache and not first.from_cache
    assert {n: f.constants for n, f in second.flights.items()} == {
        n: f.constants for n, f in first.flights.items()
    }
    assert all(f.constants is not None for f in second.flights.values())


def test_a_varied_dataset_is_the_same_for_the_same_seed(varied, tmp_path):
    again = tmp_path / "again"
    simulate_dataset(again, flights=3, seed=4, config=VARIED, workers=2, progress=False,
                     maneuvers=MANEUVERS)  # fmt: skip
    assert _hashes(again) == _hashes(varied)


def test_without_ranges_vehicle_json_has_no_load_ranges(tmp_path):
    simulate_dataset(tmp_path / "d", flights=1, seed=0, workers=1, progress=False,
                     maneuvers=["baf_very_fast"])  # fmt: skip
    meta = json.loads((tmp_path / "d" / "vehicle.json").read_text())
    assert "loads" not in meta["sim"] and "loads" in to_dict(SimConfig())
    assert not set(CONSTANT_KEYS) & set(read_npz(tmp_path / "d" / "baf_very_fast_00.npz"))


def test_recorded_constants_are_checked(tmp_path):
    params = VehicleParams()
    assert recorded_constants({}, params, tmp_path) is None
    found = recorded_constants({"mass_load": np.array(0.2)}, params, tmp_path)
    assert found == replace(params, mass_load=0.2)
    for bad in (np.array(-1.0), np.array([0.1, 0.2]), np.array(np.nan), np.array("x")):
        with pytest.raises(FlightFormatError, match="mass_load"):
            recorded_constants({"mass_load": bad}, params, tmp_path / "f.npz")


def test_the_npz_reader_refuses_a_bad_recorded_constant(varied, tmp_path):
    raw = read_npz(next(varied.glob("*.npz")))
    raw["cable_length"] = np.array(0.0)
    write_npz(tmp_path / "f.npz", raw)
    with pytest.raises(FlightFormatError, match="cable_length"):
        read_flight(tmp_path / "f.npz", VehicleParams())


def test_simulate_options_take_a_value_or_a_range(capsys):
    args = build_parser().parse_args(
        ["simulate", "--out", "x", "--load-mass", "0.05:0.3", "--cable-length", "0.8"]
    )
    assert args.load_mass == (0.05, 0.3) and args.cable_length == 0.8 and args.mass_quad is None
    for bad in ("0.3:0.05", "-1", "a:b", "1:2:3"):
        with pytest.raises(SystemExit):
            build_parser().parse_args(["simulate", "--out", "x", "--vehicle-mass", bad])
    assert "LO:HI" in capsys.readouterr().err
