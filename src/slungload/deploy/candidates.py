"""Export of a network for the MPC: the encoder once, the decoder batched over K candidates.

    result = export_for_mpc("runs/ps-exc", "ps-n15.mpc.onnx", horizon=15)  # + ps-n15.mpc.json
    model = deploy.onboard.OnnxCandidateModel("ps-n15.mpc.onnx")          # no torch needed

What is exported is ``CandidatesNet``: the network's ``forward_candidates`` (any registered
architecture: the paper's network and the physics-step network, whose discrete model f is
pure torch and traces with it) followed by the unit-quaternion projection, i.e. exactly what
``models.prediction.NetworkModel.predict_candidates`` computes, in the package layout
(``deploy.onboard`` describes the graph's inputs and outputs). The candidate count K is
dynamic; the tracer unrolls the decoder's recursion, so N is fixed per file and recorded in
the sidecar (export one file per horizon). Before the file is kept, ONNX Runtime's answer is
compared with the eager network at two values of K, one of them not the traced K; a
disagreement above ``predictor.PARITY_TOLERANCE`` raises ``OnnxModelError``.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
import onnxruntime as ort
import torch
from torch import Tensor, nn

from .._version import __version__
from ..config import VehicleParams, from_dict, to_dict
from ..evaluation.verdicts import read_verdicts
from ..fileio import atomic_path, write_json, write_npz
from ..layout import STATE_DIM
from ..models.ensemble import is_ensemble, read_manifest, spread
from ..models.prediction import PHYSICS, PhysicsModel
from ..reporting import versions
from ..state import with_unit_quaternion
from ..vehicle_constants import VehicleConstants
from . import onboard
from .onnx import (
    OPSET,
    _check_model_path,
    _load,
    export_name,
    export_record,
    trace_to_onnx,
)
from .predictor import PARITY_TOLERANCE, Predictor, states_from_file
from .sidecar import (
    COMPILED,
    COMPILED_SUFFIX,
    FORMAT_VERSIONS,
    FORMATS,
    MEMBER_STATES,
    MPC,
    MPC_SUFFIX,
    PLANS,
    STATES,
    U_PAST,
    X_HIST,
    OnnxModelError,
    check_sidecar_free,
    mpc_io_spec,
    mpc_layout,
    sha256,
    sidecar_path,
)

CHECK_CANDIDATES = (3, 8)  # K traced, and another K the export is checked at
ONNX = "onnx"
MPC_FORMATS = {
    ONNX: "a candidates graph for ONNX Runtime (N fixed): deploy.onboard",
    COMPILED: "the folded weights for the compiled rollouts on numpy + Numba (any N)",
}


class PhysicsCandidatesNet(nn.Module):
    """``models.prediction.PhysicsModel.predict_candidates`` as a module (M = 2): the discrete
    model rolled out from the last state with the load state estimated from the last two."""

    def __init__(self, params: VehicleParams) -> None:
        super().__init__()
        self.physics = PhysicsModel(params)

    def forward(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        states = self.physics.predict_candidates(x_hist, u_past, plans)
        # The discrete model does not read u_past; a zero term keeps it an input of the graph,
        # so every exported model has the contract's three inputs (finite inputs: exact).
        return states + 0.0 * u_past.sum()


class CandidatesNet(nn.Module):
    """``forward_candidates`` with unit quaternions: x_hist (M, 13), u_past (M-1, 4), plans
    (K, N, 4) -> states (K, N, 13), physical units, package layout (q w-x-y-z)."""

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        return with_unit_quaternion(self.model.forward_candidates(x_hist, u_past, plans).states)


@dataclass(frozen=True)
class MPCExportResult:
    """What ``export_for_mpc`` wrote."""

    model: Path  # the .mpc.onnx or .mpc.npz file
    sidecar: Path  # its JSON description
    horizon: int  # N, fixed in an ONNX graph; the one checked for a compiled file (any N)
    history: int  # M, the trained history
    opset: int | None  # the ONNX opset; None for a compiled file
    max_abs_diff: float  # max |exported - eager torch| at the checked K
    seconds: float  # wall-clock time of the export and check

    def summary(self) -> str:
        ks = ", ".join(map(str, CHECK_CANDIDATES))
        if self.opset is None:
            what = f"compiled MPC model (numpy + Numba), M = {self.history}, K and N dynamic"
            check = (
                f"max |compiled - torch| = {self.max_abs_diff:.2e} at K = {ks}, N = {self.horizon}"
            )
        else:
            what = (f"MPC candidates graph, N = {self.horizon}, M = {self.history}, K dynamic, "
                    f"opset {self.opset}")  # fmt: skip
            check = f"max |onnx - torch| = {self.max_abs_diff:.2e} at K = {ks}"
        return f"{self.model} (+ {self.sidecar.name}): {what}, {check}, {self.seconds:.1f} s"


class _Source(NamedTuple):
    """What is exported and how to describe it."""

    net: nn.Module  # x_hist, u_past, plans -> states
    history: int  # M
    name: str
    architecture: str
    variant: str | None
    configs: dict[str, Any]
    source: str
    inputs: Callable[[int, int], tuple[np.ndarray, np.ndarray, np.ndarray]]  # (K, seed)


def export_for_mpc(
    run_or_ckpt: str | Path | Predictor,
    out: str | Path,
    *,
    horizon: int,
    params: VehicleParams | None = None,
    opset: int = OPSET,
    format: str = ONNX,
) -> MPCExportResult:
    """Write ``out`` (the candidates graph, or the compiled model) and its sidecar
    (``sidecar_path``).

    run_or_ckpt: a run folder, a ``.ckpt`` or a loaded ``Predictor``; or ``"physics"``, the
    discrete model (``models.prediction.PhysicsModel``, M = 2) with the constants ``params``
    (default ``VehicleParams()``; ignored otherwise); out: the model file in an existing
    folder, or an existing folder to write ``<run name>-n<N>.mpc.onnx`` (``<run
    name>.mpc.npz``) into; horizon: N fixed in the graph (the MPC's horizon; for a compiled
    file, which runs any N, the N it is checked at); format (``MPC_FORMATS``): ``"onnx"``, a
    graph for ONNX Runtime (``deploy.onboard``), or ``"compiled"``, the folded weights for the
    compiled rollouts on numpy + Numba (``compiled.archive``).
    """
    if format not in MPC_FORMATS:
        raise ValueError(f"export_for_mpc: unknown format {format!r}; known: {list(MPC_FORMATS)}")
    start = time.perf_counter()
    out = Path(out)
    if not out.is_dir():
        _check_model_path(out)
    if horizon < 2:
        raise ValueError(f"export_for_mpc: horizon must be >= 2, got {horizon}")
    src = _export_source(run_or_ckpt, horizon, params, format)
    checks = (read_verdicts(run_or_ckpt) if isinstance(run_or_ckpt, str | Path)
              and str(run_or_ckpt) != PHYSICS else {})  # fmt: skip
    if format == COMPILED:
        return _export_compiled(src, out, horizon, start, checks)
    if out.is_dir():
        out = out / f"{src.name}-n{horizon}{MPC_SUFFIX}"
    check_sidecar_free(out)
    ensemble = isinstance(src.net, EnsembleCandidatesNet)
    members = len(src.net.nets) if ensemble else None
    graph, output = onnx_graph(src.net), MEMBER_STATES if ensemble else STATES
    with atomic_path(out) as tmp:
        trace_to_onnx(
            graph, src.inputs(CHECK_CANDIDATES[0], 0), tmp, opset,
            ([X_HIST, U_PAST, PLANS], [output]),
            {PLANS: {0: "candidates"}, output: {1 if ensemble else 0: "candidates"}},
        )  # fmt: skip
        session = ort.InferenceSession(str(tmp), onboard.session_options(1), providers=onboard.CPU)
        diff = max(_parity(src, session, k) for k in CHECK_CANDIDATES)
        if not diff <= PARITY_TOLERANCE:
            raise OnnxModelError(
                f"{out}: exported candidates graph disagrees with the eager model by "
                f"{diff:.3g} (> {PARITY_TOLERANCE}); not written"
            )
        digest = sha256(tmp)
    m = src.history
    sidecar = sidecar_path(out)
    write_json(
        sidecar,
        {
            "format": FORMATS[MPC],
            "format_version": FORMAT_VERSIONS[MPC],
            "package_version": __version__,
            "model_file": out.name,
            "model_sha256": digest,
            "name": src.name,
            "architecture": src.architecture,
            "history": m,
            "horizon": horizon,
            **mpc_io_spec(m, horizon, members),
            **({"member_count": members, "calibration": src.net.calibration} if ensemble else {}),
            "layout": mpc_layout(),
            "params": src.configs["params"],
            "variant": src.variant,
            "configs": src.configs,
            "source": src.source,
            "preflight": checks,
            "export": {**export_record(opset, diff), "checked_candidates": list(CHECK_CANDIDATES)},
        },
    )
    return MPCExportResult(out, sidecar, horizon, m, opset, diff, time.perf_counter() - start)


def _export_compiled(
    src: _Source, out: Path, horizon: int, start: float, checks: dict[str, Any]
) -> MPCExportResult:
    """``export_for_mpc``'s compiled format: the fold (or the discrete model's constants) as an
    archive, checked through the very rollouts that will load it before it is kept; ``checks``:
    the run's pre-flight verdicts, carried in the sidecar."""
    from .compiled.archive import (
        PHYSICS_MODEL,
        arrays,
        columns_of,
        ensemble_arrays,
        folded_record,
    )
    from .compiled.fold import fold

    if out.is_dir():
        out = out / f"{src.name}{COMPILED_SUFFIX}"
    elif out.suffix != ".npz":
        raise ValueError(
            f"export_for_mpc: a compiled model is a .npz file ({COMPILED_SUFFIX}), not {out}"
        )
    check_sidecar_free(out)
    meta: dict[str, Any] = {
        "name": src.name,
        "architecture": src.architecture,
        "history": src.history,
    }
    if src.architecture == PHYSICS_MODEL:
        physics = src.net.physics
        meta.update(constants=physics.constants, prior_weight=physics.prior_weight)
        data = arrays(None, VehicleConstants.of(from_dict(VehicleParams, src.configs["params"])))
    elif isinstance(src.net, EnsembleCandidatesNet):
        folds = [fold(net.model) for net in src.net.nets]
        meta.update(members=[folded_record(w) for w in folds], calibration=src.net.calibration)
        data = ensemble_arrays(folds)
    else:
        folded = fold(src.net.model)
        meta["folded"] = folded_record(folded)
        data = arrays(folded, folded.vehicle)
    model = columns_of(data, meta)
    diff = max(_parity(src, model.predict_candidates, k) for k in CHECK_CANDIDATES)
    if not diff <= PARITY_TOLERANCE:
        raise OnnxModelError(
            f"{out}: the compiled model disagrees with the eager model by {diff:.3g} "
            f"(> {PARITY_TOLERANCE}); not written"
        )
    write_npz(out, data)
    write_json(
        sidecar_path(out),
        {
            "format": FORMATS[COMPILED],
            "format_version": FORMAT_VERSIONS[COMPILED],
            "package_version": __version__,
            "model_file": out.name,
            "model_sha256": sha256(out),
            **meta,
            "layout": mpc_layout(),
            "params": src.configs["params"],
            "variant": src.variant,
            "configs": src.configs,
            "source": src.source,
            "preflight": checks,
            "export": {**versions("torch", "numba", "numpy"), "max_abs_diff_vs_torch": diff,
                       "checked_candidates": list(CHECK_CANDIDATES), "checked_horizon": horizon},
        },
    )  # fmt: skip
    seconds = time.perf_counter() - start
    return MPCExportResult(out, sidecar_path(out), horizon, src.history, None, diff, seconds)


class MembersNet(nn.Module):
    """Every member's candidates, stacked (E, K, N, 13): an ensemble's ONNX graph (the mean,
    and the spread, are taken in numpy: ``members.members_mean``)."""

    def __init__(self, nets: nn.ModuleList) -> None:
        super().__init__()
        self.nets = nets

    def forward(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        return torch.stack([net(x_hist, u_past, plans) for net in self.nets])


class EnsembleCandidatesNet(nn.Module):
    """An ensemble's candidates (``CandidatesNet`` members): their mean
    (``models.ensemble.spread``), what the compiled export is checked against."""

    def __init__(self, nets: list[CandidatesNet], calibration: dict | None) -> None:
        super().__init__()
        self.nets = nn.ModuleList(nets)
        self.calibration = calibration

    def forward(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        return spread(torch.stack([net(x_hist, u_past, plans) for net in self.nets])).mean


def onnx_graph(net: nn.Module) -> nn.Module:
    """What the candidates graph traces of ``net``: an ensemble's members stacked
    (``MembersNet``), any other model as it is."""
    return MembersNet(net.nets) if isinstance(net, EnsembleCandidatesNet) else net


def _export_source(run_or_ckpt, horizon: int, params: VehicleParams | None, format: str) -> _Source:
    """What ``export_for_mpc`` exports: an ensemble folder or one model."""
    if isinstance(run_or_ckpt, Predictor) or not is_ensemble(run_or_ckpt):
        return _source(run_or_ckpt, horizon, params)
    return _ensemble_source(run_or_ckpt, horizon)


def _ensemble_source(folder: str | Path, horizon: int) -> _Source:
    """An ensemble folder as one source: its members' candidates, the first member's configs
    and inputs (the members share a recipe), the calibration as a dict."""
    manifest = read_manifest(folder)
    members = [_source(run, horizon, None) for run in manifest.members]
    if len({m.history for m in members}) != 1:
        raise ValueError(f"{folder}: ensemble members with different histories M")
    first = members[0]
    calibration = None if manifest.calibration is None else to_dict(manifest.calibration)
    net = EnsembleCandidatesNet([m.net for m in members], calibration).eval()
    name = Path(folder).expanduser().resolve().name
    return first._replace(net=net, name=name, architecture="ensemble",
                          source=f"ensemble {folder} ({len(members)} members)")  # fmt: skip


def _source(run_or_ckpt, horizon: int, params: VehicleParams | None) -> _Source:
    if not isinstance(run_or_ckpt, Predictor) and str(run_or_ckpt) == PHYSICS:
        params = params or VehicleParams()
        net = PhysicsCandidatesNet(params).eval()
        configs = {"params": to_dict(params)}

        def physics_inputs(k: int, seed: int):
            return hover_inputs(params, horizon, k, seed=seed)

        return _Source(net, 2, PHYSICS, PHYSICS, None, configs, "physics model", physics_inputs)
    predictor, configs, source = _load(run_or_ckpt)
    name = export_name(run_or_ckpt, horizon).removesuffix(f"-n{horizon}.onnx")

    def network_inputs(k: int, seed: int):
        return candidate_inputs(predictor, horizon, k, seed=seed)

    net = CandidatesNet(predictor.model.cpu().eval()).eval()
    arch = predictor.model.architecture
    return _Source(
        net, predictor.window.history, name, arch, predictor.variant, configs, source,
        network_inputs,
    )  # fmt: skip


def candidate_inputs(
    predictor: Predictor, horizon: int, k: int, *, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plausible float32 inputs of the candidates graph: x_hist (M, 13), u_past (M-1, 4) and
    plans (K, N, 4), a history from ``onnx.sample_inputs`` (package layout) and K plans
    spread around its inputs by a fifth of the fitted input spread."""
    from .onnx import sample_inputs

    history, future = sample_inputs(predictor, batch=1, horizon=horizon, seed=seed)
    x_hist = states_from_file(torch.from_numpy(history[0, :, :STATE_DIM]).double()).float().numpy()
    u = np.concatenate([history[0, :, STATE_DIM:], future[0]])  # (M + N, 4) u_0 ... u_{M+N-1}
    m = x_hist.shape[0]
    spread = 0.2 * predictor.model.input_std.cpu().numpy()
    noise = np.random.default_rng(seed).standard_normal((k, horizon, 4)) * spread
    plans = (u[m - 1 : m - 1 + horizon] + noise).astype(np.float32)
    return x_hist, u[: m - 1].astype(np.float32), plans


def hover_inputs(
    params: VehicleParams, horizon: int, k: int, *, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Float32 inputs of the physics model's graph: two history rows of a vehicle drifting
    near hover with its load a little off the vertical, and K plans around hover thrust."""
    rng = np.random.default_rng(seed)
    p = np.array([0.3, -0.2, 1.5]) + 0.1 * rng.standard_normal(3)
    v = 0.3 * rng.standard_normal(3)
    cable = np.array([0.05, -0.03, -1.0])
    load = p + params.cable_length * cable / np.linalg.norm(cable)
    x1 = np.concatenate([p, v, [1.0, 0.0, 0.0, 0.0], load])
    x0 = x1 - params.dt * np.concatenate([v, np.zeros(7), v + [0.02, 0.0, 0.0]])
    hover = np.array([(params.mass_quad + params.mass_load) * params.gravity, 0.0, 0.0, 0.0])
    plans = hover + rng.standard_normal((k, horizon, 4)) * np.array([1.0, 0.5, 0.5, 0.2])
    arrays = (np.stack([x0, x1]), hover[None], plans)
    return tuple(a.astype(np.float32) for a in arrays)


def _parity(src: _Source, predict: Callable, k: int) -> float:
    """max |predict - the eager model| on plausible inputs with K = k; predict: an ONNX
    Runtime session or a numpy candidates call."""
    x_hist, u_past, plans = src.inputs(k, k)
    net = src.net
    if isinstance(predict, ort.InferenceSession):
        got = predict.run(None, {X_HIST: x_hist, U_PAST: u_past, PLANS: plans})[0]
        net = onnx_graph(net)  # an ensemble's graph gives every member
    else:
        got = predict(*(a.astype(np.float64) for a in (x_hist, u_past, plans)))
    with torch.no_grad():
        want = net(*(torch.from_numpy(a) for a in (x_hist, u_past, plans))).numpy()
    return float(np.abs(got - want).max())
