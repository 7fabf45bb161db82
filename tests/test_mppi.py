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
from slungload.control.cost import Shape, jumps, reference_rows
from slungload.control.mppi import (
    Command,
    InputLimits,
    MPCConfig,
    MPPIController,
    ReferenceAhead,
    mppi_weights,
    payload_first,
    reference_ahead,
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


def accelerating(a, n: int = 6) -> ReferenceAhead:
    """A reference at (0, 0, 1.5) accelerating at a constant ``a`` (3,) m/s^2."""
    ref = hold([0.0, 0.0, 1.5], n)
    return ref._replace(acceleration=np.tile(np.asarray(a, float), (n, 1)))


def test_payload_first_hangs_the_cable_along_the_loads_specific_force():
    """At rest the vehicle target is the reference and the cable vertical; accelerating at a
    the cable leans back by atan(a / g) and the vehicle leads the load by l sin of it."""
    l, g = PARAMS.cable_length, PARAMS.gravity
    rest = payload_first(accelerating([0, 0, 0]), l, g)
    np.testing.assert_allclose(rest.position, np.tile([0, 0, 1.5], (6, 1)), atol=1e-12)
    np.testing.assert_allclose(rest.offset, 0.0, atol=1e-12)
    np.testing.assert_allclose(rest.velocity, 0.0, atol=1e-12)
    a = 3.0
    lean = math.atan2(a, g)
    turn = payload_first(accelerating([a, 0, 0]), l, g)
    load = np.array([0.0, 0.0, 1.5 - l])  # the load's path: the reference l below
    np.testing.assert_allclose(turn.position - load, np.tile(l * np.array([math.sin(lean), 0,
                               math.cos(lean)]), (6, 1)), atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(turn.offset, np.tile([-l * math.sin(lean), 0.0], (6, 1)))
    np.testing.assert_allclose(turn.velocity, 0.0, atol=1e-12)  # the load's
    with pytest.raises(ValueError, match="needs the reference's acceleration"):
        payload_first(hold([0, 0, 1.5], 6), l, g)


def test_the_payload_cost_charges_nothing_for_the_lean_a_turn_needs():
    """A vehicle where the load's path puts it, its load on that path: no state cost under
    the payload cost, a swing and position cost under the vehicle cost."""
    ref = accelerating([3.0, 0.0, 0.0])
    l = PARAMS.cable_length
    target = payload_first(ref, l, PARAMS.gravity)
    states = np.zeros((1, 6, 13))
    states[..., 0:3], states[..., 6] = target.position, 1.0
    states[..., 10:13] = ref.position - [0.0, 0.0, l]
    plans = np.tile([HOVER_T, 0.0, 0.0, 0.0], (1, 6, 1))
    u_prev = plans[0, 0]
    payload = replace(SMALL, cost="payload")
    no_inputs = {"w_thrust": 0.0, "w_rates": 0.0, "w_thrust_rate": 0.0, "w_rates_rate": 0.0}
    zero = trajectory_cost(states, plans, ref, u_prev, replace(payload, **no_inputs), l, HOVER_T,
                           target)  # fmt: skip
    assert zero[0] == pytest.approx(0.0, abs=1e-18)
    vehicle = trajectory_cost(states, plans, ref, u_prev, replace(SMALL, **no_inputs), l, HOVER_T)
    assert vehicle[0] > 1.0


def test_the_payload_cost_needs_the_references_acceleration_and_flies_with_it():
    mpc = MPPIController(HoldModel(), LIMITS, replace(SMALL, cost="payload"), PARAMS)
    with pytest.raises(ValueError, match="payload-first cost .* needs the acceleration"):
        mpc.step(hover_state(), hold([0, 0, 1.5], 6))
    command = mpc.step(hover_state(), accelerating([1.0, 0.0, 0.0]))
    assert LIMITS.contains([command.thrust, *command.rates]) and mpc.stats.fallback_steps == 0
    with pytest.raises(ValueError, match="unknown 'payload-first'"):
        MPCConfig(cost="payload-first")


def doublet_reference(t: int = 200, start: int = 60, width: int = 8, a: float = 4.6):
    """A whole flight's reference (``sim.maneuvers.Reference``'s fields): hover, then +a for
    ``width`` rows, -a for 2 ``width``, +a for ``width`` along x (a roll doublet), then hover."""
    acc = np.zeros((t, 3))
    acc[start : start + width, 0] = a
    acc[start + width : start + 3 * width, 0] = -a
    acc[start + 3 * width : start + 4 * width, 0] = a
    zero = np.zeros((t, 3))
    return type("Reference", (), dict(position=zero + [0, 0, 1.5], velocity=zero,
                                      acceleration=acc, yaw=np.zeros(t)))  # fmt: skip


def test_the_lean_averages_the_flights_acceleration_with_no_lag_and_no_window_edge():
    """lean 0: the rows as they are. lean > 0: a constant acceleration is unchanged; a doublet
    (net zero, faster than the average) shrinks, symmetric about its middle as it was (no lag);
    each row's value is the flight's, whatever step k and horizon n the window starts at."""
    ref = doublet_reference()
    np.testing.assert_array_equal(reference_ahead(ref, 50, 40).acceleration,
                                  ref.acceleration[51:91])  # fmt: skip
    steady = type("R", (), dict(vars(ref), acceleration=np.tile([1.0, -2.0, 0.5], (200, 1))))
    np.testing.assert_allclose(reference_ahead(steady, 3, 25, lean=9.0).acceleration,
                               np.tile([1.0, -2.0, 0.5], (25, 1)), rtol=1e-12)  # fmt: skip
    leaned = reference_ahead(ref, 40, 60, lean=9.0).acceleration[:, 0]  # rows 41..100
    raw = ref.acceleration[41:101, 0]
    assert np.abs(leaned).max() < 0.5 * np.abs(raw).max()
    # the doublet (rows 60-91) is even about row 75.5: so is its average, with no lag
    rows = np.arange(52, 76)
    np.testing.assert_allclose(leaned[rows - 41], leaned[151 - rows - 41], rtol=1e-9)
    for k, n in ((40, 60), (55, 10), (70, 3)):
        window = reference_ahead(ref, k, n, lean=9.0).acceleration[:, 0]
        np.testing.assert_allclose(window, leaned[k - 40 : k - 40 + n], rtol=1e-12)
    with pytest.raises(ValueError, match="lean must be a finite number >= 0"):
        MPCConfig(lean=-1.0)


def test_the_controller_leans_only_the_payload_costs_acceleration():
    """``MPPIController.ahead``: the payload cost reads the flight's acceleration averaged over
    lean x sqrt(l / g) (in rows of dt), the vehicle cost (which never reads it) the raw rows
    and refuses a lean."""
    ref = doublet_reference()
    rows = math.sqrt(PARAMS.cable_length / PARAMS.gravity) / PARAMS.dt
    for cost, lean, expect in (("payload", 1.0, rows), ("payload", 0.0, 0.0),
                               ("vehicle", 0.0, 0.0)):  # fmt: skip
        mpc = MPPIController(HoldModel(), LIMITS, replace(SMALL, cost=cost, lean=lean), PARAMS)
        got = mpc.ahead(ref, 58)
        want = reference_ahead(ref, 58, SMALL.horizon, lean=expect)
        np.testing.assert_array_equal(got.acceleration, want.acceleration)
        assert (np.abs(got.acceleration - ref.acceleration[59:65]).max() > 0.1) == (expect > 0)
    with pytest.raises(ValueError, match="lean is the payload cost's"):
        replace(SMALL, lean=1.0)


def step_reference(t: int = 200, at: int = 100, size: float = 1.0):
    """A whole flight's setpoint (``sim.maneuvers.Reference``'s fields): hover, then a step of
    ``size`` m along x at row ``at``, no velocity or acceleration (as ``xy_step``)."""
    pos = np.tile([0.0, 0.0, 1.5], (t, 1))
    pos[at:, 0] += size
    zero = np.zeros((t, 3))
    return type("Reference", (), dict(position=pos, velocity=zero, acceleration=zero,
                                      yaw=np.zeros(t)))  # fmt: skip


def test_the_shape_spreads_a_setpoints_step_into_a_path_and_leaves_a_path_alone():
    """shape > 0: a step becomes a path with no lag (half way at the step, odd about it),
    rising monotonically, its velocity the path's and integrating to the step, its
    acceleration forward then back, peaking at g / (2 shape^2) for a jump longer than the
    cable and at |jump| g / (2 l shape^2) for a shorter one; far from the step and at shape 0
    the rows as they are; each row the flight's whatever the window; a path whose velocity
    accounts for its position is left exactly as it is."""
    dt, g, cable = 0.03, 9.81, 0.7
    shape = Shape(1.0, cable, g, dt)
    ref = step_reference()
    np.testing.assert_array_equal(reference_ahead(ref, 0, 199).position, ref.position[1:])
    whole = reference_rows(ref, np.arange(200), shape=shape)
    x, v, a = whole.position[:, 0], whole.velocity[:, 0], whole.acceleration[:, 0]
    assert 0.0 < x[90] < 0.5 < x[110] < 1.0 and np.all(np.diff(x) > 0)
    np.testing.assert_allclose(x[70:100] + x[129:99:-1], 1.0, rtol=1e-12)  # odd about 99.5
    np.testing.assert_allclose(whole.position[:20], ref.position[:20], atol=1e-3)
    np.testing.assert_allclose(v, np.gradient(x, dt), atol=0.02 * v.max())
    assert v.min() > 0.0 and abs(v.sum() * dt - 1.0) < 1e-3
    assert a[85:100].min() > 0.0 and a[100:115].max() < 0.0
    for k, n in ((40, 60), (95, 10), (150, 49)):
        got = reference_ahead(ref, k, n, shape=shape)
        np.testing.assert_array_equal(got.position, whole.position[k + 1 : k + n + 1])
    for size, peak in ((3.0, g / 2), (0.2, 0.2 * g / (2 * cable))):
        stepped = reference_rows(step_reference(size=size), np.arange(200), shape=shape)
        assert np.abs(stepped.acceleration).max() == pytest.approx(peak, rel=0.1)
    t = np.arange(200) * dt
    circle = np.stack([np.cos(t), np.sin(t), 1.5 + 0 * t], -1)
    turning = np.stack([-np.sin(t), np.cos(t), 0 * t], -1)
    path = type("R", (), dict(position=circle, velocity=turning,
                              acceleration=-circle * [1, 1, 0], yaw=np.zeros(200)))  # fmt: skip
    same = reference_rows(path, np.arange(200), shape=shape)
    for got, want in zip(same[:2], (path.position, path.velocity), strict=True):
        np.testing.assert_array_equal(got, want)
    assert jumps(path.position, path.velocity, dt)[0].size == 0
    with pytest.raises(ValueError, match="shape must be a finite number >= 0"):
        MPCConfig(cost="payload", shape=-1.0)


def test_the_controller_shapes_only_the_payload_costs_reference():
    """``MPPIController.ahead``: the payload cost reads the step shaped with its cable length
    and the rows' spacing dt; shape 0 and the vehicle cost the rows as they are; the vehicle
    cost refuses a shape."""
    ref = step_reference()
    for cost, shape, expect in (("payload", 1.0, 1.0), ("payload", 0.0, 0.0),
                                ("vehicle", 0.0, 0.0)):  # fmt: skip
        mpc = MPPIController(HoldModel(), LIMITS, replace(SMALL, cost=cost, shape=shape), PARAMS)
        got = mpc.ahead(ref, 96)
        swing = (PARAMS.cable_length, PARAMS.gravity, PARAMS.dt)
        want = reference_ahead(ref, 96, SMALL.horizon, shape=Shape(expect, *swing))
        np.testing.assert_array_equal(got.position, want.position)
        assert (np.abs(got.position - ref.position[97:103]).max() > 0.1) == (expect > 0)
    with pytest.raises(ValueError, match="shape is the payload cost's"):
        replace(SMALL, shape=1.0)


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
