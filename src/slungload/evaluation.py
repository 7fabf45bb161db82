"""Evaluation on the test flights: errors per state group, MAE per horizon step with quartiles,
the RMSE table, batch-1 inference time, and the paper's numbers to compare with.

Read top to bottom: the paper's numbers, predictors (physics-only and network, one signature
over a batch of windows), error metrics, timing, the typed ``Report``, and the entry
``evaluate`` that loads runs and a dataset, runs every predictor at every horizon and (with
``out``) writes the report (``report.write_report``).

Metrics (the paper's Section IV-B), per group g of ``state.GROUPS`` (position, velocity,
quaternion, load position), with W test windows and horizon N::

    e_g[j, k] = || x_hat_g[j, k] - x_g[j, k] ||       (quaternion: || q_hat (x) q^-1 - q_id ||)
    MAE_g[k]  = mean_j e_g[j, k], with Q1 / Q3 the 25th / 75th percentiles over j
    RMSE_g    = sqrt( sum_{j,k} e_g[j, k]^2 / (W N) ),  combined = sum of the four RMSE_g

The quaternion error is the paper's: it is not sign-invariant (q and -q differ by 2); the
data are sign-continuous (``state.quat_continuous``) and both predictors continue the sign of
the last measured quaternion, so no sign ambiguity arises. Network quaternions are normalised
before the error is taken (the slack variables are ignored).

Horizon step k = 1 ... N predicts x_{M-1+k}, i.e. k dt seconds ahead.
"""

from __future__ import annotations

import dataclasses
import json
import platform
import statistics
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import torch
from torch import Tensor, nn

from . import predictor as facade  # its ``Predictor`` is not this module's protocol of that name
from .checkpoints import LoadedModel, load_checkpoint
from .compiled import CompiledPredictor
from .config import VehicleParams, WindowConfig, to_dict
from .data import load_dataset
from .model import SlungLoadNet
from .physics import rollout
from .state import GROUPS, QUAT, quat_error, quat_normalize
from .windows import Windows, make_windows

COMBINED = "combined"
METRIC_KEYS = (*GROUPS, COMBINED)  # columns of the RMSE table
PHYSICS = "physics"  # label of the physics-only open-loop predictor

# --- the paper's numbers (Tables I and II) ------------------------------------------------

PAPER_RMSE_N50: dict[str, dict[str, float]] = {
    "physics": {
        "position": 0.458,
        "velocity": 0.924,
        "quaternion": 0.073,
        "load_position": 0.424,
        "combined": 1.879,
    },
    "no-physics": {
        "position": 0.153,
        "velocity": 0.193,
        "quaternion": 0.033,
        "load_position": 0.182,
        "combined": 0.561,
    },
    "no-slack": {
        "position": 0.153,
        "velocity": 0.200,
        "quaternion": 0.034,
        "load_position": 0.184,
        "combined": 0.571,
    },
    "proposed": {
        "position": 0.136,
        "velocity": 0.175,
        "quaternion": 0.032,
        "load_position": 0.166,
        "combined": 0.508,
    },
}  # fmt: skip  (RMSE over the test set, N = 50; m, m/s, -, m)
PAPER_MODEL_NAMES = {
    "physics": "Physics",
    "no-physics": "Proposed model (w/o physics)",
    "no-slack": "Proposed model (w/o slack vars)",
    "proposed": "Proposed model",
}


@dataclass(frozen=True)
class PaperTiming:
    """One cell pair of the paper's Table II: batch-1 inference time."""

    device: str
    history: int  # M
    horizon: int  # N
    mean_ms: float
    std_ms: float


PAPER_TIMING: tuple[PaperTiming, ...] = (
    PaperTiming("NVIDIA RTX 3090", 50, 25, 10.76, 0.53),
    PaperTiming("NVIDIA RTX 3090", 50, 50, 21.24, 0.99),
    PaperTiming("NVIDIA Jetson Orin Nano", 50, 25, 59.44, 0.26),
    PaperTiming("NVIDIA Jetson Orin Nano", 50, 50, 115.26, 0.59),
)

# --- predictors ---------------------------------------------------------------------------


class Predictor(Protocol):
    """Predicts the N future states of a batch of windows.

    windows: states (W, M+N, 13), inputs (W, M+N, 4), aux (W, M+N, 6); only the history, the
    inputs and the aux at the last history step may be used. Returns (W, N, 13)
    x_hat_M ... x_hat_{M+N-1}, physical units, unit quaternion w-x-y-z.
    """

    def __call__(self, windows: Windows) -> Tensor: ...


@dataclass
class PhysicsPredictor:
    """Open-loop physics-only prediction (the paper's "physics" row).

    Rolls ``physics.rollout`` from the last measured state x_{M-1} with its estimated
    (vL, Omega_L) and the true inputs u_{M-1} ... u_{M+N-2}; float64 inside.
    """

    params: VehicleParams
    batch_size: int = 8192

    def __call__(self, windows: Windows) -> Tensor:
        m, n = windows.window.history, windows.window.horizon
        out = []
        for i in range(0, len(windows), self.batch_size):
            w = windows[i : i + self.batch_size]
            x0 = w.states[:, m - 1].double()
            aux0 = w.aux[:, m - 1].double()
            inputs = w.inputs[:, m - 1 : m + n - 1].double()
            states, _ = rollout(x0, aux0, inputs, self.params)
            out.append(states.to(windows.states.dtype))
        return _cat(out, windows)


@dataclass
class NetworkPredictor:
    """A trained network (``forward(x_hist, u_hist, u_future) -> Prediction``), batched.

    The network runs in eval mode under ``torch.inference_mode``; its quaternion is normalised
    and its slack variables are ignored.
    """

    model: nn.Module
    batch_size: int = 1024
    device: str | torch.device = "cpu"

    def __call__(self, windows: Windows) -> Tensor:
        m = windows.window.history
        self.model.eval()
        self.model.to(self.device)
        out = []
        with torch.inference_mode():
            for i in range(0, len(windows), self.batch_size):
                w = windows[i : i + self.batch_size].to(self.device)
                pred = self.model(w.states[:, :m], w.inputs[:, :m], w.inputs[:, m:])
                out.append(unit_quaternion(pred.states).float().cpu())
        return _cat(out, windows)


def unit_quaternion(states: Tensor) -> Tensor:
    """States (..., 13) with the quaternion block normalised (evaluation only)."""
    out = states.clone()
    out[..., QUAT] = quat_normalize(states[..., QUAT])
    return out


def _cat(parts: list[Tensor], windows: Windows) -> Tensor:
    if parts:
        return torch.cat(parts)
    return windows.states.new_zeros(0, windows.window.horizon, windows.states.shape[-1])


# --- errors and metrics ---------------------------------------------------------------------


def group_errors(pred: Tensor, true: Tensor) -> dict[str, Tensor]:
    """Error norm per group: pred, true (W, N, 13) -> {group: (W, N)}, float64.

    Quaternion: || q_hat (x) q^-1 - q_id ||; the others: the Euclidean norm of the difference.
    """
    if pred.shape != true.shape:
        raise ValueError(f"prediction {tuple(pred.shape)} and truth {tuple(true.shape)} differ")
    pred, true = pred.double(), true.double()
    errors = {}
    for name, sl in GROUPS.items():
        if sl == QUAT:
            diff = quat_error(pred[..., sl], true[..., sl])
        else:
            diff = pred[..., sl] - true[..., sl]
        errors[name] = diff.norm(dim=-1)
    return errors


@dataclass(frozen=True)
class Curve:
    """MAE of one group per horizon step k = 1 ... N over the test windows, with quartiles.

    Arrays (N,) in the group's unit.
    """

    mean: np.ndarray
    q1: np.ndarray  # 25th percentile over windows
    median: np.ndarray
    q3: np.ndarray  # 75th percentile over windows

    def to_dict(self) -> dict[str, list[float]]:
        return {k: getattr(self, k).tolist() for k in ("mean", "q1", "median", "q3")}


def mae_curve(error: Tensor) -> Curve:
    """error (W, N) -> MAE_k and quartiles over the W windows, each (N,)."""
    e = error.detach().cpu().double().numpy()
    if e.shape[0] == 0:
        raise ValueError("no test windows: cannot compute an MAE")
    q1, median, q3 = np.percentile(e, [25.0, 50.0, 75.0], axis=0)
    return Curve(mean=e.mean(axis=0), q1=q1, median=median, q3=q3)


def rmse(error: Tensor) -> float:
    """sqrt(sum ||e||^2 / (W N)) of an error-norm array (W, N)."""
    return float(error.double().square().mean().sqrt())


@dataclass(frozen=True)
class Metrics:
    """Errors of one predictor on one set of windows."""

    horizon: int  # N
    windows: int  # W
    rmse: dict[str, float]  # METRIC_KEYS -> RMSE (group unit); "combined" = sum of the groups
    curves: dict[str, Curve]  # group -> MAE curve

    def to_dict(self) -> dict[str, Any]:
        return {
            "horizon": self.horizon,
            "windows": self.windows,
            "rmse": dict(self.rmse),
            "mae": {g: c.to_dict() for g, c in self.curves.items()},
        }


def metrics_from_errors(errors: Mapping[str, Tensor]) -> Metrics:
    """{group: (W, N)} error norms -> RMSE per group and combined, MAE curves."""
    values = {g: rmse(errors[g]) for g in GROUPS}
    values[COMBINED] = sum(values[g] for g in GROUPS)
    first = errors[next(iter(GROUPS))]
    return Metrics(
        horizon=int(first.shape[1]),
        windows=int(first.shape[0]),
        rmse=values,
        curves={g: mae_curve(errors[g]) for g in GROUPS},
    )


def compute_metrics(pred: Tensor, windows: Windows) -> Metrics:
    """Metrics of predictions (W, N, 13) against the windows' future states."""
    return metrics_from_errors(group_errors(pred, windows.future.states))


# --- inference time -------------------------------------------------------------------------


@dataclass(frozen=True)
class Timing:
    """Batch-1 inference time of one model: mean and sample std over ``repeats`` calls."""

    history: int  # M
    horizon: int  # N
    mean_ms: float
    std_ms: float
    repeats: int
    threads: int  # torch.get_num_threads() during the measurement
    device: str  # e.g. "cpu (x86_64)" or the CUDA device name
    backend: str = "torch eager"  # or "numba compiled" (``time_compiled``)


def time_inference(
    model: nn.Module,
    windows: Windows,
    *,
    repeats: int = 100,
    warmup: int = 10,
    device: str | torch.device = "cpu",
) -> Timing:
    """Time ``model`` on the first window of ``windows`` (batch 1), after ``warmup`` calls."""
    m, w = _timing_window("time_inference", windows, repeats)
    w = w.to(device)
    args = (w.states[:, :m], w.inputs[:, :m], w.inputs[:, m:])
    dev = torch.device(device)
    sync: Callable[[], None] = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    model.eval()
    model.to(dev)
    mean_ms, std_ms = _time_calls(lambda: model(*args), repeats, warmup, sync)
    return Timing(
        history=m,
        horizon=windows.window.horizon,
        mean_ms=mean_ms,
        std_ms=std_ms,
        repeats=repeats,
        threads=torch.get_num_threads(),
        device=device_name(dev),
    )


def time_compiled(
    compiled: CompiledPredictor, windows: Windows, *, repeats: int = 100, warmup: int = 10
) -> Timing:
    """Time ``compiled.predict`` on the first window of ``windows`` (batch 1, one thread),
    numpy in and out in the file layout, as a controller calls it."""
    m, w = _timing_window("time_compiled", windows, repeats)
    history = torch.cat([facade.states_to_file(w.states[:, :m]), w.inputs[:, :m]], -1)[0].numpy()
    future = w.inputs[0, m:].numpy()
    mean_ms, std_ms = _time_calls(lambda: compiled.predict(history, future), repeats, warmup)
    return Timing(
        history=m,
        horizon=windows.window.horizon,
        mean_ms=mean_ms,
        std_ms=std_ms,
        repeats=repeats,
        threads=1,
        device=device_name(torch.device("cpu")),
        backend="numba compiled",
    )


def _timing_window(caller: str, windows: Windows, repeats: int) -> tuple[int, Windows]:
    """History length M and the first window (batch 1) to time on, after checking both."""
    if repeats < 2:
        raise ValueError(f"{caller}: repeats must be >= 2, got {repeats}")
    if len(windows) == 0:
        raise ValueError(f"{caller}: no window to time on")
    return windows.window.history, windows[0]


def _time_calls(
    call: Callable[[], object],
    repeats: int,
    warmup: int,
    sync: Callable[[], None] = lambda: None,
) -> tuple[float, float]:
    """Mean and standard deviation, ms, of ``repeats`` calls after ``warmup`` untimed ones;
    ``sync`` waits for the device before and after each call (CUDA runs asynchronously)."""
    times = []
    with torch.inference_mode():
        for i in range(warmup + repeats):
            sync()
            t0 = time.perf_counter()
            call()
            sync()
            if i >= warmup:
                times.append(1e3 * (time.perf_counter() - t0))
    return statistics.fmean(times), statistics.stdev(times)


def _compiled(model: nn.Module | None, window: WindowConfig, params: VehicleParams):
    """A ``CompiledPredictor`` for a network it supports, else None (then only eager timing)."""
    if not isinstance(model, SlungLoadNet):
        return None
    try:
        return CompiledPredictor(facade.Predictor(model, window, params, "timing"))
    except ValueError:  # another layer structure than the paper's
        return None


def device_name(device: torch.device) -> str:
    """A readable name of the device the timings were taken on."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return f"cpu ({cpu_model() or platform.machine()})"


def cpu_model() -> str | None:
    """The CPU model name from /proc/cpuinfo (Linux), or None."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


# --- test windows per horizon ---------------------------------------------------------------


def horizon_windows(dataset: Any, *, history: int, horizons: Sequence[int]) -> dict[int, Windows]:
    """Test windows for each horizon N, cut with stride 1 from the test flights of ``dataset``.

    dataset: a ``data.Dataset`` (``.splits["test"].names``, ``.flights[name].states`` ...).
    Every horizon uses the same flights; a flight shorter than M + N gives no window at N.
    """
    test = dataset.splits["test"]
    flights = [dataset.flights[name] for name in test.names if name in dataset.flights]
    if not flights:
        raise ValueError("evaluate: the dataset has no test flight")
    return {
        n: make_windows(flights, WindowConfig(history=history, horizon=n, stride=1))
        for n in horizons
    }


# --- the report --------------------------------------------------------------------------


@dataclass(frozen=True)
class Candidate:
    """One predictor to evaluate: ``label`` groups seeds of one variant in the table."""

    label: str
    predictor: Predictor
    seed: int | None = None
    model: nn.Module | None = None  # for timing; None for the physics predictor
    info: dict[str, Any] = field(default_factory=dict)  # run path, variant, configs


@dataclass(frozen=True)
class RunResult:
    """Metrics of one candidate (one trained run, or the physics predictor) at one horizon."""

    label: str
    seed: int | None
    metrics: Metrics


@dataclass(frozen=True)
class RmseRow:
    """One row of the RMSE table: mean and std across the seeds of one label."""

    label: str
    horizon: int
    seeds: int  # runs averaged
    mean: dict[str, float]  # METRIC_KEYS -> mean RMSE
    std: dict[str, float]  # METRIC_KEYS -> sample std across seeds (0 for one seed)


@dataclass(frozen=True)
class TimingResult:
    label: str
    seed: int | None
    timing: Timing


@dataclass(frozen=True)
class Example:
    """One test window for the time-series and 3D figures.

    flight_states (T, 13) the whole flight (as far as the windows cover it); window_states
    (M+N, 13) the window from ``start``; predictions: label -> (N, 13).
    """

    flight: str
    start: int  # first step of the window in the flight
    history: int  # M
    flight_states: np.ndarray
    window_states: np.ndarray
    predictions: dict[str, np.ndarray]


@dataclass(frozen=True)
class Report:
    """Everything ``evaluate`` measured; ``report.write_report`` turns it into files."""

    dataset: str  # folder of the flights
    test_flights: tuple[str, ...]
    params: VehicleParams
    history: int  # M
    training_horizon: int  # N used in training (the dashed line in the MAE figures)
    horizons: tuple[int, ...]
    labels: tuple[str, ...]  # in display order, physics first
    results: tuple[RunResult, ...]  # per candidate and horizon
    table: tuple[RmseRow, ...]  # per label and horizon
    curves: dict[str, dict[int, dict[str, Curve]]]  # label -> N -> group -> MAE pooled over seeds
    timings: tuple[TimingResult, ...]
    example: Example | None
    models: tuple[dict[str, Any], ...]  # per trained run: label, seed, run, configs
    environment: dict[str, Any]  # package and torch versions, threads, device

    @property
    def dt(self) -> float:
        return self.params.dt

    def row(self, label: str, horizon: int) -> RmseRow | None:
        """The table row of ``label`` at ``horizon``, or None."""
        for r in self.table:
            if r.label == label and r.horizon == horizon:
                return r
        return None

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly content (``report.json``)."""
        ex = self.example
        return {
            "dataset": self.dataset,
            "test_flights": list(self.test_flights),
            "params": to_dict(self.params),
            "history": self.history,
            "training_horizon": self.training_horizon,
            "horizons": list(self.horizons),
            "labels": list(self.labels),
            "results": [
                {"label": r.label, "seed": r.seed, **r.metrics.to_dict()} for r in self.results
            ],
            "table": [dataclasses.asdict(r) for r in self.table],
            "timings": [
                {"label": t.label, "seed": t.seed, **dataclasses.asdict(t.timing)}
                for t in self.timings
            ],
            "example": None
            if ex is None
            else {"flight": ex.flight, "start": ex.start, "history": ex.history},
            "models": list(self.models),
            "environment": dict(self.environment),
            "paper": {
                "rmse_n50": PAPER_RMSE_N50,
                "timing": [dataclasses.asdict(t) for t in PAPER_TIMING],
            },
        }


def table_rows(results: Sequence[RunResult]) -> tuple[RmseRow, ...]:
    """Mean and std across seeds of the RMSE, per label and horizon (first-seen order)."""
    groups: dict[tuple[str, int], list[Metrics]] = {}
    for r in results:
        groups.setdefault((r.label, r.metrics.horizon), []).append(r.metrics)
    rows = []
    for (label, horizon), runs in groups.items():
        vals = {k: [m.rmse[k] for m in runs] for k in METRIC_KEYS}
        rows.append(
            RmseRow(
                label=label,
                horizon=horizon,
                seeds=len(runs),
                mean={k: statistics.fmean(v) for k, v in vals.items()},
                std={k: statistics.stdev(v) if len(v) > 1 else 0.0 for k, v in vals.items()},
            )
        )
    return tuple(rows)


def pick_example(windows: Windows) -> tuple[int, int]:
    """A deterministic example window: the middle window of the flight with the most windows.

    Returns (index into ``windows``, flight index).
    """
    if len(windows) == 0:
        raise ValueError("no test windows to pick an example from")
    counts = torch.bincount(windows.flight)
    flight = int(torch.argmax(counts))
    idx = torch.nonzero(windows.flight == flight).flatten()
    return int(idx[len(idx) // 2]), flight


def flight_from_windows(windows: Windows, flight: int) -> np.ndarray:
    """States (T, 13) of one flight pieced together from its windows (steps they cover)."""
    idx = torch.nonzero(windows.flight == flight).flatten()
    starts = windows.start[idx]
    length = windows.window.length
    out = np.full((int(starts.max()) + length, windows.states.shape[-1]), np.nan)
    for i, s in zip(idx.tolist(), starts.tolist(), strict=True):
        out[s : s + length] = windows.states[i].double().numpy()
    return out


def evaluate_predictors(
    candidates: Sequence[Candidate],
    windows: Mapping[int, Windows],
    *,
    params: VehicleParams,
    training_horizon: int,
    dataset: str = "",
    flights: Mapping[str, np.ndarray] | None = None,
    timing: bool = True,
    timing_repeats: int = 100,
    device: str | torch.device = "cpu",
    progress: bool = False,
    environment: Mapping[str, Any] | None = None,
) -> Report:
    """Run every candidate on the windows of every horizon and collect a ``Report``.

    windows: N -> test windows cut with horizon N (same flights, same M). flights: optional
    name -> states (T, 13) for the example figure (pieced from windows otherwise).
    """
    if not candidates:
        raise ValueError("evaluate: nothing to evaluate")
    if not windows:
        raise ValueError("evaluate: no horizon to evaluate")
    horizons = tuple(sorted(windows))
    histories = {w.window.history for w in windows.values()}
    if len(histories) != 1:
        raise ValueError(f"evaluate: windows of different histories M {sorted(histories)}")
    history = histories.pop()
    labels = tuple(dict.fromkeys(c.label for c in candidates))

    jobs = [(c, n) for n in horizons for c in candidates]
    bar = _progress(len(jobs), progress)
    results: list[RunResult] = []
    pooled: dict[tuple[str, int], list[dict[str, Tensor]]] = {}
    predictions: dict[tuple[int, int], Tensor] = {}  # (candidate, N) -> (W, N, 13)
    for c, n in jobs:
        bar.set_description(f"{c.label} N={n}")
        pred = c.predictor(windows[n])
        errors = group_errors(pred, windows[n].future.states)
        results.append(RunResult(c.label, c.seed, metrics_from_errors(errors)))
        pooled.setdefault((c.label, n), []).append(errors)
        predictions[(id(c), n)] = pred
        bar.update()
    bar.close()

    curves: dict[str, dict[int, dict[str, Curve]]] = {}
    for (label, n), parts in pooled.items():
        joined = {g: torch.cat([p[g] for p in parts]) for g in GROUPS}
        curves.setdefault(label, {})[n] = {g: mae_curve(joined[g]) for g in GROUPS}

    example = _example(candidates, windows[horizons[-1]], predictions, horizons[-1], flights)

    timings: list[TimingResult] = []
    if timing:
        for c in candidates:
            if c.model is None:
                continue
            for n in horizons:
                t = time_inference(c.model, windows[n], repeats=timing_repeats, device=device)
                timings.append(TimingResult(c.label, c.seed, t))
            # The batch-1 deployment path (one CPU thread) beside the eager network.
            compiled = _compiled(c.model, windows[horizons[0]].window, params)
            for n in horizons if compiled is not None else ():
                t = time_compiled(compiled, windows[n], repeats=timing_repeats)
                timings.append(TimingResult(c.label, c.seed, t))

    test_flights = windows[horizons[0]].names
    env = {
        "torch": torch.__version__,
        "threads": torch.get_num_threads(),
        "device": device_name(torch.device(device)),
        **(environment or {}),
    }
    return Report(
        dataset=dataset,
        test_flights=tuple(test_flights),
        params=params,
        history=history,
        training_horizon=training_horizon,
        horizons=horizons,
        labels=labels,
        results=tuple(results),
        table=table_rows(results),
        curves=curves,
        timings=tuple(timings),
        example=example,
        models=tuple({"label": c.label, "seed": c.seed, **c.info} for c in candidates if c.model),
        environment=env,
    )


def _example(
    candidates: Sequence[Candidate],
    windows: Windows,
    predictions: Mapping[tuple[int, int], Tensor],
    horizon: int,
    flights: Mapping[str, np.ndarray] | None,
) -> Example:
    index, flight = pick_example(windows)
    name = windows.names[flight]
    if flights is not None and name in flights:
        flight_states = np.asarray(flights[name], dtype=np.float64)
    else:
        flight_states = flight_from_windows(windows, flight)
    preds: dict[str, np.ndarray] = {}
    for c in candidates:  # the first seed of each label
        preds.setdefault(c.label, predictions[(id(c), horizon)][index].double().numpy())
    return Example(
        flight=name,
        start=int(windows.start[index]),
        history=windows.window.history,
        flight_states=flight_states,
        window_states=windows.states[index].double().numpy(),
        predictions=preds,
    )


class _NoBar:
    def set_description(self, _: str) -> None: ...
    def update(self) -> None: ...
    def close(self) -> None: ...


def _progress(total: int, enabled: bool) -> Any:
    if not enabled:
        return _NoBar()
    from tqdm.auto import tqdm

    return tqdm(total=total, unit="run", leave=False)


# --- entry ----------------------------------------------------------------------------------


def evaluate(
    runs: Sequence[str | Path],
    *,
    data: str | Path | None = None,
    out: str | Path | None = None,
    horizons: Sequence[int] = (25, 50),
    include_physics: bool = True,
    timing: bool = True,
    timing_repeats: int = 100,
    device: str = "cpu",
    batch_size: int = 1024,
    progress: bool = True,
) -> Report:
    """Evaluate trained runs (run folders or ``.ckpt`` files) on the test flights.

    data: dataset folder (default: the one recorded in the first run). Every run must share
    the history M and the vehicle constants. Test windows are cut with stride 1 for each
    horizon in ``horizons`` from the same test flights. Runs of one variant are seeds of one
    label (mean +- std in the table). ``include_physics`` adds the physics-only predictor;
    ``timing`` measures batch-1 inference on ``device`` (torch's current thread count). With
    ``out`` the report is written there (``report.write_report``).
    """
    from . import __version__

    horizons = tuple(sorted({int(n) for n in horizons}))
    if not horizons or horizons[0] < 1:
        raise ValueError(f"evaluate: horizons must be positive step counts, got {horizons}")
    loaded = [load_checkpoint(run) for run in runs]
    if not loaded and not include_physics:
        raise ValueError("evaluate: no run given and the physics predictor switched off")
    folder = data if data is not None else (loaded[0].meta.get("data") if loaded else None)
    if folder is None:
        raise ValueError("evaluate: no dataset folder recorded in the run; pass data=")
    history, params = _common_setup(loaded)

    window = WindowConfig(history=history, horizon=horizons[0], stride=1)
    dataset = load_dataset(folder, window=window, params=params)
    windows = horizon_windows(dataset, history=history, horizons=horizons)
    candidates = []
    if include_physics:
        candidates.append(Candidate(PHYSICS, PhysicsPredictor(dataset.params)))
    for lm in loaded:
        predictor = NetworkPredictor(lm.model, batch_size=batch_size, device=device)
        seed = lm.train_config.seed
        candidates.append(Candidate(lm.variant, predictor, seed, lm.model, _run_info(lm)))
    test = windows[horizons[0]].names
    report = evaluate_predictors(
        candidates,
        windows,
        params=dataset.params,
        training_horizon=loaded[0].window.horizon if loaded else horizons[0],
        dataset=str(dataset.folder),
        flights={name: dataset.flights[name].states for name in test},
        timing=timing,
        timing_repeats=timing_repeats,
        device=device,
        progress=progress,
        environment={"slungload": __version__, "params_source": dataset.params_source},
    )
    if out is not None:
        # report.py builds on this module's types, so it is imported here, not at the top.
        from .report import write_report

        write_report(report, out)
    return report


def _common_setup(loaded: Sequence[LoadedModel]) -> tuple[int, VehicleParams | None]:
    """History M and vehicle constants shared by all runs (defaults without runs)."""
    if not loaded:
        return WindowConfig().history, None
    histories = {lm.window.history for lm in loaded}
    if len(histories) > 1:
        names = ", ".join(f"{lm.path} (M = {lm.window.history})" for lm in loaded)
        raise ValueError(f"evaluate: runs with different histories M cannot share windows: {names}")
    params = {lm.params for lm in loaded}
    if len(params) > 1:
        names = ", ".join(str(lm.path) for lm in loaded)
        raise ValueError(f"evaluate: runs trained with different vehicle constants: {names}")
    return histories.pop(), params.pop()


def _run_info(lm: LoadedModel) -> dict[str, Any]:
    """What the report says about one run: where, what, how long, its configs."""
    info: dict[str, Any] = {
        "run": str(lm.path.parent),
        "checkpoint": str(lm.path),
        "variant": lm.variant,
        "parameters": sum(p.numel() for p in lm.model.parameters()),
        "configs": {k: v for k, v in lm.meta.items() if k != "format"},
    }
    summary = lm.path.parent / "run.json"
    if summary.is_file():
        try:
            run = json.loads(summary.read_text())
            info["epochs"] = run.get("epochs")
            info["stop_reason"] = run.get("stop_reason")
        except (json.JSONDecodeError, AttributeError):
            pass  # the checkpoint alone is enough; run.json only adds the epoch count
    return info
