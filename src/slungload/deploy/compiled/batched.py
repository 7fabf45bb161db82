"""Fast batched rollouts for a sampling controller: ``PredictionModel``s on compiled kernels.

    model = load_model("runs/ps-exc", backend="compiled")   # deploy.backends; or "physics"
    states = model.predict_candidates(x_hist, u_past, plans)  # (K, N, 13), as the eager model

What a model-predictive controller asks for at every step is one history and K candidate
input sequences (``models.prediction``, ``predict_candidates``). The eager paths answer it with
torch operators: the network's decoder is ~60 of them per horizon step, the physics model's
step ~50 float64 ones, and at K = 256-4096 their element-wise work (attention tanh over K x M x
H, GELUs, gates, quaternions) and allocations cost as much as the matrix products. Here the
torch models are wrapped around the torch-free rollouts of ``columns`` (the same code the
onboard path runs from an exported file, ``archive``):

- ``CompiledPhysicsModel``: ``columns.PhysicsColumns``, the discrete model rolled out for the K
  candidates in one compiled float64 call.
- ``CompiledNetworkModel``: ``columns.NetworkColumns`` on the network's ``fold``, float32.

Both equal the eager model to float32 rounding for the network (tests: both architectures,
every model mode) and to round-off for the physics (float64); ``predict_windows`` is the eager
model's. The ``cuda`` backend is the eager model on the GPU, replayed from CUDA graphs
(``deploy.gpu``; CPU tensors in and out, as the MPC calls it). ``with_backend`` puts a model
on one of ``config.PREDICTION_BACKENDS`` (``deploy.backends.load_model`` loads and puts); a
model a backend cannot run, or a GPU that torch does not see, is a ``ValueError`` naming why,
never a silent fallback. Both compiled models also take the MPC's numpy call directly
(``numpy_candidates``, ``control.mppi.CandidateModel``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from ...config import ADAPT_PRIOR_WEIGHT, PREDICTION_BACKENDS, VehicleParams
from ...data.windows import Windows
from ...models.ensemble import EnsembleModel
from ...models.prediction import (
    PHYSICS,
    NetworkModel,
    PhysicsModel,
    PredictionModel,
    check_candidates,
)
from ...vehicle_constants import VehicleConstants
from ..gpu import CUDA, on_gpu
from .columns import DATASET, WINDOW, NetworkColumns, PhysicsColumns
from .fold import fold


@dataclass
class CompiledPhysicsModel:
    """``PhysicsModel``'s candidates in one compiled float64 loop (same constants, same
    causal load-state estimate from the last two measured states): ``columns.PhysicsColumns``
    behind the torch contract."""

    params: VehicleParams
    name: str = PHYSICS
    history: int = 2
    constants: str = "dataset"  # or "window" (``PhysicsModel``'s; "flight" predicts windows only)
    prior_weight: float = ADAPT_PRIOR_WEIGHT  # the in-flight estimate's mass prior ("window")

    def __post_init__(self) -> None:
        self._eager = PhysicsModel(self.params, self.name, self.history, constants=self.constants,
                                   prior_weight=self.prior_weight)  # fmt: skip
        self.history = self._eager.history
        self._columns: PhysicsColumns | None = None
        if self.constants in (DATASET, WINDOW):
            self._columns = PhysicsColumns(
                VehicleConstants.of(self.params), self.constants, self.prior_weight,
                self.history, self.name,
            )  # fmt: skip

    def predict_windows(self, windows: Windows) -> Tensor:
        return self._eager.predict_windows(windows)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        if self._columns is None:
            self._eager.predict_candidates(x_hist, u_past, plans)  # its error
        out = self.numpy_candidates(*_arrays(x_hist, u_past, plans))
        return torch.from_numpy(out).to(plans.device, plans.dtype)

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """``predict_candidates`` on float64 arrays, without torch: the MPC's call
        (``control.mppi.CandidateModel``, through ``control.mpc.candidate_model``)."""
        if self._columns is None:
            raise ValueError(
                f"the compiled physics predicts candidates with constants 'dataset' or "
                f"'window', not {self.constants!r}"
            )
        return self._columns.numpy_candidates(x_hist, u_past, plans)

    def prepare(self, m: int, k: int, n: int) -> None:
        """Compile before the first control step (``columns.warm_up``; the MPC calls it)."""
        if self._columns is not None:
            self._columns.prepare(m, k, n)


def _arrays(x_hist: Tensor, u_past: Tensor, plans: Tensor) -> tuple[np.ndarray, ...]:
    """A torch caller's candidates call as the float64 arrays of ``numpy_candidates`` (exact:
    float32 inputs widen without rounding)."""
    return tuple(t.detach().to("cpu", torch.float64).numpy() for t in (x_hist, u_past, plans))


class CompiledNetworkModel:
    """A network's candidates on compiled kernels and numpy's BLAS, float32
    (``columns.NetworkColumns`` on its ``fold``) behind the torch contract.

    net: a ``SlungLoadNet`` or ``PhysicsStepNet`` (``fold.COMPILED_ARCHITECTURES``, any widths
    and layer counts; another architecture is a ``ValueError`` naming it); history: its M.
    ``predict_windows`` is ``NetworkModel``'s.
    """

    def __init__(self, net: torch.nn.Module, history: int, name: str = "network") -> None:
        self.folded = fold(net)  # raises, naming why, for what it cannot run
        self.columns = NetworkColumns(self.folded, history, name)
        self.constants = self.folded.constants
        self.name, self.history = name, history
        self._eager = NetworkModel(net, history, name=name)

    def predict_windows(self, windows: Windows) -> Tensor:
        return self._eager.predict_windows(windows)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        out = self.numpy_candidates(*_arrays(x_hist, u_past, plans))
        return torch.from_numpy(out).to(plans.device, plans.dtype)

    def numpy_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """``predict_candidates`` on float64 arrays (K, N, 13) out: the MPC's call
        (``control.mppi.CandidateModel``, through ``control.mpc.candidate_model``), no tensor
        conversion at its edges."""
        return self.columns.numpy_candidates(x_hist, u_past, plans)

    def prepare(self, m: int, k: int, n: int) -> None:
        """Compile before the first control step (``columns.warm_up``; the MPC calls it)."""
        self.columns.prepare(m, k, n)


def with_backend(model: PredictionModel, backend: str) -> PredictionModel:
    """``model`` on ``backend`` (one of ``config.PREDICTION_BACKENDS``): itself for "eager";
    for "compiled" a ``CompiledPhysicsModel`` of a ``PhysicsModel`` or a
    ``CompiledNetworkModel`` of a ``NetworkModel`` on the CPU; for "cuda" a
    ``deploy.gpu.GraphedModel`` of a copy on the GPU; an ``EnsembleModel`` with each member so.
    Anything else is a ``ValueError`` naming why, a GPU that torch does not see too."""
    if backend not in PREDICTION_BACKENDS:
        raise ValueError(
            f"unknown prediction backend {backend!r}; known: {list(PREDICTION_BACKENDS)}"
        )
    if backend == "eager":
        return model
    if isinstance(model, EnsembleModel):  # each member on the backend, the mean taken outside
        return model.with_members(tuple(with_backend(m, backend) for m in model.members))
    if backend == CUDA:
        return on_gpu(model)
    if isinstance(model, PhysicsModel):
        return CompiledPhysicsModel(
            model.params, model.name, model.history, model.constants, model.prior_weight
        )
    if isinstance(model, NetworkModel):
        if torch.device(model.device).type != "cpu":
            raise ValueError(
                f"the compiled backend runs on the CPU; {model.name!r} is on {model.device}"
            )
        return CompiledNetworkModel(model.net, model.history, model.name)
    raise ValueError(
        f"the compiled backend runs a PhysicsModel or a NetworkModel, not a {type(model).__name__}"
    )
