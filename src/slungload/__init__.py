"""slungload: physics-informed learned dynamics of a quadrotor carrying a cable-slung load.

The public API is re-exported here. Names are resolved on first use (PEP 562), so that
``import slungload`` and the CLI's ``--help`` stay fast: the simulator pulls in MuJoCo and
training pulls in Lightning only when they are used.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_EXPORTS: dict[str, tuple[str, ...]] = {
    "config": ("LossWeights", "ModelConfig", "TrainConfig", "VehicleParams", "WindowConfig",
               "load_vehicle"),
    "state": ("GROUPS", "INPUT_DIM", "STATE_DIM", "quat_error"),
    "physics": ("rollout", "step"),
    "sim": ("Effects", "MANEUVERS", "SimConfig", "SimulatedDataset", "simulate_dataset",
            "simulate_flight"),
    "data": ("Dataset", "DatasetError", "DatasetSummary", "Flight", "FlightFormatError",
             "estimate_load_state", "load_dataset", "read_flight", "read_splits", "summarize"),
    "windows": ("Windows", "make_windows"),
    "model": ("Prediction", "SlungLoadNet", "count_parameters"),
    "loss": ("LOSS_VARIANTS", "LossTerms", "compute_loss", "model_config_for"),
    "checkpoints": ("LoadedModel", "load_checkpoint"),
    "presets": ("PRESETS", "Preset", "TrainExtras"),
    "training": ("Run", "TrainingDiverged", "TrainingInterrupted", "train"),
    "predictor": ("Predictor",),
    "compiled": ("CompiledPredictor",),
    "evaluation": ("NetworkPredictor", "PhysicsPredictor", "Report", "evaluate", "time_inference"),
    "report": ("write_report",),
    "experiment": ("Reproduction", "reproduce"),
    "deploy": ("ExportResult", "OnnxModelError", "OnnxPredictor", "export"),
    "benchmarks": ("BenchmarkResult", "benchmark"),
}  # fmt: skip
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE) + ["__version__"]


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'slungload' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
