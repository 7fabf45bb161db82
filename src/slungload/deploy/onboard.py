"""Exported graphs on ONNX Runtime, numpy only: what runs on the vehicle's computer.

    model = OnnxCandidateModel("ps-n15.mpc.onnx")    # + ps-n15.mpc.json (its sidecar)
    states = model.predict_candidates(x_hist, u_past, plans)   # (K, N, 13) float64
    controller = MPPIController.from_file("ps-n15.mpc.onnx", limits, MPCConfig(samples=256))
    predictor = OnnxPredictor("proposed-n50.onnx")   # a whole-window export
    states = predictor.predict(history, future_inputs)           # (N, 13), file layout

``OnnxCandidateModel`` runs the MPC's graph (``deploy.candidates.export_for_mpc``, ``slungload
export --for-mpc``): the network's ``forward_candidates`` with its normalisation and the final
unit-quaternion projection, in the **package layout** (``layout.py``: quaternions w-x-y-z,
physical units, world z up), float32 inside::

    x_hist  (M, 13)      the last M measured states x_{k-M+1} ... x_k
    u_past  (M-1, 4)     the inputs applied at x_{k-M+1} ... x_{k-1}
    plans   (K, N, 4)    K candidate sequences u_k ... u_{k+N-1}; K dynamic, N fixed per file
    states  (K, N, 13)   the predicted x_{k+1} ... x_{k+N}

The encoder runs once over the M - 1 rows the candidates share (batch 1); the candidates' last
history step and the decoder run at batch K. N is fixed because the exporter unrolls the
decoder's recursion (the sidecar records it); M is the trained M. ``OnnxPredictor`` runs the
whole-window graph (``deploy.onnx.export``) with ``deploy.Predictor``'s ``predict`` call, in
the data files' layout. Both files' sidecars and their checks: ``sidecar``.

Imports numpy, onnxruntime and the package's torch-free modules only (``layout``, ``config``,
``sidecar``, ``inputs``): no torch (a test checks ``sys.modules`` in a fresh interpreter). The
controller over a candidates graph is ``control.mppi.MPPIController`` (``from_file``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnxruntime as ort

from ..config import VehicleParams, from_dict
from ..layout import INPUT_DIM, STATE_DIM
from .inputs import check_inputs, unbatch
from .members import members_mean, members_novel
from .sidecar import (
    FUTURE_INPUT,
    HISTORY_INPUT,
    MEMBER_STATES,
    MPC,
    PLANS,
    STATES,
    U_PAST,
    WINDOW,
    X_HIST,
    OnnxModelError,
    check_session,
    mpc_io_spec,
    read_sidecar,
    window_io_spec,
)

CPU = ["CPUExecutionProvider"]


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


class OnnxCandidateModel:
    """An exported network on ONNX Runtime behind the MPC's numpy call
    (``control.mppi.CandidateModel``): ``predict_candidates(x_hist, u_past, plans)``.

    threads: ONNX Runtime's intra-op threads; providers: its execution providers (default the
    CPU; on a Jetson with onnxruntime-gpu, ``["CUDAExecutionProvider", "CPUExecutionProvider"]``).
    ``history`` (M), ``horizon`` (N), ``params`` (the run's vehicle constants) and ``name`` come
    from the sidecar.
    """

    numpy = True  # numpy in and out: ``control.mpc.candidate_model`` takes it as it is

    def __init__(
        self, path: str | Path, *, threads: int = 1, providers: list[str] | None = None
    ) -> None:
        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"exported model {self.path} does not exist")
        self.meta = read_sidecar(self.path, MPC)
        self.session = _session(self.path, threads, providers)
        members = self.meta.get("member_count")  # an ensemble's graph: every member's states
        check_session(
            self.path,
            self.session,
            self.meta,
            mpc_io_spec(self.meta["history"], self.meta["horizon"], members),
        )
        self.history: int = self.meta["history"]
        self.horizon: int = self.meta["horizon"]
        self.name: str = self.meta.get("name", self.path.stem)
        self.params = from_dict(VehicleParams, self.meta["params"])
        self._output = STATES
        if members is not None:  # the MPC's ensemble calls (``control.mppi.CandidateModel``)
            self._output, self.calibration = MEMBER_STATES, self.meta.get("calibration")
            self.predict_candidates_members = self._run
            self.novel = self._novel

    def _novel(self, members: np.ndarray, shift: np.ndarray | None = None) -> np.ndarray:
        """(E, K, N, 13) (and the constants shift, where calibrated with it) -> (K,) bool:
        ``members.members_novel``."""
        return members_novel(members, self.calibration, shift)

    def predict_candidates(
        self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray
    ) -> np.ndarray:
        """(K, N, 13) float64 predictions of K plans (K, N, 4) from the history x_hist (M, 13)
        and u_past (M-1, 4); package layout (an ensemble: its members' mean,
        ``members.members_mean``; each member's: ``predict_candidates_members``). A
        wrong shape raises ValueError; a failure inside ONNX Runtime raises RuntimeError (the
        MPC falls back on either)."""
        states = self._run(x_hist, u_past, plans)
        return members_mean(states) if self._output == MEMBER_STATES else states

    def _run(self, x_hist: np.ndarray, u_past: np.ndarray, plans: np.ndarray) -> np.ndarray:
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
            (states,) = self.session.run([self._output], feeds)
        except Exception as exc:  # ORT's own exception types
            raise RuntimeError(f"{self.path.name}: ONNX Runtime failed ({exc})") from exc
        return states.astype(np.float64)


class OnnxPredictor:
    """An exported whole-window network (``deploy.onnx.export``) on ONNX Runtime, with
    ``deploy.Predictor``'s ``predict`` call.

    Loading checks the model file against its sidecar (``sidecar.read_sidecar``: format
    version, checksum, input and output names and shapes, state layout) and refuses a mismatch
    with ``OnnxModelError``. threads: ONNX Runtime's intra-op threads; providers: its execution
    providers (default the CPU); any_history: accept histories of any length M >= 1 (the
    graph's M is dynamic), not only the M the network was trained with.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        threads: int = 1,
        any_history: bool = False,
        providers: list[str] | None = None,
    ) -> None:
        self.path = Path(path)
        self.any_history = any_history
        if not self.path.is_file():
            raise FileNotFoundError(f"exported model {self.path} does not exist")
        self.meta = read_sidecar(self.path, WINDOW)
        self.session = _session(self.path, threads, providers)
        check_session(
            self.path, self.session, self.meta, window_io_spec("history", self.meta["horizon"])
        )
        self.horizon: int = self.meta["horizon"]
        self.history: int = self.meta["history"]  # M it was trained with

    def predict(self, history: np.ndarray, future_inputs: np.ndarray) -> np.ndarray:
        """Predict the next N states, as ``Predictor.predict``.

        history (M, 17) or (B, M, 17), future_inputs (N, 4) or (B, N, 4), file layout; M must
        be ``self.history`` (unless ``any_history``) and N this file's horizon. Returns (N, 13)
        or (B, N, 13) float64, unit quaternion x-y-z-w.
        """
        hist, fut, single = check_inputs(
            history,
            future_inputs,
            caller="OnnxPredictor.predict",
            history_rows=None if self.any_history else self.history,
        )
        if fut.shape[1] != self.horizon:
            raise ValueError(
                f"OnnxPredictor.predict: {self.path} is exported for N = {self.horizon} future "
                f"inputs, got {fut.shape[1]} (export one file per horizon)"
            )
        feeds = {
            HISTORY_INPUT: np.ascontiguousarray(hist, dtype=np.float32),
            FUTURE_INPUT: np.ascontiguousarray(fut, dtype=np.float32),
        }
        return unbatch(self.session.run(None, feeds)[0], single)


def _session(path: Path, threads: int, providers: list[str] | None) -> ort.InferenceSession:
    """An ONNX Runtime session of the graph at ``path`` (``session_options``); a file it cannot
    load is an ``OnnxModelError``."""
    try:
        return ort.InferenceSession(str(path), session_options(threads), providers=providers or CPU)
    except Exception as exc:  # ORT raises its own exception types for unreadable files
        raise OnnxModelError(f"{path}: not a loadable ONNX model ({exc})") from exc
