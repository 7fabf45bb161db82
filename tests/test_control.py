"""Model-predictive control: the controller's history, the sampling MPC, its safety (limits,
fallbacks, the arena) and the closed-loop command (docs/control.md). The prediction models it
runs are tested in test_prediction.py."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch

from slungload import physics
from slungload.config import VehicleParams
from slungload.control.closed_loop import Arena, flight_metrics, fly, log_path, read_log
from slungload.control.history import History
from slungload.control.mpc import InputLimits, MPCConfig, SamplingMPC
from slungload.lab.control.report import report_markdown, versus_lines
from slungload.lab.control.results import ControlComparison, versus_physics
from slungload.models.prediction import PhysicsModel
from slungload.sim.config import SimConfig
from slungload.sim.controller import Measurement
from slungload.sim.maneuvers import Reference
from slungload.state import LOAD_POS, POS, QUAT, VEL, quat_to_rotmat

PARAMS = VehicleParams()
HOVER_T = (PARAMS.mass_quad + PARAMS.mass_load) * PARAMS.gravity
LIMITS = InputLimits(0.3 * HOVER_T, 30.0, 4.0)
FAST = MPCConfig(samples=24, horizon=10, knots=4)


def hover_state(p=(0.0, 0.0, 1.5)) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return np.concatenate([p, np.zeros(3), [1.0, 0, 0, 0], p - [0, 0, PARAMS.cable_length]])


def measurement(x: np.ndarray, t: float = 0.0) -> Measurement:
    q = torch.from_numpy(x[QUAT])
    rot = quat_to_rotmat(q).numpy()
    return Measurement(t, x[POS].copy(), x[VEL].copy(), x[QUAT].copy(), rot, x[LOAD_POS].copy())


def hold_reference(point, steps: int) -> Reference:
    pos = np.tile(np.asarray(point, dtype=float), (steps, 1))
    return Reference(pos, np.zeros_like(pos), np.zeros_like(pos), np.zeros(steps))


# --- the history ------------------------------------------------------------------------


def test_history_pads_with_the_first_row_and_keeps_the_last_m():
    h = History(4)
    h.push_state(np.full(13, 1.0))
    x, u = h.window(np.full(4, 7.0))
    assert x.shape == (4, 13) and u.shape == (3, 4)
    assert (x == 1.0).all() and (u == 7.0).all()
    for k in range(2, 8):
        h.push_input(np.full(4, float(k - 1)))
        h.push_state(np.full(13, float(k)))
    x, u = h.window(np.zeros(4))
    assert x[:, 0].tolist() == [4.0, 5.0, 6.0, 7.0]
    assert u[:, 0].tolist() == [4.0, 5.0, 6.0]  # u_j was applied at x_j


# --- the MPC on the discrete model itself ---------------------------------------------


def fly_discrete(mpc: SamplingMPC, x0: np.ndarray, point, steps: int) -> tuple[np.ndarray, list]:
    """Close the loop on physics.step (the MPC's own model) holding ``point``."""
    x = torch.from_numpy(x0)
    aux = torch.zeros(6, dtype=torch.float64)
    ref = hold_reference(point, steps + mpc.cfg.horizon + 1)
    path, commands = [], []
    for k in range(steps):
        thrust, rates = mpc(measurement(x.numpy(), k * PARAMS.dt), ref, k)
        commands.append(np.array([thrust, *rates]))
        u = torch.tensor([thrust, *rates], dtype=torch.float64)
        x, aux = physics.step(x, u, aux, PARAMS)
        path.append(x.numpy().copy())
    return np.array(path), commands


def test_mpc_with_the_physics_model_holds_a_point_on_the_discrete_model():
    mpc = SamplingMPC(PhysicsModel(PARAMS), LIMITS, FAST, PARAMS)
    target = np.array([0.0, 0.0, 1.5])
    x0 = hover_state(target + [0.3, -0.2, 0.1])  # start 0.37 m away, hanging still
    path, commands = fly_discrete(mpc, x0, target, 70)
    err = np.linalg.norm(path[:, 0:3] - target, axis=1)
    assert err[-10:].max() < 0.1, err[::10]
    swing = np.linalg.norm(path[:, 10:12] - path[:, 0:2], axis=1)  # m, horizontal offset
    assert swing.max() < 0.2  # about 16 degrees: the move does not throw the load around
    assert all(LIMITS.contains(c) for c in commands)
    assert mpc.stats.fallback_steps == 0 and mpc.stats.steps == 70


class Recording:
    """A numpy candidate model that predicts ``value`` everywhere and keeps what it was given."""

    numpy = True

    def __init__(self, name: str, history: int, value: float) -> None:
        self.name, self.history, self.value, self.got = name, history, value, None

    def predict_candidates(self, x_hist, u_past, plans):
        self.got = (x_hist.shape, u_past.shape, x_hist[-1, 0])
        return np.full((*plans.shape[:2], 13), self.value)


def test_a_network_paired_with_physics_gives_both_their_own_history():
    from slungload.control.paired import PhysicsPaired

    network, physics = Recording("net", 5, 1.0), Recording("physics", 2, 2.0)
    pair = PhysicsPaired(network, physics, window=0)  # the veto alone
    assert pair.history == 5 and pair.name == "net+physics"
    x_hist, u_past = np.arange(65.0).reshape(5, 13), np.zeros((4, 4))
    plans = np.zeros((3, 7, 4))
    assert (pair.predict_candidates(x_hist, u_past, plans) == 1.0).all()
    members = pair.predict_candidates_members(x_hist, u_past, plans)
    assert members.shape == (2, 3, 7, 13)
    assert (members[0] == 1.0).all() and (members[1] == 2.0).all()
    assert network.got == ((5, 13), (4, 4), 52.0) and physics.got == ((2, 13), (1, 4), 52.0)


def test_physics_pricing_halves_a_biased_networks_height_error():
    """A model that believes the rotors 15 % stronger than they are holds the vehicle about
    9 cm low; paired with the true physics model and priced by the worse of the two costs
    (risk 1), the height error about halves."""
    from slungload.control.mpc import candidate_model
    from slungload.control.paired import PhysicsPaired

    biased = PhysicsModel(replace(PARAMS, thrust_gain=1.15))
    target = np.array([0.0, 0.0, 1.5])
    low = {}
    for name, model, cfg in (
        ("alone", biased, FAST),
        ("paired", PhysicsPaired(candidate_model(biased), candidate_model(PhysicsModel(PARAMS)),
                                 window=0),  # the veto alone
         replace(FAST, risk=1.0)),
    ):  # fmt: skip
        mpc = SamplingMPC(model, LIMITS, cfg, PARAMS)
        path, _ = fly_discrete(mpc, hover_state(target), target, 90)
        low[name] = float(np.abs(path[-20:, 2] - target[2]).max())
    assert low["paired"] < 0.7 * low["alone"], low


def flown_window(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """x_hist (m, 13) and u_past (m - 1, 4): m states of physics.step under varied inputs from
    hover, u_j applied at x_j (the controller's ``History.window``)."""
    rng = np.random.default_rng(seed)
    x = torch.from_numpy(hover_state())
    aux = torch.zeros(6, dtype=torch.float64)
    xs, us = [x.numpy().copy()], []
    for _ in range(m - 1):
        u = np.array([HOVER_T * (1 + 0.2 * rng.standard_normal()), *rng.normal(0, 0.5, 3)])
        x, aux = physics.step(x, torch.from_numpy(u), aux, PARAMS)
        xs.append(x.numpy().copy())
        us.append(u)
    return np.array(xs), np.array(us)


def test_the_trust_window_asks_each_member_to_predict_the_steps_just_flown():
    """Each member predicts the last H states from the one H steps before them under the
    inputs applied since: the physics model that flew them is right there to millimetres (its
    cable rate is estimated from two states), a network that believes the rotors 30 % stronger
    is not and has no say; a network equal to physics is trusted."""
    from slungload.control.mpc import candidate_model
    from slungload.control.paired import PhysicsPaired

    truth = candidate_model(PhysicsModel(PARAMS))
    biased = candidate_model(PhysicsModel(replace(PARAMS, thrust_gain=1.3)))
    pair = PhysicsPaired(biased, truth, window=8)
    assert pair.history == 2 + 8 and pair.name.endswith("+physics-trust8")
    x_hist, u_past = flown_window(pair.history)
    plans = np.tile(u_past[-1], (5, 12, 1))
    members = pair.predict_candidates_members(x_hist, u_past, plans)
    net_error, physics_error = pair.errors
    assert physics_error < 0.005 and net_error > 10 * physics_error, pair.errors
    assert not pair.trusted and np.array_equal(members[0], members[1])  # physics twice
    same = PhysicsPaired(candidate_model(PhysicsModel(PARAMS)), truth, window=8)
    members = same.predict_candidates_members(x_hist, u_past, plans)
    assert same.trusted and same.errors[0] == pytest.approx(same.errors[1], abs=1e-9)
    # a plan shorter than the window: only its N steps are compared (an earlier start would
    # compare states the inputs did not lead to)
    pair.predict_candidates_members(x_hist, u_past, plans[:, :4])
    assert pair.errors[1] < 0.005 and pair.errors[0] < 0.5 * net_error  # a bias grows with t
    with pytest.raises(ValueError, match="window >= 0"):
        PhysicsPaired(biased, truth, window=-1)


def test_members_are_priced_by_their_weights_and_by_their_record():
    """Equal weights: mean + risk x std of the members' costs; weights (3, 1): the weighted
    mean and spread, by hand. A pair that weighs by its record gives the member that predicted
    the window just flown better the larger weight, 1 / (error + floor)^2; without weighing,
    or untrusted, it gives none."""
    from slungload.control.contract import priced
    from slungload.control.mpc import candidate_model
    from slungload.control.paired import PhysicsPaired

    costs = np.array([[1.0, 4.0], [3.0, 4.0]])
    np.testing.assert_allclose(priced(costs, 0.5), [2.0 + 0.5, 4.0])
    # weights 0.75 / 0.25: mean 1.5, spread sqrt(0.75 x 0.25) x 2
    np.testing.assert_allclose(priced(costs, 1.0, np.array([3.0, 1.0])),
                               [1.5 + np.sqrt(0.1875) * 2, 4.0])  # fmt: skip
    truth = candidate_model(PhysicsModel(PARAMS))
    biased = candidate_model(PhysicsModel(replace(PARAMS, thrust_gain=1.2)))
    x_hist, u_past = flown_window(2 + 8)
    plans = np.tile(u_past[-1], (5, 12, 1))
    for weigh in (False, True):
        pair = PhysicsPaired(truth, biased, window=8, weigh=weigh)  # the network is right
        pair.predict_candidates_members(x_hist, u_past, plans)
        assert pair.trusted
        if not weigh:
            assert pair.member_weights is None
            continue
        errors = np.asarray(pair.errors)
        np.testing.assert_allclose(pair.member_weights, (errors + pair.floor) ** -2.0)
        assert pair.member_weights[0] > 2 * pair.member_weights[1], pair.errors
    wrong = PhysicsPaired(biased, truth, window=8, weigh=True, floor=0.0)
    wrong.predict_candidates_members(x_hist, u_past, plans)
    assert not wrong.trusted and wrong.member_weights is None


def test_a_wrong_network_under_the_trust_window_flies_as_physics_alone():
    """A network of another vehicle (rotors 60 % stronger) priced with physics still pulls the
    flight off; with the trust window it never takes part and the MPC flies exactly as physics
    alone, counting every step."""
    from slungload.control.mpc import candidate_model
    from slungload.control.paired import PhysicsPaired

    wrong = PhysicsModel(replace(PARAMS, thrust_gain=1.6))
    target = np.array([0.0, 0.0, 1.5])
    cfg = replace(FAST, risk=0.5)
    paths, stats = {}, {}
    for window in (0, 8):
        pair = PhysicsPaired(candidate_model(wrong), candidate_model(PhysicsModel(PARAMS)), window)
        mpc = SamplingMPC(pair, LIMITS, cfg, PARAMS)
        paths[window], _ = fly_discrete(mpc, hover_state(target), target, 60)
        stats[window] = mpc.stats
    alone = SamplingMPC(PhysicsModel(PARAMS), LIMITS, FAST, PARAMS)
    physics_path, _ = fly_discrete(alone, hover_state(target), target, 60)
    np.testing.assert_allclose(paths[8], physics_path, atol=1e-9)
    assert stats[8].physics_only_steps == 60 and stats[0].physics_only_steps == 0
    error = {w: np.abs(p[:, 2] - target[2]).max() for w, p in paths.items()}
    assert error[0] > 2 * error[8], error


class TwoPhysics:
    """A numpy ensemble of two members: the physics model + ``bias`` in every component, 2 cm
    (or m/s, or 0.02 in the quaternion) below and above it; calibrated by hand (scale 1 at
    every step and group, level 0.9)."""

    name, history = "two-physics", 2

    def __init__(self, bias: float) -> None:
        from slungload.control.mpc import candidate_model
        from slungload.layout import GROUPS

        self.physics, self.bias = candidate_model(PhysicsModel(PARAMS)), bias
        self.calibration = {"scale": [[1.0] * len(GROUPS)] * 3, "level": 0.9}

    def predict_candidates_members(self, x_hist, u_past, plans):
        states = self.physics.predict_candidates(x_hist, u_past, plans) + self.bias
        return np.stack([states - 0.02, states + 0.02])

    def predict_candidates(self, x_hist, u_past, plans):
        return self.physics.predict_candidates(x_hist, u_past, plans)


def test_an_ensembles_interval_is_tracked_over_the_steps_just_flown():
    """Members 2 cm around the vehicle flown are within their interval and never surprised;
    members that agree on a prediction 0.3 off in every component are outside it, and after
    16 resolved windows (rate 0.05 x level 0.9 a window, up to log 2) surprised. The MPC wraps
    a calibrated ensemble itself and counts those steps."""
    from slungload.control.mppi import MPPIController, ReferenceAhead
    from slungload.control.tracked import TrackedMembers

    x_hist, u_past = flown_window(2 + 8)
    plans = np.tile(u_past[-1], (5, 12, 1))
    for bias, surprised in ((0.0, False), (0.3, True)):
        model = TwoPhysics(bias)
        tracked = TrackedMembers(model, model.calibration, window=8)
        assert tracked.history == 10
        for i in range(20):
            states = tracked.predict_candidates_members(x_hist, u_past, plans)
            assert tracked.surprised == (surprised and i >= 15), (bias, i)
        assert states.shape == (2, 5, 12, 13) and tracked.tracker.resolved == 20
        mpc = MPPIController(model, LIMITS, replace(FAST, risk=0.5), PARAMS)
        assert isinstance(mpc.model, TrackedMembers) and mpc.model.window == FAST.horizon
        ref = ReferenceAhead(np.tile(hover_state()[:3], (FAST.horizon, 1)),
                             np.zeros((FAST.horizon, 3)), np.zeros(FAST.horizon))  # fmt: skip
        x = hover_state()
        for _ in range(30):
            u = mpc.step(x, ref)
            x, _ = physics.step(torch.from_numpy(x), torch.tensor([u.thrust, *u.rates]),
                                torch.zeros(6, dtype=torch.float64), PARAMS)  # fmt: skip
            x = x.numpy()
        assert (mpc.stats.surprised_steps > 0) == surprised, mpc.stats
    with pytest.raises(ValueError, match="no members"):
        TrackedMembers(model.physics, model.calibration, window=8)


def test_the_interval_half_width_in_numpy_is_the_calibrations():
    """``members_half_width`` (numpy, onboard) equals ``Calibration.half_width`` of the
    members' spread, past the calibration's steps too, with a member in the other quaternion
    hemisphere."""
    from slungload.deploy.members import members_half_width
    from slungload.layout import GROUPS
    from slungload.models.ensemble import Calibration, spread

    rng = np.random.default_rng(3)
    scale = tuple(tuple(rng.uniform(0.5, 2.0, len(GROUPS))) for _ in range(4))
    calibration = Calibration(scale, tuple((1.0,) * 13 for _ in range(4)), 1.0, level=0.8)
    members = rng.standard_normal((3, 5, 6, 13))
    members[1, ..., 6:10] *= -1
    want = calibration.half_width(spread(torch.from_numpy(members)).std).numpy()
    got = members_half_width(members, {"scale": scale, "level": 0.8})
    np.testing.assert_allclose(got, want, rtol=1e-12)


# --- safety ----------------------------------------------------------------------------


class BrokenModel:
    """A prediction model that returns NaN for the samples in ``bad`` (all by default)."""

    name, history = "broken", 2

    def __init__(self, bad=None, raises: bool = False) -> None:
        self.bad, self.raises = bad, raises
        self.inner = PhysicsModel(PARAMS)

    def predict_candidates(self, x_hist, u_past, plans):
        if self.raises:
            raise RuntimeError("boom")
        out = self.inner.predict_candidates(x_hist, u_past, plans)
        out[slice(None) if self.bad is None else self.bad] = math.nan
        return out


def test_nan_predictions_never_reach_the_vehicle_fall_back_and_are_counted():
    mpc = SamplingMPC(BrokenModel(), LIMITS, replace(FAST, max_fallback_steps=3), PARAMS)
    safe = mpc.plan.copy()  # numpy (float64) since the MPPI core moved to control.mppi
    x = hover_state()
    ref = hold_reference(x[:3], 40)
    commands = [mpc(measurement(x), ref, k) for k in range(5)]
    for thrust, rates in commands:
        assert math.isfinite(thrust) and np.isfinite(rates).all()
        assert LIMITS.contains(np.array([thrust, *rates]))
    assert commands[0][0] == pytest.approx(float(safe[0, 0]))  # the last safe plan first
    assert mpc.stats.fallbacks == {"non-finite prediction": 5}
    assert mpc.stats.hover_steps == 2  # after 3 fallbacks in a row: the hover command
    assert commands[-1][0] == pytest.approx(HOVER_T)


def test_some_nan_samples_are_dropped_without_a_fallback():
    mpc = SamplingMPC(BrokenModel(bad=slice(1, 8)), LIMITS, FAST, PARAMS)
    x = hover_state()
    thrust, rates = mpc(measurement(x), hold_reference(x[:3], 40), 0)
    assert math.isfinite(thrust) and np.isfinite(rates).all()
    assert mpc.stats.nonfinite_steps == 1 and mpc.stats.fallback_steps == 0


def test_a_model_that_raises_falls_back():
    mpc = SamplingMPC(BrokenModel(raises=True), LIMITS, FAST, PARAMS)
    x = hover_state()
    thrust, _ = mpc(measurement(x), hold_reference(x[:3], 40), 0)
    assert math.isfinite(thrust)
    assert mpc.stats.fallbacks == {"prediction error (RuntimeError)": 1}


def test_a_model_is_prepared_for_the_mpcs_calls_before_the_flight():
    class Prepared(PhysicsModel):  # as deploy.gpu.GraphedModel: it captures at these shapes
        asked: list = []

        def prepare(self, history, samples, horizon):
            self.asked.append((history, samples, horizon))
            if samples > 8:
                raise ValueError("cannot capture this one")

    model = Prepared(PARAMS)
    SamplingMPC(model, LIMITS, replace(FAST, samples=8, horizon=6), PARAMS)
    assert model.asked == [(2, 8, 6)]  # M = the model's history (at least 2), K, N
    with pytest.raises(ValueError, match="cannot capture"):  # before flying, not a fallback
        SamplingMPC(model, LIMITS, replace(FAST, samples=9), PARAMS)

    class NumpyPrepared:  # the controller core itself, without torch: the same call
        name, history, asked = "np", 20, []

        def prepare(self, history, samples, horizon):
            self.asked.append((history, samples, horizon))

        def predict_candidates(self, x_hist, u_past, plans):
            return np.broadcast_to(x_hist[-1], (*plans.shape[:2], 13)).copy()

    from slungload.control.mppi import MPPIController

    core = NumpyPrepared()
    MPPIController(core, LIMITS, replace(FAST, samples=8, horizon=6), PARAMS)
    assert core.asked == [(20, 8, 6)]


def test_input_limits():
    assert LIMITS.contains(np.array([HOVER_T, 4.0, -4.0, 0.0]))
    assert not LIMITS.contains(np.array([HOVER_T, 4.1, 0.0, 0.0]))
    assert not LIMITS.contains(np.array([31.0, 0.0, 0.0, 0.0]))
    assert not LIMITS.contains(np.array([math.nan, 0.0, 0.0, 0.0]))
    assert LIMITS.at_limit(np.array([30.0, 0.0, 0.0, 0.0]))
    assert not LIMITS.at_limit(np.array([HOVER_T, 1.0, 0.0, 0.0]))


# --- closed loop in the simulator ----------------------------------------------------


def test_every_applied_command_is_within_tight_limits_in_the_simulator():
    cfg = SimConfig()
    tight = InputLimits(0.5 * HOVER_T, 1.2 * HOVER_T, 0.5)
    mpc = SamplingMPC(PhysicsModel(PARAMS), tight, replace(FAST, samples=8), PARAMS)
    log = fly("roll_35", 100, mpc, label="mpc", config=cfg, steps=20)
    assert log.stopped is None and len(log.inputs) == 20 + round(cfg.warmup / cfg.control_dt)
    assert all(tight.contains(u) for u in log.inputs)
    row = flight_metrics(log, tight, cfg.cable_length)
    assert row["completed"] and row["steps"] == 20 and math.isfinite(row["load_rmse"])
    assert row["fallback_steps"] == 0


def test_a_vehicle_leaving_the_arena_ends_the_run_with_a_reason():
    def climb(m, reference, k):
        return 25.0, np.zeros(3)

    log = fly("roll_35", 100, climb, label="climb", arena=Arena(hi=(3.0, 3.0, 1.7)), steps=50)
    assert log.stopped is not None and "left the arena: z" in log.stopped
    assert len(log.t) < 50  # stopped before the end, never an exception
    row = flight_metrics(log, LIMITS, 0.7)
    assert not row["completed"] and row["stopped"] == log.stopped


def test_a_measurements_state_is_the_package_layout():
    x = hover_state((0.1, 0.2, 1.3))
    x[VEL] = (0.4, -0.5, 0.6)  # every block distinct, so a swapped block would show
    np.testing.assert_array_equal(measurement(x).state, x)


def test_control_command_writes_the_report(run_cli, tmp_path):
    out = tmp_path / "ctl"
    code, stdout, err = run_cli(
        "control", "--maneuvers", "roll_35", "--seeds", "100", "--samples", "4",
        "--horizon", "3", "--steps", "8", "--out", out, "--quiet",
    )  # fmt: skip
    assert code == 0, err  # a horizon shorter than the sampler's default knots flies too
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert [r["controller"] for r in rows] == ["pid", "mpc-physics K=4"]
    assert all(r["completed"] for r in rows)
    report = (out / "report.md").read_text()
    assert "| mpc-physics K=4 |" in report
    for name in ("paths_3d.png", "swing.png", "table.png"):
        assert (out / name).stat().st_size > 0

    def refuse(constant: str) -> None:
        raise AssertionError(f"results.json holds {constant}: not standard JSON")

    json.loads((out / "results.json").read_text(), parse_constant=refuse)
    # each flight's log lies where the control study keeps its own, and reads back whole
    for row in rows:
        path = log_path(out, "nominal", row["controller"], "roll_35", 100).with_suffix(".npz")
        folder = {"pid": "pid", "mpc-physics K=4": "mpc-physics_K_4"}[row["controller"]]
        assert path == out / "flights" / "nominal" / folder / "roll_35_s100.npz"
        again = flight_metrics(
            read_log(path, row), InputLimits.from_sim(SimConfig()), SimConfig().cable_length
        )
        assert again.items() <= row.items()  # the errors from the log are the row's


def test_control_help_is_light_and_bad_maneuvers_are_a_user_error(run_cli, tmp_path):
    code = (
        "import sys\n"
        "from slungload.cli import build_parser\n"
        "try:\n"
        "    build_parser().parse_args(['control', '--help'])\n"
        "except SystemExit:\n"
        "    pass\n"
        "assert 'torch' not in sys.modules and 'mujoco' not in sys.modules\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    code, _, err = run_cli("control", "--maneuvers", "loop_the_loop", "--out", tmp_path / "x")
    assert code == 2 and "unknown maneuvers ['loop_the_loop']" in err
    # each command that flies the MPC takes the payload cost's lean
    from slungload.cli import build_parser
    from slungload.cli.autopilot import cmd_fly
    from slungload.cli.control import cmd_control
    from slungload.cli.study_control import cmd_study_control

    for argv, func in ((["control", "--out", "x"], cmd_control),
                       (["study", "control", "--out", "x"], cmd_study_control),
                       (["fly", "m.mpc.npz"], cmd_fly)):  # fmt: skip
        args = build_parser().parse_args([*argv, "--lean", "0.5", "--shape", "2"])
        assert args.func is func and args.lean == 0.5 and args.shape == 2.0
    code, _, err = run_cli("control", "--shape", "1", "--out", tmp_path / "x")
    assert code == 2 and "shape is the payload cost's" in err


def _row(controller, seed, load, swing, vehicle, completed=True, k=32):
    return dict(controller=controller, K=k, maneuver="roll_35", seed=seed, load_rmse=load,
                swing_rms=swing, vehicle_rmse=vehicle, completed=completed,
                stopped=None if completed else "vehicle left the arena")  # fmt: skip


def test_a_network_is_compared_with_physics_on_the_flights_both_flew_to_the_end():
    ref = "mpc-physics K=32"
    physics = [_row(ref, 0, 0.20, 20, 0.1), _row(ref, 1, 0.20, 20, 0.1),
               _row(ref, 2, 9.0, 90, 9.0, completed=False)]  # fmt: skip
    good = [_row("mpc-net K=32", s, 0.14, 19, 0.1) for s in range(3)]  # 30 % lower load error
    pid = [dict(_row("pid", s, 0.3, 30, 0.1), K=None) for s in range(3)]  # not an MPC: left out
    (v,) = versus_physics(pid + physics + good)
    # the physics flight that ended early is left out of the means (not 1 - 0.14 / 3.13)
    assert (v.controller, v.samples, v.paired, v.physics_failed, v.failed) == (
        "mpc-net K=32", 32, 2, 1, 0)  # fmt: skip
    assert v.network["load_rmse"] == pytest.approx(0.14) and v.lower("load_rmse") == (
        pytest.approx(0.3)
    )
    (line,) = versus_lines([v])
    assert "0.140 vs 0.200 m (30 % lower)" in line and "over the 2 flights" in line
    assert "ended 1 more early" in line
    # A network flight that ended early is counted, and the others are still compared.
    crashed = [*good[:2], _row("mpc-net K=32", 2, 0.1, 10, 0.1, completed=False)]
    (v,) = versus_physics(physics + crashed)
    assert (v.failed, v.flights, v.paired, v.stopped) == (1, 3, 2, "vehicle left the arena")
    (line,) = versus_lines([v])
    assert line.startswith("- mpc-net K=32: 1 of 3 flights ended early (vehicle left")
    assert "over the 2 flights" in line
    # worse than physics reads as higher, not as a negative lower
    worse = [_row("mpc-net K=32", s, 0.30, 21, 0.1) for s in range(2)]
    assert "0.300 vs 0.200 m (50 % higher)" in versus_lines(versus_physics(physics + worse))[0]
    # No flight both flew to the end: said so, no means.
    lost = [_row("mpc-net K=32", 2, 0.1, 10, 0.1)]
    assert (
        "no flight that MPC + physics also flew" in versus_lines(versus_physics(physics + lost))[0]
    )
    # A pair whose trust window gave physics the say on a quarter of its steps says so.
    audited = [dict(r, mpc_steps=100, physics_only_steps=25) for r in good]
    (v,) = versus_physics(physics + audited)
    assert v.physics_only == pytest.approx(0.25)
    assert "physics alone priced 25 % of its steps" in versus_lines([v])[0]
    assert v.surprised == 0.0 and "surprised" not in versus_lines([v])[0]
    # A calibrated ensemble surprised on 40 of 100 steps of one flight and none of another's:
    # the share is over all its steps, and the line says what to do about it.
    tracked = [dict(r, mpc_steps=100, surprised_steps=40 * (s == 0)) for s, r in enumerate(good)]
    (v,) = versus_physics(physics + tracked)
    assert v.surprised == pytest.approx(40 / 300)
    line = versus_lines([v])[0]
    assert "surprised on 13 % of its steps" in line and "--with-physics" in line


def test_the_control_report_shows_results_only():
    ref = "mpc-physics K=32"
    rows = [_row(ref, 0, 0.20, 20, 0.1), _row("mpc-net K=32", 0, 0.14, 19, 0.1)]
    for r in rows:
        r.update(swing_max=30.0, at_limit=1.0, compute_median=5.0, compute_p99=9.0)
    settings = dict(date="2026-11-24", maneuvers=["roll_35"], seeds=[0], samples=[32],
                    mpc={"horizon": 15}, threads=1,
                    machine={"cpu": "x", "cores": 2, "load_average": None})  # fmt: skip
    text = report_markdown(ControlComparison(rows, settings))
    assert "load average at the end unknown" in text and "| mpc-net K=32 |" in text
    assert "K = 32, cost vehicle;" in text  # an old results.json names no cost: the default
    assert "0.140 vs 0.200 m (30 % lower)" in text
    assert "target" not in text.lower() and "met**" not in text
    assert "Smoke run" not in text
    settings["presets"] = {"runs/net": "quick", "runs/other": "default"}
    text = report_markdown(ControlComparison(rows, settings))
    banner = text.split("\n\n")[1]  # under the title
    assert "Smoke run: these numbers are not results" in banner
    assert "`runs/net`" in banner and "runs/other" not in banner
    assert "GPU" not in text  # an old results.json names none; a GPU is named where flown
    settings["mpc"] = {"horizon": 15, "cost": "payload", "lean": 0.0, "shape": 1.0}
    assert "K = 32, cost payload (shape 1);" in report_markdown(ControlComparison(rows, settings))
    settings["machine"] = {"cpu": "x", "cores": 16, "gpu": "NVIDIA H100", "load_average": None}
    assert "(16 cores, load average at the end unknown); GPU NVIDIA H100." in report_markdown(
        ControlComparison(rows, settings)
    )


def test_the_realized_cost_of_a_perfect_hover_is_zero_and_each_error_lands_in_its_term():
    from slungload.control.closed_loop import COST_TERMS, FlightLog, realized_cost

    s, warm = 12, 3
    t = (np.arange(s) - warm) * 0.03
    ref = Reference(np.tile([0.2, -0.1, 1.5], (s, 1)), np.zeros((s, 3)), np.zeros((s, 3)),
                    np.zeros(s))  # fmt: skip
    states = np.tile(hover_state((0.2, -0.1, 1.5)), (s, 1))
    inputs = np.tile([HOVER_T, 0.0, 0.0, 0.0], (s, 1))
    log = FlightLog("m", 0, "c", s - warm, t, states, ref.position, inputs, np.zeros(s))
    cost = realized_cost(log, ref, MPCConfig(), PARAMS)
    assert set(cost) == {*COST_TERMS, "total"} and all(v == 0.0 for v in cost.values())
    # the load 0.1 m off in x over the recorded steps: the load and swing terms, nothing else
    states[warm:, LOAD_POS.start] += 0.1
    cost = realized_cost(log, ref, MPCConfig(), PARAMS)
    cfg, n = MPCConfig(), s - warm
    assert cost["load"] == pytest.approx(cfg.w_load * 0.01 * n)
    assert cost["swing"] == pytest.approx(cfg.w_swing * 0.01 * n)
    assert cost["total"] == pytest.approx(cost["load"] + cost["swing"])
    assert cost["vehicle"] == cost["velocity"] == cost["inputs"] == 0.0
    # the terminal weight is left out: a flight is scored step by step, not as one horizon
    assert realized_cost(log, ref, replace(cfg, terminal=50.0), PARAMS) == cost
    # the payload cost scores the flight against the acceleration its controller read, leaned
    pulse = np.zeros((s, 3))
    pulse[5:7, 0] = 3.0
    payload = replace(cfg, cost="payload", lean=1.0)
    jolted = replace(ref, acceleration=pulse)
    from slungload.control.mppi import MPPIController

    class Still:  # a numpy model: nothing moves
        name, history = "still", 2

        def predict_candidates(self, x_hist, u_past, plans):
            return np.broadcast_to(x_hist[-1], (*plans.shape[:2], 13)).copy()

    seen = MPPIController(Still(), LIMITS, replace(payload, horizon=n, knots=3), PARAMS)
    as_read = replace(
        ref, acceleration=np.concatenate([pulse[:warm], seen.ahead(jolted, warm - 1).acceleration])
    )
    raw = realized_cost(log, as_read, replace(payload, lean=0.0), PARAMS)
    assert realized_cost(log, jolted, payload, PARAMS) == pytest.approx(raw, rel=1e-12)
    assert realized_cost(log, jolted, replace(payload, lean=0.0), PARAMS)["swing"] != raw["swing"]
    # and against the path its controller read a step shaped into
    stepped = np.tile([0.2, -0.1, 1.5], (s, 1))
    stepped[warm + 4 :, 0] += 0.5
    shaped = replace(payload, lean=0.0, shape=1.0)
    step = replace(ref, position=stepped)
    seen = MPPIController(Still(), LIMITS, replace(shaped, horizon=n, knots=3), PARAMS)
    path = seen.ahead(step, warm - 1)
    before = slice(0, warm)
    as_read = Reference(*(np.concatenate([whole[before], read]) for whole, read in
                          ((stepped, path.position), (ref.velocity, path.velocity),
                           (ref.acceleration, path.acceleration))), ref.yaw)  # fmt: skip
    flown = realized_cost(log, step, shaped, PARAMS)
    assert flown == pytest.approx(realized_cost(log, as_read, replace(shaped, shape=0.0), PARAMS))
    assert flown["load"] != pytest.approx(realized_cost(log, step, replace(payload, lean=0.0),
                                                        PARAMS)["load"])  # fmt: skip


def test_what_to_know_before_a_network_flies_is_said(tiny_run, tmp_path):
    from slungload.control.mpc import model_notes
    from slungload.models.checkpoints import CKPT_KEY

    checkpoint = torch.load(tiny_run.out / "best.ckpt", weights_only=False)
    for excitation, named in (({"thrust_std": 0.0, "rate_std": [0.0, 0.0, 0.0]}, True),
                              ({"thrust_std": 0.0, "rate_std": [0.5, 0.5, 0.0]}, False),
                              (None, False)):  # fmt: skip
        data = tmp_path / f"data_{named}_{excitation is None}"
        data.mkdir()
        sim = {} if excitation is None else {"sim": {"excitation": excitation}}
        (data / "vehicle.json").write_text(json.dumps(sim))  # None: real flights, no "sim"
        run = tmp_path / f"run_{data.name}"
        run.mkdir()
        meta = {**checkpoint[CKPT_KEY], "data": str(data)}
        torch.save({**checkpoint, CKPT_KEY: meta}, run / "best.ckpt")
        notes = model_notes(run, 3)
        assert len(notes) == named and (not named or str(data) in notes[0])
    # a dataset of the MPC's own flights (record), an old one without excitation
    # settings, and a file that is no dict
    for found, named in (({"sim": {"excitation": None}, "recorded": {"model": "x"}}, False),
                         ({"sim": {}}, True), ([1, 2], False)):  # fmt: skip
        (data / "vehicle.json").write_text(json.dumps(found))
        assert len(model_notes(run, 3)) == named
    assert model_notes("physics", 500) == []
    assert model_notes(tiny_run.out, 3) == []  # its dataset holds no simulator settings
    trained = tiny_run.dataset.window.horizon
    (note,) = model_notes(tiny_run.out, trained + 1)  # beyond what it learned to predict
    assert f"predictions past step {trained} are extrapolation" in note
    assert model_notes(tiny_run.out, trained) == []


def test_the_command_line_says_what_to_know_before_a_network_flies(run_cli, tiny_run, tmp_path):
    from slungload.control.mpc import ModelNote
    from slungload.lab.control.comparison import compare
    from slungload.lab.control.config import ComparisonConfig

    fast = ("--maneuvers", "roll_35", "--seeds", "100", "--samples", "4", "--steps", "3",
            "--quiet")  # fmt: skip
    with pytest.warns(ModelNote, match="past step 4 are extrapolation"):  # N = 15 > 4
        code, _, err = run_cli("control", "--model", tiny_run.out, *fast, "--out", tmp_path / "a")
    assert code == 0, err
    # "physics" given as a model flies beside itself, and its report is written
    config = ComparisonConfig(maneuvers=("roll_35",), seeds=(100,), samples=(4,), steps=3)
    done = compare(["physics"], tmp_path / "b", config, progress=None)
    assert done.settings["presets"] == {} and (tmp_path / "b" / "report.md").exists()
