"""The JSON sidecar beside an exported model, for its three formats: numpy-free, torch-free.

An exported file ``x.onnx`` (or ``x.mpc.npz``) has a sidecar ``x.json`` (``sidecar_path``)
holding the format and its version, the file's checksum, the graph's inputs and outputs, the
columns and conventions it takes (``layout``), the history M and horizon N, and the run's
configs. Loading refuses a file whose sidecar is missing, of another format or version, or
disagrees with the file (checksum), the graph's signature (``check_session``) or this package's
columns, with an ``OnnxModelError`` naming the file and the difference.

Three formats, each in the layout of the arrays its caller holds:

============ ========================== ================================ ===================
format       written by                 read by                          layout
============ ========================== ================================ ===================
``window``   ``deploy.onnx.export``     ``onboard.OnnxPredictor``        the data files':
                                        (``predict``)                    quaternion x-y-z-w;
                                                                         batch and M dynamic
``mpc``      ``deploy.candidates        ``onboard.OnnxCandidateModel``   the package's:
             .export_for_mpc``          (the MPC)                        quaternion w-x-y-z;
                                                                         K dynamic, N fixed
``compiled`` ``export_for_mpc(...,      ``compiled.archive               the package's;
             format="compiled")``       .load_columns`` (the MPC)        K and N dynamic
============ ========================== ================================ ===================

A ``compiled`` file is not a graph but the folded weights (``compiled.weights``) as a numpy
archive, run by the same compiled rollouts as the ``compiled`` backend.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from ..layout import (
    GROUP_UNITS,
    GROUPS,
    HISTORY_DIM,
    INPUT_DIM,
    INPUT_NAMES,
    RATES,
    STATE_COLUMNS,
    STATE_DIM,
    STATE_NAMES,
    THRUST,
)

WINDOW, MPC, COMPILED = "window", "mpc", "compiled"
# the sidecar's "format"
FORMATS = {WINDOW: "slungload-onnx", MPC: "slungload-onnx-mpc", COMPILED: "slungload-compiled-mpc"}
# bump a format's version when its inputs/outputs, its arrays or its sidecar change incompatibly
FORMAT_VERSIONS = {WINDOW: 1, MPC: 1, COMPILED: 1}
# what ``export_for_mpc`` names a file it writes into a folder, per format
MPC_SUFFIX, COMPILED_SUFFIX = ".mpc.onnx", ".mpc.npz"
# the graphs' input and output names
HISTORY_INPUT, FUTURE_INPUT, STATES_OUTPUT = "history", "future_inputs", "states"
X_HIST, U_PAST, PLANS, STATES = "x_hist", "u_past", "plans", "states"
MEMBER_STATES = "member_states"  # an ensemble's candidates graph: every member's states


class OnnxModelError(ValueError):
    """An exported model that cannot be used: missing, altered or inconsistent sidecar."""


# --- what the files mean ---------------------------------------------------------------------


def window_layout() -> dict[str, Any]:
    """The ``window`` graph's columns and conventions (the data files')."""
    cols = list(STATE_COLUMNS)
    state_units = [""] * STATE_DIM
    for group, sl in GROUPS.items():
        state_units[sl] = [GROUP_UNITS[group]] * (sl.stop - sl.start)
    input_units = [""] * INPUT_DIM
    input_units[THRUST] = ["N"] * (THRUST.stop - THRUST.start)
    input_units[RATES] = ["rad/s"] * (RATES.stop - RATES.start)
    return {
        "state_columns": cols,
        "state_units": state_units,
        "input_columns": list(INPUT_NAMES),
        "input_units": input_units,
        "history_columns": cols + list(INPUT_NAMES),
        "quaternion": "x-y-z-w (as in the data files), body -> world, unit norm on output",
        "frame": "world z up, gravity -g e3",
    }


def mpc_layout() -> dict[str, Any]:
    """The ``mpc`` graph's columns and conventions (the package's, ``layout.py``)."""
    return {
        "state_columns": list(STATE_NAMES),
        "input_columns": list(INPUT_NAMES),
        "quaternion": "w-x-y-z (the package layout), body -> world, unit norm on output",
        "frame": "world z up, gravity -g e3; body rates FLU",
        "units": "m, m/s, N, rad/s",
    }


def window_io_spec(history: int | str, horizon: int) -> dict[str, Any]:
    """The ``window`` graph's inputs and outputs: history (B, M, 17), future inputs (B, N, 4)
    -> states (B, N, 13); ``history`` a number or "history" (dynamic)."""
    return {
        "inputs": [
            {"name": HISTORY_INPUT, "shape": ["batch", history, HISTORY_DIM], "dtype": "float32"},
            {"name": FUTURE_INPUT, "shape": ["batch", horizon, INPUT_DIM], "dtype": "float32"},
        ],
        "outputs": [
            {"name": STATES_OUTPUT, "shape": ["batch", horizon, STATE_DIM], "dtype": "float32"}
        ],
    }


def mpc_io_spec(history: int, horizon: int, members: int | None = None) -> dict[str, Any]:
    """The ``mpc`` graph's inputs and outputs (``"candidates"``: the dynamic K); an ensemble
    of ``members`` networks gives each member's states (E, K, N, 13) instead of one."""
    if members is not None:
        spec = mpc_io_spec(history, horizon)
        spec["outputs"] = [{"name": MEMBER_STATES, "dtype": "float32",
                            "shape": [members, "candidates", horizon, STATE_DIM]}]  # fmt: skip
        return spec
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


# --- checking a file against its sidecar -------------------------------------------------------


def sidecar_path(model_path: str | Path) -> Path:
    """The sidecar of an exported model: ``x.onnx`` -> ``x.json``, ``x.mpc.onnx`` (``x.mpc.npz``)
    -> ``x.mpc.json``."""
    return Path(model_path).with_suffix(".json")


def check_sidecar_free(model_path: str | Path) -> None:
    """Exporting ``model_path`` must not overwrite another file's sidecar (``x.mpc.onnx`` and
    ``x.mpc.npz`` share ``x.mpc.json``): a ``ValueError`` naming both, before anything is
    written."""
    model_path = Path(model_path)
    side = sidecar_path(model_path)
    if not side.is_file():
        return
    try:
        other = json.loads(side.read_text()).get("model_file")
    except (json.JSONDecodeError, UnicodeDecodeError, AttributeError):
        other = None
    if other not in (None, model_path.name) and (model_path.parent / other).exists():
        raise ValueError(
            f"export: {model_path.name}'s sidecar {side.name} would overwrite that of {other} "
            "beside it; name the file otherwise"
        )


def sha256(path: str | Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def read_sidecar(model_path: str | Path, kind: str) -> dict[str, Any]:
    """The sidecar of the ``kind`` (``WINDOW``, ``MPC`` or ``COMPILED``) file at ``model_path``,
    checked for its format and version, the file's checksum, its columns against this package's
    and a positive history (M >= 2 for the MPC's) and horizon (a compiled file has none: any
    N); the MPC's must hold the run's vehicle constants (``params``). Any failure is an
    ``OnnxModelError`` naming the file."""
    model_path = Path(model_path)
    path = sidecar_path(model_path)
    name = {WINDOW: "ONNX", MPC: "MPC", COMPILED: "compiled MPC"}[kind]
    if not path.is_file():
        raise OnnxModelError(f"{model_path}: its sidecar {path.name} is missing")
    try:
        meta = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise OnnxModelError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMATS[kind]:
        raise OnnxModelError(
            f"{path}: not a slungload {name} sidecar (format != {FORMATS[kind]!r})"
        )
    if meta.get("format_version") != FORMAT_VERSIONS[kind]:
        raise OnnxModelError(
            f"{path}: sidecar format version {meta.get('format_version')}, this package reads "
            f"{FORMAT_VERSIONS[kind]}; re-export the model"
        )
    if meta.get("model_sha256") != sha256(model_path):
        raise OnnxModelError(
            f"{model_path}: the file does not match its sidecar {path.name} (checksum differs); "
            "was it replaced or damaged?"
        )
    want = window_layout() if kind == WINDOW else mpc_layout()
    keys = ("state_columns", "input_columns") + (("history_columns",) if kind == WINDOW else ())
    got = meta.get("layout", {})
    for key in keys:
        if got.get(key) != want[key]:
            raise OnnxModelError(
                f"{path}: {key} {got.get(key)} differ from this package's {want[key]}"
            )
    least = {"history": 1} if kind == WINDOW else {"history": 2}
    if kind != COMPILED:
        least["horizon"] = 1
    for key, low in least.items():
        if not isinstance(meta.get(key), int) or meta[key] < low:
            raise OnnxModelError(f"{path}: '{key}' must be an integer >= {low}")
    if kind != WINDOW and not isinstance(meta.get("params"), dict):
        raise OnnxModelError(f"{path}: the vehicle constants ('params') are missing")
    return meta


def check_session(path: Path, session: Any, meta: dict[str, Any], spec: dict[str, Any]) -> None:
    """The graph's inputs and outputs (an ONNX Runtime session's) must be the ones ``spec``
    (``window_io_spec`` / ``mpc_io_spec``) says and the sidecar ``meta`` declares."""
    for kind, actual in (("inputs", session.get_inputs()), ("outputs", session.get_outputs())):
        want = [(s["name"], s["shape"]) for s in spec[kind]]
        declared = [(s.get("name"), s.get("shape")) for s in meta.get(kind, [])]
        got = [(a.name, list(a.shape)) for a in actual]
        if declared != want or got != want:
            raise OnnxModelError(
                f"{path}: graph {kind} {got} and sidecar {kind} {declared} must both be {want}"
            )
