"""Deployment speed: batch-1 latency, batched throughput and training throughput.

    result = benchmark("runs/proposed")  # or benchmark() for a random paper-size network
    print(result.markdown())

One run measures every backend on the same inputs (windows rolled out by the physics model):

    torch eager     ``predictor.Predictor.predict`` (numpy in, numpy out)
    torch script    the same network traced and frozen with TorchScript
    onnxruntime     ``deploy.OnnxPredictor.predict`` on a file written by ``deploy.export``
    numba compiled  ``compiled.CompiledPredictor.predict`` (one compiled call per window)

all through numpy in and numpy out, so every number includes the facade's checks and the
file-layout conversion a controller would pay. Latency: batch 1, M = 50, N = 25 and 50, on
``threads`` CPU threads (default one), median / p90 / std over many calls. Throughput: batches
of 256 and 1024 windows, windows predicted per second (sampling-based MPC). Training: the
paper-size network, proposed loss (physics term with slack), N = 25, batch 256, Adam, through
``train_windows`` windows (default 10,000, or a measured fraction extrapolated: ``quick``).

Training is timed on a plain loop (forward, loss, backward, clipping, Adam step): the work of
``training.SlungLoadModule.training_step`` without Lightning's own per-step bookkeeping.
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import statistics
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort
import torch
from torch import Tensor

from .._version import __version__
from ..config import (
    DEFAULT_ARCHITECTURE,
    LossWeights,
    ModelConfig,
    TrainConfig,
    VehicleParams,
    WindowConfig,
)
from ..data.windows import Windows, make_windows
from ..evaluation.machine import cpu_model
from ..evaluation.results import PAPER_TIMING
from ..load_state import estimate_load_state
from ..loss import compute_loss, model_config_for
from ..models.base import count_parameters
from ..models.registry import build
from ..physics import hover_thrust, rollout
from ..state import join_state, quat_from_rotvec
from .compiled import CompiledPredictor, unsupported
from .onnx import OnnxPredictor, export
from .predictor import (
    FileLayoutNet,
    Predictor,
    check_inputs,
    states_to_file,
    torch_threads,
    unbatch,
)
from .timing import time_calls

EAGER, SCRIPT, ONNX, COMPILED = "torch eager", "torch script", "onnxruntime", "numba compiled"
BACKENDS = (EAGER, SCRIPT, ONNX, COMPILED)
# Targets of this project's issue (CPU, one thread for latency, the whole 2-core machine for
# training); reported beside the measurements, never asserted.
TARGET_LATENCY_MS = {25: 1.0, 50: 2.0}
PAPER_DEVICES = ("NVIDIA RTX 3090", "NVIDIA Jetson Orin Nano")  # columns of the latency table
PAPER_WINDOW = WindowConfig(history=50, horizon=25)  # M, N of the training benchmark
TARGET_TRAIN_S = 6.0  # s to train the paper-size model through 10,000 windows


# --- results -----------------------------------------------------------------------------


@dataclass(frozen=True)
class Latency:
    """Batch-1 call times of one backend at one horizon, ms."""

    backend: str
    horizon: int
    history: int
    threads: int
    median_ms: float  # wall clock
    p90_ms: float
    std_ms: float
    cpu_median_ms: float  # CPU time of the calling thread: what a busy machine cannot inflate
    repeats: int


@dataclass(frozen=True)
class Throughput:
    """Batched prediction speed of one backend: windows predicted per second."""

    backend: str
    horizon: int
    batch: int
    threads: int
    median_s: float  # per call of ``batch`` windows
    windows_per_s: float
    repeats: int


@dataclass(frozen=True)
class TrainingSpeed:
    """Training throughput of the paper-size network (or the given config)."""

    variant: str
    parameters: int
    history: int
    horizon: int
    batch: int
    threads: int
    windows_measured: int  # windows actually run through forward + backward + Adam
    seconds_measured: float
    target_windows: int  # the epoch size ``epoch_s`` refers to
    extrapolated: bool  # epoch_s scaled from windows_measured < target_windows

    @property
    def windows_per_s(self) -> float:
        return self.windows_measured / self.seconds_measured

    @property
    def epoch_s(self) -> float:
        """Seconds to train through ``target_windows`` windows."""
        return self.target_windows / self.windows_per_s


@dataclass(frozen=True)
class BenchmarkResult:
    """Everything one ``benchmark`` call measured, with the conditions."""

    latency: list[Latency]
    throughput: list[Throughput]
    training: list[TrainingSpeed]  # one per thread count
    parity: dict[int, float]  # N -> max |backend - eager| over backends and benchmark inputs
    source: str  # the run or "random paper-size network"
    device: str
    versions: dict[str, str]
    quick: bool
    notes: list[str] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        for row, t in zip(d["training"], self.training, strict=True):
            row.update(windows_per_s=t.windows_per_s, epoch_s=t.epoch_s)
        return d

    def markdown(self) -> str:
        """Tables with the paper's figures and the targets beside ours, ratios to eager."""
        return _markdown(self)


# --- inputs ------------------------------------------------------------------------------


def physics_windows(
    count: int, window: WindowConfig, *, params: VehicleParams | None = None, seed: int = 0
) -> Windows:
    """``count`` windows of M + N steps, each rolled out by the physics model from its own
    random start: arena position, attitude within 0.3 rad, a swinging load, thrust around
    hover and smooth random body rates (package layout, float32).

    Synthetic flights, not a prediction: each whole flight is generated from its first state
    (the load at rest); predicting from windows is ``models.prediction.PhysicsModel``."""
    params = params or VehicleParams()
    gen = torch.Generator().manual_seed(seed)
    steps = window.length

    def uniform(*shape: int, scale: float) -> Tensor:
        return scale * (2 * torch.rand(*shape, generator=gen, dtype=torch.float64) - 1)

    p0 = uniform(count, 3, scale=2.0)
    q0 = quat_from_rotvec(uniform(count, 3, scale=0.3))
    swing = torch.cat([uniform(count, 2, scale=0.2), torch.full((count, 1), -0.66)], dim=-1)
    x0 = join_state(p0, uniform(count, 3, scale=0.5), q0, p0 + swing)
    t = torch.arange(steps, dtype=torch.float64) * params.dt  # (S,)
    freq, phase = 0.5 + 3 * torch.rand(count, 1, 4, generator=gen), uniform(count, 1, 4, scale=3)
    wave = torch.sin(freq * t[:, None] + phase)  # (count, S, 4)
    u = torch.cat([hover_thrust(params) * (1 + 0.05 * wave[..., :1]), 0.4 * wave[..., 1:]], -1)
    after, _ = rollout(x0, torch.zeros(count, 6, dtype=torch.float64), u[:, :-1], params)
    states = torch.cat([x0[:, None], after], dim=1).numpy()
    flights = [
        _Series(f"physics{i}", states[i], u[i].numpy(), estimate_load_state(states[i], params))
        for i in range(count)
    ]
    return make_windows(flights, window)


@dataclass(frozen=True)
class _Series:
    name: str
    states: np.ndarray
    inputs: np.ndarray
    aux: np.ndarray


def file_inputs(windows: Windows) -> tuple[np.ndarray, np.ndarray]:
    """Windows -> ``predict`` arguments: history (W, M, 17) file layout, future (W, N, 4)."""
    m = windows.window.history
    x = states_to_file(windows.states[:, :m])
    history = torch.cat([x, windows.inputs[:, :m]], dim=-1)
    return history.numpy(), windows.inputs[:, m:].numpy()


# --- backends ----------------------------------------------------------------------------

PredictFn = Callable[[np.ndarray, np.ndarray], np.ndarray]


def script_predict(predictor: Predictor, history: np.ndarray, future: np.ndarray) -> PredictFn:
    """``predictor`` traced with TorchScript at this horizon, frozen: same call and checks.

    Tracing unrolls the decoder loop (fixed N, like the ONNX export); freezing inlines the
    weights and lets TorchScript fold the per-call weight preparation.
    """
    net = FileLayoutNet(predictor.model.eval()).eval()
    args = (torch.as_tensor(history[:1]), torch.as_tensor(future[:1]))
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # tracer warnings about Python-side shape checks
        traced = torch.jit.freeze(torch.jit.trace(net, args, check_trace=False))

    def predict(h: np.ndarray, f: np.ndarray) -> np.ndarray:
        hist, fut, single = check_inputs(h, f, caller="script predict")
        with torch.inference_mode():
            h32, f32 = (torch.as_tensor(a, dtype=torch.float32) for a in (hist, fut))
            out = traced(h32, f32)
        return unbatch(out.numpy(), single)

    return predict


# --- timing ------------------------------------------------------------------------------


def measure_latency(
    backend: str, fn: PredictFn, history: np.ndarray, future: np.ndarray, *, threads: int,
    repeats: int, warmup: int,
) -> Latency:  # fmt: skip
    """Batch-1 calls cycling over the windows of ``history`` (W, M, 17) / ``future``."""
    count = len(history)
    wall, cpu = time_calls(lambda i: fn(history[i % count], future[i % count]), repeats, warmup)
    ms = np.array(wall) * 1e3
    return Latency(
        backend,
        future.shape[1],
        history.shape[1],
        threads,
        float(np.median(ms)),
        float(np.percentile(ms, 90)),
        float(ms.std(ddof=1)) if len(ms) > 1 else 0.0,
        float(np.median(cpu)) * 1e3,
        repeats,
    )


def measure_throughput(
    backend: str, fn: PredictFn, history: np.ndarray, future: np.ndarray, *, threads: int,
    repeats: int,
) -> Throughput:  # fmt: skip
    """Calls on the whole batch ``history`` (B, M, 17) / ``future`` (B, N, 4)."""
    wall, _ = time_calls(lambda i: fn(history, future), repeats, warmup=1)
    median = statistics.median(wall)
    batch = len(history)
    return Throughput(backend, future.shape[1], batch, threads, median, batch / median, repeats)


def measure_training(
    *,
    model_config: ModelConfig | None = None,
    variant: str = "proposed",
    window: WindowConfig = PAPER_WINDOW,
    batch: int = 256,
    target_windows: int = 10_000,
    measured_windows: int | None = None,
    threads: int | None = None,
    seed: int = 0,
) -> TrainingSpeed:
    """Train the network (paper size by default) on physics windows and time it.

    One warm-up step, then ``measured_windows`` windows (default: all ``target_windows``;
    fewer means the epoch time is extrapolated) in batches of ``batch``, each a forward pass,
    the loss of ``variant``, backward, gradient clipping and an Adam step with the default
    ``TrainConfig``. ``threads``: torch intra-op threads (default: every CPU core).
    """
    cfg = TrainConfig()
    threads = threads or os.cpu_count() or 1
    todo = target_windows if measured_windows is None else min(measured_windows, target_windows)
    params = VehicleParams()
    pool = physics_windows(min(batch, 256), window, params=params, seed=seed)
    torch.manual_seed(seed)
    net = build(model_config_for(variant, model_config or ModelConfig()), VehicleParams())
    net.fit_normalization(pool.states, pool.inputs, origin_step=window.history - 1)
    net.train()
    opt = torch.optim.Adam(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    gen = torch.Generator().manual_seed(seed)
    m = window.history

    def train_step(size: int) -> None:
        idx = torch.randint(len(pool), (size,), generator=gen)
        states, inputs, aux = pool.states[idx], pool.inputs[idx], pool.aux[idx]
        pred = net(states[:, :m], inputs[:, :m], inputs[:, m:])
        loss = compute_loss(
            pred, states, inputs, aux, history=m, params=params, weights=LossWeights(),
            variant=variant,
        ).total  # fmt: skip
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(net.parameters(), cfg.grad_clip)
        opt.step()

    with torch_threads(threads):
        train_step(batch)  # warm-up: allocator, Adam state
        t0 = time.perf_counter()
        done = 0
        while done < todo:
            size = min(batch, todo - done)
            train_step(size)
            done += size
        seconds = time.perf_counter() - t0
    return TrainingSpeed(
        variant, count_parameters(net), m, window.horizon, batch, threads, done, seconds,
        target_windows, done < target_windows,
    )  # fmt: skip


# --- the benchmark -----------------------------------------------------------------------


def benchmark(
    run: str | Path | None = None,
    *,
    quick: bool = False,
    horizons: Sequence[int] = (25, 50),
    history: int = 50,
    threads: int = 1,
    batches: Sequence[int] = (256, 1024),
    repeats: int | None = None,
    train: bool = True,
    train_windows: int = 10_000,
    train_threads: Sequence[int] | None = None,
    model_config: ModelConfig | None = None,
    seed: int = 0,
) -> BenchmarkResult:
    """Measure every backend on the same physics windows; see the module doc.

    run: a run folder or checkpoint (default: a random paper-size network with normalisation
    fitted on the benchmark windows; speed does not depend on the weights). quick: fewer
    repeats and a measured fifth of ``train_windows`` (extrapolated), for a smoke run.
    threads: CPU threads for latency and throughput (torch and ONNX Runtime alike);
    train_threads: for training (default: every core). model_config: the network built when no
    run is given (tests use a tiny one).
    """
    repeats = repeats or (20 if quick else 300)
    load_start, device, versions = os.getloadavg()[0], _device(), _versions()
    big = max(batches, default=1)
    predictor, source = _predictor(run, history, max(horizons), model_config, seed)
    latency, throughput, parity = [], [], {}
    notes = [
        "All backends are called through numpy in / numpy out with the same checks "
        "(Predictor.predict, OnnxPredictor.predict, CompiledPredictor.predict, or the traced "
        "network behind the same checks)."
    ]
    reason = unsupported(predictor.model)
    if reason is not None:
        notes.append(f"No compiled backend: {reason}.")
    compiled = CompiledPredictor(predictor) if reason is None else None  # compiles once
    with tempfile.TemporaryDirectory(prefix="slungload-bench-") as tmp, torch_threads(threads):
        for n in horizons:
            window = WindowConfig(history=history, horizon=n)
            windows = physics_windows(max(big, 16), window, params=predictor.params, seed=seed + n)
            hist, fut = file_inputs(windows)
            fns: dict[str, PredictFn] = {
                EAGER: predictor.predict,
                SCRIPT: script_predict(predictor, hist, fut),
                ONNX: OnnxPredictor(export(predictor, Path(tmp) / f"n{n}.onnx", horizon=n).model,
                                    threads=threads, any_history=True).predict,
            }  # fmt: skip
            if compiled is not None:
                fns[COMPILED] = compiled.predict
            parity[n] = _parity(fns, hist[:64], fut[:64])
            latency += _latencies(fns, hist[:16], fut[:16], threads=threads, repeats=repeats)
            for b in batches:
                for name, fn in fns.items():
                    throughput.append(
                        measure_throughput(
                            name, fn, hist[:b], fut[:b], threads=threads, repeats=3 if quick else 7
                        )
                    )
    cores = os.cpu_count() or 1
    training = [
        measure_training(
            model_config=model_config,
            window=WindowConfig(history=history, horizon=25 if 25 in horizons else horizons[0]),
            target_windows=train_windows,
            measured_windows=max(256, train_windows // 5) if quick else None,
            threads=n_threads,
            seed=seed,
        )
        for n_threads in ((train_threads or sorted({1, cores})) if train else ())
    ]
    notes.append(
        f"Load average (1 min) {load_start:.2f} at the start, {os.getloadavg()[0]:.2f} at the end "
        f"on {cores} cores: other processes compete for the cores and inflate wall-clock times."
    )
    return BenchmarkResult(
        latency, throughput, training, parity, source, device, versions, quick, notes
    )


def _parity(fns: dict[str, PredictFn], history: np.ndarray, future: np.ndarray) -> float:
    """Largest |difference| of any backend from the eager predictor on the same windows."""
    reference = fns[EAGER](history, future)
    return max(float(np.abs(fn(history, future) - reference).max()) for fn in fns.values())


def _latencies(
    fns: dict[str, PredictFn], history: np.ndarray, future: np.ndarray, *, threads: int,
    repeats: int,
) -> list[Latency]:  # fmt: skip
    """Batch-1 latency of every backend, cycling over the windows of ``history``."""
    warmup = max(5, repeats // 10)
    return [
        measure_latency(name, fn, history, future, threads=threads, repeats=repeats, warmup=warmup)
        for name, fn in fns.items()
    ]


def _predictor(
    run: str | Path | None, history: int, horizon: int, config: ModelConfig | None, seed: int
) -> tuple[Predictor, str]:
    # threads=None: ``benchmark`` sets torch's threads itself; any_history: ``history`` may
    # differ from the run's M (a timing question, not a prediction).
    if run is not None:
        return Predictor.from_checkpoint(run, threads=None, any_history=True), str(run)
    torch.manual_seed(seed)
    model = build(config or ModelConfig(), VehicleParams())
    window = WindowConfig(history=history, horizon=horizon)
    fit = physics_windows(64, window, seed=seed)
    model.fit_normalization(fit.states, fit.inputs, origin_step=history - 1)
    paper = config is None or replace(config, architecture=DEFAULT_ARCHITECTURE) == ModelConfig()
    size = f"{'paper-size' if paper else 'custom-size'} {model.architecture}"
    predictor = Predictor(model.eval(), window, VehicleParams(), "proposed", threads=None)
    return predictor, f"random {size} network"


def _device() -> str:
    """CPU model and core count."""
    return f"{cpu_model() or platform.machine()}, {os.cpu_count()} cores"


def _paper_ms(device: str, history: int, horizon: int) -> float | None:
    """The paper's Table II mean time on ``device`` at (M, N), ms, or None."""
    for t in PAPER_TIMING:
        if (t.device, t.history, t.horizon) == (device, history, horizon):
            return t.mean_ms
    return None


def _versions() -> dict[str, str]:
    import onnx

    return {
        "slungload": __version__,
        "torch": torch.__version__,
        "onnxruntime": ort.__version__,
        "onnx": onnx.__version__,
        "numpy": np.__version__,
    }


# --- markdown ----------------------------------------------------------------------------


def _ratio(value: float, reference: float | None) -> str:
    if reference is None or not math.isfinite(reference) or reference <= 0:
        return "-"
    return f"{value / reference:.2f}x"


def _markdown(r: BenchmarkResult) -> str:
    """The report: where and with what it was measured, the latency, throughput and training
    tables, the parity and the notes."""
    lines = [
        f"Measured on {r.device}; {r.source}; "
        + ", ".join(f"{k} {v}" for k, v in r.versions.items())
        + (" (quick run)" if r.quick else ""),
        "",
        *_latency_table(r),
        *_throughput_table(r),
        *_training_table(r),
        "",
        "Parity (max |backend - eager| on the benchmark windows): "
        + ", ".join(f"N = {n}: {d:.1e}" for n, d in r.parity.items()),
    ]
    lines += ["", *(f"Note: {n}" for n in r.notes)]
    return "\n".join(lines) + "\n"


def _latency_table(r: BenchmarkResult) -> list[str]:
    """Batch-1 latency in ms per backend and N, beside the targets and the paper's times."""
    lines = [
        f"Batch-1 latency (M = {r.latency[0].history if r.latency else '-'} history rows; wall "
        "clock, and the calling thread's CPU time; speed-up: eager / backend in this run, on "
        "wall-clock medians; the paper's figures are GPU / Jetson times of its own code):",
        "",
        "| backend | N | threads | median ms | p90 ms | std ms | CPU median ms | "
        "speed-up vs eager | target ms | paper RTX 3090 ms | paper Orin Nano ms |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    eager = {(x.horizon,): x.median_ms for x in r.latency if x.backend == EAGER}
    for x in r.latency:
        paper = [_paper_ms(d, x.history, x.horizon) for d in PAPER_DEVICES]
        base = eager.get((x.horizon,))
        speedup = _ratio(base, x.median_ms) if base else "-"
        lines.append(
            f"| {x.backend} | {x.horizon} | {x.threads} | {x.median_ms:.3f} | {x.p90_ms:.3f} | "
            f"{x.std_ms:.3f} | {x.cpu_median_ms:.3f} | {speedup} | "
            f"{TARGET_LATENCY_MS.get(x.horizon, '-')} | "
            + " | ".join("-" if p is None else f"{p:g}" for p in paper)
            + " |"
        )
    return lines


def _throughput_table(r: BenchmarkResult) -> list[str]:
    """Windows predicted per second per backend, N and batch (after a blank line)."""
    lines = [
        "",
        "Throughput (windows predicted per second; speed-up: backend / eager, same run):",
        "",
        "| backend | N | batch | threads | ms per call | windows/s | speed-up vs eager |",
        "|---|---|---|---|---|---|---|",
    ]
    base_tp = {(x.horizon, x.batch): x.windows_per_s for x in r.throughput if x.backend == EAGER}
    for x in r.throughput:
        ratio = _ratio(x.windows_per_s, base_tp.get((x.horizon, x.batch)))
        lines.append(
            f"| {x.backend} | {x.horizon} | {x.batch} | {x.threads} | {1e3 * x.median_s:.1f} | "
            f"{x.windows_per_s:,.0f} | {ratio} |"
        )
    return lines


def _training_table(r: BenchmarkResult) -> list[str]:
    """Training windows per second and seconds per epoch (after a blank line); no lines when
    training was not measured."""
    if not r.training:
        return []
    lines = [
        "",
        "Training throughput (forward + loss + backward + clipping + Adam; plain loop):",
        "",
        "| parameters | variant | M | N | batch | threads | windows/s | "
        "s per epoch | epoch windows | how | target s |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for t in r.training:
        how = f"{t.windows_measured:,} measured, extrapolated" if t.extrapolated else "measured"
        lines.append(
            f"| {t.parameters:,} | {t.variant} | {t.history} | {t.horizon} | {t.batch} | "
            f"{t.threads} | {t.windows_per_s:,.0f} | {t.epoch_s:.1f} | {t.target_windows:,} | "
            f"{how} | {TARGET_TRAIN_S:g} |"
        )
    return lines
