"""The control study's parts: the oracle (the plant as the MPC's model), the payload-aware
geometric controller, the shifted plants, the paired statistics, and the study command that
flies, resumes and reports (docs/control.md, "The control study")."""

from __future__ import annotations

import itertools
import json
import math
import re
from dataclasses import fields, replace

import numpy as np
import pytest
import torch

from slungload.control import paired as paired_module
from slungload.control.closed_loop import flight_metrics, fly
from slungload.control.geometric import GeometricGains, GeometricLoadController
from slungload.control.mpc import InputLimits, MPCConfig, SamplingMPC
from slungload.control.paired import TRUST_WINDOW
from slungload.frames import rotation_matrix, swing_angle
from slungload.lab.control.config import (
    COST_GRID,
    SETTINGS_FIELDS,
    SHIFTS,
    SWING_BOUND,
    TUNING_GRID,
    UNSAFE_SWING,
    ComparisonConfig,
    StudyConfig,
    cost_changes,
    recorded_settings,
    settings_record,
)
from slungload.lab.control.oracle import PlantCandidates
from slungload.lab.control.oracle_gap import gap_closed
from slungload.lab.control.results import label_model
from slungload.lab.control.study import (
    best_horizons,
    load_log,
    run_study,
    tune_settings,
    tuning_score,
)
from slungload.lab.control.study_report import (
    best_horizon_section,
    maneuver_table,
    paired_table,
    write_study_report,
)
from slungload.layout import LOAD_POS, POS, QUAT, VEL
from slungload.reporting import gap_interval, gap_share, paired_interval, t975
from slungload.sim.aero import Aero
from slungload.sim.config import Effects, SimConfig
from slungload.sim.controller import Measurement, PIDController
from slungload.sim.dataset import vehicle_params
from slungload.sim.maneuvers import Reference
from slungload.sim.plant import Plant

NOMINAL = SimConfig()
LIMITS = InputLimits.from_sim(NOMINAL)


def _truth(plant: Plant) -> np.ndarray:
    x = np.empty(13)
    x[POS], x[VEL], x[QUAT], x[LOAD_POS] = plant.p, plant.v, plant.q, plant.p_load
    return x


# --- the oracle ------------------------------------------------------------------------


def test_a_fork_steps_apart_and_sync_brings_it_back():
    plant = Plant(NOMINAL)
    twin = plant.fork()
    before = _truth(plant)
    for _ in range(5):
        twin.advance(20.0, np.array([1.0, 0.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    assert np.array_equal(_truth(plant), before)  # the plant did not move
    assert not np.allclose(_truth(twin), before)
    twin.sync(plant)
    assert np.array_equal(_truth(twin), before)


@pytest.mark.parametrize("effects", [Effects(), Effects.none()], ids=["every effect", "none"])
def test_the_oracle_predicts_what_the_plant_then_does(effects):
    # The oracle's prediction of a plan is what the plant flies under that plan in the same
    # wind: the same MuJoCo state, latency, thrust scale, lags and forces, the K plans stepped
    # together (``PlantBatch``) against the plant's own one-by-one ``advance``. Only MuJoCo's
    # solver warm start is not carried between the batch's calls (agreement ~1e-14 m).
    cfg = SimConfig(effects=effects)
    plant = Plant(cfg)
    wind = np.array([1.5, -0.5, 0.2])
    plant.advance(14.0, np.array([0.3, -0.2, 0.1]), wind)  # not at rest, a command held
    oracle = PlantCandidates(threads=2)  # MuJoCo's pool: the same states as one thread
    oracle.attach(plant)
    rng = np.random.default_rng(0)
    # hard plans: thrust and rates far from hover, so the cable goes slack and snaps taut
    plans = np.tile([14.2, 0.0, 0.0, 0.0], (3, 20, 1)) + rng.normal(0, [3, 2, 2, 0.5], (3, 20, 4))
    before = _truth(plant)
    states = oracle.predict_candidates(np.zeros((2, 13)), np.zeros((1, 4)), plans)
    assert np.array_equal(_truth(plant), before)  # the plant itself did not move
    for i in (0, 2):
        twin = plant.fork()
        for j, u in enumerate(plans[i]):
            twin.advance(float(u[0]), u[1:], wind)
            np.testing.assert_allclose(states[i, j], _truth(twin), rtol=0, atol=1e-10)
    assert not np.allclose(states[0, -1], states[1, -1])  # another plan, another outcome


def test_the_batched_forces_are_the_plants_forces():
    # ``Aero``'s batched methods against its one-state ones, on random states: in front of
    # and beside the rotors, wind on, every effect, drag alone and downwash alone.
    rng = np.random.default_rng(1)
    k = 64
    p, v, v_load = rng.normal(0, 1, (k, 3)), rng.normal(0, 3, (k, 3)), rng.normal(0, 3, (k, 3))
    p_load = p + rng.normal([0, 0, -0.7], 0.5, (k, 3))
    q = rng.normal(0, 1, (k, 4))
    rot = rotation_matrix(q)
    thrust, wind = rng.uniform(-1, 30, k), np.array([2.0, -1.0, 0.3])
    for effects in (Effects(), replace(Effects(), downwash=False), replace(Effects(), drag=False)):
        aero = Aero(SimConfig(effects=effects))
        wake = aero.wake_velocities(p, rot, thrust, p_load)
        assert np.any(wake != 0) and np.any(np.all(wake == 0, axis=1))  # both cases met
        for i in range(k):
            one = aero.wake_velocity(p[i], rot[i], thrust[i], p_load[i])
            np.testing.assert_allclose(wake[i], one, rtol=1e-12, atol=1e-15)
            np.testing.assert_allclose(aero.vehicle_forces(v, rot, thrust, wind)[i],
                                       aero.vehicle_force(v[i], rot[i], thrust[i], wind),
                                       rtol=1e-12, atol=1e-15)  # fmt: skip
            np.testing.assert_allclose(aero.load_forces(v_load, wind, wake)[i],
                                       aero.load_force(v_load[i], wind, one),
                                       rtol=1e-12, atol=1e-15)  # fmt: skip


def test_the_batch_reads_mujocos_rotation():
    plant = Plant(SimConfig())
    plant.set_state(q=np.array([0.9, 0.1, -0.3, 0.2]))  # not unit: MuJoCo normalises
    xmat = plant.data.xmat[plant.quad].reshape(3, 3)  # what the plant's forces read
    np.testing.assert_allclose(rotation_matrix(plant.data.qpos[None, 3:7])[0], xmat, atol=1e-15)


def test_the_oracle_needs_its_plant():
    with pytest.raises(RuntimeError, match="attach"):
        PlantCandidates().predict_candidates(
            np.zeros((2, 13)), np.zeros((1, 4)), np.zeros((2, 3, 4))
        )


def test_the_oracle_mpc_flies_with_the_flights_plant_handed_through_the_guard():
    mpc = SamplingMPC(
        PlantCandidates(), LIMITS, MPCConfig(samples=4, horizon=4, knots=2), vehicle_params(NOMINAL)
    )
    log = fly("roll_35", 100, mpc, label="oracle", config=NOMINAL, steps=5)
    assert log.stopped is None and mpc.stats.fallback_steps == 0
    assert mpc.core.model.batch is not None


# --- the geometric controller ------------------------------------------------------------


def _hover_swing(controller, cfg: SimConfig, steps: int = 100) -> tuple[float, float]:
    """Largest swing (deg) in the first and the last second after starting 25 deg out."""
    plant = Plant(cfg)
    p, angle = plant.p, math.radians(25.0)
    plant.set_state(p_load=p + cfg.cable_length * np.array([math.sin(angle), 0, -math.cos(angle)]))
    pos = np.tile(p, (steps, 1))
    ref = Reference(pos, np.zeros_like(pos), np.zeros_like(pos), np.zeros(steps))
    swing = []
    for k in range(steps):
        m = Measurement(
            k * cfg.control_dt, plant.p, plant.v, plant.q, rotation_matrix(plant.q), plant.p_load
        )
        thrust, rates = controller(m, ref, k)
        plant.advance(thrust, rates, np.zeros(3))
        swing.append(float(np.degrees(swing_angle(_truth(plant)[None]))[0]))
    return max(swing[:33]), max(swing[-33:])


def test_the_geometric_law_damps_a_swing_the_pid_only_rides():
    # The cable loop's physics on the ideal plant, with a damping gain and an attitude loop
    # fast enough for it (the defaults, chosen on the tuning flights with every effect on, lose
    # no flight there but damp less: docs/control.md).
    cfg = SimConfig(effects=Effects.none())
    gains = GeometricGains(kq=12.0, kw=8.0, k_att=(12.0, 12.0, 3.0))
    first, last = _hover_swing(GeometricLoadController(cfg, gains), cfg)
    _, pid_last = _hover_swing(PIDController(cfg), cfg)
    assert first > 20.0 and last < 0.2 * first
    assert last < 0.5 * pid_last
    wrong = GeometricGains(kq=12.0, kw=-8.0, k_att=(12.0, 12.0, 3.0))  # the damping reversed
    assert _hover_swing(GeometricLoadController(cfg, wrong), cfg)[1] > first


def test_the_geometric_controller_hovers_with_the_weight_and_no_rates():
    # Known solution: the load hanging still under the vehicle at its reference.
    cfg = SimConfig()
    ctrl = GeometricLoadController(cfg)
    p = np.array([0.0, 0.0, 1.5])
    m = Measurement(
        0.0, p, np.zeros(3), np.array([1.0, 0, 0, 0]), np.eye(3), p - [0, 0, cfg.cable_length]
    )
    ref = Reference(p[None], np.zeros((1, 3)), np.zeros((1, 3)), np.zeros(1))
    thrust, rates = ctrl(m, ref, 0)
    assert thrust == pytest.approx(cfg.total_mass * cfg.gravity, rel=1e-9)
    assert np.allclose(rates, 0.0, atol=1e-12)


def test_the_geometric_controller_tracks_a_gentle_maneuver():
    log = fly(
        "slow_ellipses_xy",
        200,
        GeometricLoadController(NOMINAL),
        label="g",
        config=NOMINAL,
        steps=200,
    )
    row = flight_metrics(log, LIMITS, NOMINAL.cable_length)
    assert row["completed"] and row["load_rmse"] < 0.25 and row["swing_max"] < 20.0


# --- shifts and statistics -------------------------------------------------------------


def test_each_shift_changes_what_it_names_and_nothing_else():
    shifted = {name: shift(NOMINAL) for name, shift in SHIFTS.items()}
    assert shifted["load +50%"].load_mass == pytest.approx(0.15)
    assert shifted["cable +20%"].cable_length == pytest.approx(0.84)
    assert shifted["wind x2"].wind_std == pytest.approx(0.30)
    assert shifted["thrust lag x2"].thrust_tau == pytest.approx(0.08)
    assert shifted["load +50%"].cable_length == NOMINAL.cable_length
    assert shifted["cable +20%"].load_mass == NOMINAL.load_mass
    with pytest.raises(ValueError, match="unknown plant shifts"):
        StudyConfig(shifts=("gravity x2",))


def test_paired_interval_is_the_t_interval():
    mean, lo, hi = paired_interval([1.0, 2.0, 3.0])
    assert mean == 2.0 and hi - mean == pytest.approx(4.303 / math.sqrt(3))
    assert lo == pytest.approx(2.0 - 4.303 / math.sqrt(3))
    assert math.isnan(paired_interval([1.0])[1]) and paired_interval([1.0])[0] == 1.0
    assert all(math.isnan(v) for v in paired_interval([]))
    many = paired_interval(np.r_[np.zeros(50), np.ones(50)])  # t at 99 dof: 1.9842, not 1.96
    assert many[2] - many[0] == pytest.approx(
        1.9842 * np.std(np.r_[np.zeros(50), np.ones(50)], ddof=1) / 10, abs=1e-4
    )


def test_t_beyond_the_table_is_students_and_falls_to_the_normals():
    # published t at 97.5 %: 40 dof 2.0211, 60 dof 2.0003, 120 dof 1.9799
    assert [round(t975(n), 4) for n in (40, 60, 120)] == [2.0211, 2.0003, 1.9799]
    ts = [t975(n) for n in range(1, 400)]
    assert all(a > b for a, b in itertools.pairwise(ts)) and t975(10**6) == pytest.approx(
        1.959964, abs=1e-5
    )


def _row(controller, maneuver, seed, load, completed=True):
    return dict(
        plant="nominal",
        controller=controller,
        maneuver=maneuver,
        seed=seed,
        load_rmse=load,
        completed=completed,
    )


def test_gap_closed_is_measured_on_the_flights_all_three_finished():
    rows = [
        _row("p", "m", 1, 0.3),
        _row("l", "m", 1, 0.2),
        _row("o", "m", 1, 0.1),
        _row("p", "m", 2, 0.9),
        _row("l", "m", 2, 0.1, completed=False),
        _row("o", "m", 2, 0.1),
    ]
    assert gap_closed(rows, "p", "l", "o", "load_rmse") == [
        ["m", "1", "0.300", "0.200", "0.100", "50 %", "+0.100 [-, -]"]
    ]
    # an oracle no better than physics leaves no gap: no ratio, not a negative one
    worse = [_row("p", "m", 1, 0.2), _row("l", "m", 1, 0.1), _row("o", "m", 1, 0.3)]
    assert gap_closed(worse, "p", "l", "o", "load_rmse")[0][-2] == "-"
    # learned - oracle is paired per seed: its interval excludes zero only where the seeds agree
    seeds = [_row(c, "m", s, v) for s, vals in enumerate([(0.5, 0.30, 0.20), (0.6, 0.41, 0.30),
             (0.4, 0.22, 0.10)]) for c, v in zip("plo", vals, strict=True)]  # fmt: skip
    mean, interval = gap_closed(seeds, "p", "l", "o", "load_rmse")[0][-1].split(" ", 1)
    assert mean == "+0.110" and interval == "[+0.085, +0.135]"


def test_the_gap_closed_and_its_bootstrap_interval():
    # the learned model flying as the oracle does closes all of the gap, on every resample
    physics, oracle = [0.5, 0.6, 0.4, 0.7], [0.2, 0.3, 0.1, 0.3]
    assert gap_share(*np.asarray([physics, oracle, oracle])) == pytest.approx(1.0)
    assert gap_interval(physics, oracle, oracle) == pytest.approx((1.0, 1.0))
    # halfway on every flight: 50 % whatever the resample
    half = [(p + o) / 2 for p, o in zip(physics, oracle, strict=True)]
    assert gap_interval(physics, half, oracle) == pytest.approx((0.5, 0.5))
    # a spread over seeds: the interval holds the point, is reproduced, and widens with it
    rng = np.random.default_rng(3)
    learned = np.asarray(half) + 0.05 * rng.standard_normal(4)
    point = float(gap_share(*np.asarray([physics, learned, oracle])))
    low, high = gap_interval(physics, learned, oracle)
    assert low < point < high and (low, high) == gap_interval(physics, learned, oracle)
    wider = np.asarray(half) + 0.15 * rng.standard_normal(4)
    assert np.ptp(gap_interval(physics, wider, oracle)) > high - low
    # resamples where the oracle is no better than physics leave no gap: an infinite bound
    assert gap_interval([0.5, 0.2, 0.3], [0.3, 0.1, 0.2], [0.2, 0.4, 0.2])[1] == math.inf
    assert gap_share(*np.asarray([[0.2], [0.3], [0.4]])) == -math.inf
    # too few flights for an interval: two give only three distinct resamples
    assert all(math.isnan(v) for v in gap_interval([0.5, 0.6], [0.3, 0.35], [0.2, 0.3]))
    # the gap table writes the interval beside the share
    figures = [(0.5, 0.3, 0.2), (0.6, 0.35, 0.3), (0.4, 0.25, 0.1)]
    rows = [_row(c, "m", seed, v) for seed, vals in enumerate(figures)
            for c, v in zip("plo", vals, strict=True)]  # fmt: skip
    cell = gap_closed(rows, "p", "l", "o", "load_rmse")[0][-2]
    low, high = gap_interval(*zip(*figures, strict=True))
    assert cell == f"67 % [{100 * low:.0f} %, {100 * high:.0f} %]" and low < 2 / 3 < high


def test_the_paired_table_pairs_flights_and_states_the_share_of_the_second():
    figures = dict(swing_rms=10.0, swing_max=20.0, vehicle_rmse=0.1)
    flights = (("a", 1, 0.15), ("a", 2, 0.25), ("a", 4, 0.05),  # seed 4: b never flew it
               ("b", 3, 0.1), ("b", 2, 0.30), ("b", 1, 0.20))  # fmt: skip
    rows = [{**_row(c, "m", s, v), **figures} for c, s, v in flights]
    rows.append({**_row("a", "m", 3, 9.0, completed=False), **figures})  # lost: not paired
    table = paired_table(rows, "nominal", [("a", "b")])
    row = next(line for line in table.splitlines() if line.startswith("| a - b"))
    # -0.05 on both flights, paired by seed (no spread: a zero-width interval), -20 % of b's
    # 0.25 m mean over them
    assert "| a - b | 2 | -0.050 [-0.050, -0.050] (-20 %) | +0.0 [+0.0, +0.0] (+0 %) |" in row
    # a difference of a figure that is zero for b has no share
    zero = [{**r, "vehicle_rmse": 0.0} for r in rows]
    row = paired_table(zero, "nominal", [("a", "b")]).splitlines()[-1]
    assert row.endswith("| +0.000 [+0.000, +0.000] |")


def test_each_model_is_set_against_the_other_at_its_own_best_horizon():
    # The best horizon is the one whose chosen settings scored best on the tuning seeds:
    # fewest lost, then fewest past the swing limit, then load RMSE; never the evaluation seeds.
    scores = {"learned": {"25": [0, 0, 0.195], "50": [0, 0, 0.131]},
              "physics": {"25": [0, 0, 0.199], "50": [1, 0, 0.120]}}  # fmt: skip
    settings = {"tuning_score": scores}
    assert best_horizons(settings) == {"learned": 50, "physics": 25}
    assert best_horizons({"tuning_score": {"physics": {"25": [0, 0, 0.2]}}}) == {}
    assert best_horizons({}) == {}  # not tuned
    figures = dict(swing_rms=10.0, swing_max=20.0, vehicle_rmse=0.1)
    flights = [("mpc-learned N=50", 1, 0.10), ("mpc-learned N=50", 2, 0.20),
               ("mpc-physics N=25", 1, 0.15), ("mpc-physics N=25", 2, 0.25),
               ("mpc-learned N=25", 1, 0.9), ("mpc-physics N=50", 2, 0.01)]  # fmt: skip
    rows = [{**_row(c, "m", s, v), **figures} for c, s, v in flights]
    lines = best_horizon_section(rows, settings)
    assert lines[0] == "## Each model at its own best horizon"
    assert "mpc-learned N=50 (0 lost, 0 past 60 deg, load RMSE 0.131 m" in lines[2]
    assert "mpc-physics N=25 (0 lost, 0 past 60 deg, load RMSE 0.199 m" in lines[2]
    # -0.05 on both flights, -25 % of physics's 0.2 m mean over them
    assert "| mpc-learned N=50 - mpc-physics N=25 | 2 | -0.050 [-0.050, -0.050] (-25 %) |" in (
        "\n".join(lines)
    )
    # nothing to say when one of the pair never flew, or a model was tuned at one horizon
    assert best_horizon_section(rows[:2], settings) == []
    one = {"tuning_score": {**scores, "learned": {"50": [0, 0, 0.131]}}}
    assert best_horizon_section(rows, one) == []


def test_the_maneuver_table_shows_each_maneuvers_mean_and_its_lost_flights():
    timing = dict(compute_median=1.0, compute_p99=2.0, vehicle_rmse=0.1, swing_rms=5.0,
                  swing_max=9.0, at_limit=0.0)  # fmt: skip
    flights = (("mpc-physics N=25", "step", 1, 0.5), ("mpc-physics N=25", "step", 2, 0.7),
               ("mpc-physics N=25", "turn", 1, 0.1), ("pid", "turn", 1, 0.3))  # fmt: skip
    rows = [{**_row(c, m, s, v), **timing} for c, m, s, v in flights]
    rows.append({**_row("mpc-physics N=25", "turn", 2, 9.0, completed=False), **timing})
    rows.append({**_row("pid", "turn", 1, 5.0), **timing, "plant": "wind x2"})  # not nominal
    lines = maneuver_table(rows, "nominal").splitlines()
    # the PID first (reading order); a maneuver it did not fly is "-"; a lost flight is not
    # in the mean but is counted
    assert lines[0].split("|")[2:4] == [" step ", " turn "]
    assert lines[2] == "| pid | - | 0.300 |"
    assert lines[3] == "| mpc-physics N=25 | 0.600 | 0.100 / 1 lost |"


def test_the_ratio_to_the_truth_is_over_the_flights_both_flew():
    from slungload.lab.control.unseen_loads import IN_FLIGHT, TRUE, label, ratio_to_truth

    def row(constants, seed, load, completed=True):
        return {**_row(label("mpc-fixed", constants), "m", seed, load, completed),
                "plant": "p"}  # fmt: skip

    rows = [row(IN_FLIGHT, 1, 0.3), row(TRUE, 1, 0.2), row(IN_FLIGHT, 2, 0.9, completed=False),
            row(TRUE, 2, 0.1), row(IN_FLIGHT, 3, 0.5)]  # fmt: skip
    assert ratio_to_truth(rows, "p", "mpc-fixed", "load_rmse") == pytest.approx(1.5)
    assert math.isnan(ratio_to_truth(rows, "p", "mpc-adaptive", "load_rmse"))  # never flown
    perfect = [row(IN_FLIGHT, 1, 0.0), row(TRUE, 1, 0.0)]
    assert math.isnan(ratio_to_truth(perfect, "p", "mpc-fixed", "load_rmse"))  # 0 / 0


def test_a_controller_label_names_its_model():
    assert [label_model(x) for x in ("mpc-learned N=25", "mpc-net K=32", "pid", "geometric")] == [
        "learned", "net", "pid", "geometric"]  # fmt: skip


# --- the study ---------------------------------------------------------------------------

TINY = StudyConfig(
    maneuvers=("roll_35",),
    seeds=(100,),
    tuning_seeds=(200,),
    horizons=(3, 4),
    oracle_samples=3,
    oracle_horizons=(3,),
    shifts=("wind x2",),
    steps=6,
    tune=False,
    samples=4,
)


def test_the_study_flies_resumes_and_reports(tmp_path):
    out = tmp_path / "study"
    lines: list[str] = []
    rows = run_study(None, out, TINY, progress=lines.append)
    flown = {(r["plant"], r["controller"]) for r in rows}
    assert flown == {
        ("nominal", "pid"),
        ("nominal", "geometric"),
        ("nominal", "mpc-physics N=3"),
        ("nominal", "mpc-physics N=4"),
        ("nominal", "mpc-oracle N=3"),
        ("wind x2", "pid"),
        ("wind x2", "geometric"),
        ("wind x2", "mpc-physics N=3"),
    }
    assert len(lines) == len(rows) == 8
    lines.clear()
    again = run_study(None, out, TINY, progress=lines.append)  # nothing left to fly
    assert lines == [] and again == rows  # the same rows (wall times too): none flown again
    report = write_study_report(again, TINY, out).read_text()
    assert "Smoke run" not in report  # no network flew
    assert "MPC settings: the defaults, not tuned" in report  # TINY does not tune
    for part in (
        "## Nominal plant",
        "| mpc-oracle N=3 |",
        "mpc-physics N=4 - mpc-physics N=3",
        "## Shifted plant: wind x2",
    ):
        assert part in report
    assert all((out / name).stat().st_size > 0 for name in ("horizons.png", "paths_3d.png"))
    settings = json.loads((out / "settings.json").read_text())
    assert settings["samples"]["physics"] == {"3": 4, "4": 4}
    for other in (replace(TINY, tuning_seeds=(202,)), replace(TINY, horizons=(3, 5))):
        with pytest.raises(ValueError, match="another study configuration"):
            run_study(None, out, other, progress=None)
    # more evaluation seeds and shifted-plant horizons fly on the settings already chosen
    wider = replace(TINY, seeds=(100, 101), shift_horizons=(3, 4))
    stamp = (out / "settings.json").stat().st_mtime_ns
    rows = run_study(None, out, wider, controllers=("physics",), plants=("wind x2",), progress=None)
    assert (out / "settings.json").stat().st_mtime_ns == stamp
    new = {(r["controller"], r["seed"]) for r in rows if r["plant"] == "wind x2"} - {
        ("pid", 100), ("geometric", 100), ("mpc-physics N=3", 100)}  # fmt: skip
    assert new == {("mpc-physics N=3", 101), ("mpc-physics N=4", 100), ("mpc-physics N=4", 101)}
    assert "evaluation seeds 100, 101;" in write_study_report(rows, TINY, out).read_text()
    with pytest.raises(ValueError, match="oracle_samples differ"):
        run_study(None, out, replace(TINY, oracle_samples=5), progress=None)
    with pytest.raises(ValueError, match="steps differ"):  # whatever flies
        run_study(None, out, replace(TINY, steps=7), controllers=("pid",), progress=None)


def test_a_study_flies_its_named_plant_and_keeps_to_it(tmp_path):
    from slungload.sim.plants import plant_config

    chain = replace(TINY, plant="chain-light", shifts=("load +50%",))
    out = tmp_path / "study"
    rows = run_study(None, out, chain, controllers=("physics", "oracle"), progress=None)
    assert {(r["plant"], r["controller"]) for r in rows} >= {
        ("nominal", "mpc-physics N=3"), ("nominal", "mpc-oracle N=3"),
        ("load +50%", "mpc-physics N=3")}  # fmt: skip
    # the flights are the named plant's: its hover height, not the default's
    row = next(r for r in rows if r["controller"] == "mpc-physics N=3" and r["plant"] == "nominal")
    log = load_log(out, row)
    assert log.states[0, 2] == pytest.approx(plant_config("chain-light").hover_z, abs=0.05)
    with pytest.raises(ValueError, match="plant differ"):
        run_study(None, out, replace(chain, plant="default"), controllers=("pid",), progress=None)
    # a folder written before studies named their plant is the default plant's
    settings = json.loads((out / "settings.json").read_text())
    del settings["config"]["plant"]
    (out / "settings.json").write_text(json.dumps(settings))
    with pytest.raises(ValueError, match="plant differ"):
        run_study(None, out, chain, controllers=("pid",), progress=None)


def test_a_study_flies_its_cost_and_keeps_to_it(tmp_path):
    """``StudyConfig.cost`` reaches every MPC of the study (its flights differ from today's
    cost's where the reference accelerates), and a folder keeps the cost it was flown with."""
    payload = replace(TINY, cost="payload", maneuvers=("baf_very_fast",), shifts=())
    rows = {}
    for cfg in (payload, replace(payload, cost="vehicle")):
        out = tmp_path / cfg.cost
        found = run_study(None, out, cfg, controllers=("physics",), progress=None)
        rows[cfg.cost] = [r["load_rmse"] for r in found if r["controller"].startswith("mpc")]
    assert rows["payload"] != rows["vehicle"]
    with pytest.raises(ValueError, match="cost differ"):
        run_study(None, tmp_path / "payload", replace(payload, cost="vehicle"),
                  controllers=("physics",), progress=None)  # fmt: skip
    with pytest.raises(ValueError, match="unknown MPC cost 'lean'"):
        replace(TINY, cost="lean")


def test_a_study_and_a_comparison_never_share_a_folder(tmp_path):
    from slungload.lab.control.comparison import compare
    from slungload.lab.control.config import ComparisonConfig

    run_study(None, tmp_path / "study", TINY, controllers=("physics",), plants=("nominal",),
              progress=None)  # fmt: skip
    with pytest.raises(ValueError, match="holds a control study"):
        config = ComparisonConfig(maneuvers=("roll_35",), seeds=(100,), steps=4)
        compare(out=tmp_path / "study", config=config, progress=None)
    (tmp_path / "ctl").mkdir()
    (tmp_path / "ctl" / "results.json").write_text("{}")
    with pytest.raises(ValueError, match="flights of a `control` comparison"):
        run_study(None, tmp_path / "ctl", TINY, controllers=("pid",), progress=None)


def test_the_fields_a_study_folder_follows_from_are_study_config_fields():
    assert set(SETTINGS_FIELDS) < {f.name for f in fields(StudyConfig)}
    with pytest.raises(ValueError, match="steps"):
        StudyConfig(steps=0)


def test_control_study_refuses_zero_steps_and_empty_lists(run_cli, tmp_path):
    for bad, says in (
        (("--steps", "0"), "steps"),
        (("--maneuvers", ","), "--maneuvers"),
        (("--horizons", ","), "--horizons"),
    ):
        code, _, err = run_cli("study", "control", *bad, "--out", str(tmp_path / "x"))
        assert code == 2 and says in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()


def test_flights_flown_by_workers_are_the_flights_flown_in_turn(tmp_path):
    # The same rows, whichever process flew them (the compute columns aside); the parent
    # writes the settings, the workers read them.
    config = replace(TINY, shifts=(), horizons=(3,))
    kinds = ("pid", "physics", "oracle")
    alone = run_study(None, tmp_path / "one", config, controllers=kinds, progress=None)
    lines: list[str] = []
    pooled = run_study(None, tmp_path / "two", config, controllers=kinds, workers=2,
                       progress=lines.append)  # fmt: skip
    timing = {"wall_s", "compute_median", "compute_p99"}
    strip = lambda rows: [{k: v for k, v in r.items() if k not in timing} for r in rows]  # noqa: E731
    assert strip(pooled) == strip(alone) and len(pooled) == 3 and len(lines) == 3
    assert (tmp_path / "two" / "settings.json").exists()


def test_the_report_sets_the_learned_model_against_the_oracle(tiny_run, tmp_path):
    # With a learned model the oracle flies its settings, and the report pairs the two at
    # each horizon the oracle flew and measures the gap closed there.
    # (the payload-first cost: every MPC of the study, its equal-compute timing too, takes it)
    config = replace(TINY, shifts=(), horizons=(3, 4), oracle_horizons=(3, 4), cost="payload")
    kinds = ("geometric", "physics", "learned", "oracle")
    rows = run_study(tiny_run.out, tmp_path, config, controllers=kinds, progress=None)
    assert len(rows) == 7
    report = write_study_report(rows, config, tmp_path, str(tiny_run.out)).read_text()
    for n in (3, 4):
        assert f"## The gap to the oracle, N = {n}" in report
        assert f"| mpc-learned N={n} - mpc-oracle N={n} |" in report
        assert f"| mpc-learned N={n} - geometric |" in report  # the classic one, every horizon
    assert "the oracle flies the learned one's" in report
    assert "| learned | 4 | 4 | defaults |" in report  # the settings per horizon (TINY: untuned)
    tuned_for = json.loads((tmp_path / "settings.json").read_text())["learned_network"]
    assert f"`{tuned_for['checkpoint']}` (SHA-256 {tuned_for['sha256'][:12]})" in report
    # the fixture's network trained with the smoke-test preset: said at the top
    assert tuned_for["preset"] == "quick"
    assert "Smoke run: these numbers are not results" in report.split("## ")[0]
    # another network (here: the same weights saved again) would mix two networks' flights
    other = tmp_path / "other_run"
    other.mkdir()
    checkpoint = torch.load(tiny_run.out / "best.ckpt", weights_only=False)
    torch.save({**checkpoint, "saved_again": True}, other / "best.ckpt")
    with pytest.raises(ValueError, match="tuned for the learned network"):
        run_study(other, tmp_path, config, controllers=("learned",), progress=None)
    # a folder that does not say which network it was tuned for is no safer
    untold = json.loads((tmp_path / "settings.json").read_text())
    del untold["learned_network"]
    (tmp_path / "settings.json").write_text(json.dumps(untold))
    with pytest.raises(ValueError, match="names no learned network"):
        run_study(tiny_run.out, tmp_path, config, controllers=("learned",), progress=None)
    # without the learned model the oracle would fly other settings under the same label
    with pytest.raises(ValueError, match="give the learned model"):
        run_study(None, tmp_path, config, controllers=("oracle",), progress=None)
    # an oracle alone reads the settings the real MPCs wrote, and never tunes them itself
    with pytest.raises(ValueError, match="no settings.json yet"):
        run_study(tiny_run.out, tmp_path / "new", config, controllers=("oracle",), progress=None)


def test_the_shifted_plants_fly_the_horizons_asked():
    from slungload.lab.control.study import _plan

    nominal = SimConfig()
    settings = {"mpc": {"physics": {"3": {}, "4": {}}}, "samples": {"physics": {"3": 4, "4": 4}}}
    for shift, expected in (
        ((), {"mpc-physics N=3"}),
        ((3, 4), {"mpc-physics N=3", "mpc-physics N=4"}),
    ):
        config = replace(TINY, shift_horizons=shift)
        plans = _plan(config, settings, {"physics": object()}, vehicle_params(nominal), LIMITS,
                      nominal, ("physics",), ("wind x2",))  # fmt: skip
        assert {f.label for f in plans} == expected
    with pytest.raises(ValueError, match="among the horizons"):
        replace(TINY, shift_horizons=(50,))


def test_the_study_command_refuses_two_models(run_cli, tmp_path):
    code, _, err = run_cli(
        "study", "control", "--model", tmp_path, "--model", tmp_path, "--out", tmp_path / "x"
    )
    assert code == 2 and "one --model" in err


def test_the_study_flies_only_the_plants_and_controllers_asked(tmp_path):
    rows = run_study(None, tmp_path, TINY, controllers=("pid",), plants=("wind x2",), progress=None)
    assert [(r["plant"], r["controller"]) for r in rows] == [("wind x2", "pid")]
    assert not (tmp_path / "settings.json").exists()  # no real MPC: nothing tuned or timed
    with pytest.raises(ValueError, match="unknown plants"):
        run_study(None, tmp_path, TINY, plants=("moon",), progress=None)


def test_the_oracle_flies_the_learned_mpcs_settings_at_its_own_k():
    # The oracle and the learned MPC differ only in their model (the gap closed compares
    # them); without a learned model in the study the oracle flies the defaults.
    from slungload.lab.control.study import _plan

    nominal = SimConfig()
    learned = {"temperature": 0.1, "thrust_std": 2.0, "rate_std": [1.0, 1.0, 0.4],
               "max_swing": 0.7}  # fmt: skip
    settings = {"mpc": {"learned": {"3": learned}}}
    for models, expected in (({"learned": object()}, learned), ({}, {})):
        (flown,) = _plan(TINY, settings, models, vehicle_params(nominal), LIMITS, nominal,
                         ("oracle",), ("nominal",))  # fmt: skip
        cfg = flown.make(100).cfg
        assert (cfg.samples, cfg.horizon, cfg.seed) == (TINY.oracle_samples, 3, 100)
        wanted = replace(MPCConfig(), **{k: tuple(v) if isinstance(v, list) else v
                                          for k, v in expected.items()})  # fmt: skip
        for name in learned:
            assert getattr(cfg, name) == getattr(wanted, name), name


def test_tuning_chooses_the_best_scored_choice_it_flew_on_the_tuning_seeds():
    from slungload.deploy.backends import load_model

    nominal = SimConfig()
    params = vehicle_params(nominal)
    lines: list[str] = []
    chosen, scored = tune_settings(load_model("physics", params), InputLimits.from_sim(nominal),
                                   params, replace(TINY, tune=True), 4, lines.append)  # fmt: skip
    # the noise grid, then the cost grid at its winner (its default cost not flown again),
    # then the noise grid at the chosen cost when that changed
    assert len(lines) >= len(TUNING_GRID) + len(COST_GRID)
    assert len(set(lines)) == len(lines)  # no choice flown twice
    MPCConfig(**chosen)  # fields of the MPC's config
    # The winner is a best score its progress lines show (lost, past the swing limit, load RMSE
    # to the printed digit: printed ties may go either way).
    found = [re.search(r": (\d+) lost, (\d+) past \S+ deg, load RMSE (\S+) m$", x) for x in lines]
    scores = [tuple(float(v) for v in m.groups()) for m in found]
    winners = [x.split(": ")[1] for x, sc in zip(lines, scores, strict=True) if sc == min(scores)]
    assert ", ".join(f"{k} {v}" for k, v in chosen.items()) in winners
    assert scored[:2] == min(scores)[:2] and f"{scored[2]:.3f}" == f"{min(scores)[2]:.3f}"


def test_tuning_alternates_until_a_round_keeps_its_choice(monkeypatch):
    """The chain-light case: a noise that swings the load under the default cost flies best
    under the swing bound, which only the cost round brings in."""
    from slungload.lab.control import study

    base = MPCConfig()
    calm = (0.1, 0.5)  # (temperature, noise scale): best with the swing bound
    flown: list[dict] = []

    def score(model, limits, params, cfg, n, choice, progress):
        flown.append(choice)
        scale = choice["thrust_std"] / base.thrust_std
        pair = (choice["temperature"], round(scale, 6))
        bound = choice.get("max_swing") == SWING_BOUND and len(choice) == 4
        if pair == calm:
            return (0, 0, 0.09) if bound else (0, 3, 0.10)
        return (0, 0, 0.12) if bound else (0, 2, 0.15)

    monkeypatch.setattr(study, "_score", score)
    chosen, scored = tune_settings(None, None, None, TINY, 4)
    assert scored == (0, 0, 0.09)
    assert (chosen["temperature"], chosen["thrust_std"]) == (0.1, 0.5 * base.thrust_std)
    assert chosen["max_swing"] == SWING_BOUND and len(chosen) == 4
    keys = [tuple(sorted(c.items())) for c in flown]
    assert len(set(keys)) == len(keys)  # each choice flown once
    # round 1: six noises; round 2: five cost changes; round 3: five noises with the bound;
    # round 4: the cost changes at the new noise (the bound itself already flown)
    assert len(flown) == 2 * len(TUNING_GRID) - 1 + 2 * len(COST_GRID) - 1


def test_the_tuning_score_puts_lost_flights_then_large_swings_before_the_error():
    def row(completed=True, swing_max=30.0, load=0.2):
        return {"completed": completed, "swing_max": swing_max, "load_rmse": load}

    safe = [row(load=0.3), row(load=0.3)]
    swinging = [row(load=0.1), row(swing_max=UNSAFE_SWING + 1, load=0.1)]
    lost = [row(load=0.1), row(completed=False, swing_max=120.0)]
    assert tuning_score(safe) == (0, 0, pytest.approx(0.3))
    assert tuning_score(swinging)[:2] == (0, 1)
    assert tuning_score(lost) == (1, 0, pytest.approx(0.1))  # counted once, as lost
    assert sorted([lost, swinging, safe], key=tuning_score) == [safe, swinging, lost]
    assert tuning_score([row(completed=False)]) == (1, 0, math.inf)


def test_the_report_scores_every_mpc_in_the_cost_the_oracle_minimises(tmp_path):
    import shutil

    config = replace(TINY, horizons=(3,))
    rows = run_study(None, tmp_path, config, controllers=("physics", "oracle"), progress=None)
    # the physics flights stand in for a learned model's (same settings: the defaults here), on
    # the nominal and the shifted plant
    for plant in ("nominal", "wind_x2"):
        flights = tmp_path / "flights" / plant
        shutil.copytree(flights / "mpc-physics_N_3", flights / "mpc-learned_N_3")
        for path in (flights / "mpc-learned_N_3").glob("*.json"):
            path.write_text(path.read_text().replace("mpc-physics N=3", "mpc-learned N=3"))
    settings = json.loads((tmp_path / "settings.json").read_text())
    settings["mpc"]["learned"] = settings["mpc"]["physics"]
    (tmp_path / "settings.json").write_text(json.dumps(settings))
    rows = run_study(None, tmp_path, config, controllers=(), progress=None)
    report = write_study_report(rows, config, tmp_path).read_text()
    section = report.split("The MPC's own cost over each flight at N = 3")[1].split("##")[0]
    table = {line.split(" | ")[0].strip("| "): line.split(" | ")[1:] for line in
             section.splitlines() if line.startswith("| ")}  # fmt: skip
    assert set(table) - {"controller", "---"} >= {
        "mpc-physics N=3", "mpc-learned N=3", "mpc-oracle N=3", "learned - oracle"}  # fmt: skip
    assert table["mpc-learned N=3"] == table["mpc-physics N=3"]  # the same flights, scored alike
    total, *terms = (float(v.strip(" |")) for v in table["mpc-oracle N=3"][1:])
    assert total > 0 and total == pytest.approx(sum(terms), abs=0.1 * len(terms))
    # the paired difference, term by term (one flight: its mean, no interval)
    learned = [float(v.strip(" |")) for v in table["mpc-learned N=3"][1:]]
    oracle = [total, *terms]
    for cell, a, b in zip(table["learned - oracle"][1:], learned, oracle, strict=True):
        assert float(cell.split(" [")[0]) == pytest.approx(a - b, abs=0.11)
        assert cell.endswith("[-, -] |") or cell.endswith("[-, -]")
    assert "| mpc-oracle N=3 - mpc-physics N=3 | 1 |" in report
    # on the shifted plant the learned MPC is paired with physics: the same flights, no difference
    shifted = report.split("## Shifted plant: wind x2")[1]
    assert "| mpc-learned N=3 - mpc-physics N=3 | 1 | +0.000 [-, -] (+0 %) |" in shifted


def test_each_horizon_gets_its_own_settings(tmp_path):
    # The settings that suit a short horizon need not suit a long one: each N is tuned.
    lines: list[str] = []
    config = replace(TINY, tune=True, shifts=())
    run_study(None, tmp_path, config, controllers=("physics",), progress=lines.append)
    settings = json.loads((tmp_path / "settings.json").read_text())
    assert set(settings["mpc"]["physics"]) == {"3", "4"}
    for n in (3, 4):  # the chosen settings' score at each N, which names the best horizon
        lost, unsafe, load = settings["tuning_score"]["physics"][str(n)]
        assert f": {lost} lost, {unsafe} past 60 deg, load RMSE {load:.3f} m" in "\n".join(
            line for line in lines if line.startswith(f"tuning physics N={n}:")
        )
    for n in (3, 4):  # at least the first two rounds at each horizon
        flown = sum(line.startswith(f"tuning physics N={n}:") for line in lines)
        assert flown >= len(TUNING_GRID) + len(COST_GRID)
    # a folder written with one setting for every horizon is refused, not misread
    settings["mpc"]["physics"] = settings["mpc"]["physics"]["3"]
    (tmp_path / "settings.json").write_text(json.dumps(settings))
    with pytest.raises(ValueError, match="one MPC setting for every horizon"):
        run_study(None, tmp_path, config, controllers=("physics",), progress=None)
    with pytest.raises(ValueError, match="oracle horizons"):
        replace(TINY, oracle_horizons=(5,))


def test_the_unseen_loads_flown_lie_where_the_loads_study_trains_and_beyond():
    # Two experiments of loads, two configs: the closed-loop one flies loads the open-loop
    # study's ranges call inside (the first two) and beyond (the last).
    from slungload.lab.control.config import UnseenLoadsConfig
    from slungload.lab.study.config import LoadsStudyConfig

    study, flown = LoadsStudyConfig(), UnseenLoadsConfig().loads

    def within(value: float, bounds: tuple[float, float]) -> bool:
        return bounds[0] <= value <= bounds[1]

    for mass, length in flown[:-1]:
        assert within(mass, study.train_mass) and within(length, study.train_length)
    mass, length = flown[-1]
    assert within(mass, study.beyond_mass) and within(length, study.beyond_length)


def test_the_learned_mpc_priced_with_physics(tiny_run, tmp_path):
    # --with-physics: the learned MPC's plans priced under the network and physics, flown,
    # matched at equal compute and reported as that pair; a folder of the network alone
    # refuses it (its settings and Ks were chosen for another controller)
    config = replace(TINY, shifts=(), horizons=(3,), oracle_horizons=(3,))
    paired = replace(config, with_physics=True, risk=1.0)
    kinds = ("physics", "learned")
    alone = run_study(tiny_run.out, tmp_path / "alone", config, controllers=kinds, progress=None)
    rows = run_study(tiny_run.out, tmp_path / "paired", paired, controllers=kinds, progress=None)

    def learned(rows):
        return next(r for r in rows if r["controller"] == "mpc-learned N=3")

    physics = [r["load_rmse"] for r in (alone + rows) if r["controller"] == "mpc-physics N=3"]
    ks = [json.loads((tmp_path / d / "settings.json").read_text())["samples"]["physics"]["3"]
          for d in ("alone", "paired")]  # fmt: skip
    if ks[0] == ks[1]:  # equal compute is timed: on a busy machine the two can differ
        assert physics[0] == pytest.approx(physics[1])  # the same physics MPC either way
    assert learned(rows)["load_rmse"] != pytest.approx(learned(alone)["load_rmse"])
    report = write_study_report(rows, paired, tmp_path / "paired", str(tiny_run.out)).read_text()
    assert "priced under it and under the physics model" in report
    assert f"no say while it predicted the last {TRUST_WINDOW} steps" in report  # the default
    assert ("Otherwise each model's cost was weighted" in report) == paired_module.WEIGH_BY_RECORD
    assert "priced under" not in write_study_report(alone, config, tmp_path / "alone").read_text()
    with pytest.raises(ValueError, match="risk, with_physics, trust_window(, pair_weighs)? differ"):
        run_study(tiny_run.out, tmp_path / "alone", paired, controllers=kinds, progress=None)
    with pytest.raises(ValueError, match="give both or neither"):
        replace(config, with_physics=True)
    # --trust-window: the pair's flights count the steps physics priced alone, and the report
    # gives their share; a folder flown without the window refuses it
    audited = replace(paired, trust_window=2)
    rows = run_study(tiny_run.out, tmp_path / "audited", audited, controllers=kinds,
                     progress=None)  # fmt: skip
    mine = learned(rows)
    assert 0 <= mine["physics_only_steps"] <= mine["mpc_steps"] and mine["mpc_steps"] > 0
    share = 100 * mine["physics_only_steps"] / mine["mpc_steps"]
    report = write_study_report(rows, audited, tmp_path / "audited").read_text()
    assert f"physics priced alone {share:.0f} % of its steps" in report
    with pytest.raises(ValueError, match="trust_window differ"):
        run_study(tiny_run.out, tmp_path / "paired", audited, controllers=kinds, progress=None)
    with pytest.raises(ValueError, match="give --with-physics"):
        replace(config, trust_window=2)
    # the file records the window flown, resolved; one written with null (the default, then
    # 10 steps) is read as 10; one that lacks the field was flown before it existed: none
    path = tmp_path / "paired" / "settings.json"
    settings = json.loads(path.read_text())
    assert settings["config"]["trust_window"] == TRUST_WINDOW
    settings["config"]["trust_window"] = None
    path.write_text(json.dumps(settings))
    ten = replace(paired, trust_window=10)
    run_study(tiny_run.out, tmp_path / "paired", ten, controllers=kinds, progress=None)
    if TRUST_WINDOW != 10:
        with pytest.raises(ValueError, match="trust_window differ"):
            run_study(tiny_run.out, tmp_path / "paired", paired, controllers=kinds, progress=None)
    del settings["config"]["trust_window"]
    path.write_text(json.dumps(settings))
    with pytest.raises(ValueError, match="trust_window differ"):
        run_study(tiny_run.out, tmp_path / "paired", ten, controllers=kinds, progress=None)
    # the file says whether the pair weighed its members by their record; one that lacks the
    # field was flown with equal weights
    assert settings["config"]["pair_weighs"] == paired_module.WEIGH_BY_RECORD
    settings["config"]["trust_window"] = TRUST_WINDOW
    del settings["config"]["pair_weighs"]
    path.write_text(json.dumps(settings))
    if paired_module.WEIGH_BY_RECORD:
        with pytest.raises(ValueError, match="pair_weighs differ"):
            run_study(tiny_run.out, tmp_path / "paired", paired, controllers=kinds, progress=None)
    else:
        run_study(tiny_run.out, tmp_path / "paired", paired, controllers=kinds, progress=None)


def test_the_settings_file_records_the_lean_and_only_the_payload_cost_takes_one():
    """The lean is recorded as flown; a file without the field was flown before it existed,
    with the reference's own acceleration (0); the vehicle cost refuses a lean by name."""
    assert settings_record(StudyConfig(cost="payload", lean=1.0))["lean"] == 1.0
    assert settings_record(StudyConfig())["lean"] == 0.0
    old = settings_record(StudyConfig(cost="payload", lean=1.0))
    del old["lean"]
    assert recorded_settings(old)["lean"] == 0.0
    assert StudyConfig(cost="payload", lean=0.5).mpc(horizon=15).lean == 0.5
    for config in (StudyConfig, ComparisonConfig):
        with pytest.raises(ValueError, match="lean is the payload cost's .* 'vehicle' cost"):
            config(lean=1.0)


def test_tuning_tries_the_lean_only_where_the_cost_reads_it():
    """The vehicle cost's changes are the grid's; the payload cost's each also with the lean
    (once: not again where the study already leans), and a choice's own lean is flown."""
    grid = [{}, *COST_GRID]
    assert cost_changes("vehicle", 0.0) == grid
    assert cost_changes("payload", 1.0) == grid
    leaning = cost_changes("payload", 0.0)
    assert leaning[: len(grid)] == grid and leaning[len(grid) :] == [
        {**c, "lean": 1.0} for c in grid
    ]
    cfg = StudyConfig(cost="payload", lean=0.0)
    assert cfg.mpc(horizon=15).lean == 0.0 and cfg.mpc(horizon=15, lean=1.0).lean == 1.0
