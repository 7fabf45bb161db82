"""Prediction models: what evaluation and control predict with, behind one contract.

Contract (``PredictionModel``), two entry points over the same model::

    model.predict_windows(windows) -> states (W, N, 13)                        evaluation
    model.predict_candidates(x_hist (M, 13), u_past (M-1, 4), plans (K, N, 4))
                                   -> states (K, N, 13)                        control

Both return the predicted states in physical units with unit quaternions (w-x-y-z).

- ``predict_windows``: a batch of ``data.Windows``, states (W, M+N, 13), inputs and aux; only
  the history, the inputs and the aux at the last history step are used. Returns
  x_hat_M ... x_hat_{M+N-1}, in the windows' dtype for the physics model and float32 for a
  network (what evaluation compares).
- ``predict_candidates``: x_hist holds the last M measured states x_{k-M+1} ... x_k, u_past
  the inputs applied at x_{k-M+1} ... x_{k-1}, and plans K candidate input sequences
  u_k ... u_{k+N-1} (u_k is applied at x_k, the step being decided). Returns the predicted
  x_{k+1} ... x_{k+N} per candidate, in the plans' dtype.

The two agree: the candidates equal the windows whose history is (x_hist, [u_past; u_k]) and
whose future inputs are the rest of each plan (a test holds it for both implementations).
``history`` is the M that ``predict_candidates`` needs; ``name`` labels the model in reports.

- ``PhysicsModel``: the paper's discrete model rolled out open loop from x_{M-1}
  (``physics.rollout``, float64): over windows with the data's load-state estimate at step
  M-1 (``data.windows.physics_rollout``, the one physics-only rollout over windows, which
  training and ``identify`` share); over candidates with the same causal estimate from the
  last two measured states (``load_state.estimate_load_state``).
- ``NetworkModel``: any registered architecture (``models.MODELS``) in eval mode: ``forward``
  over windows in batches, ``forward_candidates`` over candidates (the encoder runs once over
  the M - 1 rows the candidates share; equal to ``forward`` per candidate). Its quaternion is
  normalised and its slack outputs are dropped.
- ``models.ensemble.EnsembleModel``: several networks' mean, and each member's prediction
  for a spread.

``load_prediction_model("physics" | run folder | .ckpt | ensemble folder)`` builds any. The
numpy facade for embedding a network in a user's own controller is ``deploy.Predictor``, a
different thing.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

import torch
from torch import Tensor, nn

from .. import physics
from ..config import ADAPT_PRIOR_WEIGHT, CONSTANTS_SOURCES, VehicleParams, WindowConfig
from ..constants_estimate import adapted
from ..data.windows import Windows, physics_rollout
from ..layout import AUX_DIM, INPUT_DIM, STATE_DIM
from ..load_state import estimate_load_state
from ..state import with_unit_quaternion
from .checkpoints import LoadedModel, load_checkpoint
from .ensemble import EnsembleManifest, EnsembleModel, is_ensemble, load_members

PHYSICS = "physics"  # the name that selects the physics model (``load_prediction_model``)


@runtime_checkable
class PredictionModel(Protocol):
    """A model that predicts N future states (see the module)."""

    name: str
    history: int  # M: measured states ``predict_candidates`` needs (>= 2)

    def predict_windows(self, windows: Windows) -> Tensor: ...

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor: ...


@dataclass
class PhysicsModel:
    """The paper's discrete model rolled out from the last measured state (float64 inside).

    constants: which constants f runs with (``config.CONSTANTS_SOURCES``): "dataset"
    (``params``, one set), "window" (each window's cable length and load mass estimated from
    its history, ``constants_estimate.adapted``; M >= 17, candidates take the network's 50)
    or "flight" (each window's flight's recorded constants, ``Windows.constants``: the truth
    of simulated varied loads; windows only). prior_weight: the in-flight estimate's mass
    prior ("window"; ``constants_estimate.estimate_constants``), (m/s^2)^2 per equation.
    batch_size: windows per rollout in ``predict_windows``. device: where
    ``predict_candidates`` rolls out (its inputs moved there, the states back to the plans').
    """

    params: VehicleParams
    name: str = PHYSICS
    history: int = 2
    batch_size: int = 8192
    constants: str = "dataset"
    prior_weight: float = ADAPT_PRIOR_WEIGHT
    device: str | torch.device = "cpu"

    def __post_init__(self) -> None:
        if self.constants not in CONSTANTS_SOURCES:
            raise ValueError(
                f"unknown constants source {self.constants!r}; known: {list(CONSTANTS_SOURCES)}"
            )
        if not self.prior_weight >= 0:
            raise ValueError(f"PhysicsModel.prior_weight must be >= 0, got {self.prior_weight}")
        if self.prior_weight != ADAPT_PRIOR_WEIGHT and self.constants != "window":
            raise ValueError(
                f"PhysicsModel.prior_weight is the in-flight estimate's (constants='window'); "
                f"with constants={self.constants!r} there is no estimate to give it"
            )
        if self.constants == "window":  # the estimate wants seconds of swing: the network's M
            self.history = max(self.history, WindowConfig().history)

    def predict_windows(self, windows: Windows) -> Tensor:
        params: physics.Vehicle = self.params
        if self.constants == "flight":
            params = windows.vehicle()
            if params is None:
                raise ValueError(
                    "physics with the flights' constants: no flight of these windows records "
                    "its own (fileio.CONSTANT_KEYS; simulate with --load-mass / --cable-length)"
                )
        elif self.constants == "window":
            history = windows.history
            params = adapted(
                history.states.double(), history.inputs.double(), self.params, self.prior_weight
            )
        states = physics_rollout(windows, params, self.batch_size)
        return states.to(windows.states.dtype)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        if self.constants == "flight":
            raise ValueError(
                "physics with the flights' constants predicts windows only; a controller "
                "knows no flight (give it PhysicsModel(true_params) instead)"
            )
        home = plans.device
        x_hist, u_past = x_hist.to(self.device, plans.dtype), u_past.to(self.device)
        plans = plans.to(self.device)
        params: physics.Vehicle = self.params
        if self.constants == "window":  # the history's inputs; u_k is not used by the estimate
            u = torch.cat([u_past.to(plans.dtype), plans[0, :1]])
            est = adapted(x_hist, u, self.params, self.prior_weight)
            params = est._replace(
                mass_load=float(est.mass_load), cable_length=float(est.cable_length)
            )
        aux = estimate_load_state(x_hist[-2:], params)[-1]  # (6,) causal, steps k-1 and k
        k = plans.shape[0]
        states, _ = physics.rollout(
            x_hist[-1].expand(k, STATE_DIM), aux.expand(k, AUX_DIM), plans, params
        )
        return states.to(home)


@dataclass
class NetworkModel:
    """A trained network (any registered architecture) in eval mode, physical units.

    history: the M it was trained with; batch_size: windows per forward pass in
    ``predict_windows``; device: where the network runs (moved there once).
    """

    net: nn.Module
    history: int
    name: str = "network"
    batch_size: int = 1024
    device: str | torch.device = "cpu"

    def __post_init__(self) -> None:
        self.net.eval()
        self.net.to(self.device)
        self.dtype = next(self.net.parameters()).dtype

    def predict_windows(self, windows: Windows) -> Tensor:
        m = windows.window.history
        self.net.eval()
        self.net.to(self.device)
        out = []
        with torch.inference_mode():
            for i in range(0, len(windows), self.batch_size):
                w = windows[i : i + self.batch_size].to(self.device)
                pred = self.net(w.states[:, :m], w.inputs[:, :m], w.inputs[:, m:])
                out.append(with_unit_quaternion(pred.states).float().cpu())
        if not out:
            return windows.states.new_zeros(0, windows.window.horizon, STATE_DIM)
        return torch.cat(out)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        device, dtype = self.device, self.dtype
        with torch.inference_mode():
            states = self.net.forward_candidates(
                x_hist.to(device, dtype), u_past.to(device, dtype), plans.to(device, dtype)
            ).states
        return with_unit_quaternion(states).to(plans.device, plans.dtype)


def load_prediction_model(
    spec: str | Path,
    params: VehicleParams | None = None,
    *,
    constants: VehicleParams | None = None,
) -> PredictionModel:
    """``"physics"`` (the discrete model with ``params``, default ``VehicleParams()``), a
    run folder / ``.ckpt`` of any registered architecture, named after its folder, or an
    ensemble folder (``models.ensemble``: an ``EnsembleModel`` of its members).

    constants: a physics-step network's f runs with these, fixed, for every window (e.g. a
    flight's true load), whatever its checkpoint's (``ModelConfig.constants``); its weights
    unchanged. Another architecture is a ``ValueError``."""
    if str(spec) == PHYSICS:
        return PhysicsModel(params or VehicleParams())
    path = Path(spec)
    if is_ensemble(path):
        return ensemble_model(*load_members(path), constants)
    label = path.name if path.is_dir() else path.parent.name
    return network_model(load_checkpoint(spec), constants, label=label)


def ensemble_model(
    manifest: EnsembleManifest,
    members: list[LoadedModel],
    constants: VehicleParams | None = None,
    **options: Any,
) -> EnsembleModel:
    """An ensemble folder's loaded members (``models.ensemble.load_members``) as one
    ``EnsembleModel`` named after the folder; ``constants`` and ``options`` (``NetworkModel``'s
    batch_size, device) as in ``network_model``."""
    nets = [
        network_model(lm, constants, label=folder.name, **options)
        for lm, folder in zip(members, manifest.members, strict=True)
    ]
    # the shift is measured against the constants the members' f runs with
    params = constants or members[0].params
    return EnsembleModel(tuple(nets), manifest.folder.name, manifest.calibration, params)


def network_model(
    loaded: LoadedModel,
    constants: VehicleParams | None = None,
    *,
    label: str = "network",
    **options: Any,
) -> NetworkModel:
    """A loaded checkpoint as a ``NetworkModel`` (``options``: its batch_size, device);
    ``constants`` as in ``load_prediction_model``."""
    net = loaded.model
    if constants is not None:
        if net.architecture != "physics-step":
            raise ValueError(
                f"{loaded.path}: a {net.architecture!r} network runs no physics model; only a "
                "physics-step network can be given its constants"
            )
        net.params = constants
        net.config = replace(net.config, constants="dataset")
    return NetworkModel(net, loaded.window.history, name=label, **options)


def check_candidates(x_hist: Tensor, u_past: Tensor, plans: Tensor) -> None:
    """``predict_candidates``' shapes: x_hist (M >= 2, 13), u_past (M-1, 4), plans (K, N, 4)."""
    ok = (
        x_hist.dim() == 2
        and x_hist.shape[1] == STATE_DIM
        and x_hist.shape[0] >= 2
        and u_past.shape == (x_hist.shape[0] - 1, INPUT_DIM)
        and plans.dim() == 3
        and plans.shape[-1] == INPUT_DIM
    )
    if not ok:
        raise ValueError(
            f"predict_candidates: expected x_hist (M>=2, {STATE_DIM}), u_past (M-1, "
            f"{INPUT_DIM}), plans (K, N, {INPUT_DIM}); got {tuple(x_hist.shape)}, "
            f"{tuple(u_past.shape)}, {tuple(plans.shape)}"
        )
