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

Training is timed on a plain loop over the training module (``training.SlungLoadModule``: its
forward, its optimiser; the loss of ``loss.compute_loss``), then backward, clipping and the
optimiser step, which Lightning's loop does in training: the work of a training step without
Lightning's own per-step bookkeeping. The records and their Markdown are in
``report``; this module measures.
"""

from __future__ import annotations

import os
import statistics
import tempfile
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ...config import (
    DEFAULT_ARCHITECTURE,
    LossWeights,
    ModelConfig,
    TrainConfig,
    VehicleParams,
    WindowConfig,
)
from ...data.windows import Windows, make_windows
from ...deploy.compiled import CompiledPredictor, unsupported
from ...deploy.inputs import check_inputs, unbatch
from ...deploy.onboard import OnnxPredictor
from ...deploy.onnx import export
from ...deploy.predictor import FileLayoutNet, Predictor, states_to_file, torch_threads
from ...deploy.timing import time_calls
from ...load_state import estimate_load_state
from ...loss import compute_loss, model_config_for
from ...models.base import count_parameters
from ...models.registry import build
from ...physics import hover_thrust, rollout
from ...reporting import load_average, machine_line, versions
from ...state import join_state, quat_from_rotvec
from .report import (
    COMPILED,
    EAGER,
    ONNX,
    SCRIPT,
    BenchmarkResult,
    Latency,
    Throughput,
    TrainingSpeed,
)

PAPER_WINDOW = WindowConfig(history=50, horizon=25)  # M, N of the training benchmark
PACKAGES = ("torch", "onnxruntime", "onnx", "numpy")  # whose versions a benchmark records


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
    epoch_windows: int = 10_000,
    measured_windows: int | None = None,
    threads: int | None = None,
    seed: int = 0,
) -> TrainingSpeed:
    """Train the network (paper size by default) on physics windows and time it.

    One warm-up step, then ``measured_windows`` windows (default: all ``epoch_windows``;
    fewer means the epoch time is extrapolated) in batches of ``batch``, each a training step
    of ``training.SlungLoadModule`` with the default ``TrainConfig``: its forward pass, the
    loss of ``variant``, backward, gradient clipping (``grad_clip``) and a step of the module's
    own optimiser (Adam). ``threads``: torch intra-op threads (default: every CPU core).
    """
    from ...training.module import SlungLoadModule  # Lightning: only when training is timed

    cfg = TrainConfig()
    threads = threads or os.cpu_count() or 1
    todo = epoch_windows if measured_windows is None else min(measured_windows, epoch_windows)
    params = VehicleParams()
    pool = physics_windows(min(batch, 256), window, params=params, seed=seed)
    torch.manual_seed(seed)
    net = build(model_config_for(variant, model_config or ModelConfig()), params)
    net.fit_normalization(pool.states, pool.inputs, origin_step=window.history - 1)
    module = SlungLoadModule(net, variant=variant, params=params, weights=LossWeights(),
                             window=window, config=cfg, meta={})  # fmt: skip
    module.train()
    opt = module.configure_optimizers()  # a plain optimiser under the constant lr schedule
    gen = torch.Generator().manual_seed(seed)

    def train_step(size: int) -> None:
        idx = torch.randint(len(pool), (size,), generator=gen)
        states, inputs, aux = pool.states[idx], pool.inputs[idx], pool.aux[idx]
        loss = compute_loss(
            module(states, inputs), states, inputs, aux, history=module.history, params=params,
            weights=module.weights, variant=variant, fit_scale=module.fit_scale,
        ).total  # fmt: skip
        opt.zero_grad(set_to_none=True)
        loss.backward()
        if cfg.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(module.parameters(), cfg.grad_clip)
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
        variant, count_parameters(net), window.history, window.horizon, batch, threads, done,
        seconds, epoch_windows, done < epoch_windows,
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
    load_start = load_average()
    stamp = versions(*PACKAGES)
    big = max(batches, default=1)
    predictor, source = benchmark_predictor(run, history, max(horizons), model_config, seed)
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
            fns = _backends(predictor, compiled, hist, fut, Path(tmp) / f"n{n}.onnx", threads)
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
            epoch_windows=train_windows,
            measured_windows=max(256, train_windows // 5) if quick else None,
            threads=n_threads,
            seed=seed,
        )
        for n_threads in ((train_threads or sorted({1, cores})) if train else ())
    ]
    notes.append(
        f"Load average (1 min) {_load(load_start)} at the start, {_load(load_average())} at the "
        f"end on {cores} cores: other processes compete for the cores and inflate wall-clock "
        "times."
    )
    return BenchmarkResult(
        latency, throughput, training, parity, source, machine_line(), stamp, quick, notes
    )


def _backends(
    predictor: Predictor,
    compiled: CompiledPredictor | None,
    history: np.ndarray,
    future: np.ndarray,
    onnx_file: Path,
    threads: int,
) -> dict[str, PredictFn]:
    """Backend name -> its predict call at the horizon of ``future`` (the ONNX file exported
    there, TorchScript traced on these inputs)."""
    n = future.shape[1]
    fns: dict[str, PredictFn] = {
        EAGER: predictor.predict,
        SCRIPT: script_predict(predictor, history, future),
        ONNX: OnnxPredictor(export(predictor, onnx_file, horizon=n).model, threads=threads,
                            any_history=True).predict,
    }  # fmt: skip
    if compiled is not None:
        fns[COMPILED] = compiled.predict
    return fns


def _load(value: float | None) -> str:
    return "unknown" if value is None else f"{value:.2f}"


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


def benchmark_predictor(
    run: str | Path | None, history: int, horizon: int, config: ModelConfig | None, seed: int
) -> tuple[Predictor, str]:
    """The predictor to time and its description: the run's (``run``), or a random network of
    ``config`` (default paper size) with normalisation fitted on physics windows."""
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
