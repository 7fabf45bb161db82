"""The onboard prediction model: an exported network for the MPC on ONNX Runtime, numpy only.

    model = OnnxCandidateModel("ps-n15.mpc.onnx")    # + ps-n15.mpc.json (its sidecar)
    states = model.predict_candidates(x_hist, u_past, plans)   # (K, N, 13) float64
    controller = MPPIController.from_onnx("ps-n15.mpc.onnx", limits, MPCConfig(samples=256))

The file (written by ``deploy.candidates.export_for_mpc``, ``slungload export --for-mpc``) is
the network's ``forward_candidates`` with its normalisation and the final unit-quaternion
projection, in the **package layout** (``layout.py``: quaternions w-x-y-z, physical units,
world z up), float32 inside::

    x_hist  (M, 13)      the last M measured states x_{k-M+1} ... x_k
    u_past  (M-1, 4)     the inputs applied at x_{k-M+1} ... x_{k-1}
    plans   (K, N, 4)    K candidate sequences u_k ... u_{k+N-1}; K dynamic, N fixed per file
    states  (K, N, 13)   the predicted x_{k+1} ... x_{k+N}

The encoder runs once over the M - 1 rows the candidates share (batch 1); the candidates' last
history step and the decoder run at batch K. N is fixed because the exporter unrolls the
decoder's recursion (the sidecar records it); M is the trained M. The sidecar (same name,
``.json``) holds the shapes, the layout, the vehicle constants of the run's data (hover thrust
and cable length for the MPC), every config and the versions; loading refuses a file whose
checksum, inputs, outputs or layout disagree with it.

Imports numpy, onnxruntime and the package's torch-free modules only (``layout``, ``config``):
no torch (a test checks ``sys.modules`` in a fresh interpreter). The controller over it is
``control.mppi.MPPIController`` (``from_onnx``).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from ..config import VehicleParams, from_dict
from ..layout import INPUT_DIM, INPUT_NAMES, STATE_DIM, STATE_NAMES

FORMAT = "slungload-onnx-mpc"
FORMAT_VERSION = 1  # bump when the graph's inputs/outputs or the sidecar change incompatibly
X_HIST, U_PAST, PLANS, STATES = "x_hist", "u_past", "plans", "states"
SUFFIX = ".mpc.onnx"  # what ``export_for_mpc`` names a file it writes into a folder
CPU = ["CPUExecutionProvider"]


class OnboardModelError(ValueError):
    """An exported MPC model that cannot be used: missing, altered or inconsistent sidecar."""


def layout() -> dict[str, Any]:
    """The columns and conventions the graph takes and returns (recorded in the sidecar)."""
    return {
        "state_columns": list(STATE_NAMES),
        "input_columns": list(INPUT_NAMES),
        "quaternion": "w-x-y-z (the package layout), body -> world, unit norm on output",
        "frame": "world z up, gravity -g e3; body rates FLU",
        "units": "m, m/s, N, rad/s",
    }


def io_spec(history: int, horizon: int) -> dict[str, Any]:
    """Names, shapes (``"candidates"``: the dynamic K) and dtypes of the graph's inputs and
    outputs."""
    return {
        "inputs": [
            {"name": X_HIST, "shape": [history, STATE_DIM], "dtype": "float32"},
            {"name": U_PAST, "shape": [history - 1, INPUT_DIM], "dtype": "float32"},
            {"name": PLANS, "shape": ["candidates", horizon, INPUT_DIM], "dtype": "float32"},
        ],
        "outputs": [
            {"name": STATES, "shape": ["candidates", horizon, STATE_DIM], "dtype": "float32"}
        ],
    }


def session_options(threads: int = 1) -> ort.SessionOptions:
    """ONNX Runtime options for small, latency-bound graphs.

    All graph optimisations (constant folding, GELU and Gemm fusions), ``threads`` intra-op
    threads, sequential execution (the graph is a chain: parallel execution only adds
    scheduling).
    """
    so = ort.SessionOptions()
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.log_severity_level = 3  # errors only
    return so


def sidecar_path(model_path: str | Path) -> Path:
    """The sidecar of an exported MPC model: ``x.mpc.onnx`` -> ``x.mpc.json``."""
    return Path(model_path).with_suffix(".json")


def sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class OnnxCandidateModel:
    """An exported network on ONNX Runtime behind the MPC's numpy call
    (``control.mppi.CandidateModel``): ``predict_candidates(x_hist, u_past, plans)``.

    threads: ONNX Runtime's intra-op threads; providers: its execution providers (default the
    CPU; on a Jetson with onnxruntime-gpu, ``["CUDAExecutionProvider", "CPUExecutionProvider"]``).
    ``history`` (M), ``horizon`` (N), ``params`` (the run's vehicle constants) and ``name`` come
    from the sidecar.
    """

    def __init__(
        self, path: str | Path, *, threads: int = 1, providers: list[str] | None = None
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"exported model {self.path} does not exist")
        self.meta = read_sidecar(self.path)
        try:
            self.session = ort.InferenceSession(
                str(self.path), session_options(threads), providers=providers or CPU
            )
        except Exception as exc:  # ORT raises its own exception types for unreadable files
            raise OnboardModelError(f"{self.path}: not a loadable ONNX model ({exc})") from exc
        check_session(self.path, self.session, self.meta)
        self.history: int = self.meta["history"]
        self.horizon: int = self.meta["horizon"]
        self.name: str = self.meta.get("name", self.path.stem)
        self.params = from_dict(VehicleParams, self.meta["params"])

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13) float64 predictions of K plans (K, N, 4) from the history x_hist (M, 13)
        and u_past (M-1, 4); package layout. A wrong shape raises ValueError; a failure inside
        ONNX Runtime raises RuntimeError (the MPC falls back on either)."""
        m, n = self.history, self.horizon
        x_hist, u_past, plans = (np.asarray(a) for a in (x_hist, u_past, plans))
        if (
            x_hist.shape != (m, STATE_DIM)
            or u_past.shape != (m - 1, INPUT_DIM)
            or plans.ndim != 3
            or plans.shape[1:] != (n, INPUT_DIM)
        ):
            raise ValueError(
                f"{self.path.name}: expected x_hist ({m}, {STATE_DIM}), u_past ({m - 1}, "
                f"{INPUT_DIM}), plans (K, {n}, {INPUT_DIM}); got {x_hist.shape}, "
                f"{u_past.shape}, {plans.shape}"
            )
        feeds = {
            X_HIST: np.ascontiguousarray(x_hist, dtype=np.float32),
            U_PAST: np.ascontiguousarray(u_past, dtype=np.float32),
            PLANS: np.ascontiguousarray(plans, dtype=np.float32),
        }
        try:
            (states,) = self.session.run([STATES], feeds)
        except Exception as exc:  # ORT's own exception types
            raise RuntimeError(f"{self.path.name}: ONNX Runtime failed ({exc})") from exc
        return states.astype(np.float64)


def check_sidecar(
    model_path: str | Path,
    *,
    what: str,
    format: str,
    format_version: int,
    columns: dict[str, Any],
    min_history: int,
    error: type[ValueError],
) -> dict[str, Any]:
    """The sidecar of an exported model, checked for its format and version, the model
    file's checksum, its layout's entries against ``columns`` (this package's column names)
    and positive integer history (at least ``min_history``) and horizon. Shared by the MPC's
    export and the whole-window export (``deploy.onnx``); ``what`` names the sidecar in
    messages, ``error`` is the exception raised."""
    model_path = Path(model_path)
    path = sidecar_path(model_path)
    if not path.is_file():
        raise error(f"{model_path}: its sidecar {path.name} is missing")
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != format:
        raise error(f"{path}: not a slungload {what} sidecar (format != {format!r})")
    if meta.get("format_version") != format_version:
        raise error(
            f"{path}: sidecar format version {meta.get('format_version')}, this package reads "
            f"{format_version}; re-export the model"
        )
    if meta.get("model_sha256") != sha256(model_path):
        raise error(
            f"{model_path}: the file does not match its sidecar {path.name} (checksum differs); "
            "was it replaced or damaged?"
        )
    got = meta.get("layout", {})
    for key, want in columns.items():
        if got.get(key) != want:
            raise error(f"{path}: {key} {got.get(key)} differ from this package's {want}")
    for key in ("history", "horizon"):
        if not isinstance(meta.get(key), int) or meta[key] < (
            min_history if key == "history" else 1
        ):
            raise error(f"{path}: '{key}' must be a positive integer")
    return meta


def read_sidecar(model_path: str | Path) -> dict[str, Any]:
    """The sidecar of an exported MPC model, checked (``check_sidecar``), with its vehicle
    constants."""
    meta = check_sidecar(
        model_path,
        what="MPC",
        format=FORMAT,
        format_version=FORMAT_VERSION,
        columns={k: layout()[k] for k in ("state_columns", "input_columns")},
        min_history=2,
        error=OnboardModelError,
    )
    if not isinstance(meta.get("params"), dict):
        path = sidecar_path(model_path)
        raise OnboardModelError(f"{path}: the vehicle constants ('params') are missing")
    return meta


def check_session(
    path: Path,
    session: ort.InferenceSession,
    meta: dict[str, Any],
    spec: dict[str, Any] | None = None,
    error: type[ValueError] = OnboardModelError,
) -> None:
    """The graph's inputs and outputs must be the ones the sidecar describes: ``spec``
    (default: the MPC graph's, ``io_spec``)."""
    spec = spec if spec is not None else io_spec(meta["history"], meta["horizon"])
    for kind, actual in (("inputs", session.get_inputs()), ("outputs", session.get_outputs())):
        want = [(s["name"], s["shape"]) for s in spec[kind]]
        declared = [(s.get("name"), s.get("shape")) for s in meta.get(kind, [])]
        got = [(a.name, list(a.shape)) for a in actual]
        if declared != want or got != want:
            raise error(
                f"{path}: graph {kind} {got} and sidecar {kind} {declared} must both be {want}"
            )
