"""The ``cuda`` prediction backend: the eager models on a GPU, replayed from CUDA graphs.

    model = load_model("runs/ps-exc", backend="cuda")       # deploy.compiled.load_model
    states = model.predict_candidates(x_hist, u_past, plans)  # CPU tensors in and out

At the MPC's sizes an eager call is thousands of small kernels (counted at torch's dispatcher
at N = 15: the `small` physics-step network ~2,100, ~140 per horizon step; the physics model
~1,550), so on a GPU a call costs what launching them costs, whatever K. ``GraphedModel``
captures one call per input shape (M, K, N, dtypes) as a CUDA graph after warm-up calls, then
answers each call by copying the inputs into that graph's buffers, replaying it and copying
the states back: what the MPC calls once per control step with the same shapes (``MAX_GRAPHS``
shapes are kept, the least recently used dropped). The eager model on the device (``model``)
answers ``predict_windows``.

What a graph cannot hold is refused before a flight, never left to fail in flight (where the
MPC would fly on its fallback): the physics model with constants estimated in flight (it reads
its estimate on the host at every call) when the backend is chosen, and any other failed
capture when the MPC is built (``prepare``, called by ``control.mppi.MPPIController`` with
its M, K and N). A graph replays the constants and weights it was captured with: the model
must not be changed after its first call.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace

import torch
from torch import Tensor

from ..data.windows import Windows
from ..layout import INPUT_DIM, LOAD_POS, QUAT, STATE_DIM
from ..models.prediction import NetworkModel, PhysicsModel, PredictionModel, check_candidates

CUDA = "cuda"
WARMUP_CALLS = 3  # eager calls on a side stream before a capture (cuBLAS and allocator set-up)
MAX_GRAPHS = 8  # shapes kept per model (the MPC calls one); the least recently used goes first


@dataclass
class _Graph:
    """One captured call: its input buffers, the graph and its output buffer."""

    x_hist: Tensor
    u_past: Tensor
    plans: Tensor
    graph: torch.cuda.CUDAGraph
    states: Tensor


class GraphedModel:
    """A ``PhysicsModel`` or ``NetworkModel`` on the GPU whose ``predict_candidates`` replays a
    CUDA graph per input shape (see the module); ``predict_windows`` is the eager model's."""

    def __init__(self, model: PhysicsModel | NetworkModel) -> None:
        self.model = model
        self.name = model.name
        self.history = model.history
        self._graphs: dict[tuple, _Graph] = {}

    def predict_windows(self, windows: Windows) -> Tensor:
        return self.model.predict_windows(windows)

    def prepare(self, history: int, samples: int, horizon: int) -> None:
        """Capture the graph of float64 calls of M = ``history``, K = ``samples``, N =
        ``horizon`` (the MPC's) now, if not yet: a ``ValueError`` here rather than at the first
        control step. The inputs are a vehicle at rest with its load hanging 1 m below."""
        x_hist = torch.zeros(history, STATE_DIM, dtype=torch.float64)
        x_hist[:, QUAT] = torch.tensor([1.0, 0.0, 0.0, 0.0])  # w-x-y-z: level
        x_hist[:, LOAD_POS] = torch.tensor([0.0, 0.0, -1.0])
        u_past = torch.zeros(history - 1, INPUT_DIM, dtype=torch.float64)
        plans = torch.zeros(samples, horizon, INPUT_DIM, dtype=torch.float64)
        if _key(x_hist, u_past, plans) not in self._graphs:
            self.predict_candidates(x_hist, u_past, plans)

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        check_candidates(x_hist, u_past, plans)
        key = _key(x_hist, u_past, plans)
        graph = self._graphs.pop(key, None)  # put back last: the most recently used
        if graph is None:
            graph = self._capture(x_hist, u_past, plans)
            if len(self._graphs) >= MAX_GRAPHS:  # each holds its own device memory
                del self._graphs[next(iter(self._graphs))]
        else:
            graph.x_hist.copy_(x_hist)
            graph.u_past.copy_(u_past)
            graph.plans.copy_(plans)
        self._graphs[key] = graph
        graph.graph.replay()
        return graph.states.to(plans.device, copy=True)  # waits for the replay

    def _capture(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> _Graph:
        """Warm-up calls on a side stream, then one call captured (torch's recipe)."""
        inputs = [t.to(CUDA, copy=True) for t in (x_hist, u_past, plans)]
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            for _ in range(WARMUP_CALLS):
                self.model.predict_candidates(*inputs)
        torch.cuda.current_stream().wait_stream(side)
        graph = torch.cuda.CUDAGraph()
        try:
            with torch.cuda.graph(graph):
                states = self.model.predict_candidates(*inputs)
        except RuntimeError as exc:
            raise ValueError(
                f"the {CUDA} backend could not capture {self.name!r} as a CUDA graph "
                f"(M = {x_hist.shape[0]}, K = {plans.shape[0]}, N = {plans.shape[1]}): {exc}"
            ) from exc
        return _Graph(*inputs, graph, states)


def _key(x_hist: Tensor, u_past: Tensor, plans: Tensor) -> tuple:
    """What sets a graph: M, K, N and the dtypes."""
    return (x_hist.shape[0], *plans.shape[:2], x_hist.dtype, u_past.dtype, plans.dtype)


def require_gpu() -> None:
    """A ``ValueError`` naming why the ``cuda`` backend cannot run here, if it cannot."""
    if not torch.cuda.is_available():
        raise ValueError(
            f"the {CUDA} backend runs on a GPU, and torch {torch.__version__} sees none here "
            "(a CPU build of torch, or no CUDA device); use 'compiled' or 'eager'"
        )


def on_gpu(model: PredictionModel) -> GraphedModel:
    """``model`` (eager) on the current CUDA device, graphed; a network's weights are copied,
    so that ``model`` stays where it is. A ``ValueError`` naming why where it cannot be."""
    require_gpu()
    if isinstance(model, PhysicsModel):
        if model.constants != "dataset":
            raise ValueError(
                f"the {CUDA} backend replays CUDA graphs, and the physics model with "
                f"constants={model.constants!r} reads its constants on the host at every call; "
                "use 'compiled' or 'eager'"
            )
        return GraphedModel(replace(model, device=CUDA))
    if isinstance(model, NetworkModel):
        net = copy.deepcopy(model.net)
        return GraphedModel(
            NetworkModel(net, model.history, model.name, model.batch_size, device=CUDA)
        )
    raise ValueError(
        f"the {CUDA} backend runs a PhysicsModel or a NetworkModel, not a {type(model).__name__}"
    )
