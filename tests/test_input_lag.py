"""The commands' lag in front of the physics model: the filter's known solution, its warm-up,
the MPC's wrapper (parity with the physics model fed the lagged plans), the pair, the fit that
recovers a known lag, and the command line."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from flights import Flight, file_arrays, physics_flight, roll_out_flight

from slungload.config import VehicleParams, to_dict
from slungload.control.lagged import LaggedPhysics, with_input_lag
from slungload.control.limits import InputLimits
from slungload.control.mpc import candidate_model
from slungload.control.mppi import MPCConfig, MPPIController
from slungload.control.paired import PhysicsPaired
from slungload.fileio import write_json, write_npz, write_splits
from slungload.input_lag import NO_LAG, check_lag, lagged, smoothing, warm_rows
from slungload.lab.control.config import StudyConfig, recorded_settings, settings_record
from slungload.models.prediction import PhysicsModel
from slungload.sim.config import SimConfig
from slungload.training.identify import fit_input_lag

DT = 0.03


def test_step_response_is_the_first_order_solution():
    tau = (0.05, 0.1, 0.2)
    u_before = np.zeros((1, 4))
    inputs = np.ones((20, 4))
    out = lagged(u_before, inputs, tau, DT)
    k = np.arange(1, 21)[:, None]
    taus = np.array([0.05, 0.1, 0.1, 0.2])
    np.testing.assert_allclose(out, 1.0 - np.exp(-k * DT / taus), rtol=1e-12)


def test_no_lag_passes_the_inputs_and_a_zero_channel_passes_its_own():
    rng = np.random.default_rng(0)
    u_before, inputs = rng.normal(size=(3, 4)), rng.normal(size=(5, 7, 4))
    np.testing.assert_array_equal(lagged(u_before, inputs, NO_LAG, DT), inputs)
    out = lagged(u_before, inputs, (0.0, 0.1, 0.1, 0.0)[:1] + (0.1, 0.0), DT)
    np.testing.assert_allclose(out[..., 0], inputs[..., 0], atol=1e-12)  # thrust: no lag
    np.testing.assert_allclose(out[..., 3], inputs[..., 3], atol=1e-12)  # yaw rate: no lag
    assert not np.allclose(out[..., 1:3], inputs[..., 1:3])


def test_settled_history_holds_a_constant_plan_and_warms_the_filter():
    u = np.array([12.0, 0.3, -0.2, 0.1])
    plans = np.tile(u, (4, 6, 1))
    np.testing.assert_allclose(lagged(np.tile(u, (5, 1)), plans, (0.1, 0.1, 0.2), DT), plans)
    # the filter runs over the history: a command held for many time constants has arrived
    history = np.vstack([np.zeros((1, 4)), np.tile(u, (60, 1))])
    np.testing.assert_allclose(lagged(history, plans, (0.1, 0.1, 0.2), DT), plans, atol=1e-3)
    assert warm_rows((0.1, 0.1, 0.2), DT) == math.ceil(4 * 0.2 / DT)
    assert warm_rows(NO_LAG, DT) == 0
    assert smoothing((0.1, 0.0, 0.0), DT)[0] == pytest.approx(1 - math.exp(-0.3))


@pytest.mark.parametrize("bad", [(-0.1, 0.0, 0.0), (0.1, 0.1), (math.nan, 0, 0), (math.inf, 0, 0)])
def test_bad_lags_are_refused(bad):
    with pytest.raises(ValueError, match="input lag"):
        check_lag(bad)
    with pytest.raises(ValueError, match="input lag"):
        MPCConfig(input_lag=bad)
    with pytest.raises(ValueError, match="input lag"):
        StudyConfig(input_lag=bad)


def _history(m: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A hovering history of m states and m - 1 commands (varied, so the filter has work)."""
    params = VehicleParams()
    rng = np.random.default_rng(seed)
    x = np.zeros((m, 13))
    x[:, 2] = 1.5
    x[:, 6] = 1.0
    x[:, 12] = 1.5 - params.cable_length
    u = np.zeros((m - 1, 4))
    u[:, 0] = (params.mass_quad + params.mass_load) * params.gravity
    u[:, 1:] = rng.normal(scale=0.5, size=(m - 1, 3))
    return x, u


def test_lagged_physics_is_physics_fed_the_lagged_plans():
    physics = candidate_model(PhysicsModel(VehicleParams()))
    lag = (0.04, 0.1, 0.2)
    model = LaggedPhysics(physics, lag, DT)
    assert model.history == physics.history + warm_rows(lag, DT)
    x_hist, u_past = _history(model.history)
    plans = np.random.default_rng(1).normal(scale=0.5, size=(8, 15, 4))
    plans[..., 0] += u_past[-1, 0]
    got = model.predict_candidates(x_hist, u_past, plans)
    fed = lagged(u_past, plans, lag, DT)
    want = physics.predict_candidates(x_hist[-2:], u_past[-1:], fed)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    unlagged = physics.predict_candidates(x_hist[-2:], u_past[-1:], plans)
    assert np.abs(got - unlagged).max() > 1e-3  # the lag changes the prediction


class _Network:
    """A stand-in for a network's candidate model (anything not named physics)."""

    numpy, name, history = True, "learned", 3

    def predict_candidates(self, x_hist, u_past, plans):
        return np.zeros((*plans.shape[:2], 13))


def test_only_the_physics_model_is_fed_through_the_lag():
    physics = candidate_model(PhysicsModel(VehicleParams()))
    lag = (0.04, 0.1, 0.2)
    assert with_input_lag(physics, NO_LAG, DT) is physics
    assert isinstance(with_input_lag(physics, lag, DT), LaggedPhysics)
    network = _Network()
    assert with_input_lag(network, lag, DT) is network  # it learned its vehicle's lag
    pair = PhysicsPaired(network, physics, window=5)
    lagged_pair = with_input_lag(pair, lag, DT)
    assert isinstance(lagged_pair, PhysicsPaired) and lagged_pair is not pair
    assert lagged_pair.network is network and isinstance(lagged_pair.physics, LaggedPhysics)
    assert lagged_pair.window == 5 and pair.physics is physics  # the given pair is untouched


def test_the_mpc_keeps_the_history_the_lag_needs_and_flies():
    params = VehicleParams()
    limits = InputLimits.from_sim(SimConfig())
    model = PhysicsModel(params)
    config = MPCConfig(samples=16, horizon=10, knots=4, input_lag=(0.04, 0.1, 0.2))
    mpc = MPPIController(candidate_model(model), limits, config, params)
    assert mpc.history.m == model.history + warm_rows(config.input_lag, params.dt)
    x, _ = _history(2)
    from slungload.control.mppi import ReferenceAhead

    ref = ReferenceAhead(np.tile([0.0, 0.0, 1.5], (10, 1)), np.zeros((10, 3)), np.zeros(10))
    for _ in range(3):
        command = mpc.step(x[-1], ref)
    assert math.isfinite(command.thrust) and mpc.stats.fallback_steps == 0


def test_study_settings_record_the_lag_and_old_files_had_none():
    record = settings_record(StudyConfig(input_lag=(0.1, 0.1, 0.2)))
    assert record["input_lag"] == [0.1, 0.1, 0.2]
    old = {k: v for k, v in settings_record(StudyConfig()).items() if k != "input_lag"}
    assert recorded_settings(old)["input_lag"] == [0.0, 0.0, 0.0]


def _lagged_flight(name: str, seed: int, steps: int, lag) -> Flight:
    """``physics_flight``'s commands, the flight flown on what a vehicle with ``lag`` receives
    of them (the file records the commands)."""
    commanded = physics_flight(name, seed, steps)
    received = lagged(commanded.inputs[:1], commanded.inputs, lag, DT)
    states, aux = roll_out_flight(
        torch.from_numpy(commanded.states[0]),
        torch.zeros(6, dtype=torch.float64),
        torch.from_numpy(received),
        VehicleParams(),
    )
    return Flight(name, states, commanded.inputs, aux)


@pytest.fixture(scope="module")
def lagged_data(tmp_path_factory):
    folder = tmp_path_factory.mktemp("lagged")
    names = [f"f{i}" for i in range(5)]
    for i, name in enumerate(names):
        write_npz(
            folder / f"{name}.npz", file_arrays(_lagged_flight(name, i, 90, (0.04, 0.1, 0.2)))
        )
    write_splits(folder, {"train": names[:3], "val": names[3:4], "test": names[4:]})
    write_json(folder / "vehicle.json", to_dict(VehicleParams()))
    return folder


def test_fit_recovers_a_known_lag(lagged_data):
    grid = (0.0, 0.02, 0.04, 0.1, 0.2)
    fit = fit_input_lag(lagged_data, horizon=8, grid=grid)
    assert fit.lag == (0.04, 0.1, 0.2)
    # what is left is the file's estimate of the load's state at each window's start
    assert fit.train_error[1] < 0.7 * fit.train_error[0]
    assert fit.val_error[1] < 0.8 * fit.val_error[0]
    assert "--input-lag 0.04,0.1,0.2" in fit.summary()


def test_identify_prints_the_lag_and_refuses_an_out_file(lagged_data, run_cli, tmp_path):
    code, out, _ = run_cli("identify", lagged_data, "--input-lag", "--horizon", "8")
    assert code == 0 and "--input-lag" in out and "rollout error" in out
    code, _, err = run_cli(
        "identify", lagged_data, "--input-lag", "--out", tmp_path / "vehicle.json"
    )
    assert code == 2 and "--input-lag" in err
    assert not (tmp_path / "vehicle.json").exists()


def test_the_fit_defaults_to_the_mpc_horizon():
    from slungload.input_lag import FIT_HORIZON

    assert FIT_HORIZON == MPCConfig().horizon


class _Prepared:
    """A physics candidate model with a warm-up (as the compiled and graphed backends)."""

    numpy, name, history = True, "physics", 2

    def __init__(self) -> None:
        self.calls: list[tuple[int, int, int]] = []

    def prepare(self, m: int, k: int, n: int) -> None:
        self.calls.append((m, k, n))

    def predict_candidates(self, x_hist, u_past, plans):
        return np.zeros((*plans.shape[:2], 13))


def test_the_warm_up_reaches_the_wrapped_model_with_its_own_history():
    inner = _Prepared()
    limits = InputLimits.from_sim(SimConfig())
    config = MPCConfig(samples=8, horizon=6, knots=3, input_lag=(0.04, 0.1, 0.2))
    MPPIController(inner, limits, config, VehicleParams())
    assert inner.calls == [(2, 8, 6)]
    assert not hasattr(LaggedPhysics(_Network(), (0.1, 0.1, 0.1), DT), "prepare")


def test_a_bad_lag_on_the_command_line_exits_2(run_cli, tmp_path, capsys):
    for bad in ("0.1,-1,0", "0.1,0.1", "a,b,c"):
        with pytest.raises(SystemExit) as stop:
            run_cli("study", "control", "--input-lag", bad, "--out", tmp_path / "s")
        assert stop.value.code == 2 and "--input-lag" in capsys.readouterr().err
    assert not (tmp_path / "s").exists()
