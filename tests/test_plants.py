"""Tests of the plant families and the named plants: the ``chain`` family's physics against
known solutions (hover, the hanging chain's swing, its rate loop), its look-ahead against the
plant itself, and ``--plant`` through the configs and the command line."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from slungload.config import to_dict
from slungload.sim import Effects, SimConfig, simulate_flight
from slungload.sim.chain import ChainPlant, bead_masses
from slungload.sim.families import make_plant
from slungload.sim.plant import Plant, PlantParams
from slungload.sim.plants import DEFAULT_PLANT, PLANTS, plant_config

CHAINS = [name for name in PLANTS if plant_config(name).family == "chain"]


def ideal(name: str) -> SimConfig:
    return plant_config(name).with_effects(Effects.none())


def hold(plant, seconds: float, thrust: float, rates=(0.0, 0.0, 0.0)) -> list[np.ndarray]:
    """Advance with a constant command in still air; the load offsets from the vehicle."""
    rel = []
    for _ in range(round(seconds / plant.cfg.control_dt)):
        plant.advance(thrust, np.asarray(rates, dtype=float), np.zeros(3))
        rel.append(plant.p_load - plant.p)
    return rel


def hanging_chain_period(cfg: SimConfig) -> float:
    """Period, s, of the slowest swing of the ideal chain plant: the vehicle (attitude held,
    thrust balancing the weight) free to move sideways, point masses on massless links,
    linearised: M x'' = -K x with K from the links' tensions (mass below x g) over their
    length. The load does not turn (slide joints), so its hook swings, on the string's length."""
    m = np.concatenate([[cfg.mass_quad], bead_masses(cfg), [cfg.load_mass]])
    link = cfg.string_length / cfg.chain.links
    tension = np.cumsum(m[::-1])[::-1][1:] * cfg.gravity  # link j between node j and j + 1
    k = np.zeros((len(m), len(m)))
    for j, t in enumerate(tension):
        k[j : j + 2, j : j + 2] += t / link * np.array([[1.0, -1.0], [-1.0, 1.0]])
    w2 = np.linalg.eigvals(k / m[:, None]).real
    return 2.0 * math.pi / math.sqrt(min(w2[w2 > 1e-9]))


def test_named_plants_span_the_stated_vehicles():
    assert plant_config(DEFAULT_PLANT) == SimConfig()
    assert {plant_config(n).family for n in PLANTS} == {"tendon", "chain"}
    for name in set(PLANTS) - {DEFAULT_PLANT}:  # the default: the paper's vehicle, load 7 %
        cfg = plant_config(name)
        assert 0.5 <= cfg.mass_quad <= 2.0 and 0.5 <= round(cfg.cable_length, 9) <= 1.5, name
        assert 0.1 - 1e-9 <= cfg.load_mass / cfg.mass_quad <= 0.4 + 1e-9, name
        assert cfg.max_thrust > 2.0 * cfg.total_mass * cfg.gravity, name
    with pytest.raises(ValueError, match="unknown plant 'nope'"):
        plant_config("nope")


def test_family_picks_the_plant_class_and_round_trips():
    assert type(make_plant(SimConfig())) is Plant
    cfg = plant_config("chain")
    assert type(make_plant(cfg)) is ChainPlant
    assert SimConfig.from_dict(json.loads(json.dumps(to_dict(cfg)))) == cfg
    with pytest.raises(ValueError, match="family"):
        SimConfig(family="rope")


@pytest.mark.parametrize("name", CHAINS)
def test_chain_hovers_with_the_load_a_cable_below(name):
    cfg = ideal(name)
    plant = ChainPlant(cfg)
    p0 = plant.p
    rel = hold(plant, 1.5, plant.command[0])  # the hover thrust, the cable's mass included
    assert np.abs(plant.p - p0).max() < 5e-3
    np.testing.assert_allclose(rel[-1][:2], 0.0, atol=1e-6)
    # the links stretch a little under the weight below them (MuJoCo's soft limit)
    assert -rel[-1][2] == pytest.approx(cfg.cable_length, abs=0.01)


@pytest.mark.parametrize("name", CHAINS)
def test_chain_swings_with_the_hanging_chain_period(name):
    cfg = ideal(name)
    plant = ChainPlant(cfg)
    angle = math.radians(5.0)
    top = plant.p - np.array([0.0, 0.0, cfg.attach_below])
    hook = top + cfg.string_length * np.array([math.sin(angle), 0.0, -math.cos(angle)])
    plant.set_state(p_load=hook - np.array([0.0, 0.0, 0.5 * cfg.load_size]))
    x = np.array([r[0] for r in hold(plant, 8.0, plant.command[0])])
    crossings = np.flatnonzero(np.diff(np.sign(x)) != 0)
    period = 2.0 * np.mean(np.diff(crossings)) * cfg.control_dt
    assert period == pytest.approx(hanging_chain_period(cfg), rel=0.015)
    # and not the point mass on the whole cable length (what the paper's model assumes)
    point = 2.0 * math.pi * math.sqrt(cfg.cable_length * cfg.mass_quad / cfg.total_mass / 9.81)
    assert abs(period / point - 1.0) > 0.02


def test_chain_rate_loop_tracks_a_step_and_removes_an_offset():
    cfg = replace(ideal("chain"), effects=Effects.only("rate_loop", "thrust_lag"))
    plant = ChainPlant(cfg)
    step = np.array([0.0, 0.6, 0.0])
    achieved = []
    for _ in range(10):
        plant.advance(plant.command[0], step, np.zeros(3))
        achieved.append(plant.rates[1])
    assert achieved[0] < 0.5 * step[1]  # the rotors lag: far from it after 0.03 s
    assert max(achieved) < 1.4 * step[1]  # damped
    assert achieved[-1] == pytest.approx(step[1], abs=0.06)
    # a thrust centre 5 mm off: an unbalanced torque the loop's integral takes out
    plant = ChainPlant(cfg, PlantParams(thrust_offset=(0.004, -0.003)))
    hold(plant, 0.1, plant.command[0])
    assert np.abs(plant.rates).max() > 0.1  # it does turn the vehicle at first
    hold(plant, 1.1, plant.command[0])
    assert np.abs(plant.rates).max() < 0.01


def test_chain_rotors_saturate():
    cfg = ideal("chain").with_effects(Effects.only("rate_loop", "thrust_lag"))
    plant = ChainPlant(cfg)
    hold(plant, 0.5, 10.0 * cfg.max_thrust)
    assert plant.thrust == pytest.approx(cfg.max_thrust, rel=1e-3)


def test_chain_lookahead_is_the_plant_itself():
    from slungload.lab.control.plant_batch import ChainBatch, lookahead

    cfg = plant_config("chain")  # every effect on
    plant = make_plant(cfg, PlantParams(1.03, 0.002, (0.002, -0.001)))
    rng = np.random.default_rng(0)
    wind = np.array([0.2, -0.1, 0.05])
    for _ in range(10):
        plant.advance(plant.command[0] + rng.normal(), 0.5 * rng.normal(size=3), wind)
    plans = np.array([plant.command[0], 0.0, 0.0, 0.0]) + rng.normal(size=(3, 6, 4)) * 0.5
    batch = lookahead(plant)
    assert isinstance(batch, ChainBatch)
    flown = batch.advance(plans, plant.wind)
    for i in range(len(plans)):
        twin = plant.fork()
        for j in range(plans.shape[1]):
            twin.advance(plans[i, j, 0], plans[i, j, 1:], plant.wind)
            np.testing.assert_allclose(flown["p"][i, j], twin.p, atol=1e-9)
            np.testing.assert_allclose(flown["p_load"][i, j], twin.p_load, atol=1e-9)
            np.testing.assert_allclose(flown["q"][i, j], twin.q, atol=1e-9)
    assert plant.time == pytest.approx(10 * cfg.control_dt)  # the plant itself untouched


def test_chain_flights_are_deterministic_and_recorded_as_any():
    cfg = plant_config("chain-light")
    a = simulate_flight("xy_step", seed=3, config=cfg, steps=40)
    b = simulate_flight("xy_step", seed=3, config=cfg, steps=40)
    for key, value in a.arrays.items():
        np.testing.assert_array_equal(value, b.arrays[key])
    assert a.arrays["p_load"].shape == (40, 3)
    assert np.median(a.truth["cable"]) == pytest.approx(cfg.string_length, abs=0.01)


def test_study_and_comparison_configs_name_a_plant():
    from slungload.lab.control.config import ComparisonConfig, RecordConfig, StudyConfig

    assert StudyConfig().plant == ComparisonConfig().plant == RecordConfig().plant == "default"
    for cls in (StudyConfig, ComparisonConfig, RecordConfig):
        with pytest.raises(ValueError, match="unknown plant"):
            cls(plant="nope")


def test_simulate_plant_option_writes_its_vehicle(tmp_path):
    from slungload.cli import main
    from slungload.vehicle_file import load_vehicle

    code = main(["simulate", "--plant", "chain-light", "--flights", "1", "--maneuvers",
                 "xy_step", "--out", str(tmp_path / "d"), "--quiet"])  # fmt: skip
    assert code == 0
    cfg = plant_config("chain-light")
    params = load_vehicle(tmp_path / "d")
    assert (params.mass_quad, params.mass_load) == (cfg.mass_quad, cfg.load_mass)
    assert params.cable_length == pytest.approx(cfg.cable_length)
    sim = json.loads((tmp_path / "d" / "vehicle.json").read_text())["sim"]
    assert sim["family"] == "chain"


def test_plan_errors_are_zero_for_the_plant_itself_and_not_for_physics(tmp_path):
    from slungload.control.mpc import MPCConfig
    from slungload.deploy.backends import load_model
    from slungload.lab.control.config import PlanErrorConfig
    from slungload.lab.control.oracle import PlantCandidates
    from slungload.lab.control.plan_errors import plan_errors, write_plan_errors
    from slungload.sim.config import vehicle_params

    cfg = plant_config("chain-light")
    params = vehicle_params(cfg)
    models = {"physics": load_model("physics", params, backend="compiled"),
              "oracle": PlantCandidates()}  # fmt: skip
    probe = PlanErrorConfig(maneuvers=("baf_very_fast",), seeds=(100,), horizon=6, samples=16,
                            candidates=6, every=10, steps=31, plant="chain-light")  # fmt: skip
    out = plan_errors(models, "physics", cfg, params, MPCConfig(), probe)
    assert out["oracle"]["probes"] == out["physics"]["probes"] == 4  # steps 0, 10, 20, 30
    assert out["oracle"]["load"].max() < 1e-9 and out["oracle"]["response"].max() < 1e-9
    assert out["oracle"]["spearman"] == pytest.approx(1.0) and out["oracle"]["regret"] == 0.0
    assert out["physics"]["load"].shape == (6,)
    assert out["physics"]["load"][-1] > 1e-3 and out["physics"]["spearman"] < 1.0
    report = write_plan_errors({"physics": out}, tmp_path, "test").read_text()
    assert "| physics | oracle | 4 | 0.000 |" in report
    assert (tmp_path / "plan-errors.png").stat().st_size > 0
    assert (tmp_path / "plan-errors.csv").read_text().startswith("mpc,model,probes,load_1,")
