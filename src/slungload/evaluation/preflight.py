"""The check before flying: will a network beat the physics model *in an MPC*, judged from
held-out flights alone.

Predicting logged flights better is not enough: an MPC compares candidate input sequences
from one state, and MPPI weighs them by their costs' differences at a scale-free temperature,
so what it needs from a model is how each plan's outcome *follows its commands*, up to a
scale (``lab.control.plan_errors`` measures that along the MPC's own plans, where a simulator
can fly them). Flights alone hold no two plans from one state, but flights whose commands
varied (a pilot's, a PID's with noise, ``simulate --excite``, the MPC's own) hold the same
information on average: ``input_part`` fits a displacement over the MPC's N steps on the
window's start state and its commands (out of fold: a held-out flight is explained by a fit
on the others) and keeps the part that follows the commands. Applied to the true and to each
model's predicted displacement it gives the commands' true and predicted effects; the share
of the true effect the predicted one leaves unexplained at its best scale (``unexplained``,
1 - rho^2) is the model's *response score*. A model that ignores its commands scores 1
however well it predicts the flights; a bias every plan shares does not count.

The verdict (``verdict_of``): the network **may pay** when the flight-bootstrap interval of its
load score relative to physics's lies below ``PreflightConfig.pays_below`` and that of its
vehicle score below ``PreflightConfig.vehicle_below``; otherwise it **does not pay**.
``slungload check`` writes the verdict beside the run (``VERDICTS_FILE``) and ``slungload
control`` warns before flying a network whose check says it does not pay (``verdict_note``).
What it cannot see: where the MPC itself, not its model, limits the flight (a short
horizon; a plant whose unmodelled effects shift every plan alike), a better model buys
little; with a simulator, the oracle says so (``study control --controllers
physics,oracle``). Its agreement with closed-loop flights: docs/BENCHMARKS.md, "The check
before flying".
"""

from __future__ import annotations

import datetime as _dt
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..config import PreflightConfig, VehicleParams, WindowConfig, from_dict
from ..data.dataset import load_dataset
from ..data.windows import Windows
from ..fileio import write_json, write_text
from ..layout import LOAD_POS, LOAD_VEL, POS, QUAT, VEL
from ..models.ensemble import model_meta
from ..models.prediction import PhysicsModel, PredictionModel, load_prediction_model
from ..reporting import markdown_table, model_colors, save_figure
from ..vehicle_file import load_vehicle, simulated_without_excitation
from .verdicts import NOT, PAYS, read_verdicts, verdicts_path
from .windows import horizon_windows, split_name

GROUPS_CHECKED = {"load position": LOAD_POS, "vehicle position": POS}  # the MPC's targets


@dataclass(frozen=True)
class Ratio:
    """A network / physics ratio (of response scores or of RMS errors) with its
    flight-bootstrap interval."""

    value: float
    low: float
    high: float

    def text(self) -> str:
        return f"{self.value:.3f} [{self.low:.3f}, {self.high:.3f}]"


@dataclass(frozen=True)
class PreflightResult:
    """What ``check`` measured on one split at one horizon.

    response / logged: per ``GROUPS_CHECKED`` name, the network's response score (the share
    of the commands' effect left unexplained over steps 1..N) / RMS error, relative to
    physics's (``Ratio``). curves: per model ("network", "physics") the load position's
    response score per step (N,). verdict: ``PAYS`` or ``NOT``: ``verdict_of`` the scores,
    or ``NOT`` for a network trained on simulated flights without input excitation
    (``reason`` says so; ``vehicle_file.simulated_without_excitation``)."""

    model: str
    data: str
    split: str
    horizon: int
    flights: int
    windows: int
    dt: float  # s a step
    response: dict[str, Ratio]
    logged: dict[str, Ratio]
    curves: dict[str, list[float]]
    verdict: str
    config: PreflightConfig
    reason: str | None = None  # a "does not pay" the score did not give

    def why(self) -> str:
        """The verdict's ground, in a clause."""
        if self.reason:
            return self.reason
        (load, pays), (vehicle, learned) = _bounds(self)
        if self.verdict == NOT and load.high < pays:
            return (f"leaves {vehicle.text()} x physics's share of the commands' effect on the "
                    f"vehicle unexplained; may pay where the interval lies below {learned:g}: "
                    "has it learned this vehicle?")  # fmt: skip
        return (
            f"leaves {load.text()} x physics's share of the commands' effect on the load "
            f"unexplained; may pay where the interval lies below {pays:g}"
        )

    def summary(self) -> str:
        return f"{self.model} at N = {self.horizon}: {self.verdict} ({self.why()})"


def _bounds(result: PreflightResult) -> tuple[tuple[Ratio, float], tuple[Ratio, float]]:
    """(load score, its bound), (vehicle score, its bound)."""
    cfg, response = result.config, result.response
    return ((response["load position"], cfg.pays_below),
            (response["vehicle position"], cfg.vehicle_below))  # fmt: skip


def start_features(windows: Windows) -> Tensor:
    """(W, 17) a window's start state as the fit sees it: the vehicle's velocity and attitude
    (quaternion with w >= 0), the load's offset from the vehicle and its estimated velocity,
    and the last command applied (a plant with lags carries it); translation-invariant."""
    m = windows.window.history
    x, u = windows.states[:, m - 1].double(), windows.inputs[:, m - 2].double()
    a = windows.aux[:, m - 1, LOAD_VEL].double()
    quat = x[:, QUAT] * torch.where(x[:, QUAT][:, :1] < 0, -1.0, 1.0)
    return torch.cat([x[:, VEL], quat, x[:, LOAD_POS] - x[:, POS], a, u], dim=1)


def input_basis(n: int, knots: int) -> Tensor:
    """(n, knots) piecewise-linear hat functions over n steps: a plan's commands summarised
    as ``knots`` values per channel, the basis ``control.mppi`` draws its noise on (at most n
    knots; one constant column for n = 1)."""
    knots = min(knots, n)
    if knots < 2:
        return torch.ones(n, 1, dtype=torch.float64)
    centres = torch.linspace(0, n - 1, knots, dtype=torch.float64)
    width = (n - 1) / (knots - 1)
    t = torch.arange(n, dtype=torch.float64)[:, None]
    return (1 - (t - centres[None]).abs() / width).clamp_min(0)


def _standardise(a: Tensor) -> Tensor:
    return (a - a.mean(dim=0)) / a.std(dim=0).clamp_min(1e-9)


def input_part(values: Tensor, windows: Windows, cfg: PreflightConfig) -> Tensor:
    """(W, N, C) the part of ``values`` (W, N, C: displacements per window and step, each
    column fitted on its own) that follows the window's commands, out of fold: per held-out
    flight, a ridge regression fitted on the other flights of the values on the start state
    (``start_features``) and the commands (each channel through ``input_basis``), evaluated
    with the command terms alone (commands centred on the fitting flights' mean)."""
    w, n, _ = values.shape
    basis = input_basis(n, cfg.knots)
    m = windows.window.history  # the plan's commands: u_{M-1} (applied at the last measured
    u = windows.inputs[:, m - 1 : m - 1 + n].double()  # state) ... u_{M+N-2}, (W, N, 4)
    commands = _standardise(torch.einsum("wnc,nk->wck", u, basis).reshape(w, -1))
    states = _standardise(start_features(windows))
    design = torch.cat([torch.ones(w, 1, dtype=torch.float64), states, commands], dim=1)
    first = 1 + states.shape[1]  # the command columns start here
    target = values.reshape(w, -1).double()
    out = torch.zeros_like(target)
    ridge = cfg.ridge * torch.eye(design.shape[1], dtype=torch.float64)
    ridge[0, 0] = 0.0
    for f in windows.flight.unique():
        held = windows.flight == f
        a, b = design[~held], target[~held]
        coef = torch.linalg.solve(a.T @ a + ridge * len(a), a.T @ b)
        centred = design[held, first:] - a[:, first:].mean(dim=0)
        out[held] = centred @ coef[first:]
    return out.reshape(values.shape)


def _flight_sums(values: Tensor, flight: Tensor, flights: int) -> np.ndarray:
    """(F, k) the sums of ``values`` (W, k) over each flight's windows."""
    out = torch.zeros(flights, values.shape[1], dtype=torch.float64)
    return out.index_add_(0, flight, values.double()).numpy()


def unexplained(sums: np.ndarray) -> np.ndarray:
    """1 - rho^2 from sums (..., 3) of (r_model . r_true, r_model^2, r_true^2): the share of
    the commands' true effect a model's predicted effect leaves unexplained at its best
    scale (1 for a model that does not answer its commands; a scale-free score, as MPPI's
    weighting is)."""
    cross, model, true = sums[..., 0], sums[..., 1], sums[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        share = 1.0 - np.square(cross) / (model * true)
    return np.where(model > 0, share, 1.0)


def bootstrap_ratio(
    network: np.ndarray, physics: np.ndarray, stat, cfg: PreflightConfig, seed: int = 0
) -> Ratio:
    """stat(network sums) / stat(physics sums) of per-flight sums (F, k) (``stat`` maps
    (..., k) sums to (...) scores), and its ``cfg.level`` percentile interval over
    ``cfg.resamples`` resamplings of the flights (NaN where physics scores exactly 0)."""
    rng = np.random.default_rng(seed)
    f = len(network)
    weights = rng.multinomial(f, np.full(f, 1.0 / f), size=cfg.resamples).astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        boot = stat(weights @ network) / stat(weights @ physics)
        value = stat(network.sum(axis=0)) / stat(physics.sum(axis=0))
    tail = 50 * (1 - cfg.level)
    low, high = np.percentile(boot, [tail, 100 - tail])
    return Ratio(float(value), float(low), float(high))


def _rms(sums: np.ndarray) -> np.ndarray:
    return np.sqrt(sums[..., 0])


def measure(
    network: PredictionModel,
    physics: PredictionModel,
    windows: Windows,
    cfg: PreflightConfig,
) -> tuple[dict[str, Ratio], dict[str, Ratio], dict[str, list[float]]]:
    """Per ``GROUPS_CHECKED`` group, network / physics with flight-bootstrap intervals: the
    share of the commands' effect left unexplained (``unexplained`` of ``input_part`` of
    predicted and true displacements from the last measured state) and the RMS error; and
    per model the load position's unexplained share per step (N,)."""
    held = windows.flight.unique().numel()
    if held < 3:
        raise ValueError(f"check: {held} held-out flight(s); the commands' effect is fitted "
                         "on the other flights, and needs at least 3")  # fmt: skip
    m, flights = windows.window.history, len(windows.names)
    truth = windows.future.states.double()
    preds = {"network": network.predict_windows(windows).double(),
             "physics": physics.predict_windows(windows).double()}  # fmt: skip
    response, logged, curves = {}, {}, {}
    for group, cols in GROUPS_CHECKED.items():
        last = windows.states[:, m - 1, None, cols].double()
        # one fit for the true displacement (what the commands moved) and each model's
        moved = input_part(torch.cat([truth[..., cols] - last,
                                      *(pred[..., cols] - last for pred in preds.values())],
                                     dim=-1), windows, cfg).split(3, dim=-1)  # fmt: skip
        true = moved[0]
        effect, error = {}, {}
        for (name, pred), model in zip(preds.items(), moved[1:], strict=True):
            per_step = torch.stack(
                [(model * true).sum(-1), model.square().sum(-1), true.square().sum(-1)], dim=-1
            )  # (W, N, 3); fmt: skip
            effect[name] = _flight_sums(per_step.sum(dim=1), windows.flight, flights)
            err = (pred[..., cols] - truth[..., cols]).square().sum(dim=(1, 2))[:, None]
            error[name] = _flight_sums(err, windows.flight, flights)
            if group == "load position":
                curves[name] = unexplained(per_step.sum(dim=0).numpy()).tolist()
        response[group] = bootstrap_ratio(effect["network"], effect["physics"], unexplained, cfg)
        logged[group] = bootstrap_ratio(error["network"], error["physics"], _rms, cfg, seed=1)
    return response, logged, curves


def verdict_of(response: dict[str, Ratio], cfg: PreflightConfig) -> str:
    """``PAYS`` ("may pay") where the network explains the commands' effect on the load
    clearly better than physics (the ratio's upper end below ``cfg.pays_below``) and on the
    vehicle far better (below ``cfg.vehicle_below``); else ``NOT``."""
    load, vehicle = response["load position"], response["vehicle position"]
    return PAYS if load.high < cfg.pays_below and vehicle.high < cfg.vehicle_below else NOT


def check(
    run: str | Path,
    data: str | Path | None = None,
    *,
    cfg: PreflightConfig | None = None,
) -> PreflightResult:
    """The pre-flight check of a run folder, ``.ckpt`` or ensemble folder (its members' mean)
    on a dataset's ``cfg.split`` (default: the run's own dataset) at the MPC horizon
    ``cfg.horizon``, against the physics model with the vehicle's constants, the model the
    user's physics MPC flies: on the run's own dataset the run's (with any it was trained
    with), on another that dataset's ``vehicle.json`` (the run's where it has none)."""
    cfg = cfg or PreflightConfig()
    n, split = cfg.horizon, cfg.split
    meta = model_meta(run)
    folder = data if data is not None else meta.get("data")
    if folder is None:
        raise ValueError(f"{run}: no dataset folder recorded in the run; pass --data")
    history = int(meta["window"]["history"])
    params = from_dict(VehicleParams, meta["params"])
    if meta.get("data") is None or Path(folder).resolve() != Path(meta["data"]).resolve():
        params = load_vehicle(folder) or params
    dataset = load_dataset(folder, window=WindowConfig(history=history, horizon=n, stride=1),
                           params=params)  # fmt: skip
    windows = horizon_windows(dataset, history=history, horizons=(n,), split=split)[n]
    predicted = load_prediction_model(run).predict_windows(windows)
    finite = torch.isfinite(predicted).flatten(1).all(dim=1)
    diverged = int((~finite).sum())
    kept = windows[finite]
    if diverged and kept.flight.unique().numel() < 3:
        raise ValueError(f"check: {run} predicts states that are not finite on {diverged} of "
                         f"{len(windows)} windows of {folder} ({split_name(split)}): it diverges "
                         "there (a network of another vehicle?) and cannot pay")  # fmt: skip
    physics = PhysicsModel(dataset.params)
    response, logged, curves = measure(_Predicted(predicted[finite]), physics, kept, cfg)
    reasons = []
    trained_on = meta.get("data")
    if bool(trained_on) and simulated_without_excitation(trained_on):
        reasons.append(f"trained on {trained_on}, simulated without input excitation: a "
                       "network that learned from a PID's flights alone fails in the states "
                       "its MPC leads it into, whatever its score (docs/control.md)")  # fmt: skip
    if diverged:
        reasons.append(f"its predictions are not finite on {diverged} of {len(windows)} "
                       "windows: it diverges there (scores from the rest)")  # fmt: skip
    return PreflightResult(
        model=str(run), data=str(folder), split=split, horizon=n,
        flights=len(windows.names), windows=len(windows), dt=dataset.params.dt,
        response=response, logged=logged,
        curves=curves, verdict=NOT if reasons else verdict_of(response, cfg), config=cfg,
        reason="; ".join(reasons) or None,
    )  # fmt: skip


@dataclass(frozen=True)
class _Predicted:
    """A model's predictions (W, N, 13) of the windows ``measure`` is given, made once."""

    values: Tensor

    def predict_windows(self, windows: Windows) -> Tensor:
        return self.values


# --- the verdict beside the run, and what control says of it -------------------------------


def record_verdict(result: PreflightResult) -> Path:
    """Add ``result``'s verdict at its horizon to the run's ``VERDICTS_FILE`` (replacing an
    earlier one at that horizon)."""
    path = verdicts_path(result.model)
    found = read_verdicts(result.model)
    r = result.response["load position"]
    found[str(result.horizon)] = {
        "verdict": result.verdict, "ratio": [r.value, r.low, r.high],
        "pays_below": result.config.pays_below, "data": result.data, "split": result.split,
        "date": _dt.date.today().isoformat(), "reason": result.reason, "why": result.why(),
    }  # fmt: skip
    write_json(path, found)
    return path


# --- the report ----------------------------------------------------------------------------


def render(result: PreflightResult) -> str:
    """check.md: the verdict and its evidence."""
    rows = [[g, result.response[g].text(), result.logged[g].text()] for g in GROUPS_CHECKED]
    c, n = result.curves, result.horizon
    thin = [f"The {group}'s score itself lies below {bound:g}, but {result.flights} held-out "
            f"flights cannot tell it from {bound:g}: more held-out flights with varied commands "
            "may turn the verdict either way."
            for group, (r, bound) in zip(("load", "vehicle"), _bounds(result), strict=True)
            if not result.reason and r.value < bound <= r.high]  # fmt: skip
    lines = [
        "# Pre-flight check", "",
        f"**{result.summary()}**", "",
        f"{result.model} against the physics model on the {split_name(result.split)} of "
        f"{result.data}: {result.flights} flights, {result.windows} windows at N = {n}. The "
        "response score is the share of the commands' true effect on a displacement over the "
        "N steps that a model's predicted effect leaves unexplained (each fitted on the start "
        "state and the commands, out of fold by flight; 0 is perfect, 1 a model that ignores "
        "its commands): what an MPC's choice among plans from one state depends on. The "
        f"network may pay when the load's interval lies below {result.config.pays_below:g} and "
        f"the vehicle's below {result.config.vehicle_below:g}.", "",
        markdown_table(["network / physics, steps 1..N",
                        f"response score [{100 * result.config.level:.0f} % flight bootstrap]",
                        "RMS error on the flights"], rows),
        "", *(f"{line}\n" for line in thin),
        f"At step {n}, load position: the network leaves {c['network'][-1]:.3f} of the "
        f"commands' effect unexplained, physics {c['physics'][-1]:.3f}. Flights whose commands "
        "barely varied (a PID's alone) leave little to fit: the verdict then says little. "
        "Where the MPC itself limits the flight (a short horizon; a plant whose unmodelled "
        "effects shift every plan alike) a better score buys little: with a simulator, "
        "`study control --controllers physics,oracle` says how much any model could give.", "",
        "Figure: `check.png`.", "",
    ]  # fmt: skip
    return "\n".join(lines)


def plot(result: PreflightResult, out: Path) -> Path:
    """The load position's response score per step, network and physics."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4))
    ax = fig.subplots()
    steps = np.arange(1, result.horizon + 1) * result.dt
    colors = model_colors(["physics", "network"])
    for name in ("physics", "network"):
        ax.plot(steps, result.curves[name], label=name, color=colors[name])
    ax.set_xlabel("time ahead (s)")
    ax.set_ylabel("share of the commands' effect unexplained")
    ax.set_ylim(0, 1.05)
    ax.set_title(f"load position, N = {result.horizon}: {result.verdict}")
    ax.legend()
    fig.tight_layout()
    return save_figure(fig, out / "check.png")


def write_check(result: PreflightResult, out: str | Path) -> list[Path]:
    """``out/check.md``, ``out/check.json``, ``out/check.png``."""
    out = Path(out).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / "check.md", render(result))
    record = asdict(result)
    write_json(out / "check.json", record)
    return [out / "check.md", out / "check.json", plot(result, out)]
