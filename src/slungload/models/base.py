"""What every architecture shares: the ``DynamicsModel`` contract, its ``Prediction``, and the
parameter count. Shapes: B batch, M history steps, N horizon steps.
"""

from __future__ import annotations

from typing import NamedTuple, Protocol

from torch import Tensor, nn

from ..config import ModelConfig


class DynamicsModel(Protocol):
    """What every registered architecture is (an ``nn.Module`` built as ``cls(config, params)``).

    ``forward(x_hist (B, M, 13), u_hist (B, M, 4), u_future (B, N, 4)) -> Prediction`` in
    physical units (states w-x-y-z); ``fit_normalization(states, inputs, origin_step=)`` sets
    its normalisation from training windows; ``config`` is the ``ModelConfig`` it was built
    from and ``architecture`` its name in ``models.MODELS``.
    """

    architecture: str
    config: ModelConfig

    def __call__(self, x_hist: Tensor, u_hist: Tensor, u_future: Tensor) -> Prediction: ...

    def fit_normalization(
        self, states: Tensor, inputs: Tensor, *, origin_step: int = -1
    ) -> None: ...


class Prediction(NamedTuple):
    """Network output over the horizon, physical units.

    states: (B, N, 13) x_hat_M ... x_hat_{M+N-1}; the quaternion is NOT normalised (the
        projection loss needs its norm; see ``with_unit_quaternion`` for evaluation).
    slack: (B, N, 13) slack variables s_M ... s_{M+N-1} in state units (with normalisation,
        the head's output times ``delta_std``: a physics mismatch is of the size of one step's
        change), or None when the model was built with ``slack=False``. Used by the loss only;
        ignore them at evaluation.
    """

    states: Tensor
    slack: Tensor | None


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
