"""What an evaluation produced, as typed records (``Report`` and its parts), and the paper's
numbers to compare with, written once: Table I (RMSE at N = 50) and Table II (batch-1
inference time).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..config import VehicleParams, to_dict
from ..reporting import mean_std
from .metrics import METRIC_KEYS, Curve, Metrics

PHYSICS = "physics"  # label of the physics-only open-loop predictor
# The physics row with each flight's recorded constants, beside "physics" (the dataset's), where
# the flights record their own (simulated varied loads).
PHYSICS_TRUTH = "physics (flights' constants)"

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
    # 1-min load average of the machine when the measurement ended (None: not measured); the
    # timing process itself adds about 1, anything above that is another process's share.
    load_average: float | None = None


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
    test_flights: tuple[str, ...]  # the flights evaluated on (of ``split``)
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
    split: str = "test"  # the dataset split evaluated on ("val": to choose a configuration)
    # a calibrated ensemble's interval per label and N (``uncertainty.UncertaintyStats``)
    spreads: dict[str, dict[int, Any]] = dataclasses.field(default_factory=dict)

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
            "split": self.split,
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
            "spreads": {
                label: {
                    str(n): {
                        "level": st.level,
                        "novel": st.novel,
                        "coverage_min": float(st.coverage.min()),
                        "coverage_max": float(st.coverage.max()),
                    }
                    for n, st in by_n.items()
                }
                for label, by_n in self.spreads.items()
            },  # fmt: skip
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
        stats = {k: mean_std(m.rmse[k] for m in runs) for k in METRIC_KEYS}
        rows.append(
            RmseRow(
                label=label,
                horizon=horizon,
                seeds=len(runs),
                mean={k: mean for k, (mean, _, _) in stats.items()},
                std={k: std for k, (_, std, _) in stats.items()},
            )
        )
    return tuple(rows)
