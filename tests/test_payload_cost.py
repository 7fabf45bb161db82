"""The payload-first cost's reference (control/cost.py, read by control/mppi.py): the cable
along the load's specific force, the lean, the shape of a setpoint's steps, and the
controller reading them; the jumps of a flight found once per reference."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from test_mppi import HOVER_T, LIMITS, PARAMS, SMALL, HoldModel, hold, hover_state

from slungload.control import mppi
from slungload.control.cost import Shape, jumps, reference_rows
from slungload.control.mppi import (
    MPCConfig,
    MPPIController,
    ReferenceAhead,
    payload_first,
    reference_ahead,
    trajectory_cost,
)


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


def test_the_controller_finds_a_flights_jumps_once_and_again_for_a_new_reference(monkeypatch):
    """``MPPIController.ahead`` with the shape: the jumps (which read every row of the flight)
    are found at the first step of a reference and kept while it is flown, every row exactly
    what ``reference_ahead`` finds afresh; another reference, or the same one with a new
    position array, is read anew."""
    calls = []

    def counted(position, velocity, dt):
        calls.append(len(position))
        return jumps(position, velocity, dt)

    monkeypatch.setattr(mppi, "jumps", counted)
    mpc = MPPIController(HoldModel(), LIMITS, replace(SMALL, cost="payload", shape=1.0), PARAMS)
    shape = Shape(1.0, PARAMS.cable_length, PARAMS.gravity, PARAMS.dt)
    ref = step_reference()
    for k in range(0, 200, 7):
        got, want = mpc.ahead(ref, k), reference_ahead(ref, k, SMALL.horizon, shape=shape)
        for a, b in zip(got, want, strict=True):
            np.testing.assert_array_equal(a, b)
    assert calls == [200]
    other = step_reference(at=60, size=-2.0)
    want = reference_ahead(other, 58, SMALL.horizon, shape=shape)
    np.testing.assert_array_equal(mpc.ahead(other, 58).position, want.position)
    assert calls == [200, 200]
    other.position = other.position + [0.5, 0.0, 0.0]
    mpc.ahead(other, 58)
    assert calls == [200, 200, 200]
    unshaped = MPPIController(HoldModel(), LIMITS, replace(SMALL, cost="payload"), PARAMS)
    unshaped.ahead(ref, 5)
    assert len(calls) == 3
