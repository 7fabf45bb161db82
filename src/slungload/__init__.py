"""slungload: physics-informed learned dynamics of a quadrotor carrying a cable-slung load.

The public API is re-exported here. Names are resolved on first use (PEP 562), so that
``import slungload`` and the CLI's ``--help`` stay fast: the simulator pulls in MuJoCo and
training pulls in Lightning only when they are used.
"""

from __future__ import annotations

from ._lazy import lazy_exports
from ._version import __version__

_EXPORTS: dict[str, tuple[str, ...]] = {
    "config": ("LossWeights", "ModelConfig", "TrainConfig", "VehicleParams", "WindowConfig"),
    "vehicle_file": ("load_vehicle", "read_vehicle"),
    "state": ("GROUPS", "INPUT_DIM", "STATE_DIM", "quat_error"),
    "physics": ("rollout", "step"),
    "sim": ("Controller", "Effects", "MANEUVERS", "Measurement", "PIDController", "SimConfig",
            "SimulatedDataset", "simulate_dataset", "simulate_flight"),
    "data.flight": ("DatasetError", "Flight", "FlightFormatError"),
    "load_state": ("estimate_load_state",),
    "data.readers": ("READERS", "read_flight"),
    "data.dataset": ("Dataset", "load_dataset", "read_splits"),
    "data.summary": ("DatasetSummary", "summarize"),
    "data.windows": ("Windows", "make_windows"),
    "models": ("MODELS", "LoadedModel", "PhysicsStepNet", "Prediction", "SlungLoadNet", "build",
               "count_parameters", "load_checkpoint"),
    "models.prediction": ("NetworkModel", "PhysicsModel", "PredictionModel"),
    "models.ensemble": ("Calibration", "EnsembleModel"),
    "loss": ("LOSS_VARIANTS", "LossTerms", "compute_loss", "model_config_for"),
    "run_config": ("PRESETS", "Preset", "RunConfig", "read_toml"),
    "training.module": ("TrainingDiverged",),
    "training.trainer": ("Run", "TrainingInterrupted", "train"),
    "training.ensemble": ("train_ensemble",),
    "evaluation.results": ("Report",),
    "evaluation.evaluator": ("evaluate",),
    "evaluation.report": ("write_report",),
    "evaluation.uncertainty": ("assess", "calibrate"),
    "deploy.predictor": ("EnsemblePredictor", "FlightWindow", "Interval", "Predictor",
                         "flight_window"),
    "deploy.compiled": ("CompiledPredictor",),
    "control.mppi": ("COSTS", "CandidateModel", "Command", "InputLimits", "MPCConfig",
                     "MPPIController", "ReferenceAhead"),
    "deploy.onnx": ("ExportResult", "export"),
    "deploy.backends": ("load_model",),
    "deploy.sidecar": ("OnnxModelError",),
    "deploy.onboard": ("OnnxCandidateModel", "OnnxPredictor"),
    "deploy.timing": ("evaluate_runs", "time_inference"),
}  # fmt: skip
__all__, __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS, globals())
__all__ += ["__version__"]
