"""Checkpoints: what a slungload ``.ckpt`` holds, and the network rebuilt from one.

A checkpoint is a Lightning checkpoint (written by ``training.train``) that embeds every
config as plain dicts under the key ``CKPT_KEY``, so ``load_checkpoint`` rebuilds the model
from the file alone: ``ModelConfig.architecture`` names its class in ``models.MODELS`` (an
unknown name is an error naming it; a checkpoint without the name is the paper's network).
Files are read with ``torch.load(weights_only=True)``: no arbitrary
object is ever unpickled, and reading needs torch only, not Lightning. A file that is not a
readable slungload checkpoint of this ``CKPT_FORMAT`` raises ``ValueError`` naming the file.
"""

from __future__ import annotations

import re
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch
from torch import nn

from .._version import __version__
from ..config import (
    LossWeights,
    ModelConfig,
    TrainConfig,
    VehicleParams,
    WindowConfig,
    from_dict,
    to_dict,
)
from ..run_config import RunConfig
from .registry import build

CKPT_KEY = "slungload"  # where the configs live inside a Lightning checkpoint
CKPT_FORMAT = 1  # bump when the embedded dict changes incompatibly
BEST, LAST = "best.ckpt", "last.ckpt"  # a run folder's best and latest checkpoints


@dataclass(frozen=True)
class LoadedModel:
    """A trained network rebuilt from a checkpoint, in eval mode on the CPU."""

    model: nn.Module  # a registered architecture (``model.architecture`` names it)
    variant: str
    window: WindowConfig
    params: VehicleParams  # the dataset's constants it trained with (windows, physics baseline)
    model_params: VehicleParams  # the constants of its physics: fitted ones, or ``params``
    model_config: ModelConfig
    weights: LossWeights
    train_config: TrainConfig
    meta: dict[str, Any]  # everything embedded in the file (plain dicts)
    path: Path

    @property
    def run(self) -> RunConfig:
        """The run it was trained as: its folder name and its label in the tables."""
        return RunConfig.from_meta(self.meta)


def checkpoint_path(path: str | Path) -> Path:
    """A ``.ckpt`` file as given, or a run folder's ``best.ckpt``."""
    path = Path(path).expanduser()
    if path.is_dir():
        if not (path / BEST).is_file() and (path / LAST).is_file():
            raise FileNotFoundError(
                f"{path} has no {BEST} (the run stopped before its first validation); "
                f"use its latest weights: {path / LAST}"
            )
        path = path / BEST
    if not path.is_file():
        raise FileNotFoundError(f"checkpoint {path} does not exist")
    return path


def load_checkpoint(path: str | Path, *, map_location: str | torch.device = "cpu") -> LoadedModel:
    """Rebuild the network of a slungload checkpoint (a ``.ckpt``, or a run folder's best).

    Loads with ``torch.load(weights_only=True)``: no arbitrary object is ever unpickled.
    Raises ``ValueError`` naming the file if it is not a slungload checkpoint.
    """
    path = checkpoint_path(path)
    ckpt, meta = _read_checkpoint(path, map_location)
    try:
        # A checkpoint written before architectures had names has no "architecture" key: its
        # ModelConfig takes the default, the paper's network, which is what it holds.
        model_config = from_dict(ModelConfig, meta["model"])
        params = from_dict(VehicleParams, meta["params"])
        # A run that fitted the constants (TrainConfig.fit_constants) built its network with
        # them; the dataset's own stay in "params" (the windows and the physics baseline).
        model_params = from_dict(VehicleParams, meta.get("model_params", meta["params"]))
        net = build(model_config, model_params)
        prefix = "net."
        state = {k[len(prefix) :]: v for k, v in ckpt["state_dict"].items() if k.startswith(prefix)}
        net.load_state_dict(state)
        loaded = LoadedModel(
            model=net.eval(),
            variant=str(meta["variant"]),
            window=from_dict(WindowConfig, meta["window"]),
            params=params,
            model_params=model_params,
            model_config=model_config,
            weights=from_dict(LossWeights, meta["weights"]),
            train_config=from_dict(TrainConfig, meta["train"]),
            meta=meta,
            path=path,
        )
    except (KeyError, TypeError, ValueError, RuntimeError) as exc:
        raise ValueError(
            f"{path}: {_written_by(meta)} does not fit this slungload {__version__} "
            f"({type(exc).__name__}: {_first_line(exc)})"
        ) from exc
    return loaded


def checkpoint_meta(path: str | Path) -> dict[str, Any]:
    """The configs embedded in a checkpoint (a ``.ckpt``, or a run folder's best), e.g. its
    ``preset`` or ``window``, read with the same checks as ``load_checkpoint`` but without
    building the network (an ensemble folder: ``ensemble.model_meta``)."""
    return _read_checkpoint(checkpoint_path(path))[1]


def _read_checkpoint(path: Path, map_location: Any = "cpu") -> tuple[dict, dict[str, Any]]:
    """The checkpoint dict and its embedded configs, loaded with ``weights_only=True``."""
    if not zipfile.is_zipfile(path):  # torch.load would try any other bytes as a raw pickle
        raise ValueError(
            f"{path}: not a readable checkpoint (not a torch zip archive: truncated, or "
            "another format)"
        )
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # zip, pickle or format errors all mean the same to the caller
        if "Weights only load failed" in str(exc):
            # torch's message is a paragraph on how to allow it; keep only what was refused.
            found = re.search(r"GLOBAL ([\w.]+)", str(exc))
            what = f"it calls {found.group(1)}" if found else _first_line(exc)
            raise ValueError(
                f"{path}: holds pickled Python objects beyond tensors and plain data, which "
                f"are refused, never unpickled ({what})"
            ) from None
        raise ValueError(
            f"{path}: not a readable checkpoint ({type(exc).__name__}: {_first_line(exc)})"
        ) from exc
    meta = ckpt.get(CKPT_KEY) if isinstance(ckpt, dict) else None
    if not isinstance(meta, dict) or not isinstance(ckpt.get("state_dict"), Mapping):
        raise ValueError(f"{path}: not a slungload checkpoint (no '{CKPT_KEY}' configs inside)")
    if meta.get("format") != CKPT_FORMAT:
        raise ValueError(
            f"{path}: {_written_by(meta)} uses checkpoint format {meta.get('format')!r}; "
            f"this slungload {__version__} reads format {CKPT_FORMAT}"
        )
    return ckpt, _upgrade(meta)


def _upgrade(meta: dict[str, Any]) -> dict[str, Any]:
    """Configs of an older checkpoint in today's layout: the options that were kept beside
    ``TrainConfig`` under "extras" are ``TrainConfig`` fields now."""
    extras = meta.get("extras")
    if isinstance(extras, dict) and isinstance(meta.get("train"), dict):
        meta = {k: v for k, v in meta.items() if k != "extras"}
        meta["train"] = {**meta["train"], **extras}
    return meta


def _written_by(meta: dict[str, Any]) -> str:
    return f"checkpoint written by slungload {meta.get('package_version', '(unknown version)')}"


def _first_line(exc: BaseException) -> str:
    """An exception's message on one line: its first two lines, at most 300 characters."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    text = " ".join(lines[:2]) or type(exc).__name__
    return text if len(text) <= 300 else text[:297] + "..."


def check_resumable(last: Path, meta: dict[str, Any]) -> None:
    """Refuse to resume a run with other settings than it was started with, naming them."""
    _, saved = _read_checkpoint(last)
    # fields added since get their defaults
    for key, kind in (("weights", LossWeights), ("model", ModelConfig)):
        if isinstance(saved.get(key), dict):
            saved = {**saved, key: to_dict(from_dict(kind, saved[key]))}
    # The epoch budget may be raised on resume, the data folder may have moved, and the same
    # constants may come from vehicle.json or from options.
    # The time cap is a safety net, not part of the schedule: a run it stopped resumes without.
    free = {"package_version", "data", "params_source", "train.max_epochs", "train.max_time"}
    # Fitted constants are refitted on resume (the same data give the same fit).
    refitted = ("constants", "model_params")
    differ = [
        d
        for d in _differences(saved, meta)
        if d[0] not in free and d[0].split(".")[0] not in refitted
    ]
    order = ["variant", "preset", "window", "params", "model", "weights", "train"]
    differ.sort(
        key=lambda d: order.index(d[0].split(".")[0]) if d[0].split(".")[0] in order else 99
    )
    if differ:
        details = "; ".join(f"{k}: {a!r} -> {b!r}" for k, a, b in differ[:8])
        details += f"; and {len(differ) - 8} more" if len(differ) > 8 else ""
        weights = {k.split(".")[0] for k, _, _ in differ} <= {"physics_rms", "physics_diverged"}
        advice = (
            "its step weights came out otherwise (the training flights changed, or windows whose "
            "physics rollout diverged are now left out): start a new run folder"
            if weights
            else "resume with the same options or start a new run folder"
        )
        raise ValueError(
            f"cannot resume {last}: it was started with other settings ({details}); {advice}"
        )


def _differences(a: Any, b: Any, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """(dotted key, a's value, b's value) wherever two nested dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for key in sorted(set(a) | set(b), key=str):
            out += _differences(a.get(key), b.get(key), f"{prefix}{key}.")
        return out
    return [] if a == b else [(prefix.rstrip("."), a, b)]
