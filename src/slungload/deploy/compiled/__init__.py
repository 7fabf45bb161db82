"""The compiled (Numba) paths, one home: the batch-1 ``CompiledPredictor`` for a control loop
(``predictor``) and the batched candidate rollouts for the MPC (``batched``:
``CompiledPhysicsModel``, ``CompiledNetworkModel``, ``with_backend``), on one
weight fold (``fold``), one set of math kernels (``kernels``) and one compiled copy of the
discrete model and the load-state estimates (``physics``).
"""

from __future__ import annotations

from .batched import (
    CompiledNetworkModel,
    CompiledPhysicsModel,
    with_backend,
)
from .fold import COMPILED_ARCHITECTURES, FoldedWeights, fold
from .predictor import PARITY_TOLERANCE, CompiledPredictor, unsupported

__all__ = [
    "COMPILED_ARCHITECTURES",
    "PARITY_TOLERANCE",
    "CompiledNetworkModel",
    "CompiledPhysicsModel",
    "CompiledPredictor",
    "FoldedWeights",
    "fold",
    "unsupported",
    "with_backend",
]
