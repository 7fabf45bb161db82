"""The constants shift (the physics model's move under the constants estimated from a window's
history) and an ensemble interval widened by it: near zero on the vehicle the constants are of,
large on a longer cable; the calibration fitted with it covers its level, needs the shift
wherever it is used, round-trips, and the numpy paths (the MPC, onboard) compute it alike."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from slungload.config import to_dict
from slungload.constants_estimate import constants_shift
from slungload.data.readers.npz import from_arrays
from slungload.evaluation.uncertainty import fit_calibration, uncertainty_stats
from slungload.layout import GROUPS, LOAD_POS, POS, QUAT, STATE_DIM, WXYZ_TO_XYZW
from slungload.models.ensemble import Calibration, spread
from slungload.sim import Effects, SimConfig, simulate_flight
from slungload.sim.config import vehicle_params

M, N = 50, 25
CLEAN = Effects().without("thrust_error", "wind", "mocap_noise", "thrust_offset")


def _windows(cable: float):
    """(the nominal vehicle's constants, the flight's, states (W, M+N, 13), inputs (W, M+N, 4))
    of one clean flight with the given cable length, windows 10 steps apart."""
    cfg = SimConfig(effects=CLEAN).with_loads(cable_length=cable)
    nominal = vehicle_params(SimConfig(effects=CLEAN).nominal)
    flight = simulate_flight("fast_ellipses_xy", seed=0, config=cfg, steps=300)
    read = from_arrays(flight.arrays, Path("f"), nominal)
    x, u = torch.from_numpy(read.states), torch.from_numpy(read.inputs)
    states = x.unfold(0, M + N, 10).permute(0, 2, 1)
    inputs = u.unfold(0, M + N, 10).permute(0, 2, 1)
    return nominal, vehicle_params(flight.config), states, inputs


def _load_shift(states, inputs, params) -> torch.Tensor:
    """Median over windows of the load position's shift at the last step (m)."""
    shift = constants_shift(states[:, :M], inputs[:, :M], inputs[:, M:], params)
    assert shift.shape == (states.shape[0], N, STATE_DIM) and shift.dtype == torch.float64
    return shift[:, -1, LOAD_POS].norm(dim=-1).median()


def test_the_shift_is_small_on_its_own_vehicle_and_large_on_a_longer_cable():
    nominal, _, states, inputs = _windows(cable=nominal_cable())
    own = _load_shift(states, inputs, nominal)
    nominal, longer, states, inputs = _windows(cable=1.2 * nominal_cable())
    assert longer.cable_length == pytest.approx(1.2 * nominal.cable_length)
    against_nominal = _load_shift(states, inputs, nominal)
    against_truth = _load_shift(states, inputs, longer)
    assert against_nominal > 0.05  # metres at 0.5 s: the cable the members never saw
    assert own < 0.2 * against_nominal and against_truth < 0.2 * against_nominal
    # batched over any leading dimensions
    one = constants_shift(states[:1, :M], inputs[:1, :M], inputs[:1, M:], nominal)
    two = constants_shift(states[None, :2, :M], inputs[None, :2, :M], inputs[None, :2, M:], nominal)
    torch.testing.assert_close(two[0, :1], one)


def nominal_cable() -> float:
    return SimConfig().nominal.cable_length


def _members_and_truth(windows: int, shift_scale: float, seed: int):
    """64 members of std ~1 per component, a shift of up to ``shift_scale`` per window, and
    truth off the mean by a Gaussian of sqrt(std^2 + shift^2) (the quaternion far away)."""
    g = torch.Generator().manual_seed(seed)
    centre = torch.zeros(windows, 2, STATE_DIM, dtype=torch.float64)
    centre[..., QUAT.start] = 1000.0
    members = centre + torch.randn(64, windows, 2, STATE_DIM, generator=g, dtype=torch.float64)
    shift = shift_scale * torch.rand(windows, 1, 1, generator=g, dtype=torch.float64)
    shift = shift.expand(windows, 2, STATE_DIM).clone()
    mean, std = spread(members)
    noise = torch.randn(windows, 2, STATE_DIM, generator=g, dtype=torch.float64)
    return members, mean + (std**2 + shift**2).sqrt() * noise, shift


def test_a_calibration_with_the_shift_covers_its_level_where_the_members_alone_cannot():
    members, truth, shift = _members_and_truth(4000, 5.0, seed=0)
    cal = fit_calibration(members, truth, shift=shift)
    assert cal.constants_shift
    fresh_members, fresh_truth, fresh_shift = _members_and_truth(4000, 10.0, seed=1)
    stats = uncertainty_stats(fresh_members, fresh_truth, cal, shift=fresh_shift)
    alone = uncertainty_stats(fresh_members, fresh_truth, fit_calibration(members, truth))
    for g, name in enumerate(GROUPS):
        if name != "quaternion":  # renormalised by spread's mean
            assert stats.coverage[g] == pytest.approx([0.9, 0.9], abs=0.03)
            # fitted where the shift was half as large, the members' spread alone misses
            assert (alone.coverage[g] < 0.85).all()
    _, std = spread(fresh_members)
    torch.testing.assert_close(
        cal.half_width(std, shift=fresh_shift),
        cal.half_width((std**2 + fresh_shift**2).sqrt(), shift=torch.zeros_like(std)),
    )
    with pytest.raises(ValueError, match="no shift was given"):
        cal.half_width(std)
    with pytest.raises(ValueError, match="no shift was given"):
        cal.novel(std)
    with pytest.raises(ValueError, match="fitted without one"):
        fit_calibration(members, truth).half_width(std, shift=fresh_shift)
    # the flag round-trips; a manifest written before it reads as without
    assert Calibration.from_dict(json.loads(json.dumps(to_dict(cal)))) == cal
    older = {k: v for k, v in to_dict(cal).items() if k != "constants_shift"}
    assert not Calibration.from_dict(older).constants_shift


def test_the_numpy_shift_and_interval_equal_the_torch_ones():
    from slungload.deploy.compiled.physics import candidates_shift
    from slungload.deploy.members import members_half_width, members_novel
    from slungload.vehicle_constants import VehicleConstants

    nominal, _, states, inputs = _windows(cable=1.2 * nominal_cable())
    x, u = states[3, :M].numpy(), inputs[3].numpy()
    plans = np.stack([u[M - 1 : M + N - 1], 1.02 * u[M - 1 : M + N - 1]])  # (2, N, 4)
    shift = candidates_shift(x, u[: M - 1], plans, VehicleConstants.of(nominal))
    u_hist = np.concatenate([np.broadcast_to(u[: M - 1], (2, M - 1, 4)), plans[:, :1]], 1)
    u_future = np.concatenate([plans[:, 1:], plans[:, -1:]], 1)
    x_hist = torch.from_numpy(np.broadcast_to(x, (2, M, STATE_DIM)).copy())
    want = constants_shift(x_hist, torch.from_numpy(u_hist), torch.from_numpy(u_future), nominal)
    np.testing.assert_allclose(shift, want.numpy(), atol=1e-12)
    assert np.abs(shift[..., LOAD_POS]).max() > 0.05  # not two degenerate outputs
    with pytest.raises(ValueError, match="M >= 17"):
        candidates_shift(x[:16], u[:15], plans, VehicleConstants.of(nominal))
    # the interval and the flag in numpy, as calibrated in torch
    members, truth, fit_shift = _members_and_truth(300, 1.0, seed=2)
    cal = fit_calibration(members, truth, shift=fit_shift)
    some = members[:, :3].numpy()
    d = 3 * fit_shift[:3]  # some windows beyond the fitting windows' spread, some not
    _, std = spread(members[:, :3])
    half = cal.half_width(std, shift=d).numpy()
    np.testing.assert_allclose(members_half_width(some, to_dict(cal), d.numpy()), half, rtol=1e-9)
    novel = cal.novel(std, shift=d).numpy()
    assert novel.any() and not novel.all()
    flags = members_novel(some, to_dict(cal), d.numpy())
    np.testing.assert_array_equal(flags, novel)
    with pytest.raises(ValueError, match="no shift was given"):
        members_half_width(some, to_dict(cal))


def test_calibrate_with_the_shift_through_the_cli_and_the_predictor(
    run_cli, tmp_path, tiny_run, trained_ensemble
):
    from slungload.data.readers import read_flight
    from slungload.deploy.predictor import EnsemblePredictor, flight_window
    from slungload.models.ensemble import read_manifest

    # the shared tiny ensemble's M = 6 is too short for the estimate: refused, naming why
    before = read_manifest(trained_ensemble).calibration
    code, _, err = run_cli("calibrate", trained_ensemble, "--constants-shift")
    assert code == 2 and "17 steps" in err
    assert read_manifest(trained_ensemble).calibration == before  # untouched
    ens = tmp_path / "E"
    code, out, err = run_cli("train", "--data", tiny_run.data, "--out", ens, "--preset", "quick",
                             "--size", "tiny", "--device", "cpu", "--threads", "1", "--quiet",
                             "--ensemble", "2", "--epochs", "1", "--history", "20",
                             "--horizon", "4")  # fmt: skip
    assert code == 0, err
    code, out, err = run_cli("calibrate", ens, "--constants-shift")
    assert code == 0 and "constants shift" in out, err
    cal = read_manifest(ens).calibration
    assert cal is not None and cal.constants_shift
    code, out, _ = run_cli("uncertainty", ens)
    assert code == 0 and "as calibrated" in out and "widened by the constants shift" in out
    # evaluate states the same interval: its coverage is the assessment's on the test split
    from slungload.evaluation.evaluator import evaluate
    from slungload.evaluation.uncertainty import assess

    report = evaluate([ens], data=tiny_run.data, out=tmp_path / "r", horizons=(4,), progress=False)
    label = next(la for la in report.labels if la.startswith("E (mean of 2)"))
    np.testing.assert_allclose(report.spreads[label][4].coverage, assess(ens)[0].coverage)
    # the MPC flies it, the tracked interval and the novelty count with the shift
    code, out, err = run_cli("control", "--model", ens, "--maneuvers", "xy_step", "--seeds", "100",
                             "--steps", "30", "--horizon", "4", "--samples", "8",
                             "--out", tmp_path / "flown")  # fmt: skip
    assert code == 0, err
    # and its exported file onboard
    from slungload.control.mppi import InputLimits, MPCConfig, MPPIController, ReferenceAhead
    from slungload.control.tracked import TrackedMembers
    from slungload.deploy.candidates import export_for_mpc

    flight = read_flight(tiny_run.data / "test_3.npz")
    for fmt in ("compiled", "onnx"):
        (tmp_path / fmt).mkdir()
        result = export_for_mpc(ens, tmp_path / fmt, horizon=4, format=fmt)
        cfg = MPCConfig(samples=8, horizon=4, knots=2, risk=1.0)
        mpc = MPPIController.from_file(result.model, InputLimits(4.0, 30.0, 4.0), cfg)
        for x in flight.states[:25]:
            ref = ReferenceAhead(np.tile(x[:3], (4, 1)), np.zeros((4, 3)), np.zeros(4))
            assert np.isfinite(mpc.step(x, ref).thrust)
        assert isinstance(mpc.model, TrackedMembers) and mpc.model.constants is not None
        assert mpc.model.tracker.resolved > 0 and mpc.stats.fallback_steps == 0
    # the shift is measured against the constants the members learned, not the MPC's
    from slungload.config import VehicleParams
    from slungload.control.mpc import candidate_model
    from slungload.deploy.backends import load_model
    from slungload.vehicle_constants import VehicleConstants

    compiled = load_model(ens, backend="compiled")
    learned = compiled.params
    cfg = MPCConfig(samples=8, horizon=4, knots=2)
    limits = InputLimits(4.0, 30.0, 4.0)
    other = MPPIController(candidate_model(compiled), limits, cfg, VehicleParams(cable_length=1.3))
    assert other.model.constants == VehicleConstants.of(learned)
    assert other.model.constants.cable_length != 1.3
    # a calibration is what the shift belongs to
    code, _, err = run_cli("ensemble", ens / "member-0", ens / "member-1", "--out",
                           tmp_path / "F", "--no-calibrate", "--constants-shift")  # fmt: skip
    assert code == 2 and "--constants-shift" in err
    # the predictor widens its interval by the same shift
    predictor = EnsemblePredictor.from_folder(ens)
    w = flight_window(read_flight(tiny_run.data / "test_3.npz"), 0, history=20, horizon=4)
    interval = predictor.predict_interval(w.history, w.future_inputs)
    states, _ = predictor._members(w.history, w.future_inputs)
    shift = predictor._shift(w.history, w.future_inputs)
    assert shift is not None and shift.shape == (1, 4, STATE_DIM)
    # the same shift as the windows' (the package layout, the members' constants)
    flight = read_flight(tiny_run.data / "test_3.npz")
    x, u = torch.from_numpy(flight.states), torch.from_numpy(flight.inputs)
    params = predictor.members[0].params
    torch.testing.assert_close(shift[0], constants_shift(x[:20], u[:20], u[20:24], params))
    half = cal.half_width(spread(states).std, shift=shift)[0].numpy()
    half[:, QUAT] = half[:, QUAT][:, list(WXYZ_TO_XYZW)]  # the file's x-y-z-w
    np.testing.assert_allclose(interval.half_width, half, rtol=1e-9)
    # in flight too: a resolved prediction far off widens it
    off = w.truth.copy()
    off[:, POS] += 1.0
    for _ in range(30):
        predictor.resolve(w.history, w.future_inputs, off)
    later = predictor.predict_interval(w.history, w.future_inputs)
    assert (later.half_width[:, POS] > interval.half_width[:, POS]).all()


def test_members_that_adapt_their_constants_are_refused_and_nothing_is_left(
    run_cli, tmp_path, adaptive_run
):
    out = tmp_path / "A"
    code, _, err = run_cli("ensemble", adaptive_run, adaptive_run, "--out", out,
                           "--constants-shift")  # fmt: skip
    assert code == 2 and "adapt theirs in flight" in err
    assert not out.exists()  # no uncalibrated ensemble left behind
