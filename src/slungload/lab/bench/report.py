"""What ``benchmarks.benchmark`` measured and how it reads: the typed records (``Latency``,
``Throughput``, ``TrainingSpeed``, ``BenchmarkResult``) and their Markdown (``markdown``):
where and with what it ran, the latency table beside the paper's Table II, throughput,
training speed, parity and the notes. Numbers only; nothing here measures.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from ...evaluation.results import PAPER_TIMING
from ...reporting import markdown_table

EAGER, SCRIPT, ONNX, COMPILED = "torch eager", "torch script", "onnxruntime", "numba compiled"
# The batch-1 predictors timed, by their row label (not the MPC's ``config.PREDICTION_BACKENDS``)
PREDICTORS = (EAGER, SCRIPT, ONNX, COMPILED)
PAPER_DEVICES = ("NVIDIA RTX 3090", "NVIDIA Jetson Orin Nano")  # columns of the latency table


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
    epoch_windows: int  # the epoch size ``epoch_s`` refers to
    extrapolated: bool  # epoch_s scaled from windows_measured < epoch_windows

    @property
    def windows_per_s(self) -> float:
        return self.windows_measured / self.seconds_measured

    @property
    def epoch_s(self) -> float:
        """Seconds to train through ``epoch_windows`` windows."""
        return self.epoch_windows / self.windows_per_s


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
        """Tables with the paper's figures beside ours, ratios to eager (``markdown``)."""
        return markdown(self)


def paper_ms(device: str, history: int, horizon: int) -> float | None:
    """The paper's Table II mean time on ``device`` at (M, N), ms, or None."""
    for t in PAPER_TIMING:
        if (t.device, t.history, t.horizon) == (device, history, horizon):
            return t.mean_ms
    return None


def _ratio(value: float, reference: float | None) -> str:
    if reference is None or not math.isfinite(reference) or reference <= 0:
        return "-"
    return f"{value / reference:.2f}x"


def markdown(r: BenchmarkResult) -> str:
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
    """Batch-1 latency in ms per backend and N, beside the paper's times."""
    header = ["backend", "N", "threads", "median ms", "p90 ms", "std ms", "CPU median ms",
              "speed-up vs eager", "paper RTX 3090 ms", "paper Orin Nano ms"]  # fmt: skip
    eager = {x.horizon: x.median_ms for x in r.latency if x.backend == EAGER}
    rows = []
    for x in r.latency:
        paper = [paper_ms(d, x.history, x.horizon) for d in PAPER_DEVICES]
        base = eager.get(x.horizon)
        rows.append([
            x.backend, x.horizon, x.threads, f"{x.median_ms:.3f}", f"{x.p90_ms:.3f}",
            f"{x.std_ms:.3f}", f"{x.cpu_median_ms:.3f}", _ratio(base, x.median_ms) if base else "-",
            *("-" if p is None else f"{p:g}" for p in paper),
        ])  # fmt: skip
    return [
        f"Batch-1 latency (M = {r.latency[0].history if r.latency else '-'} history rows; wall "
        "clock, and the calling thread's CPU time; speed-up: eager / backend in this run, on "
        "wall-clock medians; the paper's figures are GPU / Jetson times of its own code):",
        "",
        markdown_table(header, rows),
    ]


def _throughput_table(r: BenchmarkResult) -> list[str]:
    """Windows predicted per second per backend, N and batch (after a blank line)."""
    header = ["backend", "N", "batch", "threads", "ms per call", "windows/s",
              "speed-up vs eager"]  # fmt: skip
    base = {(x.horizon, x.batch): x.windows_per_s for x in r.throughput if x.backend == EAGER}
    rows = [
        [x.backend, x.horizon, x.batch, x.threads, f"{1e3 * x.median_s:.1f}",
         f"{x.windows_per_s:,.0f}", _ratio(x.windows_per_s, base.get((x.horizon, x.batch)))]
        for x in r.throughput
    ]  # fmt: skip
    return [
        "",
        "Throughput (windows predicted per second; speed-up: backend / eager, same run):",
        "",
        markdown_table(header, rows),
    ]


def _training_table(r: BenchmarkResult) -> list[str]:
    """Training windows per second and seconds per epoch (after a blank line); no lines when
    training was not measured."""
    if not r.training:
        return []
    header = ["parameters", "variant", "M", "N", "batch", "threads", "windows/s",
              "s per epoch", "epoch windows", "how"]  # fmt: skip
    rows = [
        [f"{t.parameters:,}", t.variant, t.history, t.horizon, t.batch, t.threads,
         f"{t.windows_per_s:,.0f}", f"{t.epoch_s:.1f}", f"{t.epoch_windows:,}",
         f"{t.windows_measured:,} measured, extrapolated" if t.extrapolated else "measured"]
        for t in r.training
    ]  # fmt: skip
    return [
        "",
        "Training throughput (forward + loss + backward + clipping + Adam; plain loop):",
        "",
        markdown_table(header, rows),
    ]
