"""Evaluation metrics, prediction models over windows and timing, on windows rolled out by the
physics model."""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from slungload.config import ModelConfig, VehicleParams, WindowConfig
from slungload.data.windows import Windows, make_windows
from slungload.deploy.compiled import CompiledPredictor, unsupported
from slungload.deploy.predictor import Predictor as Facade
from slungload.deploy.timing import time_compiled, time_inference, time_models
from slungload.evaluation.evaluator import Candidate, evaluate_predictors, horizon_windows
from slungload.evaluation.metrics import COMBINED, group_errors, metrics_from_errors
from slungload.evaluation.results import PHYSICS
from slungload.models.base import Prediction
from slungload.models.lstm_attention import SlungLoadNet
from slungload.models.prediction import NetworkModel, PhysicsModel
from slungload.state import GROUPS, POS, QUAT, quat_from_rotvec, quat_mul

torch.set_num_threads(1)
PARAMS = VehicleParams()
M, N = 6, 8


@pytest.fixture(scope="module")
def flights(physics_flight):
    return [physics_flight(f"f{i}", seed=i, steps=30 + 5 * i) for i in range(3)]


@pytest.fixture(scope="module")
def windows(flights) -> Windows:
    return make_windows(flights, WindowConfig(history=M, horizon=N))


@pytest.fixture(scope="module")
def timing_windows(physics_flight) -> Windows:
    flight = physics_flight("t", seed=9, steps=M + N)
    return make_windows([flight], WindowConfig(history=M, horizon=N))


def truth_states(windows: Windows) -> Tensor:
    return windows.future.states.clone()


def offset_states(windows: Windows, offset: Tensor) -> Tensor:
    """Truth plus a constant position offset (m)."""
    pred = windows.future.states.clone()
    pred[..., POS] += offset
    return pred


@dataclass
class OffsetModel:
    """A prediction model that knows the future: truth plus a constant position offset (m).
    Evaluation calls only ``predict_windows``."""

    offset: Tensor
    name: str = "offset"
    history: int = M

    def predict_windows(self, windows: Windows) -> Tensor:
        return offset_states(windows, self.offset)


class HoldNet(nn.Module):
    """Stand-in network: holds the last measured state, quaternion scaled off unit norm."""

    def __init__(self) -> None:
        super().__init__()
        self.scale = nn.Parameter(torch.tensor(2.0))

    def forward(self, x_hist: Tensor, u_hist: Tensor, u_future: Tensor) -> Prediction:
        n = u_future.shape[1]
        states = x_hist[:, -1:].repeat(1, n, 1).clone()
        states[..., QUAT] = states[..., QUAT] * self.scale
        return Prediction(states, torch.full_like(states, 1e3))


# --- metrics --------------------------------------------------------------------------------


def test_perfect_predictor_has_zero_error(windows):
    m = metrics_from_errors(group_errors(truth_states(windows), windows.future.states))
    assert m.windows == len(windows) and m.horizon == N
    for key, value in m.rmse.items():
        assert value == pytest.approx(0.0, abs=1e-7), key
    for curve in m.curves.values():
        assert np.allclose(curve.mean, 0.0, atol=1e-7) and curve.mean.shape == (N,)


def test_constant_position_offset(windows):
    d = torch.tensor([0.3, -0.4, 1.2])
    m = metrics_from_errors(group_errors(offset_states(windows, d), windows.future.states))
    size = float(d.norm())  # 1.3 m
    c = m.curves["position"]
    for arr in (c.mean, c.q1, c.median, c.q3):
        np.testing.assert_allclose(arr, size, rtol=1e-5)
    assert m.rmse["position"] == pytest.approx(size, rel=1e-5)
    for g in ("velocity", "quaternion", "load_position"):
        assert m.rmse[g] == pytest.approx(0.0, abs=1e-7)
        assert np.allclose(m.curves[g].mean, 0.0, atol=1e-7)
    assert m.rmse[COMBINED] == pytest.approx(size, rel=1e-5)


def test_combined_is_sum_of_groups(windows):
    g = torch.Generator().manual_seed(1)
    truth = windows.future.states
    pred = truth + 0.1 * torch.randn(truth.shape, generator=g)
    m = metrics_from_errors(group_errors(pred, truth))
    assert m.rmse[COMBINED] == pytest.approx(sum(m.rmse[k] for k in GROUPS))
    assert all(m.rmse[k] > 0 for k in GROUPS)


def test_rmse_is_root_mean_square_over_windows_and_steps(windows):
    g = torch.Generator().manual_seed(2)
    truth = windows.future.states
    pred = truth.clone()
    pred[..., POS] += torch.randn(truth.shape[:-1] + (3,), generator=g)
    errors = group_errors(pred, truth)
    expected = (pred[..., POS] - truth[..., POS]).double().square().sum() / (len(windows) * N)
    assert metrics_from_errors(errors).rmse["position"] == pytest.approx(math.sqrt(expected))


def test_quartiles_are_over_windows(windows):
    # Offsets that differ per window but not per step: each step's quartiles are those of the
    # per-window offset sizes.
    sizes = torch.linspace(0.0, 2.0, len(windows))
    pred = windows.future.states.clone()
    pred[..., 10] += sizes[:, None]  # load x offset
    m = metrics_from_errors(group_errors(pred, windows.future.states))
    c = m.curves["load_position"]
    q1, med, q3 = np.percentile(sizes.numpy(), [25, 50, 75])
    np.testing.assert_allclose(c.q1, q1, rtol=1e-5)
    np.testing.assert_allclose(c.median, med, rtol=1e-5)
    np.testing.assert_allclose(c.q3, q3, rtol=1e-5)
    np.testing.assert_allclose(c.mean, sizes.mean().item(), rtol=1e-5)
    assert np.all(c.q1 <= c.median) and np.all(c.median <= c.q3)


def test_quaternion_error_identical_rotations_and_known_angle():
    g = torch.Generator().manual_seed(3)
    q = quat_from_rotvec(torch.randn(5, 4, 3, generator=g, dtype=torch.float64))
    x = torch.zeros(5, 4, 13, dtype=torch.float64)
    x[..., QUAT] = q
    assert group_errors(x, x)["quaternion"].abs().max() < 1e-12
    # A rotation by theta about any axis: || q_hat (x) q^-1 - q_id || = 2 sin(theta / 4).
    theta = 0.7
    axis = torch.nn.functional.normalize(
        torch.randn(5, 4, 3, generator=g, dtype=torch.float64), dim=-1
    )
    x_hat = x.clone()
    x_hat[..., QUAT] = quat_mul(quat_from_rotvec(theta * axis), q)
    err = group_errors(x_hat, x)["quaternion"]
    torch.testing.assert_close(err, torch.full_like(err, 2 * math.sin(theta / 4)))
    # The paper's error is not sign-invariant: -q (same rotation) is 2 away. The data are
    # sign-continuous, so this never arises between a prediction and its truth.
    x_neg = x.clone()
    x_neg[..., QUAT] = -q
    torch.testing.assert_close(group_errors(x_neg, x)["quaternion"], torch.full_like(err, 2.0))


def test_errors_reject_shape_mismatch(windows):
    with pytest.raises(ValueError, match="differ"):
        group_errors(windows.future.states[:, :-1], windows.future.states)


# --- prediction models over windows ---------------------------------------------------------


def test_physics_model_reproduces_physics_data(windows):
    pred = PhysicsModel(PARAMS).predict_windows(windows)
    assert pred.shape == windows.future.states.shape
    m = metrics_from_errors(group_errors(pred, windows.future.states))
    for key, value in m.rmse.items():
        assert value < 1e-4, key


def test_physics_model_uses_only_history_and_inputs(windows):
    spoiled = Windows(
        states=windows.states.clone(),
        inputs=windows.inputs,
        aux=windows.aux.clone(),
        flight=windows.flight,
        start=windows.start,
        names=windows.names,
        window=windows.window,
    )
    spoiled.states[:, M:] = 99.0
    spoiled.aux[:, M:] = 99.0
    model = PhysicsModel(PARAMS)
    torch.testing.assert_close(model.predict_windows(spoiled), model.predict_windows(windows))


def test_network_model_normalises_quaternion_and_batches(windows):
    pred = NetworkModel(HoldNet(), M, batch_size=7).predict_windows(windows)
    assert pred.shape == (len(windows), N, 13)
    torch.testing.assert_close(pred[..., QUAT].norm(dim=-1), torch.ones(len(windows), N))
    last = windows.states[:, M - 1]
    torch.testing.assert_close(pred[:, 0], last)


def test_timing_positive(timing_windows):
    t = time_inference(HoldNet(), timing_windows, repeats=5, warmup=1)
    assert t.mean_ms > 0 and t.std_ms >= 0 and t.repeats == 5
    assert t.threads == torch.get_num_threads() and (t.history, t.horizon) == (M, N)
    with pytest.raises(ValueError):
        time_inference(HoldNet(), timing_windows, repeats=1)


def test_compiled_timing_for_networks_of_the_paper_shape_only(timing_windows):
    shaped = ModelConfig(embed_sizes=(8, 8, 8), hidden_size=4, num_layers=2, head_sizes=(8, 8, 8))
    net = SlungLoadNet(shaped).eval()
    windows = timing_windows
    assert unsupported(net) is None
    compiled = CompiledPredictor(Facade(net, windows.window, PARAMS, "timing"))
    t = time_compiled(compiled, windows, repeats=5, warmup=1)
    assert t.backend == "numba compiled" and t.threads == 1 and t.mean_ms > 0
    assert (t.history, t.horizon, t.repeats) == (M, N, 5)
    assert time_inference(net, windows, repeats=2, warmup=0).backend == "torch eager"
    # Other layer structures, and stand-in modules, are timed eagerly only.
    other = SlungLoadNet(
        ModelConfig(embed_sizes=(8,), hidden_size=4, num_layers=1, head_sizes=(8,), dropout=0.0)
    )
    assert "three embedding" in unsupported(other)
    assert "does not support the 'HoldNet' architecture" in unsupported(HoldNet())
    with pytest.raises(ValueError, match="HoldNet"):
        CompiledPredictor(Facade(HoldNet(), windows.window, PARAMS, "timing"))
    timings = time_models(
        [("paper-shape", 0, net), ("other", 0, other)], {N: windows}, params=PARAMS, repeats=2
    )
    backends = [(t.label, t.timing.backend) for t in timings]
    assert backends == [
        ("paper-shape", "torch eager"),
        ("paper-shape", "numba compiled"),
        ("other", "torch eager"),
    ]


# --- windows per horizon and the full table ---------------------------------------------


def test_horizon_windows_come_from_the_same_test_flights(flights):
    test = make_windows(flights[1:], WindowConfig(history=M, horizon=N))
    dataset = SimpleNamespace(
        splits={"test": test, "train": make_windows(flights[:1], WindowConfig(M, N))},
        flights={f.name: f for f in flights},
        params=VehicleParams(),
    )
    per_n = horizon_windows(dataset, history=M, horizons=(N, 2 * N))
    assert set(per_n) == {N, 2 * N}
    for n, w in per_n.items():
        assert w.window == WindowConfig(history=M, horizon=n, stride=1)
        assert set(w.names[i] for i in w.flight.tolist()) <= {"f1", "f2"}
        for i in (0, len(w) - 1):  # each window is the flight's states from its start step
            f = dataset.flights[w.names[int(w.flight[i])]]
            s = int(w.start[i])
            np.testing.assert_allclose(w.states[i].numpy(), f.states[s : s + M + n], rtol=1e-6)
    # A longer horizon leaves N fewer windows per flight.
    assert len(per_n[N]) - len(per_n[2 * N]) == N * 2
    # "all": every flight of the dataset (one no model trained on), train included
    every = horizon_windows(dataset, history=M, horizons=(N,), split="all")[N]
    assert set(every.names) == {"f0", "f1", "f2"}
    assert len(every) == len(per_n[N]) + len(flights[0].states) - M - N + 1
    with pytest.raises(ValueError, match="split must be one of"):
        horizon_windows(dataset, history=M, horizons=(N,), split="train+test")


def test_evaluate_predictors_mean_and_std_across_seeds(flights):
    per_n = {n: make_windows(flights, WindowConfig(M, n)) for n in (N, 2 * N)}
    d1, d2 = torch.tensor([0.1, 0.0, 0.0]), torch.tensor([0.0, 0.3, 0.0])
    report = evaluate_predictors(
        [
            Candidate(PHYSICS, PhysicsModel(PARAMS)),
            Candidate("proposed", OffsetModel(d1), seed=0),
            Candidate("proposed", OffsetModel(d2), seed=1),
        ],
        per_n,
        params=PARAMS,
        training_horizon=N,
    )
    assert report.labels == (PHYSICS, "proposed") and report.horizons == (N, 2 * N)
    assert len(report.results) == 6
    row = report.row("proposed", 2 * N)
    assert row.seeds == 2
    assert row.mean["position"] == pytest.approx(0.2, rel=1e-5)
    assert row.std["position"] == pytest.approx(np.std([0.1, 0.3], ddof=1), rel=1e-5)
    # Curves pool the windows of both seeds: half the errors are 0.1, half 0.3.
    c = report.curves["proposed"][2 * N]["position"]
    np.testing.assert_allclose(c.mean, 0.2, rtol=1e-5)
    assert report.row(PHYSICS, N).mean[COMBINED] < 1e-4
    ex = report.example
    assert ex.window_states.shape == (M + 2 * N, 13)
    assert ex.predictions["proposed"].shape == (2 * N, 13)
