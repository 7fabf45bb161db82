"""The encoder-decoder: size, shapes, causality of the recursion, normalisation, round trips."""

from __future__ import annotations

import pytest
import torch

from slungload.config import ModelConfig
from slungload.models.base import Prediction, count_parameters
from slungload.models.lstm_attention import STD_FLOOR, SlungLoadNet
from slungload.state import LOAD_POS, POS, QUAT, VEL, quat_normalize, with_unit_quaternion

torch.set_num_threads(1)

M = 8  # short history keeps the tests fast; the network does not depend on M


def make_model(**overrides) -> SlungLoadNet:
    torch.manual_seed(0)
    return SlungLoadNet(ModelConfig(**overrides)).eval()


def make_batch(batch: int = 2, history: int = M, horizon: int = 5, seed: int = 1):
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(batch, history, 13, generator=g)
    x[..., QUAT] = quat_normalize(x[..., QUAT])
    u = torch.randn(batch, history, 4, generator=g)
    uf = torch.randn(batch, horizon, 4, generator=g)
    return x, u, uf


def physical_windows(windows: int = 6, steps: int = 12, seed: int = 2):
    """States and inputs with offsets and scales far from 0 / 1, like real flights."""
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(windows, steps, 13, generator=g).cumsum(1) * 0.3
    x[..., :3] += torch.tensor([5.0, -3.0, 10.0])
    x[..., QUAT] = quat_normalize(x[..., QUAT] + torch.tensor([3.0, 0.0, 0.0, 0.0]))
    u = torch.randn(windows, steps, 4, generator=g) * torch.tensor([2.0, 0.5, 0.5, 0.2])
    u[..., 0] += 14.0
    return x, u


def test_parameter_count_matches_paper():
    assert count_parameters(SlungLoadNet()) == 238_906
    # Without slack outputs the last Linear loses 100 * 13 weights and 13 biases.
    assert count_parameters(SlungLoadNet(ModelConfig(slack=False))) == 238_906 - 1_313


@pytest.mark.parametrize("slack", [True, False])
def test_output_shapes_for_two_horizons(slack):
    model = make_model(slack=slack)
    x, u, _ = make_batch(batch=3)
    for horizon in (1, 25, 50):
        uf = torch.randn(3, horizon, 4)
        with torch.no_grad():
            pred = model(x, u, uf)
        assert isinstance(pred, Prediction)
        assert pred.states.shape == (3, horizon, 13)
        if slack:
            assert pred.slack.shape == (3, horizon, 13)
        else:
            assert pred.slack is None


def test_bad_shapes_are_rejected():
    model = make_model()
    x, u, uf = make_batch()
    with pytest.raises(ValueError, match="x_hist"):
        model(x[..., :12], u, uf)
    with pytest.raises(ValueError, match="u_future"):
        model(x, u, uf[:1])


def test_first_step_uses_last_measurement_not_last_future_input():
    model = make_model()
    x, u, uf = make_batch()
    with torch.no_grad():
        base = model(x, u, uf).states
        x2 = x.clone()
        x2[:, -1, :3] += 0.5
        moved_state = model(x2, u, uf).states
        u2 = u.clone()
        u2[:, -1] += 0.5
        moved_input = model(x, u2, uf).states
        uf2 = uf.clone()
        uf2[:, -1] += 10.0
        moved_last_future = model(x, u, uf2).states
    assert (moved_state[:, 0] - base[:, 0]).abs().max() > 1e-6
    assert (moved_input[:, 0] - base[:, 0]).abs().max() > 1e-6
    torch.testing.assert_close(moved_last_future, base, rtol=0, atol=0)


@pytest.mark.parametrize("j", [0, 2])
def test_prediction_is_causal_in_future_inputs(j):
    """u_{M+j} first enters at horizon step j + 1 (it is fed with x_hat_{M+j})."""
    model = make_model()
    x, u, uf = make_batch(horizon=5)
    with torch.no_grad():
        base = model(x, u, uf).states
        uf2 = uf.clone()
        uf2[:, j] += 1.0
        moved = model(x, u, uf2).states
    torch.testing.assert_close(moved[:, : j + 1], base[:, : j + 1], rtol=0, atol=0)
    assert (moved[:, j + 1] - base[:, j + 1]).abs().max() > 1e-6


def test_fit_normalization_standardises_the_fitting_data():
    model = make_model(relative_positions=False)
    x, u = physical_windows()
    x[..., 5] = 2.5  # a constant channel must not blow up
    model.fit_normalization(x, u)
    zx, zu = model.normalize_state(x), model.normalize_input(u)
    varying = [c for c in range(13) if c != 5]
    torch.testing.assert_close(zx.mean((0, 1)), torch.zeros(13), atol=1e-5, rtol=0)
    torch.testing.assert_close(zx.std((0, 1), correction=0)[varying], torch.ones(12))
    torch.testing.assert_close(zu.mean((0, 1)), torch.zeros(4), atol=1e-5, rtol=0)
    torch.testing.assert_close(zu.std((0, 1), correction=0), torch.ones(4))
    assert model.state_std[5] == pytest.approx(STD_FLOOR)
    assert torch.isfinite(zx).all()
    torch.testing.assert_close(model.denormalize_state(zx), x, atol=1e-5, rtol=1e-5)
    expected_delta = (x[:, 1:] - x[:, :-1]).reshape(-1, 13).std(0, correction=0)
    torch.testing.assert_close(model.delta_std[varying], expected_delta[varying])


def test_fit_normalization_refused_without_normalize():
    model = make_model(normalize=False)
    with pytest.raises(ValueError, match="normalize=False"):
        model.fit_normalization(*physical_windows())


@pytest.mark.parametrize("residual", [False, True])
def test_outputs_are_in_physical_units(residual):
    """A head that outputs zeros predicts the data mean (absolute) or holds x_{M-1} (residual)."""
    model = make_model(residual=residual)
    x, u = physical_windows()
    model.fit_normalization(x, u)
    last = model.head.layers[-1]
    with torch.no_grad():
        last.weight.zero_()
        last.bias.zero_()
        pred = model(x[:, :M], u[:, :M], u[:, M:])
    n = x.shape[1] - M
    if residual:
        expected = x[:, M - 1 : M].expand(-1, n, -1)
    else:  # the data mean, in the frame of the last measured vehicle position
        origin = model.origin(x[:, M - 1]).unsqueeze(1)
        expected = (model.state_mean + origin).expand(-1, n, -1)
    torch.testing.assert_close(pred.states, expected, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("normalize", [True, False])
@pytest.mark.parametrize("residual", [False, True])
def test_modes_run_and_are_finite(normalize, residual):
    model = make_model(normalize=normalize, residual=residual)
    x, u = physical_windows()
    if normalize:
        model.fit_normalization(x, u)
    with torch.no_grad():
        pred = model(x[:, :M], u[:, :M], u[:, M:])
    assert pred.states.shape == (x.shape[0], x.shape[1] - M, 13)
    assert torch.isfinite(pred.states).all() and torch.isfinite(pred.slack).all()


def test_single_row_equals_row_of_batch():
    model = make_model()
    x, u, uf = make_batch(batch=8, horizon=6)
    with torch.no_grad():
        full = model(x, u, uf)
        one = model(x[3:4], u[3:4], uf[3:4])
    torch.testing.assert_close(one.states, full.states[3:4], atol=1e-6, rtol=1e-5)
    torch.testing.assert_close(one.slack, full.slack[3:4], atol=1e-6, rtol=1e-5)


def test_decoder_step_matches_torch_lstm():
    """The hand-written decoder step reproduces nn.LSTM on the same parameters."""
    from slungload.models.lstm_attention import _lstm_cell, _stacked_lstm_weights

    model = make_model()
    lstm = model.decoder
    inp = torch.randn(4, 1, lstm.input_size)
    h0, c0 = torch.randn(3, 4, 20), torch.randn(3, 4, 20)
    with torch.no_grad():
        ref, (h_ref, c_ref) = lstm(inp, (h0, c0))
        layer_in, hs, cs = inp[:, 0], [], []
        for i, (w, b) in enumerate(_stacked_lstm_weights(lstm)):
            h, c = _lstm_cell(layer_in, h0[i], c0[i], w, b)
            hs.append(h)
            cs.append(c)
            layer_in = h
    torch.testing.assert_close(layer_in, ref[:, 0])
    torch.testing.assert_close(torch.stack(hs), h_ref)
    torch.testing.assert_close(torch.stack(cs), c_ref)


def test_state_dict_round_trip_keeps_outputs():
    model = make_model(residual=True)
    x, u = physical_windows()
    model.fit_normalization(x, u)
    torch.manual_seed(123)  # a different initialisation, overwritten by the load
    other = SlungLoadNet(ModelConfig(residual=True)).eval()
    other.load_state_dict(model.state_dict())
    with torch.no_grad():
        a = model(x[:, :M], u[:, :M], u[:, M:])
        b = other(x[:, :M], u[:, :M], u[:, M:])
    torch.testing.assert_close(b.states, a.states, rtol=0, atol=0)
    torch.testing.assert_close(b.slack, a.slack, rtol=0, atol=0)


@pytest.mark.parametrize("residual", [False, True])
def test_gradients_reach_every_parameter(residual):
    model = make_model(residual=residual).train()
    x, u = physical_windows()
    model.fit_normalization(x, u)
    pred = model(x[:, :M], u[:, :M], u[:, M:])
    (pred.states.square().sum() + pred.slack.square().sum()).backward()
    for name, p in model.named_parameters():
        assert p.grad is not None, name
        assert torch.isfinite(p.grad).all(), name
        assert p.grad.abs().max() > 0, name


def test_with_unit_quaternion_normalises_only_the_quaternion():
    states = torch.randn(2, 3, 13)
    out = with_unit_quaternion(states)
    torch.testing.assert_close(out[..., QUAT].norm(dim=-1), torch.ones(2, 3))
    keep = [c for c in range(13) if c not in range(QUAT.start, QUAT.stop)]
    torch.testing.assert_close(out[..., keep], states[..., keep], rtol=0, atol=0)


def test_relative_positions_make_the_prediction_translation_invariant():
    model = make_model()
    x, u = physical_windows()
    model.fit_normalization(x, u, origin_step=M - 1)
    x_hist, u_hist, u_future = x[:, :M], u[:, :M], u[:, M:]
    offset = torch.tensor([3.0, -7.0, 1.5])
    moved = x_hist.clone()
    moved[..., POS] += offset
    moved[..., LOAD_POS] += offset
    with torch.no_grad():
        base = model(x_hist, u_hist, u_future).states
        shifted = model(moved, u_hist, u_future).states
    for part in (POS, LOAD_POS):
        torch.testing.assert_close(shifted[..., part], base[..., part] + offset, atol=1e-4, rtol=0)
    for part in (VEL, QUAT):
        torch.testing.assert_close(shifted[..., part], base[..., part], atol=1e-5, rtol=0)
    # Absolute positions (the paper's setting) see the offset.
    absolute = make_model(relative_positions=False)
    absolute.fit_normalization(x, u)
    with torch.no_grad():
        a = absolute(x_hist, u_hist, u_future).states
        b = absolute(moved, u_hist, u_future).states
    assert (b[..., VEL] - a[..., VEL]).abs().max() > 1e-4


def test_relative_normalization_uses_the_origin_step():
    model = make_model()
    x, u = physical_windows()
    model.fit_normalization(x, u, origin_step=M - 1)
    local = x - model.origin(x[:, M - 1]).unsqueeze(1)
    torch.testing.assert_close(model.state_mean, local.reshape(-1, 13).mean(0), atol=1e-5, rtol=0)


@pytest.mark.parametrize("architecture", ["lstm-attention", "physics-step"])
def test_the_heading_frame_makes_the_prediction_turn_with_the_scene(architecture):
    """Turning a window about the vertical turns a heading-frame network's prediction with it,
    to rounding, for forward and forward_candidates; a world-frame network's it does not."""
    from slungload.models import build
    from slungload.state import rotate_about_z

    x, u = (a.double() for a in physical_windows())
    x[..., LOAD_POS] = x[..., POS] - torch.tensor([0.1, 0.0, 0.7], dtype=x.dtype)
    x_hist, u_hist, u_future = x[:, :M], u[:, :M], u[:, M:]
    yaw = torch.tensor(2.3, dtype=torch.float64)

    def turned(states):
        return rotate_about_z(states, torch.zeros(*states.shape[:-1], 6).double(), yaw)[0]

    for heading, equal in ((True, True), (False, False)):
        torch.manual_seed(0)
        config = ModelConfig.sized("tiny", architecture=architecture, heading_frame=heading)
        model = build(config).double().eval()
        model.fit_normalization(x, u, origin_step=M - 1)
        with torch.no_grad():
            for p in model.head.parameters():  # a correction of the size of a real one
                p.normal_(0.0, 0.3)
            want = turned(model(x_hist, u_hist, u_future).states)
            got = model(turned(x_hist), u_hist, u_future).states
            plans = torch.cat([u_hist[:, -1:], u_future[:, :-1]], 1)
            one = model.forward_candidates(x_hist[0], u_hist[0, :-1], plans).states
            one_turned = model.forward_candidates(turned(x_hist[0]), u_hist[0, :-1], plans)
        gap = (got - want).abs().max().item()
        gap_candidates = (one_turned.states - turned(one)).abs().max().item()
        if equal:
            assert gap < 1e-9 and gap_candidates < 1e-9, (gap, gap_candidates)
        else:
            assert gap > 1e-3 and gap_candidates > 1e-3


def test_the_heading_frame_makes_the_physics_loss_with_slack_the_same_for_every_heading():
    """The slack is added to the physics residual, whose attitude block is an error that a turn
    of the world conjugates: turned back as such, |residual + slack| is the same at every
    heading (turned back as a state, it is not)."""
    from slungload.config import VehicleParams
    from slungload.loss import physics_residual
    from slungload.models import build
    from slungload.models.base import Prediction
    from slungload.state import from_heading_frame, heading_turn, rotate_about_z

    x, u = (a.double() for a in physical_windows())
    x[..., LOAD_POS] = x[..., POS] - torch.tensor([0.1, 0.0, 0.7], dtype=x.dtype)
    u_hist, u_future = u[:, :M], u[:, M:]
    aux = torch.zeros(*x.shape[:-1], 6, dtype=x.dtype)
    yaw = torch.tensor(2.3, dtype=torch.float64)
    torch.manual_seed(0)
    config = ModelConfig.sized("tiny", architecture="physics-step", heading_frame=True)
    model = build(config).double().eval()
    model.fit_normalization(x, u, origin_step=M - 1)
    with torch.no_grad():
        for p in model.head.parameters():
            p.normal_(0.0, 0.3)

    def residual(states, as_states=False):
        with torch.no_grad():
            pred = model(states[:, :M], u_hist, u_future)
        if as_states:  # the slack turned back as if it were a state
            twist = model.heading(states[:, M - 1])
            inside = from_heading_frame(pred.slack, heading_turn(twist, errors=True).mT)
            pred = Prediction(pred.states, from_heading_frame(inside, heading_turn(twist)))
        inputs = torch.cat([u_hist[:, -1:], u_future[:, :-1]], 1)
        last, aux_steps = states[:, M - 1], aux[:, M - 1 : -1]
        r = physics_residual(pred.states, pred.slack, last, inputs, aux_steps, VehicleParams())
        return r.square().sum(-1)

    turned = rotate_about_z(x, aux, yaw)[0]
    torch.testing.assert_close(residual(turned), residual(x), atol=1e-9, rtol=0)
    assert (residual(turned, True) - residual(x, True)).abs().max() > 1e-4


def test_the_heading_frame_normalisation_is_the_same_for_every_heading():
    from slungload.state import rotate_about_z

    x, u = (a.double() for a in physical_windows())
    yaw = torch.linspace(-3.0, 3.0, x.shape[0], dtype=torch.float64)[:, None]  # one per window
    turned = rotate_about_z(x, torch.zeros(*x.shape[:-1], 6).double(), yaw)[0]
    stats = []
    for states in (x, turned):
        model = make_model(heading_frame=True).double()
        model.fit_normalization(states, u, origin_step=M - 1)
        stats.append(torch.cat([model.state_mean, model.state_std, model.delta_std]))
    torch.testing.assert_close(stats[0], stats[1], atol=1e-9, rtol=0)
