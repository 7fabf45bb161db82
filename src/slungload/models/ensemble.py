"""Ensembles: several trained networks of one recipe, predicting a mean and a spread.

An ensemble is a folder holding ``ensemble.json`` (``ENSEMBLE_FILE``) beside its members'
run folders (``train --ensemble K`` writes ``member-0`` ...; ``slungload ensemble`` names
runs trained elsewhere, by paths relative to the folder). It is one model:
``load_prediction_model(folder)`` builds an ``EnsembleModel``, which meets the
``PredictionModel`` contract with the members' mean, and adds the members themselves
(``predict_windows_members`` / ``predict_candidates_members``: (E, ..., 13)).

The spread is the members' standard deviation per state component (``spread``). A
``Calibration`` (fitted on held-out windows by ``evaluation.uncertainty.fit_calibration``
and stored in ``ensemble.json``) scales it per horizon step and state group, so that
``mean +- z(level) * scale * std`` is the stated interval: split-conformal at ``level``
(the scale is the ``level`` quantile of |error| / std on the windows it was fitted on,
divided by the Gaussian z of that level), Gaussian z at any other level. Steps beyond the
fitted horizon keep its last step's scale. ``Calibration.novelty`` flags windows whose
spread is far above what the fitting windows showed (the model outside what it has seen).
With ``Calibration.constants_shift`` the spread the scale multiplies is sqrt(std^2 +
shift^2), shift the physics model's move under the constants estimated in flight
(``constants_estimate.constants_shift``): members that learned one vehicle all agree on
another's motion, the physics model's constants do not.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from statistics import NormalDist
from typing import Any, NamedTuple

import numpy as np
import torch
from torch import Tensor

from .._version import __version__
from ..config import ENSEMBLE_LEVEL as LEVEL
from ..config import VehicleParams, from_dict, to_dict
from ..constants_estimate import constants_shift
from ..fileio import read_json, write_json
from ..layout import GROUPS, QUAT, STATE_DIM
from ..state import with_unit_quaternion
from .checkpoints import LoadedModel, checkpoint_meta, load_checkpoint

ENSEMBLE_FILE = "ensemble.json"  # an ensemble folder's manifest
ENSEMBLE_FORMAT = 1  # bump when the manifest changes incompatibly
MEMBER_PREFIX = "member-"  # ``train --ensemble``'s member folders: member-0, member-1, ...


def z_of(level: float) -> float:
    """The two-sided Gaussian z of a coverage ``level`` in (0, 1) (1.645 at 0.9)."""
    if not 0.0 < level < 1.0:
        raise ValueError(f"an interval's level must lie in (0, 1), got {level}")
    return NormalDist().inv_cdf(0.5 + level / 2.0)


class Spread(NamedTuple):
    """Members' mean and standard deviation, (..., 13) each: the mean with a unit quaternion,
    the std per component (unbiased over the members)."""

    mean: Tensor
    std: Tensor


def spread(members: Tensor) -> Spread:
    """members (E >= 2, ..., 13) -> their ``Spread``. Each member's quaternion is first turned
    to the first member's hemisphere (q and -q are one attitude)."""
    if members.dim() < 2 or members.shape[0] < 2 or members.shape[-1] != STATE_DIM:
        raise ValueError(f"spread: expected (E >= 2, ..., {STATE_DIM}), got {tuple(members.shape)}")
    q = members[..., QUAT]
    sign = torch.where((q * q[:1]).sum(-1, keepdim=True) < 0, -1.0, 1.0).to(q.dtype)
    aligned = members.clone()
    aligned[..., QUAT] = q * sign
    return Spread(with_unit_quaternion(aligned.mean(0)), aligned.std(0))


def widened(std: Tensor, shift: Tensor) -> Tensor:
    """The members' std (..., N, 13) widened in quadrature by a constants shift of the same
    shape: sqrt(std^2 + shift^2), in std's dtype."""
    return (std * std + shift.to(std) ** 2).sqrt()


def group_index() -> Tensor:
    """(13,) the ``layout.GROUPS`` index of each state component; -1 where in none."""
    index = torch.full((STATE_DIM,), -1, dtype=torch.long)
    for g, sl in enumerate(GROUPS.values()):
        index[sl] = g
    return index


ROW_FIELDS = ("scale", "reference_std")  # a Calibration's per-step tables


@dataclass(frozen=True)
class Calibration:
    """Per-step, per-group scales on the members' std, and the novelty reference.

    scale: (N, G) rows per horizon step 1..N, columns ``groups``, such that
    ``z_of(level) * scale * std`` is the interval's half width. reference_std: (N, 13) the
    median std per step and component on the fitting windows; novelty_threshold: the
    ``novelty_quantile`` of ``novelty_score`` there. fitted_on: where (a dataset and split).
    constants_shift: whether the std these apply to is first widened by each window's
    constants shift (``interval_std``); such a calibration needs the shift wherever it is used.
    """

    scale: tuple[tuple[float, ...], ...]
    reference_std: tuple[tuple[float, ...], ...]
    novelty_threshold: float
    level: float = LEVEL
    novelty_quantile: float = 0.99
    groups: tuple[str, ...] = tuple(GROUPS)
    fitted_on: str = ""
    windows: int = 0
    constants_shift: bool = False

    def __post_init__(self) -> None:
        if self.groups != tuple(GROUPS):
            raise ValueError(f"a calibration of groups {self.groups}, not {tuple(GROUPS)}")
        if not self.scale or any(len(r) != len(self.groups) for r in self.scale):
            raise ValueError("Calibration.scale must be (N >= 1, groups)")
        if len(self.reference_std) != len(self.scale):
            raise ValueError("Calibration.reference_std must have one row per step of scale")

    @property
    def horizon(self) -> int:
        return len(self.scale)

    def _rows(self, steps: int) -> Tensor:
        """The fitted row of each of ``steps`` steps: past ``horizon``, the last."""
        return torch.clamp(torch.arange(steps), max=self.horizon - 1)

    def component_scale(self, steps: int) -> Tensor:
        """(steps, 13) float64 scale per step and component; past ``horizon`` the last row."""
        scale = torch.tensor(self.scale, dtype=torch.float64)[self._rows(steps)]
        out = torch.ones(steps, STATE_DIM, dtype=torch.float64)
        idx = group_index()
        have = idx >= 0
        out[:, have] = scale[:, idx[have]]
        return out

    def interval_std(self, std: Tensor, shift: Tensor | None = None) -> Tensor:
        """The spread the scale multiplies: the members' std (..., N, 13), or with
        ``constants_shift`` sqrt(std^2 + shift^2), shift (..., N, 13) the windows'
        ``constants_estimate.constants_shift``. A ``ValueError`` where the shift is missing or
        not wanted."""
        if not self.constants_shift:
            if shift is not None:
                raise ValueError("a constants shift given to a calibration fitted without one")
            return std
        if shift is None:
            raise ValueError(
                "this calibration widens the spread by the physics model's constants shift "
                "(calibrate --constants-shift), and no shift was given: compute it "
                "(constants_estimate.constants_shift), or calibrate without --constants-shift"
            )
        return widened(std, shift)

    def half_width(
        self, std: Tensor, level: float | None = None, shift: Tensor | None = None
    ) -> Tensor:
        """std (..., N, 13) (and ``interval_std``'s shift) -> the interval's half width, same
        shape and dtype."""
        lvl = self.level if level is None else level
        std = self.interval_std(std, shift)
        scale = self.component_scale(std.shape[-2]).to(std.device, std.dtype)
        return z_of(lvl) * scale * std

    def novelty_score(self, std: Tensor, shift: Tensor | None = None) -> Tensor:
        """std (..., N, 13) (and ``interval_std``'s shift) -> (...): mean over steps and
        components of the interval's std / reference."""
        std = self.interval_std(std, shift)
        ref = torch.tensor(self.reference_std, dtype=torch.float64)[self._rows(std.shape[-2])]
        ratio = std / ref.to(std.device, std.dtype).clamp_min(1e-12)
        return ratio.mean(dim=(-2, -1))

    def novel(self, std: Tensor, shift: Tensor | None = None) -> Tensor:
        """std (..., N, 13) -> (...) bool: spread beyond what the fitting windows showed."""
        return self.novelty_score(std, shift) > self.novelty_threshold

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Calibration:
        """``config.to_dict``'s output, read back (JSON's nested lists as tuples of floats)."""
        rows = {k: tuple(tuple(float(v) for v in r) for r in d[k]) for k in ROW_FIELDS}
        return from_dict(cls, {**d, **rows})


@dataclass
class EnsembleModel:
    """Members (prediction models of one history M) predicting their mean (``PredictionModel``)
    and, through ``*_members``, each member's prediction for a spread."""

    members: tuple[Any, ...]  # PredictionModel each
    name: str = "ensemble"
    calibration: Calibration | None = None
    params: VehicleParams | None = None  # the constants the members learned (the shift's)
    history: int = field(init=False)

    def __post_init__(self) -> None:
        self.members = tuple(self.members)
        if len(self.members) < 2:
            raise ValueError(f"an ensemble needs at least 2 members, got {len(self.members)}")
        histories = {m.history for m in self.members}
        if len(histories) != 1:
            raise ValueError(f"ensemble members with different histories M: {sorted(histories)}")
        self.history = histories.pop()
        if all(hasattr(m, "numpy_candidates") for m in self.members):  # the compiled backends
            self.numpy_candidates = self._numpy_candidates
            self.numpy_candidates_members = self._numpy_candidates_members

    def _numpy_candidates_members(self, x_hist: Any, u_past: Any, plans: Any) -> Any:
        """(E, K, N, 13): the members' own numpy entries (``control.mpc.candidate_model``)."""
        return np.stack([m.numpy_candidates(x_hist, u_past, plans) for m in self.members])

    def _numpy_candidates(self, x_hist: Any, u_past: Any, plans: Any) -> Any:
        """The members' own numpy entries, their mean."""
        out = self._numpy_candidates_members(x_hist, u_past, plans)
        return spread(torch.from_numpy(out)).mean.numpy()

    def constants_shift(self, x_hist: Tensor, u_hist: Tensor, u_future: Tensor) -> Tensor:
        """``constants_estimate.constants_shift`` against the members' constants: (B, M, 13),
        (B, M, 4), (B, N, 4) -> (B, N, 13) float64."""
        if self.params is None:
            raise ValueError(f"{self.name}: no vehicle constants recorded for the constants shift")
        return constants_shift(x_hist, u_hist, u_future, self.params)

    def novel(self, members: Any, shift: Any = None) -> Any:
        """Members' predictions (E, K, N, 13) numpy (and their constants shift, where the
        calibration widens by it) -> (K,) bool numpy: ``Calibration.novel`` of their spread;
        all False without a calibration (the MPC's count)."""
        if self.calibration is None:
            return np.zeros(members.shape[1], bool)
        shift = None if shift is None else torch.as_tensor(shift)
        return self.calibration.novel(spread(torch.from_numpy(members)).std, shift).numpy()

    def predict_windows_members(self, windows: Any) -> Tensor:
        """(E, W, N, 13): each member's ``predict_windows``."""
        return torch.stack([m.predict_windows(windows) for m in self.members])

    def predict_candidates_members(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        """(E, K, N, 13): each member's ``predict_candidates``."""
        return torch.stack([m.predict_candidates(x_hist, u_past, plans) for m in self.members])

    def predict_windows(self, windows: Any) -> Tensor:
        return spread(self.predict_windows_members(windows)).mean

    def predict_candidates(self, x_hist: Tensor, u_past: Tensor, plans: Tensor) -> Tensor:
        return spread(self.predict_candidates_members(x_hist, u_past, plans)).mean

    def with_members(self, members: tuple[Any, ...]) -> EnsembleModel:
        """The same ensemble over other members (e.g. each on another backend)."""
        return replace(self, members=tuple(members))


# --- the folder ----------------------------------------------------------------------------


def is_ensemble(path: str | Path) -> bool:
    """Whether ``path`` is an ensemble folder (holds ``ENSEMBLE_FILE``)."""
    return (Path(path).expanduser() / ENSEMBLE_FILE).is_file()


def model_meta(path: str | Path) -> dict[str, Any]:
    """``checkpoint_meta`` of a run (or ``.ckpt``), or of an ensemble folder's first member (the
    members share one recipe)."""
    return checkpoint_meta(read_manifest(path).members[0] if is_ensemble(path) else path)


@dataclass(frozen=True)
class EnsembleManifest:
    """What ``ensemble.json`` says: the member run folders (absolute here; relative to the
    folder in the file) and the calibration, if fitted."""

    folder: Path
    members: tuple[Path, ...]
    calibration: Calibration | None = None


def write_manifest(
    folder: str | Path, members: list[Path], calibration: Calibration | None = None
) -> Path:
    """Write ``folder/ensemble.json`` naming ``members`` (run folders) relative to ``folder``."""
    folder = Path(folder).expanduser()
    if len(members) < 2:
        raise ValueError(f"an ensemble needs at least 2 members, got {len(members)}")
    for m in members:
        if not Path(m).is_dir():
            raise FileNotFoundError(f"ensemble member {m} is not a run folder")
    folder.mkdir(parents=True, exist_ok=True)
    rel = [_relative(Path(m), folder) for m in members]
    data = {
        "format": ENSEMBLE_FORMAT,
        "package_version": __version__,
        "members": rel,
        "calibration": None if calibration is None else to_dict(calibration),
    }
    path = folder / ENSEMBLE_FILE
    write_json(path, data)
    return path


def read_manifest(folder: str | Path) -> EnsembleManifest:
    """``folder/ensemble.json``; a ``ValueError`` naming the file where it is not one."""
    folder = Path(folder).expanduser()
    path = folder / ENSEMBLE_FILE
    try:
        data = read_json(path)
    except FileNotFoundError:
        raise FileNotFoundError(
            f"{folder} is not an ensemble folder (no {ENSEMBLE_FILE})"
        ) from None
    except ValueError as exc:
        raise ValueError(f"{path}: not readable JSON ({exc})") from None
    if not isinstance(data, dict) or data.get("format") != ENSEMBLE_FORMAT:
        got = data.get("format") if isinstance(data, dict) else None
        raise ValueError(
            f"{path}: ensemble format {got!r}; this slungload {__version__} reads "
            f"format {ENSEMBLE_FORMAT}"
        )
    try:
        members = tuple((folder / str(m)).resolve() for m in data["members"])
        cal = data.get("calibration")
        calibration = None if cal is None else Calibration.from_dict(cal)
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a slungload ensemble manifest ({exc})") from None
    if len(members) < 2:
        raise ValueError(f"{path}: an ensemble needs at least 2 members, got {len(members)}")
    return EnsembleManifest(folder, members, calibration)


def load_members(folder: str | Path) -> tuple[EnsembleManifest, list[LoadedModel]]:
    """The manifest and each member's checkpoint (``load_checkpoint``); members must share
    the history M and the dataset's constants (a ``ValueError`` naming the folder)."""
    manifest = read_manifest(folder)
    loaded = [load_checkpoint(m) for m in manifest.members]
    if len({lm.window.history for lm in loaded}) > 1 or len({lm.params for lm in loaded}) > 1:
        raise ValueError(
            f"{manifest.folder}: ensemble members trained with different histories M or "
            "vehicle constants: " + ", ".join(str(lm.path) for lm in loaded)
        )
    return manifest, loaded


def set_calibration(folder: str | Path, calibration: Calibration | None) -> Path:
    """Rewrite ``folder/ensemble.json`` with ``calibration`` (members unchanged)."""
    manifest = read_manifest(folder)
    return write_manifest(manifest.folder, list(manifest.members), calibration)


def _relative(path: Path, folder: Path) -> str:
    return os.path.relpath(path.resolve(), folder.resolve())
