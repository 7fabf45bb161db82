"""A model for the onboard MPC on numpy and Numba, without torch: the folded weights in a file.

    model = load_columns("ps.mpc.npz")      # + ps.mpc.json; a NetworkColumns or PhysicsColumns
    states = model.predict_candidates(x_hist, u_past, plans)        # (K, N, 13), any K and N

``deploy.candidates.export_for_mpc(..., format="compiled")`` (``slungload export --for-mpc
--format compiled``) writes a network's ``fold`` (``weights.FoldedWeights``) or the discrete
model's constants as an uncompressed numpy archive (``arrays``), with the sidecar of the
``compiled`` format (``deploy.sidecar``: the format and version, the archive's checksum, the
columns, M, the run's configs and vehicle constants). ``load_columns`` checks the sidecar and
the arrays, and gives the rollouts the ``compiled`` backend runs (``columns``): the same code,
so the onboard MPC steps as fast as the full install's compiled MPC. Torch-free: numpy, Numba
and the package's torch-free modules only (a test blocks torch and runs it).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ...config import VehicleParams, from_dict
from ...fileio import read_npz
from ...vehicle_constants import VehicleConstants
from ..sidecar import COMPILED, OnnxModelError, read_sidecar
from .columns import EnsembleColumns, NetworkColumns, PhysicsColumns
from .weights import FoldedWeights

PHYSICS_MODEL = "physics"  # the sidecar's "architecture" of the discrete model
ENSEMBLE = "ensemble"  # ... of an ensemble: its members' arrays under "m<i>." each
# FoldedWeights' array fields, stored under their names (embed and head per layer; the rest
# are numbers and names, stored in the sidecar's "folded")
_ARRAYS = tuple(
    name
    for name in FoldedWeights._fields
    if name not in ("embed", "head", "mode", "architecture", "vehicle", "constants", "reference")
)


def arrays(folded: FoldedWeights | None, vehicle: VehicleConstants) -> dict[str, np.ndarray]:
    """What the archive holds: a network's folded weights (``folded``; None for the discrete
    model) and f's constants ``vehicle`` (7,) float64, in ``VehicleConstants``' order."""
    out = {"vehicle": np.array(vehicle, np.float64)}
    if folded is None:
        return out
    for group in ("embed", "head"):
        for i, (weight, bias) in enumerate(getattr(folded, group)):
            out[f"{group}.{i}.weight"], out[f"{group}.{i}.bias"] = weight, bias
    out.update({name: np.asarray(getattr(folded, name)) for name in _ARRAYS})
    if folded.reference is not None:
        out["reference"] = np.array(folded.reference, np.float64)
    return out


def folded_record(folded: FoldedWeights) -> dict[str, Any]:
    """The sidecar's "folded": what of ``folded`` is not an array."""
    return {"mode": int(folded.mode), "architecture": folded.architecture,
            "constants": folded.constants}  # fmt: skip


def ensemble_arrays(members: list[FoldedWeights]) -> dict[str, np.ndarray]:
    """An ensemble's archive: each member's ``arrays`` under "m<i>."."""
    return {f"m{i}.{k}": v for i, w in enumerate(members) for k, v in arrays(w, w.vehicle).items()}


def columns_of(
    data: dict[str, np.ndarray], meta: dict[str, Any], where: str = "model"
) -> NetworkColumns | PhysicsColumns | EnsembleColumns:
    """The rollouts of an archive's arrays ``data`` and sidecar ``meta``; a missing or
    malformed array is an ``OnnxModelError`` naming ``where``."""
    if meta.get("architecture") == ENSEMBLE:
        records = meta.get("members")
        if not isinstance(records, list) or len(records) < 2:
            raise OnnxModelError(f"{where}: an ensemble's sidecar must list >= 2 members")
        members = []
        for i, record in enumerate(records):
            prefix = f"m{i}."
            own = {k[len(prefix) :]: v for k, v in data.items() if k.startswith(prefix)}
            member = {"architecture": record.get("architecture"), "folded": record,
                      "history": meta["history"], "name": f"{meta.get('name')}-m{i}"}  # fmt: skip
            members.append(columns_of(own, member, f"{where} (member {i})"))
        return EnsembleColumns(members, str(meta.get("name", ENSEMBLE)), meta.get("calibration"))
    try:
        vehicle = VehicleConstants(*(float(v) for v in _shaped(data, "vehicle", (7,))))
        if meta["architecture"] == PHYSICS_MODEL:
            return PhysicsColumns(vehicle, meta["constants"], float(meta["prior_weight"]))
        record = meta["folded"]
        layers = {g: sum(1 for k in data if k.startswith(f"{g}.") and k.endswith(".weight"))
                  for g in ("embed", "head")}  # fmt: skip
        groups = {
            g: tuple((data[f"{g}.{i}.weight"], data[f"{g}.{i}.bias"]) for i in range(n))
            for g, n in layers.items()
        }
        reference = data.get("reference")
        folded = FoldedWeights(
            **groups,
            **{name: data[name] for name in _ARRAYS},
            mode=int(record["mode"]),
            architecture=str(record["architecture"]),
            vehicle=vehicle,
            constants=str(record["constants"]),
            reference=None if reference is None else VehicleConstants(*map(float, reference)),
        )
        _check_shapes(folded)
        return NetworkColumns(folded, int(meta["history"]), str(meta.get("name", "network")))
    except (KeyError, TypeError, ValueError) as exc:
        if isinstance(exc, OnnxModelError):
            raise
        raise OnnxModelError(f"{where}: a damaged or incomplete compiled model ({exc})") from exc


def load_columns(
    path: str | Path, threads: int = 1
) -> NetworkColumns | PhysicsColumns | EnsembleColumns:
    """The onboard MPC's model from an exported ``.mpc.npz`` and its sidecar: the rollouts
    (``columns``; a network's on ``threads`` BLAS threads) with ``params`` (the run's
    ``VehicleParams``) and ``meta`` (the sidecar) set on them. A missing, altered or
    inconsistent file is an ``OnnxModelError`` naming it."""
    path = Path(path)
    if not path.is_file():
        raise OnnxModelError(f"{path}: no such file")
    meta = read_sidecar(path, COMPILED)
    try:
        data = read_npz(path)
    except ValueError as exc:
        raise OnnxModelError(str(exc)) from exc
    model = columns_of(data, meta, str(path))
    for member in getattr(model, "members", (model,)):
        if isinstance(member, NetworkColumns):
            member.threads = threads
    if model.history != meta["history"]:
        raise OnnxModelError(f"{path}: history {model.history} != the sidecar's {meta['history']}")
    model.params = from_dict(VehicleParams, meta["params"])
    model.meta = meta
    return model


def _shaped(data: dict[str, np.ndarray], name: str, shape: tuple[int, ...]) -> np.ndarray:
    array = data[name]
    if array.shape != shape:
        raise ValueError(f"'{name}' is {array.shape}, not {shape}")
    return array


def _check_shapes(w: FoldedWeights) -> None:
    """The folded arrays must fit one another (a file edited by hand, or of another build)."""
    layers, gates, hidden = w.dec_hh.shape
    emb = w.dec_emb.shape[1]
    want = {
        "enc_hh": (layers, gates, hidden), "enc_ih": (layers, gates, hidden),
        "enc_b": (layers, gates), "dec_ih": (layers, gates, hidden), "dec_b": (layers, gates),
        "att_w": (hidden, hidden), "att_u": (hidden, hidden), "att_v": (hidden,),
        "dec_ctx": (gates, hidden), "dec_emb": (gates, emb), "enc_emb": (gates, emb),
        "add_mean": (13,), "origin_shift": (3, 13),
    }  # fmt: skip
    for name, shape in want.items():
        if getattr(w, name).shape != shape:
            raise ValueError(f"'{name}' is {getattr(w, name).shape}, not {shape}")
    if gates != 4 * hidden or not w.embed or not w.head or w.head[-1][0].shape[0] != 13:
        raise ValueError("the layers do not fit together")
