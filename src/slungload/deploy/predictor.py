"""A trained model behind numpy in, numpy out: the facade for embedding it in a controller.

    predictor = Predictor.from_checkpoint("runs/proposed")   # a run folder or a .ckpt
    states = predictor.predict(history, future_inputs)        # (N, 13)

Columns follow the data files (``fileio``): quaternions are **x-y-z-w** here, as in the files,
while the package works in w-x-y-z inside (``state.py``); the conversion happens only at this
edge. ``history`` row k holds x_k then u_k::

    p (3) m | v (3) m/s | q x-y-z-w (4) | pL (3) m | T (1) N | omega (3) rad/s    (17 columns)

``future_inputs`` holds u_M ... u_{M+N-1} (T, omega); the result holds x_M ... x_{M+N-1} in
the first 13 columns' layout, with a unit quaternion. The network's recursion uses u_{M-1}
(the last history row) and u_M ... u_{M+N-2}; the last future input does not change the result.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor, nn

from ..config import VehicleParams, WindowConfig
from ..models.checkpoints import load_checkpoint
from ..models.lstm_attention import SlungLoadNet
from ..state import (
    INPUT_DIM,
    QUAT,
    STATE_DIM,
    quat_continuous,
    quat_normalize,
    quat_wxyz_to_xyzw,
    quat_xyzw_to_wxyz,
    with_unit_quaternion,
)

HISTORY_DIM = STATE_DIM + INPUT_DIM  # 17 columns: x_k then u_k
# Largest |difference| from this eager predictor, physical units, that a faster path (the ONNX
# export, the compiled predictor) may show on real windows; checked at export and in tests.
PARITY_TOLERANCE = 1e-4


def states_to_file(states: Tensor) -> Tensor:
    """(..., 13) package layout (q w-x-y-z) -> file layout (q x-y-z-w)."""
    out = states.clone()
    out[..., QUAT] = quat_wxyz_to_xyzw(states[..., QUAT])
    return out


def states_from_file(states: Tensor) -> Tensor:
    """(..., T, 13) file layout (q x-y-z-w) -> package layout (q w-x-y-z), prepared as the
    data module prepares flights: unit quaternions without sign jumps along the time axis."""
    out = states.clone()
    out[..., QUAT] = quat_continuous(quat_normalize(quat_xyzw_to_wxyz(states[..., QUAT])))
    return out


class FileLayoutNet(nn.Module):
    """The network behind file-layout arrays: what ``Predictor`` runs and ``export`` writes.

    history (B, M, 17) rows x_k, u_k with q x-y-z-w; future_inputs (B, N, 4) u_M ... u_{M+N-1}
    -> states (B, N, 13) x_M ... x_{M+N-1}, q x-y-z-w with unit norm. The slack outputs are
    dropped.
    """

    def __init__(self, model: SlungLoadNet) -> None:
        super().__init__()
        self.model = model

    def forward(self, history: Tensor, future_inputs: Tensor) -> Tensor:
        x_hist = states_from_file(history[..., :STATE_DIM])
        pred = self.model(x_hist, history[..., STATE_DIM:], future_inputs)
        return states_to_file(with_unit_quaternion(pred.states))


@dataclass
class Predictor:
    """A trained network predicting N future states from M past states and inputs."""

    model: SlungLoadNet
    window: WindowConfig  # the M and N it was trained with (other horizons also work)
    params: VehicleParams
    variant: str
    device: torch.device = field(default_factory=lambda: torch.device("cpu"))
    network: FileLayoutNet = field(init=False, repr=False)  # ``model`` behind file layouts

    def __post_init__(self) -> None:
        self.network = FileLayoutNet(self.model)

    @classmethod
    def from_checkpoint(cls, path: str | Path, *, device: str | torch.device = "cpu") -> Predictor:
        """Load a run folder (its ``best.ckpt``) or a ``.ckpt`` written by ``train``."""
        loaded = load_checkpoint(path)
        device = torch.device(device)
        return cls(
            loaded.model.to(device).eval(), loaded.window, loaded.params, loaded.variant, device
        )

    @property
    def history(self) -> int:
        """M, the number of past rows ``predict`` expects by default (any M >= 1 works)."""
        return self.window.history

    def predict(self, history: np.ndarray, future_inputs: np.ndarray) -> np.ndarray:
        """Predict the next N states.

        history (M, 17) or (B, M, 17): rows x_k, u_k (file convention, see the module doc);
        future_inputs (N, 4) or (B, N, 4): T (N), omega (rad/s) at steps M ... M+N-1.
        Returns (N, 13) or (B, N, 13) float64 states, quaternion unit and x-y-z-w.
        """
        hist, fut, single = check_inputs(history, future_inputs)
        dtype = next(self.model.parameters()).dtype
        with torch.inference_mode():
            h = torch.as_tensor(hist, dtype=dtype, device=self.device)
            u_future = torch.as_tensor(fut, dtype=dtype, device=self.device)
            states = self.network(h, u_future)
        return unbatch(states.cpu().numpy(), single)


def check_inputs(
    history: np.ndarray, future_inputs: np.ndarray, *, caller: str = "Predictor.predict"
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Check ``predict``'s arguments; return them batched, (B, M, 17) and (B, N, 4), and
    whether they came unbatched. Errors start with ``caller`` and show expected and actual
    shapes."""
    hist = np.asarray(history)
    fut = np.asarray(future_inputs)
    _check(hist, fut, caller)
    single = hist.ndim == 2
    if single:
        hist, fut = hist[None], fut[None]
    return hist, fut, single


def unbatch(states: np.ndarray, single: bool) -> np.ndarray:
    """Network output (B, N, 13) -> float64, (N, 13) when the call was unbatched."""
    out = np.asarray(states, dtype=np.float64)
    return out[0] if single else out


def _check(history: np.ndarray, future: np.ndarray, caller: str) -> None:
    """Shape and value checks with the expected and the actual shapes in the message."""
    expected = (
        f"expected history (M, {HISTORY_DIM}) with future_inputs (N, {INPUT_DIM}), or "
        f"(B, M, {HISTORY_DIM}) with (B, N, {INPUT_DIM})"
    )
    got = f"got history {history.shape} and future_inputs {future.shape}"
    ok = (
        history.ndim in (2, 3)
        and future.ndim == history.ndim
        and history.shape[-1] == HISTORY_DIM
        and future.shape[-1] == INPUT_DIM
        and history.shape[-2] >= 1
        and future.shape[-2] >= 1
        and (history.ndim == 2 or history.shape[0] == future.shape[0])
    )
    if not ok:
        raise ValueError(f"{caller}: {expected}; {got}")
    for name, arr in (("history", history), ("future_inputs", future)):
        if not np.issubdtype(arr.dtype, np.number):
            raise ValueError(f"{caller}: {name} has dtype {arr.dtype}, expected numbers")
        if not np.isfinite(arr).all():
            raise ValueError(f"{caller}: {name} holds NaN or infinite values")
