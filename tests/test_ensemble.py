"""Ensembles: the members' spread, its calibration (known solutions), the folder, the commands."""

from __future__ import annotations

import json
import re
import shutil

import numpy as np
import pytest
import torch
from flights import WINDOW_ARGS

from slungload.config import to_dict
from slungload.evaluation.uncertainty import fit_calibration, uncertainty_stats
from slungload.layout import GROUPS, QUAT, STATE_DIM
from slungload.models.ensemble import (
    ENSEMBLE_FILE,
    Calibration,
    EnsembleModel,
    read_manifest,
    spread,
    write_manifest,
    z_of,
)


def _unit_quaternions(x: torch.Tensor) -> torch.Tensor:
    x = x.clone()
    x[..., QUAT] = x[..., QUAT] / x[..., QUAT].norm(dim=-1, keepdim=True)
    return x


def test_spread_of_equal_members_is_zero_and_ignores_the_quaternion_sign():
    one = _unit_quaternions(torch.randn(7, 5, STATE_DIM, dtype=torch.float64))
    flipped = one.clone()
    flipped[..., QUAT] *= -1  # the same attitudes
    mean, std = spread(torch.stack([one, flipped, one]))
    torch.testing.assert_close(mean, one)
    assert float(std.abs().max()) < 1e-12


def test_spread_is_the_members_mean_and_unbiased_std():
    members = torch.randn(4, 3, 2, STATE_DIM, dtype=torch.float64)
    members[..., QUAT] = (
        torch.tensor([1.0, 0, 0, 0], dtype=torch.float64) + 0.01 * members[..., QUAT]
    )
    mean, std = spread(members)
    torch.testing.assert_close(mean[..., :3], members[..., :3].mean(0))
    torch.testing.assert_close(std[..., :3], members[..., :3].std(0))
    assert torch.allclose(mean[..., QUAT].norm(dim=-1), torch.ones(3, 2, dtype=torch.float64))


def test_spread_refuses_one_member():
    with pytest.raises(ValueError, match="E >= 2"):
        spread(torch.zeros(1, 3, STATE_DIM))


def _gaussian_case(windows: int, steps: int, factor: torch.Tensor, seed: int):
    """Members whose std is known (about 1 per component, the members' own noise) and truth
    off their mean by a Gaussian of ``factor`` (per step) times that std: the calibrated
    scale is ``factor`` up to the members' sampling of the std."""
    g = torch.Generator().manual_seed(seed)
    e = 64  # many members: their std is close to the std they are drawn with
    centre = torch.zeros(windows, steps, STATE_DIM, dtype=torch.float64)
    centre[..., QUAT.start] = 1000.0  # a quaternion far from the others' noise: w stays ~1
    sigma = torch.rand(windows, steps, STATE_DIM, generator=g, dtype=torch.float64) + 0.5
    members = centre + sigma * torch.randn(e, windows, steps, STATE_DIM, generator=g,
                                           dtype=torch.float64)  # fmt: skip
    mean, std = spread(members)
    noise = torch.randn(windows, steps, STATE_DIM, generator=g, dtype=torch.float64)
    truth = mean + factor.view(1, steps, 1) * std * noise
    return members, truth


def test_calibration_recovers_a_known_scale_and_covers_the_level_on_new_windows():
    steps = 3
    factor = torch.tensor([0.5, 1.0, 3.0], dtype=torch.float64)
    members, truth = _gaussian_case(4000, steps, factor, seed=0)
    # the quaternion's components are renormalised by spread's mean: leave them out here
    cal = fit_calibration(members, truth)
    scale = torch.tensor(cal.scale, dtype=torch.float64)
    for g, name in enumerate(GROUPS):
        if name != "quaternion":
            torch.testing.assert_close(scale[:, g], factor, rtol=0.05, atol=0.0)
    fresh_members, fresh_truth = _gaussian_case(4000, steps, factor, seed=1)
    stats = uncertainty_stats(fresh_members, fresh_truth, cal)
    for g, name in enumerate(GROUPS):
        if name != "quaternion":
            assert stats.coverage[g] == pytest.approx([0.9] * steps, abs=0.02)
    # the 50 % interval by Gaussian z: right for Gaussian errors too
    half = uncertainty_stats(fresh_members, fresh_truth, cal, level=0.5)
    assert half.coverage[0] == pytest.approx([0.5] * steps, abs=0.03)
    # few windows are novel on data like the fitting windows; all are with 10x the spread
    assert stats.novel < 0.03
    wide = spread(fresh_members).mean + 10 * (fresh_members - spread(fresh_members).mean)
    assert uncertainty_stats(wide, fresh_truth, cal).novel == 1.0


def test_calibration_round_trip_and_steps_beyond_its_horizon():
    cal = Calibration(
        scale=((1.0, 2.0, 3.0, 4.0), (5.0, 6.0, 7.0, 8.0)),
        reference_std=((1.0,) * STATE_DIM, (2.0,) * STATE_DIM),
        novelty_threshold=1.5,
        fitted_on="here",
        windows=3,
    )
    assert Calibration.from_dict(json.loads(json.dumps(to_dict(cal)))) == cal
    scale = cal.component_scale(4)
    assert scale.shape == (4, STATE_DIM)
    assert scale[0, QUAT].tolist() == [3.0] * 4
    assert scale[3].tolist() == scale[1].tolist()  # past the fitted horizon: its last row
    half = cal.half_width(torch.ones(2, STATE_DIM, dtype=torch.float64))
    assert half[0, 0] == pytest.approx(z_of(0.9) * 1.0)
    assert z_of(0.9) == pytest.approx(1.6449, abs=1e-4)
    with pytest.raises(ValueError, match="one row per step"):
        Calibration(scale=((1.0,) * 4,), reference_std=(), novelty_threshold=1.0)


class _Constant:
    """A prediction model that predicts a fixed state everywhere."""

    def __init__(self, value: float, history: int = 2):
        self.value, self.history, self.name = value, history, f"c{value}"

    def predict_candidates(self, x_hist, u_past, plans):
        out = torch.zeros(*plans.shape[:2], STATE_DIM, dtype=plans.dtype)
        out[..., 0] = self.value
        out[..., QUAT.start] = 1.0
        return out


def test_ensemble_model_predicts_the_members_mean():
    model = EnsembleModel((_Constant(1.0), _Constant(3.0)))
    x, u, plans = torch.zeros(2, STATE_DIM), torch.zeros(1, 4), torch.zeros(5, 7, 4)
    assert model.predict_candidates(x, u, plans)[..., 0].unique().tolist() == [2.0]
    assert model.predict_candidates_members(x, u, plans).shape == (2, 5, 7, STATE_DIM)
    with pytest.raises(ValueError, match="different histories"):
        EnsembleModel((_Constant(1.0), _Constant(1.0, history=3)))
    with pytest.raises(ValueError, match="at least 2"):
        EnsembleModel((_Constant(1.0),))


def test_manifest_round_trip_moves_with_its_folder_and_names_bad_files(tmp_path):
    folder = tmp_path / "ens"
    runs = [folder / "member-0", folder / "member-1"]
    for r in runs:
        r.mkdir(parents=True)
    write_manifest(folder, runs)
    moved = tmp_path / "moved"
    shutil.move(folder, moved)
    manifest = read_manifest(moved)
    assert [m.name for m in manifest.members] == ["member-0", "member-1"]
    assert all(m.parent == moved.resolve() for m in manifest.members)
    assert manifest.calibration is None
    (moved / ENSEMBLE_FILE).write_text('{"format": 99, "members": []}')
    with pytest.raises(ValueError, match=r"ensemble\.json.*format 99"):
        read_manifest(moved)
    with pytest.raises(ValueError, match="at least 2"):
        write_manifest(tmp_path / "one", runs[:1])


def test_train_ensemble_writes_calibrated_members_of_consecutive_seeds(trained_ensemble):
    from slungload.models.checkpoints import load_checkpoint
    from slungload.models.prediction import load_prediction_model

    manifest = read_manifest(trained_ensemble)
    seeds = [load_checkpoint(m).train_config.seed for m in manifest.members]
    assert seeds == [0, 1]
    assert manifest.calibration is not None and "val split" in manifest.calibration.fitted_on
    model = load_prediction_model(trained_ensemble)
    assert isinstance(model, EnsembleModel) and model.calibration == manifest.calibration


def test_ensemble_windows_and_candidates_agree_on_every_backend(trained_ensemble, tiny_run):
    from slungload.deploy.compiled.batched import with_backend
    from slungload.models.prediction import load_prediction_model

    model = load_prediction_model(trained_ensemble)
    windows = tiny_run.dataset.splits["test"]
    members = model.predict_windows_members(windows)
    torch.testing.assert_close(model.predict_windows(windows), spread(members).mean)
    m = model.history
    w = windows[:1]
    x_hist, u_past = w.states[0, :m].double(), w.inputs[0, : m - 1].double()
    plans = w.inputs[0, m - 1 : -1].double().expand(3, -1, -1).contiguous()
    eager = model.predict_candidates(x_hist, u_past, plans)
    from_windows = model.predict_windows(w).double()
    torch.testing.assert_close(eager[0], from_windows[0], atol=1e-4, rtol=0)
    compiled = with_backend(model, "compiled")
    assert isinstance(compiled, EnsembleModel)
    numpy_call = compiled.numpy_candidates(x_hist.numpy(), u_past.numpy(), plans.numpy())
    torch.testing.assert_close(torch.from_numpy(numpy_call), eager, atol=1e-4, rtol=0)
    torch.testing.assert_close(compiled.predict_candidates(x_hist, u_past, plans), eager,
                               atol=1e-4, rtol=0)  # fmt: skip


def test_uncertainty_command_writes_its_report_and_resume_keeps_members(
    trained_ensemble, tiny_run, run_cli, tmp_path
):
    code, out, _ = run_cli("uncertainty", trained_ensemble, "--out", tmp_path / "u")
    assert code == 0 and "flagged novel" in out and "tracked in flight" in out
    for name in ("uncertainty.md", "coverage.csv", "calibration.png"):
        assert (tmp_path / "u" / name).is_file()
    rows = (tmp_path / "u" / "coverage.csv").read_text().splitlines()
    assert len(rows) == 1 + 4  # a header and the tiny windows' N = 4 steps
    code, every, _ = run_cli("uncertainty", trained_ensemble, "--split", "all")
    count = re.compile(r"(\d+) windows")
    assert code == 0 and int(count.search(every)[1]) > int(count.search(out)[1])
    assert "every flight of" in every  # train included: another vehicle's data
    code, carried, _ = run_cli("uncertainty", trained_ensemble, "--carry", "--out", tmp_path / "c")
    assert code == 0 and "one after another" in carried and "one after another" not in out
    assert "one after another" in (tmp_path / "c" / "uncertainty.md").read_text()
    as_calibrated = [line for line in out.splitlines() if line.startswith("as calibrated")]
    assert as_calibrated and as_calibrated[0] in carried  # the calibrated interval is unchanged
    before = (trained_ensemble / "member-0" / "best.ckpt").stat().st_mtime_ns
    code, out, _ = run_cli("train", "--data", tiny_run.data, "--out", trained_ensemble,
                           "--preset", "quick", "--size", "tiny", "--device", "cpu",
                           "--threads", "1", "--quiet", "--ensemble", "2", "--epochs", "1",
                           "--resume", *WINDOW_ARGS)  # fmt: skip
    assert code == 0 and out.count("kept (finished before)") == 2
    assert (trained_ensemble / "member-0" / "best.ckpt").stat().st_mtime_ns == before


def test_ensemble_commands_refuse_what_they_cannot_use(run_cli, tmp_path, tiny_run):
    code, _, err = run_cli("uncertainty", tmp_path)
    assert code == 2 and "not an ensemble folder" in err
    code, _, err = run_cli("calibrate", tmp_path / "missing")
    assert code == 2 and "not an ensemble folder" in err
    code, _, err = run_cli("ensemble", tiny_run.out, "--out", tmp_path / "one")
    assert code == 2 and "at least 2" in err


def test_ensemble_predictor_gives_the_mean_an_interval_and_a_flag(trained_ensemble, tiny_run):
    from slungload.data.readers import read_flight
    from slungload.deploy.predictor import EnsemblePredictor, flight_window

    predictor = EnsemblePredictor.from_folder(trained_ensemble)
    flight = read_flight(tiny_run.data / "test_3.npz")
    w = flight_window(flight, 0, history=predictor.history, horizon=4)
    mean = predictor.predict(w.history, w.future_inputs)
    members = np.stack([m.predict(w.history, w.future_inputs) for m in predictor.members])
    np.testing.assert_allclose(mean[:, :7], members[:, :, :7].mean(0), atol=1e-6)
    assert np.allclose(np.linalg.norm(mean[:, 6:10], axis=-1), 1.0)
    interval = predictor.predict_interval(w.history, w.future_inputs)
    np.testing.assert_allclose(interval.mean, mean)
    assert interval.half_width.shape == mean.shape and (interval.half_width >= 0).all()
    assert interval.novel.dtype == np.bool_ and interval.novel.shape == ()
    three = (w.history[None].repeat(3, 0), w.future_inputs[None].repeat(3, 0))
    batch = predictor.predict_interval(*three)
    assert batch.mean.shape == (3, 4, STATE_DIM) and batch.novel.shape == (3,)
    np.testing.assert_allclose(batch.half_width[1], interval.half_width, atol=1e-9)
    # the 50 % interval is narrower by the ratio of the Gaussian z's
    half = predictor.predict_interval(w.history, w.future_inputs, level=0.5).half_width
    np.testing.assert_allclose(half * z_of(0.9) / z_of(0.5), interval.half_width, rtol=1e-9)
    with pytest.raises(ValueError, match="uncalibrated"):
        EnsemblePredictor(predictor.members).predict_interval(w.history, w.future_inputs)


def test_ensemble_predictor_tracks_its_interval_in_flight(trained_ensemble, tiny_run):
    from slungload.data.readers import read_flight
    from slungload.deploy.predictor import EnsemblePredictor, flight_window

    predictor = EnsemblePredictor.from_folder(trained_ensemble)
    flight = read_flight(tiny_run.data / "test_3.npz")
    w = flight_window(flight, 0, history=predictor.history, horizon=4)
    before = predictor.predict_interval(w.history, w.future_inputs)
    assert predictor.tracker is None and not before.surprised
    # a vehicle whose states run 1 m off every prediction: the position interval widens
    off = w.truth.copy()
    off[:, 0] += 1.0
    for _ in range(60):
        predictor.resolve(w.history, w.future_inputs, off)
    after = predictor.predict_interval(w.history, w.future_inputs)
    assert after.surprised and predictor.tracker.resolved == 60
    assert (after.half_width[:, :3] > before.half_width[:, :3]).all()
    np.testing.assert_allclose(after.mean, before.mean)
    with pytest.raises(ValueError, match="flown must be"):
        predictor.resolve(w.history, w.future_inputs, off[:2])


def test_the_mpc_calls_an_ensemble_for_its_mean():
    from slungload.control.mpc import candidate_model

    call = candidate_model(EnsembleModel((_Constant(1.0), _Constant(3.0))))
    states = call.predict_candidates(
        np.zeros((2, STATE_DIM)), np.zeros((1, 4)), np.zeros((5, 7, 4))
    )
    assert states.shape == (5, 7, STATE_DIM) and np.all(states[..., 0] == 2.0)


def test_evaluate_reports_an_ensembles_mean_and_its_interval(trained_ensemble, tiny_run, tmp_path):
    from slungload.evaluation.evaluator import evaluate

    report = evaluate([trained_ensemble], data=tiny_run.data, out=tmp_path / "r", horizons=(2, 4),
                      progress=False)  # fmt: skip
    label = next(la for la in report.labels if la.startswith("E (mean of 2)"))
    assert sorted(report.spreads[label]) == [2, 4]
    stats = report.spreads[label][4]
    assert stats.coverage.shape == (len(GROUPS), 4) and 0.0 <= stats.coverage.min() <= 1.0
    text = (tmp_path / "r" / "report.md").read_text()
    assert f"## The interval of {label}, N = 4" in text
    assert list((tmp_path / "r" / "figures").glob("calibration_*_N4.png"))
    saved = json.loads((tmp_path / "r" / "report.json").read_text())
    assert saved["spreads"][label]["4"]["level"] == 0.9


def test_control_prices_an_ensembles_members_with_risk(
    trained_ensemble, tiny_run, run_cli, tmp_path
):
    """``control --risk``: the ensemble's MPC prices each member's prediction (its label says
    so); the physics MPC beside it is flown as ever; without an ensemble the option is refused."""
    out = tmp_path / "ctl"
    code, _, err = run_cli(
        "control", "--model", trained_ensemble, "--maneuvers", "roll_35", "--seeds", "100",
        "--samples", "4", "--horizon", "5", "--steps", "6", "--backend", "compiled",
        "--risk", "1", "--out", out, "--quiet",
    )  # fmt: skip
    assert code == 0, err
    rows = json.loads((out / "results.json").read_text())["rows"]
    labels = {r["controller"] for r in rows}
    assert labels == {"pid", "mpc-physics K=4", "mpc-E risk 1 K=4"}
    assert all(r["completed"] for r in rows)
    code, _, err = run_cli("control", "--model", tiny_run.out, "--risk", "1", "--steps", "2",
                           "--out", tmp_path / "x")  # fmt: skip
    assert code == 2 and "no --model is an ensemble" in err


def test_split_members_are_each_members_own_prediction_on_every_backend(
    trained_ensemble, tiny_run, run_cli, tmp_path
):
    """``--members split``: candidate k is member k mod E's own prediction, eager, compiled and
    in the exported .mpc.npz alike; the ONNX graph, which predicts the members together, is
    refused by name; ``control`` flies it under its label."""
    from slungload.control.mpc import candidate_model
    from slungload.control.mppi import InputLimits, MPCConfig, MPPIController
    from slungload.control.split import SplitMembers
    from slungload.deploy.backends import load_exported
    from slungload.deploy.candidates import export_for_mpc
    from slungload.deploy.compiled import with_backend
    from slungload.models.prediction import load_prediction_model

    model = load_prediction_model(trained_ensemble)
    w = tiny_run.dataset.splits["test"][:1]
    m = model.history
    noise = torch.randn(5, 4, 4, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    arrays = [w.states[0, :m].double().numpy(), w.inputs[0, : m - 1].double().numpy(),
              (w.inputs[0, m - 1 : m + 3].double() + noise).numpy()]  # fmt: skip
    exported = export_for_mpc(trained_ensemble, tmp_path, horizon=4, format="compiled").model
    for backend in (model, with_backend(model, "compiled"), load_exported(exported)):
        numpy_model = candidate_model(backend)
        members = numpy_model.predict_candidates_members(*arrays)  # (2, 5, 4, 13)
        got = SplitMembers(numpy_model, 5).predict_candidates(*arrays)
        np.testing.assert_allclose(got[0::2], members[0, 0::2], rtol=0, atol=1e-12)
        np.testing.assert_allclose(got[1::2], members[1, 1::2], rtol=0, atol=1e-12)
    onnx = load_exported(export_for_mpc(trained_ensemble, tmp_path / "G.mpc.onnx", horizon=4).model)
    with pytest.raises(ValueError, match="no members to call one by one"):
        MPPIController(onnx, InputLimits(4.0, 30.0, 4.0),
                       MPCConfig(samples=8, horizon=4, knots=2, members="split"))  # fmt: skip
    out = tmp_path / "ctl"
    code, _, err = run_cli(
        "control", "--model", trained_ensemble, "--maneuvers", "roll_35", "--seeds", "100",
        "--samples", "4", "--horizon", "5", "--steps", "6", "--backend", "compiled",
        "--members", "split", "--out", out, "--quiet",
    )  # fmt: skip
    assert code == 0, err
    rows = json.loads((out / "results.json").read_text())["rows"]
    assert {r["controller"] for r in rows} == {"pid", "mpc-physics K=4", "mpc-E split K=4"}
    assert all(r["completed"] for r in rows)
    code, _, err = run_cli("control", "--model", tiny_run.out, "--members", "split", "--steps",
                           "2", "--out", tmp_path / "x")  # fmt: skip
    assert code == 2 and "no --model is an ensemble" in err and not (tmp_path / "x").exists()


def test_members_mean_in_numpy_is_the_spreads_mean():
    from slungload.deploy.members import members_mean

    gen = torch.Generator().manual_seed(4)
    members = torch.randn(3, 5, 7, 13, generator=gen, dtype=torch.float64)
    members[1, ..., 6:10] *= -1  # a member in the other hemisphere: the same attitudes
    want = spread(members).mean.numpy()
    np.testing.assert_allclose(members_mean(members.numpy()), want, rtol=0, atol=1e-12)


def test_an_ensemble_exports_compiled_and_flies_onboard(trained_ensemble, tiny_run, tmp_path):
    """The compiled file of an ensemble: its mean equals the eager ensemble's, its members the
    compiled backend's exactly, the calibration travels, and the onboard MPC prices members
    and tracks their interval over the steps just flown."""
    from slungload.control.mppi import InputLimits, MPCConfig, MPPIController, ReferenceAhead
    from slungload.control.tracked import TrackedMembers
    from slungload.deploy.candidates import export_for_mpc
    from slungload.deploy.compiled import with_backend
    from slungload.deploy.compiled.archive import load_columns
    from slungload.models.prediction import load_prediction_model

    result = export_for_mpc(trained_ensemble, tmp_path, horizon=4, format="compiled")
    assert result.model.name == "E.mpc.npz" and result.max_abs_diff <= 1e-4
    onboard = load_columns(result.model)
    assert len(onboard.members) == 2 and onboard.calibration["level"] == 0.9
    model = load_prediction_model(trained_ensemble)
    w = tiny_run.dataset.splits["test"][:1]
    m = model.history
    x_hist, u_past = w.states[0, :m].double(), w.inputs[0, : m - 1].double()
    plans = w.inputs[0, m - 1 : -1].double().expand(3, -1, -1).contiguous()
    arrays = [a.numpy() for a in (x_hist, u_past, plans)]
    want = model.predict_candidates(x_hist, u_past, plans).numpy()
    assert np.abs(onboard.predict_candidates(*arrays) - want).max() <= 1e-4
    compiled = with_backend(model, "compiled")
    np.testing.assert_array_equal(
        onboard.predict_candidates_members(*arrays), compiled.numpy_candidates_members(*arrays)
    )
    n = plans.shape[1]
    mpc = MPPIController.from_file(
        result.model,
        InputLimits(4.0, 30.0, 4.0),
        MPCConfig(samples=8, horizon=n, knots=2, risk=1.0),
    )
    x = arrays[0][-1]
    ref = ReferenceAhead(np.tile(x[:3], (n, 1)), np.zeros((n, 3)), np.zeros(n))
    assert np.isfinite(mpc.step(x, ref).thrust) and mpc.stats.fallback_steps == 0
    assert isinstance(mpc.model, TrackedMembers) and mpc.model.tracker.resolved == 1


def test_an_ensemble_exports_to_onnx_and_flies_onboard(trained_ensemble, tiny_run, tmp_path):
    """The ONNX graph of an ensemble gives every member's states on ONNX Runtime: each within
    the export tolerance of the compiled file's, their mean the same numpy mean, the
    calibration and its novelty flag carried; the onboard MPC prices the members and tracks
    their interval."""
    from slungload.control.mppi import InputLimits, MPCConfig, MPPIController, ReferenceAhead
    from slungload.control.tracked import TrackedMembers
    from slungload.deploy.backends import load_exported
    from slungload.deploy.candidates import export_for_mpc
    from slungload.deploy.members import members_mean

    onnx = export_for_mpc(trained_ensemble, tmp_path / "E.mpc.onnx", horizon=4)
    assert onnx.max_abs_diff <= 1e-4
    compiled = load_exported(export_for_mpc(trained_ensemble, tmp_path / "C.mpc.npz", horizon=4,
                                            format="compiled").model)  # fmt: skip
    model = load_exported(onnx.model)
    assert model.meta["member_count"] == 2 and model.calibration == compiled.calibration
    w = tiny_run.dataset.splits["test"][:1]
    m = model.history
    arrays = [w.states[0, :m].double().numpy(), w.inputs[0, : m - 1].double().numpy(),
              w.inputs[0, m - 1 : -1].double().expand(3, -1, -1).contiguous().numpy()]  # fmt: skip
    members = model.predict_candidates_members(*arrays)
    assert members.shape == (2, 3, 4, 13)
    assert np.abs(members - compiled.predict_candidates_members(*arrays)).max() <= 1e-4
    np.testing.assert_array_equal(model.predict_candidates(*arrays), members_mean(members))
    spread_out = members + np.random.default_rng(0).standard_normal(members.shape)
    for ms in (members, spread_out):
        np.testing.assert_array_equal(model.novel(ms), compiled.novel(ms))
    mpc = MPPIController.from_file(onnx.model, InputLimits(4.0, 30.0, 4.0),
                                   MPCConfig(samples=8, knots=2, risk=1.0))  # fmt: skip
    x = arrays[0][-1]
    ref = ReferenceAhead(np.tile(x[:3], (4, 1)), np.zeros((4, 3)), np.zeros(4))
    assert np.isfinite(mpc.step(x, ref).thrust) and mpc.stats.fallback_steps == 0
    assert isinstance(mpc.model, TrackedMembers) and mpc.model.tracker.resolved == 1
    single = load_exported(export_for_mpc(tiny_run.out, tmp_path, horizon=4).model)
    assert not hasattr(single, "predict_candidates_members")  # one network is no ensemble


def test_the_novelty_flag_in_numpy_is_the_calibrations(trained_ensemble, tmp_path):
    """The onboard ensemble's flag (numpy) equals ``Calibration.novel`` on the same members,
    like and 10x spread apart; the risk-priced MPC counts flagged nominal plans."""
    from slungload.deploy.candidates import export_for_mpc
    from slungload.deploy.compiled.archive import load_columns
    from slungload.models.prediction import load_prediction_model

    model = load_prediction_model(trained_ensemble)
    onboard = load_columns(export_for_mpc(trained_ensemble, tmp_path, horizon=4,
                                          format="compiled").model)  # fmt: skip
    ref = np.asarray(model.calibration.reference_std)  # (N, 13)
    rng = np.random.default_rng(0)
    centre = rng.standard_normal((1, 6, 7, 13))
    for scale in (1.0, 10.0):
        members = centre + scale * ref[None, None, :1] * rng.standard_normal((3, 6, 7, 13))
        want = model.calibration.novel(spread(torch.from_numpy(members)).std).numpy()
        np.testing.assert_array_equal(onboard.novel(members), want)
        np.testing.assert_array_equal(model.novel(members), want)
    assert onboard.novel(members).all()  # 10x the calibration's spread
