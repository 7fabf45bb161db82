"""One loader for every prediction backend: ``load_model(spec, backend=...)``.

    model = load_model("runs/ps-exc", backend="compiled")     # or "eager", "cuda"; or "physics"
    model = load_model("ps-n15.mpc.onnx", backend="onnx")     # numpy + onnxruntime, no torch
    model = load_model("ps.mpc.npz", backend="compiled")      # numpy + Numba, no torch

Two contracts come out of it, named once each: a torch ``models.prediction.PredictionModel``
(``eager``, ``compiled``, ``cuda``: evaluation's ``predict_windows`` and the MPC's
``predict_candidates``), and on ``onnx`` the MPC's numpy ``control.mppi.CandidateModel``
(``deploy.onboard.OnnxCandidateModel``: an exported candidates graph carries its own
constants); and on ``compiled`` from an exported ``.mpc.npz`` (``export --for-mpc --format
compiled``), the compiled rollouts themselves (``deploy.compiled.archive.load_columns``), the
same numpy contract. The MPC takes either (``control.mpc.candidate_model`` picks the call,
numpy on every backend but the eager and GPU ones). Loading an exported file imports no torch.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..config import PREDICTION_BACKENDS, VehicleParams

ONNX = "onnx"
# every backend ``load_model`` knows, first the default
BACKENDS: dict[str, str] = {
    **PREDICTION_BACKENDS,
    ONNX: "ONNX Runtime on numpy: a candidates graph exported with `export --for-mpc`",
}


def load_model(
    spec: str | Path,
    params: VehicleParams | None = None,
    *,
    backend: str = "eager",
    constants: VehicleParams | None = None,
    threads: int = 1,
    providers: list[str] | None = None,
) -> Any:
    """The prediction model ``spec`` on ``backend`` (``BACKENDS``).

    eager, compiled, cuda: ``spec`` is "physics" (the discrete model with ``params``) or a run
    folder / ``.ckpt`` (``models.prediction.load_prediction_model``, ``constants`` fixing a
    physics-step network's f), on ``deploy.compiled.with_backend``'s backend. compiled, with a
    ``.npz`` file: the exported compiled model (no torch; ``threads`` BLAS threads). onnx:
    ``spec`` is a ``.mpc.onnx`` file with its sidecar, on ``threads`` ONNX Runtime threads and
    its ``providers``. An
    exported file predicts with its run's constants: ``params`` and ``constants`` are refused
    there. An unknown backend or a combination a backend cannot run is a ``ValueError``
    naming why."""
    if backend not in BACKENDS:
        raise ValueError(f"unknown prediction backend {backend!r}; known: {list(BACKENDS)}")
    exported = str(spec).endswith((".onnx", ".npz"))
    if exported and (params is not None or constants is not None):
        raise ValueError(
            f"{spec}: an exported model predicts with its run's constants; export the model "
            "again to change them (an exported file takes no params or constants)"
        )
    if str(spec).endswith(".npz"):
        if backend != "compiled":
            raise ValueError(
                f"{spec}: an exported compiled model (.npz) runs on the compiled backend, not "
                f"{backend!r}"
            )
        from .compiled.archive import load_columns  # numba, only when asked

        return load_columns(spec, threads)
    if backend == ONNX:
        if not str(spec).endswith(".onnx"):
            raise ValueError(
                f"the onnx backend loads an exported candidates graph (.mpc.onnx), not {spec}: "
                "export it first (slungload export --for-mpc)"
            )
        from .onboard import OnnxCandidateModel  # onnxruntime, only when asked

        return OnnxCandidateModel(spec, threads=threads, providers=providers)
    from ..models.prediction import load_prediction_model
    from .compiled.batched import with_backend

    return with_backend(load_prediction_model(spec, params, constants=constants), backend)


def load_exported(path: str | Path, *, threads: int = 1, providers: list[str] | None = None) -> Any:
    """An exported MPC model on its own runtime, without torch: a ``.mpc.onnx`` graph on ONNX
    Runtime (``threads``, ``providers``), a ``.mpc.npz`` compiled model on numpy + Numba."""
    if not str(path).endswith((".onnx", ".npz")):
        raise ValueError(
            f"{path}: not an exported MPC model (.mpc.onnx or .mpc.npz: slungload export --for-mpc)"
        )
    backend = ONNX if str(path).endswith(".onnx") else "compiled"
    return load_model(path, backend=backend, threads=threads, providers=providers)
