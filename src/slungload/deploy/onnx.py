"""ONNX export of a trained network for whole windows (its runtime: ``onboard.OnnxPredictor``).

    result = export("runs/proposed", "model-n25.onnx", horizon=25)  # + model-n25.json
    predictor = onboard.OnnxPredictor("model-n25.onnx")  # numpy + onnxruntime, no torch
    states = predictor.predict(history, future_inputs)  # (N, 13), as predictor.Predictor

The ONNX file is self-contained: it takes and returns the **file layout** of
``predictor.Predictor`` (quaternions x-y-z-w, physical units) and holds the normalisation, the
quaternion reordering and sign continuity, and the final unit-norm projection
(``predictor.FileLayoutNet`` is what gets exported). Inputs and outputs, float32::

    history        (batch, M, 17)  rows x_k, u_k for k = 0 ... M-1 (the graph takes any M >= 1;
                                   ``OnnxPredictor`` the trained M unless ``any_history``)
    future_inputs  (batch, N, 4)   u_M ... u_{M+N-1}; N is fixed per file
    states         (batch, N, 13)  x_M ... x_{M+N-1}

N is fixed per file because the exporter unrolls the decoder's recursion (export one file per
horizon); batch and M are dynamic. A JSON sidecar beside the model (same name, ``.json``;
``sidecar``, the ``window`` format) describes the columns, units, shapes, the quaternion
convention, every config of the run and the package version; ``OnnxPredictor`` refuses a model
whose file, inputs, outputs or state layout disagree with its sidecar. The exporter needs torch;
the predictor does not.
"""

from __future__ import annotations

import copy
import math
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from .._version import __version__
from ..config import DEFAULT_ARCHITECTURE, to_dict
from ..fileio import atomic_path, write_json
from ..models.checkpoints import load_checkpoint
from ..models.registry import require_architecture
from ..reporting import versions
from ..state import (
    INPUT_DIM,
    LOAD_POS,
    POS,
    STATE_DIM,
    rotate_about_z,
    with_unit_quaternion,
)
from .onboard import CPU, session_options
from .predictor import (
    PARITY_TOLERANCE,
    FileLayoutNet,
    Predictor,
    states_to_file,
)
from .sidecar import (
    FORMAT_VERSIONS,
    FORMATS,
    FUTURE_INPUT,
    HISTORY_INPUT,
    STATES_OUTPUT,
    WINDOW,
    OnnxModelError,
    check_sidecar_free,
    sha256,
    sidecar_path,
    window_io_spec,
    window_layout,
)

OPSET = 17
# The architectures whose export is checked by tests; any other is refused by name.
ONNX_ARCHITECTURES = (DEFAULT_ARCHITECTURE, "physics-step")


# --- export ------------------------------------------------------------------------------


@dataclass(frozen=True)
class ExportResult:
    """What ``export`` wrote."""

    model: Path  # the .onnx file
    sidecar: Path  # its JSON description
    horizon: int  # N, fixed in the file
    history: int  # M the network was trained with (the graph accepts any M >= 1)
    opset: int
    max_abs_diff: float  # max |ONNX Runtime - eager torch| on the export-time check inputs
    seconds: float  # wall-clock time of the export and check

    def summary(self) -> str:
        return (
            f"{self.model} (+ {self.sidecar.name}): N = {self.horizon}, opset {self.opset}, "
            f"max |onnx - torch| = {self.max_abs_diff:.2e}, {self.seconds:.1f} s"
        )


def export(
    run_or_ckpt: str | Path | Predictor,
    out: str | Path,
    *,
    format: str = "onnx",
    horizon: int | None = None,
    opset: int = OPSET,
) -> ExportResult:
    """Write ``out`` (ONNX) and its sidecar ``out.with_suffix('.json')``.

    run_or_ckpt: a run folder (its ``best.ckpt``), a ``.ckpt`` written by ``train``, or a
    loaded ``Predictor``. out: the model file to write, in an existing folder (a missing
    folder is an error, not created); or an existing folder, to write
    ``<run name>-n<N>.onnx`` into it (``export_name``). horizon: N fixed in the file
    (default: the N it was trained with). The export is checked against the eager network
    with ONNX Runtime before it is kept; a disagreement above ``PARITY_TOLERANCE`` raises
    ``OnnxModelError``.
    """
    if format != "onnx":
        raise ValueError(f"export: unknown format {format!r}; only 'onnx' is supported")
    start = time.perf_counter()
    out = Path(out)
    if not out.is_dir():
        _check_model_path(out)  # before the (slower) load
    predictor, configs, source = _load(run_or_ckpt)
    n = predictor.window.horizon if horizon is None else int(horizon)
    if n < 1:
        raise ValueError(f"export: horizon must be >= 1, got {n}")
    m = predictor.window.history
    if out.is_dir():
        out = out / export_name(run_or_ckpt, n)
    check_sidecar_free(out)
    model = predictor.model.cpu().eval()
    net = FileLayoutNet(model).eval()
    history, future = sample_inputs(predictor, batch=2, horizon=n)

    with atomic_path(out) as tmp:
        trace_to_onnx(
            net, (history, future), tmp, opset, ([HISTORY_INPUT, FUTURE_INPUT], [STATES_OUTPUT]),
            {HISTORY_INPUT: {0: "batch", 1: "history"}, FUTURE_INPUT: {0: "batch"},
             STATES_OUTPUT: {0: "batch"}},
        )  # fmt: skip
        session = ort.InferenceSession(str(tmp), session_options(1), providers=CPU)
        got = session.run(None, {HISTORY_INPUT: history, FUTURE_INPUT: future})[0]
        want = predictor.predict(history, future).astype(np.float32)
        diff = float(np.abs(got - want).max())
        if not diff <= PARITY_TOLERANCE:
            raise OnnxModelError(
                f"{out}: exported model disagrees with the eager network by {diff:.3g} "
                f"(> {PARITY_TOLERANCE}); not written"
            )
        digest = sha256(tmp)
    sidecar = sidecar_path(out)
    write_json(
        sidecar,
        {
            "format": FORMATS[WINDOW],
            "format_version": FORMAT_VERSIONS[WINDOW],
            "package_version": __version__,
            "model_file": out.name,
            "model_sha256": digest,
            "history": m,
            "horizon": n,
            **window_io_spec("history", n),
            "layout": window_layout(),
            "variant": predictor.variant,
            "configs": configs,
            "source": source,
            "export": export_record(opset, diff),
        },
    )
    return ExportResult(out, sidecar, n, m, opset, diff, time.perf_counter() - start)


def export_name(run_or_ckpt: str | Path | Predictor, horizon: int) -> str:
    """File name ``export`` gives a model written into a folder: ``<run name>-n<N>.onnx``.

    The run name is the run folder's name (for a ``.ckpt``: its folder's, with the file's
    stem unless it is ``best``); an in-memory ``Predictor`` is ``model``.
    """
    if isinstance(run_or_ckpt, Predictor):
        name = "model"
    else:
        path = Path(run_or_ckpt).resolve()
        if path.is_dir():
            name = path.name
        else:
            name = path.parent.name + ("" if path.stem == "best" else f"-{path.stem}")
    return f"{name or 'model'}-n{horizon}.onnx"


def _check_model_path(out: Path) -> None:
    """``out`` must name a file in an existing folder (not the sidecar's name)."""
    folder = out.parent
    if not folder.exists():
        raise FileNotFoundError(
            f"export: folder {folder} does not exist (create it first); out is the model file "
            "to write, or an existing folder to write <run name>-n<N>.onnx into"
        )
    if not folder.is_dir():
        raise NotADirectoryError(f"export: {folder} is not a folder, so {out} cannot be written")
    if out.suffix.lower() == ".json":
        raise ValueError(
            f"export: {out} would be overwritten by the model's JSON sidecar; name the model "
            "file .onnx"
        )


def _load(source: str | Path | Predictor) -> tuple[Predictor, dict[str, Any], str]:
    """A predictor, the configs to record and a description of where it came from; an
    architecture outside ``ONNX_ARCHITECTURES`` is refused by name."""
    predictor, configs, where = _read(source)
    require_architecture(predictor.model, ONNX_ARCHITECTURES, "the ONNX exporter")
    return predictor, configs, where


def _read(source: str | Path | Predictor) -> tuple[Predictor, dict[str, Any], str]:
    if isinstance(source, Predictor):
        if source.device.type != "cpu":  # export on the CPU without moving the caller's model
            model = copy.deepcopy(source.model).cpu()
            source = Predictor(model, source.window, source.params, source.variant)
        configs = {
            "model": to_dict(source.model.config),
            "window": to_dict(source.window),
            "params": to_dict(source.params),
        }
        return source, configs, "in-memory Predictor"
    loaded = load_checkpoint(source)
    predictor = Predictor(loaded.model.eval(), loaded.window, loaded.params, loaded.variant)
    configs = {
        "model": to_dict(loaded.model_config),
        "window": to_dict(loaded.window),
        "params": to_dict(loaded.params),
        "weights": to_dict(loaded.weights),
        "train": to_dict(loaded.train_config),
    }
    return predictor, configs, str(loaded.path)


def trace_to_onnx(
    net: Any,
    inputs: Sequence[np.ndarray],
    path: Path,
    opset: int,
    names: tuple[Sequence[str], Sequence[str]],
    dynamic_axes: dict[str, dict[int, str]],
) -> None:
    """``net`` traced on ``inputs`` into ``path`` with the TorchScript-based exporter
    (``dynamo=False``: the dynamo one needs onnxscript); ``names`` = (input names, output
    names). The tracer unrolls Python loops, so a decoder's N is fixed by the inputs' shapes;
    ``dynamic_axes`` declares the others."""
    import torch

    args = tuple(torch.from_numpy(a) for a in inputs)
    with warnings.catch_warnings(), torch.no_grad():
        # The tracer warns about Python-side shape checks and its own deprecation; both are
        # expected (shapes are declared, and every export is checked with ONNX Runtime).
        warnings.simplefilter("ignore")
        torch.onnx.export(
            net, args, str(path), dynamo=False, opset_version=opset, input_names=list(names[0]),
            output_names=list(names[1]), dynamic_axes=dynamic_axes,
        )  # fmt: skip


def sample_inputs(
    predictor: Predictor, *, batch: int = 2, horizon: int | None = None, seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """Plausible float32 file-layout inputs around the network's normalisation statistics.

    history (batch, M, 17) and future_inputs (batch, N, 4): per window, a last state drawn
    around the fitted mean with half the fitted spread (the load at the mean offset from the
    vehicle) reached by a random walk in steps of the fitted per-step change, inputs drawn
    around their means with half their spread, unit quaternions, a random arena position, and
    for a heading-frame network (``ModelConfig.heading_frame``, whose statistics are those of
    heading zero) a random heading. Used to trace the export and to check it; not a substitute
    for real windows.
    """
    import torch

    model = predictor.model
    m = predictor.window.history
    n = predictor.window.horizon if horizon is None else horizon
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        x = model.state_mean + 0.5 * model.state_std * torch.randn(
            batch, 1, STATE_DIM, generator=gen
        )
        # Rows drawn independently would mean a load anywhere but on its cable and huge speeds
        # between rows: a network that steps the discrete model ('physics-step', from the load
        # state estimated on the last two rows) diverges from such a history.
        x[..., LOAD_POS] = x[..., POS] + (model.state_mean[LOAD_POS] - model.state_mean[POS])
        walk = model.delta_std * torch.randn(batch, m, STATE_DIM, generator=gen)
        x = x + walk.cumsum(1) - walk.sum(1, keepdim=True)  # (batch, M, 13), last row x
        x = x + model.origin(torch.randn(batch, 1, STATE_DIM, generator=gen))
        u = model.input_mean + 0.5 * model.input_std * torch.randn(
            batch, m + n, INPUT_DIM, generator=gen
        )
    x = with_unit_quaternion(x.double())
    if model.config.heading_frame:  # its statistics face one way: check the turn, every way
        yaw = torch.rand(batch, 1, generator=gen, dtype=torch.float64) * 2 * math.pi - math.pi
        x = rotate_about_z(x, torch.zeros(*x.shape[:-1], 6, dtype=x.dtype), yaw)[0]
    x = states_to_file(x)
    history = torch.cat([x, u[:, :m].double()], dim=-1)
    return history.float().numpy(), u[:, m:].float().numpy()


def export_record(opset: int, diff: float) -> dict[str, Any]:
    """The sidecar's "export" entry: the opset, the exporting libraries' versions and the
    largest |onnx - torch| of the export-time check."""
    found = versions("torch", "onnx", "onnxruntime")
    return {"opset": opset, **{k: found[k] for k in ("torch", "onnx", "onnxruntime")},
            "max_abs_diff_vs_torch": diff}  # fmt: skip
