"""The check before flying (``evaluation.preflight``): the commands' effect keeps what follows
the commands and drops what the state alone explains; the response score is scale-free, 0 for
the truth and 1 for a model that ignores its commands; the verdict's rule and interval; the
verdict beside the run and ``control``'s warning; the command's bad inputs."""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import write_dataset

from slungload.config import PreflightConfig, VehicleParams, WindowConfig
from slungload.control.mpc import model_notes
from slungload.control.mppi import MPCConfig
from slungload.data.dataset import load_dataset
from slungload.evaluation.preflight import (
    Ratio,
    bootstrap_ratio,
    input_basis,
    input_part,
    measure,
    record_verdict,
    unexplained,
    verdict_of,
)
from slungload.evaluation.verdicts import NOT, PAYS, VERDICTS_FILE, verdict_note
from slungload.evaluation.windows import horizon_windows
from slungload.layout import LOAD_POS
from slungload.models.prediction import PhysicsModel

N = 8
CFG = PreflightConfig(horizon=N, resamples=200)


@pytest.fixture(scope="module")
def windows(tmp_path_factory: pytest.TempPathFactory):
    """Test windows at N = 8 (M = 4) from six flights of the discrete model, 70-85 steps."""
    names = [f"t{i}" for i in range(6)]
    folder = write_dataset(tmp_path_factory.mktemp("pre") / "data",
                           {n: 70 + 3 * i for i, n in enumerate(names)},
                           {"train": [], "val": [], "test": names}, physics=True)  # fmt: skip
    dataset = load_dataset(folder, window=WindowConfig(history=4, horizon=N, stride=1))
    return horizon_windows(dataset, history=4, horizons=(N,))[N]


def _commands(windows) -> torch.Tensor:
    """(W, N, 4) the plan's commands of each window: u_{M-1} ... u_{M+N-2}."""
    m = windows.window.history
    return windows.inputs[:, m - 1 : m - 1 + N].double()


@dataclass
class Shifted:
    """A model whose prediction is the truth plus ``error(windows)`` (W, N, 13)."""

    error: object
    name: str = "shifted"
    history: int = 4

    def predict_windows(self, windows) -> torch.Tensor:
        return windows.future.states.double() + self.error(windows)


def _load_error(values: torch.Tensor) -> torch.Tensor:
    out = torch.zeros(*values.shape[:2], 13, dtype=torch.float64)
    out[..., LOAD_POS] = values
    return out


def test_the_defaults_follow_the_mpc() -> None:
    assert PreflightConfig().horizon == MPCConfig().horizon


def test_the_basis_is_a_partition_of_unity() -> None:
    for n, k in [(8, 5), (15, 5), (3, 5), (25, 2), (1, 5)]:
        basis = input_basis(n, k)
        assert torch.allclose(basis.sum(dim=1), torch.ones(n, dtype=torch.float64))


def test_an_error_that_follows_the_commands_is_kept_one_of_the_state_dropped(windows) -> None:
    """Known solutions: an error linear in the commands (through the basis) comes back out of
    fold; one that depends on the start state alone comes back near zero."""
    u = _commands(windows)
    centred = u - u.mean(dim=(0, 1))
    follows = torch.stack([0.05 * centred[..., 1].cumsum(dim=1), -0.03 * centred[..., 2],
                           0.02 * centred[..., 0]], dim=-1)  # fmt: skip
    recovered = input_part(follows, windows, CFG)
    assert (recovered - follows).square().mean() < 0.1 * follows.square().mean()
    m = windows.window.history
    start = windows.states[:, m - 1].double()
    steps = torch.arange(1, N + 1, dtype=torch.float64)[None, :, None]
    state_only = 0.1 * steps * start[:, None, 3:6]  # grows with the start velocity
    assert input_part(state_only, windows, CFG).square().mean() < 0.01 * state_only.square().mean()


def _follows(scale: float):
    """An error of ``scale`` x the commands' deviations, summed over the plan (W, N, 13)."""

    def error(w) -> torch.Tensor:
        u = _commands(w)
        return _load_error(scale * (u - u.mean(dim=(0, 1)))[..., 1:4].cumsum(dim=1))

    return error


def test_a_bias_every_plan_shares_does_not_count_nor_does_accuracy_alone(windows) -> None:
    """Against a reference whose predicted effect of the commands is off: the truth scores
    0; the reference itself 1 x; a model off by a state-dependent bias many times the
    reference's error still explains the commands' effect and scores far lower; a model that
    ignores its commands scores worse and does not pay."""
    reference = Shifted(_follows(0.02))
    truth = Shifted(lambda w: torch.zeros(len(w), N, 13, dtype=torch.float64))
    response, logged, curves = measure(truth, reference, windows, CFG)
    assert response["load position"].high < 1e-6 and len(curves["network"]) == N
    response, logged, _ = measure(reference, reference, windows, CFG)
    for ratio in (response["load position"], logged["load position"]):
        assert ratio.value == pytest.approx(1.0) and ratio.low == pytest.approx(1.0)

    m = windows.window.history
    steps = torch.arange(1, N + 1, dtype=torch.float64)[None, :, None]
    bias = Shifted(lambda w: _load_error(0.004 * steps * w.states[:, m - 1, None, 3:6].double()))
    response, logged, _ = measure(bias, reference, windows, CFG)
    assert logged["load position"].value > 2 and response["load position"].high < CFG.pays_below

    def still(w) -> torch.Tensor:  # the load stays where it was: no answer to any command
        error = torch.zeros(len(w), N, 13, dtype=torch.float64)
        held = w.states[:, m - 1, None, LOAD_POS].double()
        error[..., LOAD_POS] = held - w.future.states[..., LOAD_POS].double()
        return error

    response, _, _ = measure(Shifted(still), reference, windows, CFG)
    assert response["load position"].low > 1.5
    assert verdict_of(response, CFG) == NOT


def test_the_verdict_needs_the_load_better_and_the_vehicle_not_worse() -> None:
    """May pay: the load's score clearly below ``pays_below`` and the vehicle's below
    ``vehicle_below`` (a network that learned this vehicle's inner loops)."""
    far, better, same = Ratio(0.2, 0.1, 0.3), Ratio(0.5, 0.4, 0.6), Ratio(1.0, 0.95, 1.05)
    assert verdict_of({"load position": better, "vehicle position": far}, CFG) == PAYS
    assert verdict_of({"load position": far, "vehicle position": better}, CFG) == NOT
    assert verdict_of({"load position": better, "vehicle position": same}, CFG) == NOT
    assert verdict_of({"load position": same, "vehicle position": far}, CFG) == NOT
    straddles = Ratio(0.45, 0.3, 0.6)  # below 0.5 itself, but not clearly
    assert verdict_of({"load position": better, "vehicle position": straddles}, CFG) == NOT


def test_the_share_unexplained_is_scale_free() -> None:
    rng = np.random.default_rng(0)
    true = rng.standard_normal(500)
    for scale in (0.3, 1.0, 4.0):
        model = scale * true
        sums = np.array([model @ true, model @ model, true @ true])
        assert unexplained(sums) == pytest.approx(0.0, abs=1e-12)
    assert unexplained(np.array([0.0, 0.0, true @ true])) == 1.0  # no predicted effect
    noisy = true + rng.standard_normal(500)  # rho^2 = 1/2 in expectation
    sums = np.array([noisy @ true, noisy @ noisy, true @ true])
    assert 0.4 < unexplained(sums) < 0.6


def test_the_bootstrap_interval_holds_the_ratio() -> None:
    rng = np.random.default_rng(0)
    physics = rng.uniform(1, 2, (12, 1))
    network = 0.25 * physics * rng.uniform(0.8, 1.2, (12, 1))
    ratio = bootstrap_ratio(network, physics, lambda s: np.sqrt(s[..., 0]), CFG)
    assert ratio.low <= ratio.value <= ratio.high
    assert 0.4 < ratio.value < 0.6 and ratio.high - ratio.low < 0.2


def test_too_few_flights_are_refused(windows) -> None:
    two = windows[windows.flight < 2]
    physics = PhysicsModel(VehicleParams())
    with pytest.raises(ValueError, match="at least 3"):
        measure(physics, physics, two, CFG)


def test_the_verdict_beside_the_run_and_the_warning(tmp_path: Path, windows) -> None:
    """``record_verdict`` -> preflight.json; ``verdict_note`` warns at that horizon only when
    it does not pay, and ``control``'s notes carry it."""
    from slungload.evaluation.preflight import PreflightResult

    run = tmp_path / "run"
    run.mkdir()
    ratio, vehicle = Ratio(1.02, 0.95, 1.1), Ratio(0.2, 0.1, 0.3)
    response = {"load position": ratio, "vehicle position": vehicle}
    result = PreflightResult(model=str(run), data="d", split="test", horizon=N, flights=6,
                             windows=len(windows), dt=0.03, response=response,
                             logged=response, curves={}, verdict=NOT, config=CFG)  # fmt: skip
    path = record_verdict(result)
    assert path == run / VERDICTS_FILE
    note = verdict_note(run, N)
    assert note is not None and "1.020 [0.950, 1.100]" in note
    assert verdict_note(run, N + 1) is None
    record_verdict(replace(result, horizon=N + 1, verdict=PAYS))
    assert verdict_note(run, N + 1) is None and verdict_note(run, N) == note
    (run / VERDICTS_FILE).write_text("{not json")
    assert verdict_note(run, N) is None


def test_the_report_says_when_the_flights_cannot_tell_the_score_from_the_bound(windows) -> None:
    """A load score below ``pays_below`` whose interval reaches past it: "does not pay", and the
    report says the held-out flights are too few to tell; not where the score is clear. A
    vehicle score that fails: the verdict names it."""
    from slungload.evaluation.preflight import PreflightResult, render

    learned = Ratio(0.1, 0.05, 0.15)

    def report(load: Ratio, vehicle: Ratio = learned) -> str:
        response = {"load position": load, "vehicle position": vehicle}
        result = PreflightResult(model="run", data="d", split="test", horizon=N, flights=3,
                                 windows=len(windows), dt=0.03, response=response,
                                 logged=response, curves={"network": [0.7], "physics": [0.9]},
                                 verdict=verdict_of(response, CFG), config=CFG)  # fmt: skip
        return render(result)

    straddles = report(Ratio(0.77, 0.5, 0.96))
    assert NOT in straddles and "3 held-out flights cannot tell it from 0.9" in straddles
    for clear in (Ratio(0.5, 0.4, 0.6), Ratio(0.95, 0.9, 1.0)):
        assert "cannot tell" not in report(clear)
    other = report(Ratio(0.5, 0.4, 0.6), Ratio(0.7, 0.6, 0.8))  # a network of another vehicle?
    assert f"{NOT} (leaves 0.700 [0.600, 0.800]" in other and "learned this vehicle" in other


def test_control_warns_from_the_check(tiny_run, tmp_path: Path) -> None:
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run.out, run)
    assert not any("pre-flight" in n for n in model_notes(run, 4))
    (run / VERDICTS_FILE).write_text('{"4": {"verdict": "does not pay", "ratio": [1.1, 1.0, '
                                     '1.2], "pays_below": 0.9, "data": "d"}}')  # fmt: skip
    (alone,) = [n for n in model_notes(run, 4) if "pre-flight check" in n]
    (paired,) = [n for n in model_notes(run, 4, paired=True) if "pre-flight check" in n]
    assert "--with-physics lets the physics model veto" in alone  # the remedy
    assert "prices its plans too" in paired and "with --trust-window 0 it cannot" in paired
    (audited,) = [n for n in model_notes(run, 4, paired=True, trust_window=3)
                  if "pre-flight check" in n]  # fmt: skip
    assert "alone while the network predicts the last 3 steps" in audited
    (longer,) = [n for n in model_notes(run, 4, paired=True, trust_window=7)
                 if "pre-flight check" in n]  # fmt: skip
    assert "the last 4 steps" in longer  # the window is at most the plans' N
    assert "cannot veto" not in audited  # already done


def test_the_command_writes_its_report_and_refuses_bad_input(
    tiny_run, tmp_path: Path, run_cli
) -> None:
    names = [f"t{i}" for i in range(4)]
    data = write_dataset(tmp_path / "data", {n: 50 for n in names},
                         {"train": [], "val": [], "test": names}, physics=True)  # fmt: skip
    run = tmp_path / "run"
    import shutil

    shutil.copytree(tiny_run.out, run)
    code, out, err = run_cli("check", run, "--data", data, "--horizon", "6", "--out",
                             tmp_path / "report")  # fmt: skip
    assert code == 0, err
    assert "at N = 6" in out and (run / VERDICTS_FILE).is_file()
    for name in ("check.md", "check.json", "check.png"):
        assert (tmp_path / "report" / name).is_file()
    code, _, err = run_cli("check", run, "--horizon", "6", "--split", "test")  # 2 flights
    assert code == 2 and "at least 3" in err
    code, out, err = run_cli("check", run, "--horizon", "6", "--out", tmp_path / "own")
    report = (tmp_path / "own" / "check.md").read_text()
    assert code == 0, err  # by default on val and test together: 3 flights
    assert "held-out flights (val and test)" in report and ": 3 flights" in report
    code, _, err = run_cli("check", tmp_path / "nowhere", "--data", data)
    assert code == 2 and "nowhere" in err


def test_a_network_that_diverges_does_not_pay_and_one_that_always_does_is_refused(
    tiny_run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Predictions that are not finite on one flight's windows: "does not pay", saying on how
    many, scored on the rest; on every flight: a clear error, not a score of 1."""
    from slungload.evaluation import preflight

    names = [f"t{i}" for i in range(4)]
    data = write_dataset(tmp_path / "data", {n: 50 for n in names},
                         {"train": [], "val": [], "test": names}, physics=True)  # fmt: skip
    cfg = PreflightConfig(horizon=6, split="test", resamples=200)

    def nan_on(flights: int):
        def error(windows) -> torch.Tensor:
            out = torch.zeros(*windows.future.states.shape, dtype=torch.float64)
            out[windows.flight < flights] = float("nan")
            return out

        return lambda run: Shifted(error)

    monkeypatch.setattr(preflight, "load_prediction_model", nan_on(1))
    result = preflight.check(tiny_run.out, data, cfg=cfg)
    assert result.verdict == NOT and "not finite on" in result.summary()
    assert np.isfinite(result.response["load position"].value)
    monkeypatch.setattr(preflight, "load_prediction_model", nan_on(4))
    with pytest.raises(ValueError, match="not finite on"):
        preflight.check(tiny_run.out, data, cfg=cfg)


def test_physics_flies_with_the_datasets_own_constants(
    tiny_run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Flights of another vehicle (its vehicle.json): physics with that vehicle's constants,
    the model the user's physics MPC flies, not the run's; without a vehicle.json, the run's."""
    from slungload.config import to_dict
    from slungload.evaluation import preflight
    from slungload.fileio import write_json

    seen = []

    def physics(params: VehicleParams) -> PhysicsModel:
        seen.append(params)
        return PhysicsModel(params)

    monkeypatch.setattr(preflight, "PhysicsModel", physics)
    monkeypatch.setattr(preflight, "load_prediction_model", lambda run: Shifted(lambda w: 0.0))
    cfg = PreflightConfig(horizon=6, split="test", resamples=200)
    names = [f"t{i}" for i in range(4)]
    for folder, vehicle in (("other", True), ("bare", False)):
        data = write_dataset(tmp_path / folder, {n: 50 for n in names},
                             {"train": [], "val": [], "test": names}, physics=True,
                             vehicle=vehicle)  # fmt: skip
        if vehicle:
            write_json(data / "vehicle.json", to_dict(VehicleParams(cable_length=1.0)))
        preflight.check(tiny_run.out, data, cfg=cfg)
    assert seen[0].cable_length == 1.0
    assert seen[1].cable_length == VehicleParams().cable_length  # the run's (paper) constants


def test_which_datasets_count_as_unexcited(tmp_path: Path) -> None:
    from slungload.fileio import write_json
    from slungload.vehicle_file import simulated_without_excitation

    sim = {"excitation": {"thrust_std": 0.0, "rate_std": [0.0, 0.0, 0.0], "tau": 0.15}}
    cases = {
        "pid": ({"sim": sim}, True),
        "excited": ({"sim": {"excitation": {"thrust_std": 1.0, "rate_std": [0.5] * 3}}}, False),
        "older": ({"sim": {}}, True),  # written before excitation existed
        "recorded": ({"sim": sim, "recorded": [{"model": "x"}]}, False),
        "real": ({"mass_quad": 1.35}, False),
    }
    for name, (content, expected) in cases.items():
        write_json(tmp_path / name / "vehicle.json", content)
        assert simulated_without_excitation(tmp_path / name) is expected, name
    assert simulated_without_excitation(tmp_path / "nowhere") is False


def test_a_network_trained_without_excitation_does_not_pay_whatever_its_score(
    tiny_run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import slungload.evaluation.preflight as preflight

    names = [f"t{i}" for i in range(4)]
    data = write_dataset(tmp_path / "data", {n: 50 for n in names},
                         {"train": [], "val": [], "test": names}, physics=True)  # fmt: skip
    monkeypatch.setattr(preflight, "simulated_without_excitation", lambda folder: True)
    result = preflight.check(tiny_run.out, data, cfg=replace(CFG, horizon=6))
    assert result.verdict == NOT and "without input excitation" in result.summary()


def test_an_export_carries_the_verdict_and_fly_warns(
    tiny_run, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``export --for-mpc`` copies the run's verdicts into the sidecar; ``fly`` warns from
    them at the MPC's horizon (the bridge itself replaced: no flight needed)."""
    import shutil

    import slungload.autopilot.bridge as bridge
    from slungload.autopilot.config import BridgeConfig
    from slungload.deploy.candidates import export_for_mpc
    from slungload.deploy.sidecar import COMPILED, read_sidecar

    run = tmp_path / "run"
    shutil.copytree(tiny_run.out, run)
    found = {"verdict": NOT, "ratio": [1.1, 1.0, 1.2], "pays_below": 0.9, "data": "d"}
    (run / VERDICTS_FILE).write_text(f'{{"15": {json.dumps(found)}}}')
    out = export_for_mpc(run, tmp_path, horizon=4, format="compiled").model
    assert read_sidecar(out, COMPILED)["preflight"] == {"15": found}

    class Flown:
        def __init__(self, *args, **kwargs) -> None:
            pass

        def run(self) -> str:
            return "flown"

    monkeypatch.setattr(bridge, "Bridge", Flown)
    config = BridgeConfig()
    assert config.mpc.horizon == 15
    with pytest.warns(UserWarning, match="pre-flight check"):
        assert bridge.fly(out, config) == "flown"
