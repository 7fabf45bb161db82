"""The MPPI controller in the simulator: ``mppi.MPPIController`` over any prediction model.

``SamplingMPC`` meets ``sim.controller.Controller`` (``(measurement, reference, k) -> (thrust,
rates)``): it takes the state out of the simulator's ``Measurement``, the N reference rows
ahead out of its ``Reference``, and runs the one MPPI core (``mppi``: sampling, clamping, cost,
weights, fallbacks, written once in numpy float64) over one numpy contract,
``mppi.CandidateModel``: the compiled backends meet it with their own numpy entry, an ONNX
model and the oracle as they are, an eager or GPU ``models.prediction.PredictionModel``
through ``TorchCandidates`` (``candidate_model`` picks). The onboard controller is the same
core over an exported network on ONNX Runtime (``deploy.onboard``), without torch.

The MPPI update is written here rather than taken from ``pytorch-mppi``: see docs/control.md.
The names of ``mppi`` that the simulator's callers use (``InputLimits``, ``MPCConfig``,
``MPCStats``, ``trajectory_cost``) are re-exported.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from ..config import ESTIMATE_MIN_STEPS, VehicleParams
from ..deploy.compiled.physics import history_constants
from ..evaluation.verdicts import verdict_note
from ..models.ensemble import model_meta
from ..models.prediction import PHYSICS, PredictionModel
from ..physics import VehicleConstants
from ..sim.controller import Measurement
from ..sim.maneuvers import Reference
from ..vehicle_file import simulated_without_excitation
from .mppi import (
    CandidateModel,
    ConstantsEstimate,
    InputLimits,
    MPCConfig,
    MPCStats,
    MPPIController,
    has_members,
    knots_for,
    reference_ahead,
    trajectory_cost,
)

__all__ = [
    "InputLimits",
    "MPCConfig",
    "MPCStats",
    "SamplingMPC",
    "TorchCandidates",
    "candidate_model",
    "knots_for",
    "mpc_maker",
    "reference_ahead",
    "trajectory_cost",
    "window_estimate",
]


class TorchCandidates:
    """A torch ``PredictionModel`` behind the numpy ``mppi.CandidateModel`` call: float64
    arrays in, ``predict_candidates`` on float64 tensors (the model casts to its own dtype),
    float64 arrays out."""

    def __init__(self, model: PredictionModel) -> None:
        self.model = model
        self.name = model.name
        self.history = model.history
        if hasattr(model, "prepare"):  # passed on: ``mppi.CandidateModel``
            self.prepare = model.prepare
        if has_members(model):  # an ensemble's members, and its calibration (``tracked``)
            self.predict_candidates_members = self._members
            self.calibration = getattr(model, "calibration", None)
            self.params = getattr(model, "params", None)  # what the members learned
            # each member alone (``split.SplitMembers``)
            self.members = tuple(candidate_model(m) for m in getattr(model, "members", ()))

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        return self._call(self.model.predict_candidates, x_hist, u_past, plans)

    def _members(self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray) -> np.ndarray:
        return self._call(self.model.predict_candidates_members, x_hist, u_past, plans)

    @staticmethod
    def _call(predict, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray) -> np.ndarray:
        states = predict(
            torch.from_numpy(x_hist), torch.from_numpy(u_past), torch.from_numpy(plans)
        )
        return states.detach().to("cpu", torch.float64).numpy()


class _NumpyEntry:
    """A prediction model's own numpy entry point (``numpy_candidates``: the compiled
    backends) as a ``mppi.CandidateModel``: no tensor at the call's edges."""

    numpy = True

    def __init__(self, model) -> None:
        self.name, self.history = model.name, model.history
        self.predict_candidates = model.numpy_candidates
        if hasattr(model, "prepare"):  # passed on: ``mppi.CandidateModel``
            self.prepare = model.prepare
        if hasattr(model, "numpy_candidates_members"):  # an ensemble's members
            self.predict_candidates_members = model.numpy_candidates_members
            self.novel, self.calibration = model.novel, model.calibration
            self.params = getattr(model, "params", None)  # what the members learned
            # each member alone (``split.SplitMembers``)
            self.members = tuple(candidate_model(m) for m in getattr(model, "members", ()))


def candidate_model(model: PredictionModel | CandidateModel) -> CandidateModel:
    """What the MPPI core calls for ``model``: a numpy ``mppi.CandidateModel`` (``numpy =
    True``: the oracle, an ONNX model) as it is; a model with its own numpy entry point
    (``numpy_candidates``: the compiled backends) through it; any other torch
    ``PredictionModel`` through ``TorchCandidates`` (which passes a GPU model's ``prepare``
    on)."""
    if getattr(model, "numpy", False):
        return model
    if hasattr(model, "numpy_candidates"):
        return _NumpyEntry(model)
    return TorchCandidates(model)


def window_estimate(params: VehicleParams) -> ConstantsEstimate:
    """The controller's in-flight estimate of the load: the adaptive network's
    (``constants_estimate.adapted``, numpy: ``deploy.compiled.physics.history_constants``)
    over the controller's history, ``params`` as the prior."""
    prior = VehicleConstants.of(params)

    def estimate(x_hist: np.ndarray, u_past: np.ndarray) -> tuple[float, float]:
        c = history_constants(x_hist, u_past, prior)
        return c.cable_length, c.mass_load

    return estimate


class SamplingMPC:
    """MPPI controller meeting ``sim.controller.Controller``; one per flight.

    model: a ``PredictionModel`` or a numpy ``mppi.CandidateModel`` (``candidate_model`` picks
    the call: the compiled backends' numpy entry, an ONNX model or the oracle as they are, a
    torch model through ``TorchCandidates``); limits: the input
    box (``InputLimits.from_sim``); params: the vehicle constants for hover thrust and cable
    length (default ``VehicleParams()``; with ``config.constants = "window"`` the prior of the
    in-flight estimate, ``window_estimate``, which needs M >= ``ESTIMATE_MIN_STEPS``).
    ``core`` is the ``mppi.MPPIController`` it runs; ``stats`` counts steps and fallbacks;
    ``plan`` is the nominal plan of the next step. A model with ``prepare(M, K, N)``
    (``deploy.gpu.GraphedModel``) is prepared for this MPC's calls when the core is built
    (``mppi.CandidateModel``).
    """

    def __init__(
        self,
        model: PredictionModel | CandidateModel,
        limits: InputLimits,
        config: MPCConfig | None = None,
        params: VehicleParams | None = None,
    ) -> None:
        self.model = model
        numpy_model = candidate_model(model)
        estimate = None
        if config is not None and config.constants == "window":
            if model.history < ESTIMATE_MIN_STEPS:
                raise ValueError(
                    "the in-flight estimate of the load needs M >= "
                    f"{ESTIMATE_MIN_STEPS} history steps; "
                    f"{model.name} keeps {model.history}"
                )
            estimate = window_estimate(params or VehicleParams())
        self.core = MPPIController(numpy_model, limits, config, params, estimate)

    def attach(self, plant) -> None:
        """Pass the flight's plant on to a model that predicts with it (``oracle``)."""
        attach = getattr(self.core.model, "attach", None)
        if attach is not None:
            attach(plant)

    def __call__(self, measurement: Measurement, reference: Reference, k: int):
        """One control step (the ``Controller`` contract): (thrust N, body rates (3,) rad/s)."""
        ref = self.core.ahead(reference, k)
        command = self.core.step(measurement.state, ref, rotation=measurement.rotation)
        return command.thrust, command.rates

    @property
    def cfg(self) -> MPCConfig:
        return self.core.cfg

    @property
    def limits(self) -> InputLimits:
        return self.core.limits

    @property
    def stats(self) -> MPCStats:
        return self.core.stats

    @property
    def plan(self) -> np.ndarray:
        """(N, 4): the nominal plan of the next step (the latest plan, shifted by one step)."""
        return self.core.plan


def mpc_maker(
    model: PredictionModel | Callable[[], CandidateModel],
    limits: InputLimits,
    mpc: MPCConfig,
    params: VehicleParams,
) -> Callable[[int], SamplingMPC]:
    """seed -> a fresh MPC over ``model`` seeded by the flight, so every flight of a study
    samples its own noise. ``model``: a prediction model shared by the flights, or a factory
    of a fresh numpy ``CandidateModel`` per flight (one that holds the flight's plant, such as
    the lab's oracle)."""
    if model is None:
        raise ValueError("mpc_maker needs a prediction model or a factory of one per flight")
    fresh = isinstance(model, type) or not hasattr(model, "predict_candidates")

    def make(seed: int) -> SamplingMPC:
        return SamplingMPC(model() if fresh else model, limits, replace(mpc, seed=seed), params)

    return make


class ModelNote(UserWarning):
    """Something a user should know before flying a model (``model_notes``)."""


def model_notes(
    model: str | Path, horizon: int, *, paired: bool = False, trust_window: int = 0
) -> list[str]:
    """What a user should know before an MPC over ``model`` (a run folder, or "physics") plans
    ``horizon`` steps ahead (``paired``: priced with the physics model too, ``control.paired``,
    with ``trust_window``),
    where its run says so:

    - it was trained on simulated flights whose commands carried no excitation (the dataset's
      vehicle.json holds the simulator's settings, ``sim``, with every ``excitation`` standard
      deviation zero or none given, and no ``recorded`` MPC flights): such a network learned to
      predict from the state history, where the PID's commands are a function of it, and every
      plan looks alike to it (docs/control.md, "Which model to fly"); nothing is said of real
      flights, nor where the dataset is no longer where the run names it;
    - the horizon is longer than the one it was trained to predict over: the steps beyond are
      extrapolation;
    - its pre-flight check at this horizon (``slungload check``) says it will not beat the
      physics model (``evaluation.verdicts.verdict_note``)."""
    if str(model) == PHYSICS:
        return []
    meta = model_meta(model)
    notes = []
    data = meta.get("data")
    if data and simulated_without_excitation(data):
        notes.append(
            f"{model} was trained on {data}, simulated without input excitation: it predicts "
            "from the state history and barely from the commands, so the MPC cannot tell its "
            "plans apart; train the model to fly on `simulate --excite` flights "
            "(docs/control.md)"
        )
    trained = (meta.get("window") or {}).get("horizon")
    if trained and horizon > trained:
        notes.append(
            f"the MPC plans {horizon} steps ahead and {model} was trained to predict {trained}: "
            f"its predictions past step {trained} are extrapolation"
        )
    checked = verdict_note(model, horizon, paired=paired, trust_window=trust_window)
    return notes + ([checked] if checked else [])
