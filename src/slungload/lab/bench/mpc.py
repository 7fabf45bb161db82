"""MPC-shaped rollouts: ``predict_candidates`` per backend at the sampling controller's K and N.

    result = benchmark_mpc()            # or benchmark_mpc("runs/ps-exc"); quick=True to smoke
    print(result.markdown())

What one control step of the MPC costs in prediction: one history (M = 50 rows) and K plans of
N steps, ``PredictionModel.predict_candidates`` (float64 tensors in and out, as the MPC calls
it), for the physics model and a network, on every backend of ``config.PREDICTION_BACKENDS``
(eager torch, compiled kernels, eager torch on the GPU where torch sees one) and on ONNX
Runtime over the exported candidates graph (``deploy.candidates``, numpy in and out, as the
onboard MPC calls it); ``backends`` picks some. One thread (torch's and ONNX Runtime's); the
GPU's calls are whole: host arrays in, the device's work, host arrays out. The backends of one
(model, K, N) are timed interleaved, one call each in turn, so a change in the machine's load
hits them alike; each gets ``calls`` calls or what fits in ``seconds`` (at least
``MIN_CALLS``), after two warm-up calls. Median and p99 of the wall
clock per call, the calling thread's median CPU time (what other processes inflate least), the
speed-up against eager in the same run and the largest difference from eager's prediction
(against the first backend timed where eager is not); the load average is stamped at the start
and the end.
"""

from __future__ import annotations

import dataclasses
import tempfile
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from ...config import PREDICTION_BACKENDS, ModelConfig, WindowConfig
from ...deploy.compiled.batched import with_backend
from ...deploy.gpu import CUDA, require_gpu
from ...deploy.predictor import Predictor, torch_threads
from ...models.prediction import NetworkModel, PhysicsModel, PredictionModel
from ...reporting import load_average, machine_line, markdown_table, versions
from .benchmarks import PACKAGES, benchmark_predictor, physics_windows

ONNX = "onnxruntime"  # the exported candidates graph (``deploy.onboard.OnnxCandidateModel``)
TIMED = (*PREDICTION_BACKENDS, ONNX)  # what ``benchmark_mpc`` can time, by name
MIN_CALLS = 5
HISTORY = 50  # M of the benchmark's history without a run (a run's own M otherwise)


@dataclass(frozen=True)
class RolloutTiming:
    """``predict_candidates`` of one model on one backend at one (K, N)."""

    model: str  # "physics" or the network's description
    backend: str
    samples: int  # K
    horizon: int  # N
    calls: int
    median_ms: float
    p99_ms: float  # the largest of fewer than 100 calls is at least the p99
    cpu_median_ms: float  # the calling thread's CPU time: what a busy machine inflates least
    speedup: float  # the reference's median / this median, same run
    max_abs_diff: float  # largest |this - the reference| over the K x N x 13 predictions


@dataclass(frozen=True)
class MPCBenchmark:
    """Everything one ``benchmark_mpc`` call measured, with the conditions."""

    rows: list[RolloutTiming]
    source: str
    device: str
    versions: dict[str, str]
    threads: int
    history: int
    load_average: tuple[float | None, float | None]  # 1-min, at the start and the end
    quick: bool
    notes: list[str] = field(default_factory=list)
    reference: str = "eager"  # the backend the speed-up and the difference are against

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def markdown(self) -> str:
        start, end = ("unknown" if x is None else f"{x:.2f}" for x in self.load_average)
        header = ["model", "backend", "N", "K", "calls", "median ms", "p99 ms", "CPU median ms",
                  "speed-up", "max abs diff"]  # fmt: skip
        rows = [
            [r.model, r.backend, r.horizon, r.samples, r.calls, f"{r.median_ms:.1f}",
             f"{r.p99_ms:.1f}", f"{r.cpu_median_ms:.1f}", f"{r.speedup:.2f}x",
             "-" if r.backend == self.reference else f"{r.max_abs_diff:.1e}"]
            for r in self.rows
        ]  # fmt: skip
        lines = [
            f"Measured on {self.device}; {self.source}; "
            + ", ".join(f"{k} {v}" for k, v in self.versions.items())
            + (" (quick run)" if self.quick else ""),
            "",
            f"MPC-shaped rollouts: `predict_candidates` with M = {self.history}, one thread, "
            f"load average (1 min) {start} at the start, {end} at the end; backends of a row "
            f"group timed interleaved; speed-up against {self.reference} in the same run:",
            "",
            markdown_table(header, rows),
        ]
        lines += [""] + [f"Note: {n}" for n in self.notes]
        return "\n".join(lines) + "\n"


def benchmark_mpc(
    run: str | Path | None = None,
    *,
    samples: Sequence[int] = (256, 1024, 4096),
    horizons: Sequence[int] = (15, 50),
    quick: bool = False,
    calls: int | None = None,
    seconds: float | None = None,
    backends: Sequence[str] | None = None,
    physics: bool = True,
    model_config: ModelConfig | None = None,
    seed: int = 0,
) -> MPCBenchmark:
    """Time every backend on MPC-shaped calls; see the module doc.

    run: a run folder or checkpoint (default: a random network of ``model_config``, default the
    paper-size physics-step network, normalisation fitted on physics windows). calls: at most
    this many timed calls per backend and (K, N) (default 100, quick 10); seconds: the time
    each may take (default 10, quick 1). backends: which of ``TIMED`` (default every one that
    runs here: ``cuda`` where torch sees a GPU, with a note where not); physics: also time the
    physics model.
    """
    notes: list[str] = []
    backends = _chosen(backends, notes)
    calls = calls or (10 if quick else 100)
    seconds = seconds or (1.0 if quick else 10.0)
    load_start = load_average()
    config = model_config or ModelConfig(architecture="physics-step")
    predictor, source = benchmark_predictor(run, HISTORY, max(horizons), config, seed)
    m = predictor.window.history
    if run is None:
        source = f"random {config.size or 'custom'}-size {config.architecture} network"
    net = NetworkModel(predictor.model, m, name=f"{predictor.model.architecture} network")
    models: list[PredictionModel] = ([PhysicsModel(predictor.params)] if physics else []) + [net]
    rows: list[RolloutTiming] = []
    with tempfile.TemporaryDirectory(prefix="slungload-mpc-") as tmp, torch_threads(1):
        for n in horizons:
            onnx_model = _onnx_model(predictor, n, Path(tmp), notes) if ONNX in backends else None
            for model in models:
                for k in samples:
                    fns = _backends(model, backends, onnx_model if model is net else None)
                    if fns:  # none for the physics model when only onnxruntime is timed
                        args = _inputs(m, k, n, seed)
                        rows += _time_group(model.name, fns, args, k, n, calls, seconds)
    notes += [
        "eager, compiled and cuda: PredictionModel.predict_candidates on float64 CPU tensors "
        "(the torch MPC's call; cuda moves them to the GPU and the states back); onnxruntime: "
        "OnnxCandidateModel.predict_candidates on float64 arrays (the onboard MPC's call), an "
        "export of the same network per N.",
        "The physics model runs in float64 on every backend; the network in float32.",
    ]
    return MPCBenchmark(
        rows,
        source,
        machine_line(),
        versions(*PACKAGES),
        1,
        m,
        (load_start, load_average()),
        quick,
        notes,
        backends[0],
    )


Call = Callable[[tuple[Any, ...]], np.ndarray]


def _chosen(backends: Sequence[str] | None, notes: list[str]) -> tuple[str, ...]:
    """The backends to time, eager first where chosen (the reference); by default every one
    that runs here."""
    if backends is None:
        backends = TIMED if torch.cuda.is_available() else tuple(b for b in TIMED if b != CUDA)
        if CUDA not in backends:
            notes.append(f"No {CUDA} row: torch {torch.__version__} sees no GPU here.")
    unknown = [b for b in backends if b not in TIMED]
    if unknown or not backends:
        raise ValueError(f"unknown backends to time {unknown or '(none given)'}; known: "
                         f"{list(TIMED)}")  # fmt: skip
    if CUDA in backends:
        require_gpu()
    return tuple(sorted(dict.fromkeys(backends), key=TIMED.index))


def _backends(
    model: PredictionModel, backends: Sequence[str], onnx_model: Any | None
) -> dict[str, Call]:
    """Backend name -> a call on (x_hist, u_past, plans) float64 arrays returning numpy."""

    def torch_call(m: PredictionModel) -> Call:
        def call(args: tuple[Any, ...]) -> np.ndarray:
            x, u, plans = (torch.from_numpy(a) for a in args)
            return m.predict_candidates(x, u, plans).numpy()

        return call

    fns = {name: torch_call(with_backend(model, name)) for name in backends if name != ONNX}
    if onnx_model is not None:
        fns[ONNX] = lambda args: onnx_model.predict_candidates(*args)
    return fns


def _onnx_model(predictor: Predictor, horizon: int, folder: Path, notes: list[str]) -> Any:
    """The exported candidates graph at this N on ONNX Runtime, or None (with a note saying
    why) when the exporter refuses it: its own parity check against eager."""
    from ...deploy.candidates import export_for_mpc
    from ...deploy.onboard import OnnxCandidateModel
    from ...deploy.sidecar import OnnxModelError

    try:
        result = export_for_mpc(predictor, folder / f"n{horizon}.mpc.onnx", horizon=horizon)
    except OnnxModelError as exc:
        notes.append(f"No onnxruntime row at N = {horizon}: the export refused: {exc}")
        return None
    return OnnxCandidateModel(result.model, threads=1)


def _inputs(m: int, k: int, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A history of M rows of a physics flight and K plans of N steps around its inputs (the
    MPC's sampling noise), float64, as the MPC passes them."""
    window = physics_windows(1, WindowConfig(history=m, horizon=n), seed=seed + n)
    x = window.states[0, :m].double().numpy()
    u = window.inputs[0].double().numpy()
    rng = np.random.default_rng(seed + k)
    noise = rng.standard_normal((k, n, 4)) * np.array([1.0, 0.5, 0.5, 0.2])
    plans = u[m - 1 : m - 1 + n] + noise
    return np.ascontiguousarray(x), np.ascontiguousarray(u[: m - 1]), plans


def _time_group(
    model: str, fns: dict[str, Call], args: tuple[Any, ...], k: int, n: int, calls: int,
    seconds: float,
) -> list[RolloutTiming]:  # fmt: skip
    """The backends of one (model, K, N), interleaved call by call."""
    outputs = {name: (fn(args), fn(args))[1] for name, fn in fns.items()}  # two warm-up calls
    wanted, times, cpu = {}, {name: [] for name in fns}, {name: [] for name in fns}
    for name, fn in fns.items():
        start = time.perf_counter()
        fn(args)
        first = time.perf_counter() - start
        wanted[name] = max(MIN_CALLS, min(calls, int(seconds / max(first, 1e-9))))
    while any(len(times[name]) < wanted[name] for name in fns):
        for name, fn in fns.items():
            if len(times[name]) < wanted[name]:
                start, start_cpu = time.perf_counter(), time.thread_time()
                fn(args)
                times[name].append(time.perf_counter() - start)
                cpu[name].append(time.thread_time() - start_cpu)
    reference = next(iter(fns))  # eager where timed: ``_chosen`` puts it first
    reference_ms = float(np.median(times[reference])) * 1e3
    rows = []
    for name in fns:
        ms = np.array(times[name]) * 1e3
        rows.append(
            RolloutTiming(
                model,
                name,
                k,
                n,
                len(ms),
                float(np.median(ms)),
                float(np.percentile(ms, 99)),
                float(np.median(cpu[name])) * 1e3,
                reference_ms / float(np.median(ms)),
                float(np.abs(outputs[name] - outputs[reference]).max()),
            )  # fmt: skip
        )
    return rows
