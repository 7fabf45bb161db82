"""The MPPI core in numpy (control/mppi.py): torch-free, the sampler inside the limits, the
weights, the reference and state checks, the user-facing step on a numpy model."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest

from slungload.config import VehicleParams
from slungload.control.mppi import (
    Command,
    InputLimits,
    MPCConfig,
    MPPIController,
    ReferenceAhead,
    mppi_weights,
    trajectory_cost,
)
from slungload.frames import rotation_matrix, swing_angle

PARAMS = VehicleParams()
HOVER_T = (PARAMS.mass_quad + PARAMS.mass_load) * PARAMS.gravity
LIMITS = InputLimits(0.3 * HOVER_T, 30.0, 4.0)
SMALL = MPCConfig(samples=16, horizon=6, knots=3)


class HoldModel:
    """Predicts that nothing moves (a numpy ``CandidateModel``)."""

    name, history = "hold", 3

    def predict_candidates(self, x_hist, u_past, plans):
        assert x_hist.shape == (3, 13) and u_past.shape == (2, 4)
        return np.broadcast_to(x_hist[-1], (*plans.shape[:2], 13)).copy()


def hover_state(p=(0.0, 0.0, 1.5)) -> np.ndarray:
    p = np.asarray(p, dtype=float)
    return np.concatenate([p, np.zeros(3), [1.0, 0, 0, 0], p - [0, 0, PARAMS.cable_length]])


def hold(point, n: int) -> ReferenceAhead:
    return ReferenceAhead(np.tile(point, (n, 1)), np.zeros((n, 3)), np.zeros(n))


def test_the_onboard_modules_do_not_import_torch():
    code = (
        "import sys\n"
        "import slungload.control.mppi, slungload.frames, slungload.deploy.onboard\n"
        "import slungload.online_interval\n"
        "bad = sorted(m for m in ('torch', 'lightning', 'mujoco', 'onnx') if m in sys.modules)\n"
        "assert not bad, bad\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]


def test_samples_are_inside_the_limits_and_sample_zero_is_the_plan():
    mpc = MPPIController(HoldModel(), LIMITS, MPCConfig(samples=64, thrust_std=20.0), PARAMS)
    samples = mpc.sample()
    assert samples.shape == (64, 15, 4) and samples.dtype == np.float64
    np.testing.assert_array_equal(samples[0], mpc.plan)
    assert LIMITS.contains(samples) and (samples[:, :, 0] == LIMITS.thrust_max).any()


def test_weights_drop_non_finite_costs_and_sum_to_one():
    w = mppi_weights(np.array([1.0, 2.0, math.nan, math.inf, 1.0]), 0.3)
    assert w.sum() == pytest.approx(1.0) and w[2] == 0.0 and w[3] == 0.0
    assert w[0] == w[4] > w[1] > 0
    assert mppi_weights(np.array([math.nan, math.inf]), 0.3) is None


def swung(angle: float, n: int = 4) -> np.ndarray:
    """States (1, n, 13): hovering with the load swung ``angle`` rad in x, cable length kept."""
    x = hover_state()
    x[10:13] = x[:3] + PARAMS.cable_length * np.array([math.sin(angle), 0.0, -math.cos(angle)])
    return np.tile(x, (1, n, 1))


def test_swing_angle_is_the_cable_angle_from_straight_down():
    for angle in (0.0, 0.3, 1.2, 2.0):
        assert swing_angle(swung(angle))[0, 0] == pytest.approx(angle)


def test_the_swing_bound_costs_only_beyond_its_angle_and_grows_with_it():
    n, ref = 4, hold(hover_state()[:3], 4)
    plans, u_prev = np.tile([HOVER_T, 0, 0, 0], (1, n, 1)), np.array([HOVER_T, 0, 0, 0])
    bounded = MPCConfig(max_swing=0.5, w_swing_bound=100.0, terminal=0.0)

    def extra(angle: float) -> float:
        cost = [
            trajectory_cost(swung(angle), plans, ref, u_prev, c, PARAMS.cable_length, HOVER_T)[0]
            for c in (bounded, replace(bounded, max_swing=math.inf))
        ]
        return cost[0] - cost[1]  # fmt: skip

    assert extra(0.2) == 0.0 and extra(0.5) == 0.0
    assert extra(0.9) == pytest.approx(n * 100.0 * 0.4**2)  # w (angle - bound)^2 per step
    assert extra(1.4) > extra(0.9)


def test_the_huber_position_cost_is_quadratic_near_and_linear_far():
    n = 3
    plans, u_prev = np.tile([HOVER_T, 0, 0, 0], (1, n, 1)), np.array([HOVER_T, 0, 0, 0])
    only_position = MPCConfig(w_velocity=0.0, w_load=0.0, w_swing=0.0, w_yaw=0.0, w_tilt=0.0,
                              terminal=0.0, position_huber=0.5)  # fmt: skip
    x = np.tile(hover_state(), (1, n, 1))

    def cost(d: float, cfg: MPCConfig) -> float:
        ref = hold(hover_state()[:3] + [d, 0.0, 0.0], n)
        return trajectory_cost(x, plans, ref, u_prev, cfg, PARAMS.cable_length, HOVER_T)[0]

    quadratic = replace(only_position, position_huber=math.inf)
    assert cost(0.4, only_position) == pytest.approx(cost(0.4, quadratic))
    w = only_position.w_position * n
    assert cost(2.0, only_position) == pytest.approx(w * 0.5 * (2 * 2.0 - 0.5))
    assert cost(3.0, only_position) - cost(2.0, only_position) == pytest.approx(w * 2 * 0.5)
    assert cost(3.0, quadratic) - cost(2.0, quadratic) == pytest.approx(w * 5.0)


def test_the_floor_costs_only_below_its_height():
    n = 3
    plans, u_prev = np.tile([HOVER_T, 0, 0, 0], (1, n, 1)), np.array([HOVER_T, 0, 0, 0])
    floored = MPCConfig(min_height=1.0, w_floor=500.0, terminal=0.0)

    def extra(z: float) -> float:
        # hovering at height z with the reference there too: only the floor costs
        x, ref = np.tile(hover_state((0.0, 0.0, z)), (1, n, 1)), hold((0.0, 0.0, z), n)
        cost = [trajectory_cost(x, plans, ref, u_prev, c, PARAMS.cable_length, HOVER_T)[0]
                for c in (floored, replace(floored, min_height=-math.inf))]  # fmt: skip
        return cost[0] - cost[1]

    assert extra(1.5) == 0.0 and extra(1.0) == 0.0
    assert extra(0.8) == pytest.approx(n * 500.0 * 0.2**2)  # w (floor - z)^2 per step
    assert extra(0.6) > extra(0.8)


def test_step_returns_a_command_inside_the_limits_and_keeps_the_history():
    mpc = MPPIController(HoldModel(), LIMITS, SMALL, PARAMS)
    x = hover_state()
    for _ in range(4):
        command = mpc.step(x, hold(x[:3] + [0.0, 0.0, 0.5], 10))  # a longer reference is cut
        assert isinstance(command, Command) and LIMITS.contains([command.thrust, *command.rates])
    assert len(mpc.history.states) == 3 and mpc.stats.steps == 4
    assert mpc.stats.fallback_steps == 0


def test_bad_states_and_references_are_refused():
    mpc = MPPIController(HoldModel(), LIMITS, SMALL, PARAMS)
    with pytest.raises(ValueError, match="need position"):
        mpc.step(hover_state(), hold([0, 0, 1], 5))
    with pytest.raises(ValueError, match="state must be"):
        mpc.step(np.zeros(12), hold([0, 0, 1], 6))


def test_the_same_seed_gives_the_same_commands():
    runs = []
    for _ in range(2):
        mpc = MPPIController(HoldModel(), LIMITS, SMALL, PARAMS)
        runs.append([mpc.step(hover_state(), hold([0.1, 0, 1.5], 6)).thrust for _ in range(3)])
    assert runs[0] == runs[1]


class NaNModel(HoldModel):
    """Predicts NaN for every sample: every step falls back."""

    def predict_candidates(self, x_hist, u_past, plans):
        return np.full((*plans.shape[:2], 13), np.nan)


def test_a_nan_estimate_of_the_constants_never_reaches_the_hover_command():
    # A NaN in the measured history makes the in-flight estimate NaN; the hover fallback's
    # thrust comes from the constants, so they must stay the last good ones.
    cfg = replace(SMALL, constants="window", max_fallback_steps=1)
    answers = iter([(0.9, 0.2), (math.nan, math.nan), (math.nan, 0.1), (-1.0, 0.1)])
    mpc = MPPIController(NaNModel(), LIMITS, cfg, PARAMS, estimate=lambda x, u: next(answers))
    thrusts = [mpc.step(hover_state(), hold([0, 0, 1.5], 6)).thrust for _ in range(4)]
    assert mpc.stats.hover_steps == 3 and mpc.stats.estimate_rejected == 3
    expected = (PARAMS.mass_quad + 0.2) * PARAMS.gravity  # the last good estimate's hover
    assert all(math.isfinite(t) for t in thrusts)
    assert thrusts[1:] == pytest.approx([expected] * 3)
    assert mpc.cable_length == 0.9


def test_the_hover_command_levels_a_tilted_vehicle_at_the_rate_of_its_angle():
    mpc = MPPIController(HoldModel(), LIMITS, SMALL, PARAMS)
    roll = math.radians(25.0)  # rolled right about body x, yaw 0: level it by rolling back
    q = np.array([math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0])
    plan = mpc.hover_command(rotation_matrix(q), 0.0)
    np.testing.assert_allclose(plan[0, 1:], [-SMALL.hover_gain * roll, 0.0, 0.0], atol=1e-12)
    assert plan[0, 0] == pytest.approx(HOVER_T) and (plan[1:] == mpc.hover).all()
    yawed = mpc.hover_command(np.eye(3), 0.2)  # level, turned to a reference yaw of 0.2 rad
    np.testing.assert_allclose(yawed[0, 1:], [0.0, 0.0, SMALL.hover_gain * 0.2], atol=1e-12)


def test_a_reference_with_nan_is_refused():
    mpc = MPPIController(HoldModel(), LIMITS, SMALL, PARAMS)
    ref = hold([0.0, 0.0, 1.5], 6)
    ref.yaw[2] = math.nan
    with pytest.raises(ValueError, match="NaN"):
        mpc.step(hover_state(), ref)


# --- the payload-first cost ------------------------------------------------------------------


class ClimbEnsemble:
    """Members that agree on hover and disagree on how far extra thrust lifts the vehicle
    (gains ``gains``, m/N per step): the more a plan leaves hover, the more they disagree."""

    name, history = "climb", 3

    def __init__(self, gains=(0.002, 0.01)) -> None:
        self.gains = gains

    def predict_candidates_members(self, x_hist, u_past, plans):
        out = np.broadcast_to(x_hist[-1], (len(self.gains), *plans.shape[:2], 13)).copy()
        lift = np.cumsum(plans[..., 0] - HOVER_T, axis=1)  # (K, N), N per step
        for e, gain in enumerate(self.gains):
            out[e, ..., 2] += gain * lift
            out[e, ..., 12] += gain * lift
        return out

    def predict_candidates(self, x_hist, u_past, plans):
        return self.predict_candidates_members(x_hist, u_past, plans).mean(0)


def test_risk_prices_each_members_prediction_and_is_refused_without_members():
    with pytest.raises(ValueError, match="needs an ensemble .* 'hold' is one network"):
        MPPIController(HoldModel(), LIMITS, replace(SMALL, risk=0.0), PARAMS)
    with pytest.raises(ValueError, match="risk must be None or a finite number >= 0"):
        replace(SMALL, risk=-1.0)
    x, up = hover_state(), hold(hover_state()[:3] + [0.0, 0.0, 0.4], 6)
    cfg = replace(SMALL, samples=64)
    # identical members at risk 0: the cost of the mean, the same samples: the same plan
    same = MPPIController(ClimbEnsemble((0.005, 0.005)), LIMITS, replace(cfg, risk=0.0), PARAMS)
    single = MPPIController(ClimbEnsemble((0.005,)), LIMITS, cfg, PARAMS)
    for _ in range(3):
        same.step(x, up), single.step(x, up)
        np.testing.assert_allclose(same.plan, single.plan, rtol=0, atol=1e-12)
    # disagreeing members: the more the pricing fears their spread, the less it leaves hover
    thrust = {}
    for risk in (None, 0.0, 5.0):
        mpc = MPPIController(ClimbEnsemble(), LIMITS, replace(cfg, risk=risk), PARAMS)
        thrust[risk] = np.mean([mpc.step(x, up).thrust for _ in range(4)]) - HOVER_T
    assert thrust[None] > thrust[0.0] > thrust[5.0] > 0


class FlaggedEnsemble(ClimbEnsemble):
    """Members whose every plan the calibration would flag."""

    def novel(self, members):
        assert members.shape[:2] == (2, 1)  # the members' prediction of the nominal plan
        return np.ones(1, bool)


def test_a_risk_priced_mpc_counts_the_nominal_plans_its_ensemble_flags():
    x, up = hover_state(), hold(hover_state()[:3], 6)
    flagged = MPPIController(FlaggedEnsemble(), LIMITS, replace(SMALL, risk=1.0), PARAMS)
    plain = MPPIController(FlaggedEnsemble(), LIMITS, SMALL, PARAMS)  # the mean: not asked
    for _ in range(3):
        flagged.step(x, up), plain.step(x, up)
    assert (flagged.stats.novel_steps, plain.stats.novel_steps) == (3, 0)


class Marked(HoldModel):
    """A member whose every prediction carries its mark in the load's z, counting its calls."""

    def __init__(self, mark: float) -> None:
        self.mark, self.calls, self.prepared = mark, [], None

    def predict_candidates(self, x_hist, u_past, plans):
        self.calls.append(len(plans))
        out = super().predict_candidates(x_hist, u_past, plans)
        out[..., 12] = self.mark
        return out

    def prepare(self, m, k, n):
        self.prepared = (m, k, n)


class MarkedEnsemble(ClimbEnsemble):
    """Three ``Marked`` members behind an ensemble's calls."""

    def __init__(self) -> None:
        super().__init__((0.0, 0.0, 0.0))
        self.members = tuple(Marked(float(i)) for i in range(3))


def test_split_members_predict_every_eth_candidate_each_at_one_networks_compute():
    from slungload.control.split import SplitMembers

    ens = MarkedEnsemble()
    split = SplitMembers(ens, 8)
    x = np.tile(hover_state(), (3, 1))
    plans = np.tile(HOVER_T, (8, 6, 4))
    out = split.predict_candidates(x, np.zeros((2, 4)), plans)
    np.testing.assert_array_equal(out[:, 0, 12], [0, 1, 2, 0, 1, 2, 0, 1])
    assert [m.calls for m in ens.members] == [[3], [3], [2]]  # 8 candidates, not 3 x 8
    split.prepare(3, 8, 6)
    assert [m.prepared for m in ens.members] == [(3, 3, 6), (3, 3, 6), (3, 2, 6)]
    # the controller shares its K candidates out and scores each by its own member's cost
    mpc = MPPIController(MarkedEnsemble(), LIMITS, replace(SMALL, members="split"), PARAMS)
    assert np.isfinite(mpc.step(hover_state(), hold(hover_state()[:3], 6)).thrust)
    assert [m.calls[-1] for m in mpc.model.members] == [6, 5, 5]
    assert mpc.stats.fallback_steps == 0


def test_split_members_are_refused_where_they_cannot_be():
    from slungload.control.split import SplitMembers

    with pytest.raises(ValueError, match="'hold' has no members to call one by one"):
        MPPIController(HoldModel(), LIMITS, replace(SMALL, members="split"), PARAMS)
    with pytest.raises(ValueError, match="'climb' has no members to call one by one"):
        SplitMembers(ClimbEnsemble(), 16)  # members only together (a pair, an ONNX graph)
    with pytest.raises(ValueError, match="K = 2 candidates for 3 members"):
        SplitMembers(MarkedEnsemble(), 2)
    with pytest.raises(ValueError, match="'split' gives each candidate one member's cost"):
        replace(SMALL, members="split", risk=0.5)
    with pytest.raises(ValueError, match="MPCConfig.members: unknown 'some'"):
        replace(SMALL, members="some")
