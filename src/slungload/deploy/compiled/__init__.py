"""The compiled (Numba) paths, one home: the batch-1 ``CompiledPredictor`` for a control loop
(``predictor``) and the batched candidate rollouts for the MPC (``columns``: torch-free, what
the onboard path runs from an exported file, ``archive``; ``batched``: the torch models around
them, ``CompiledPhysicsModel``, ``CompiledNetworkModel``, ``with_backend``), on one weight fold
(``fold``, ``weights``), one set of math kernels (``kernels``) and one compiled copy of the
discrete model and the load-state estimates (``physics``). Names resolve on first use, so that
the torch-free modules load without torch.
"""

from __future__ import annotations

from ..._lazy import lazy_exports

__all__, __getattr__, __dir__ = lazy_exports(
    __name__,
    {
        "batched": ("CompiledNetworkModel", "CompiledPhysicsModel", "with_backend"),
        "columns": ("NetworkColumns", "PhysicsColumns"),
        "fold": ("COMPILED_ARCHITECTURES",),  # the function: ``compiled.fold.fold``
        "predictor": ("PARITY_TOLERANCE", "CompiledPredictor", "unsupported"),
        "weights": ("FoldedWeights",),
    },
    globals(),
)
