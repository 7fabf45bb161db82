"""What ``slungload inspect`` prints: per split, flights, steps, seconds and windows; value
ranges (speed, swing, thrust); validation or test maneuvers without a flight in training. No
windows are built and no cache is used.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import VehicleParams, WindowConfig
from ..fileio import SPLITS
from ..state import (
    THRUST,
    split_state,
)
from .dataset import check_folder, read_splits, resolve_params
from .flight import DatasetError, DataWarning, Flight
from .readers import load_flight
from .windows import window_count


@dataclass(frozen=True)
class SplitSummary:
    """Size of one split: flights listed, their steps and seconds, windows cut."""

    flights: int
    steps: int
    duration: float  # s
    windows: int


@dataclass(frozen=True)
class DatasetSummary:
    """What ``slungload inspect`` prints: sizes per split, ranges of the data, the constants."""

    folder: Path
    params: VehicleParams
    params_source: str
    window: WindowConfig
    splits: dict[str, SplitSummary]
    ranges: dict[str, tuple[float, float, float]]  # quantity -> (min, median, max)
    skipped: tuple[str, ...]  # flights shorter than one window
    notes: tuple[str, ...] = ()
    # split -> maneuvers (``maneuver_of``) with no flight in training: a test on them measures
    # extrapolation to new kinds of motion, not prediction of known ones
    unseen: dict[str, tuple[str, ...]] = field(default_factory=dict)

    def to_table(self) -> str:
        p, w = self.params, self.window
        total = sum(s.windows for s in self.splits.values())
        lines = [
            f"dataset   {self.folder}",
            f"vehicle   mQ = {p.mass_quad} kg, mL = {p.mass_load} kg, l = {p.cable_length} m, "
            f"d = {p.load_damping}, dt = {p.dt} s, g = {p.gravity} m/s^2  ({self.params_source})",
            f"windows   M = {w.history} history + N = {w.horizon} future steps, stride {w.stride}",
            "",
            f"{'split':<8}{'flights':>8}{'steps':>9}{'duration':>12}{'windows':>10}{'share':>9}",
        ]
        rows = [*self.splits.items()]
        sums = [sum(getattr(s, k) for _, s in rows) for k in ("flights", "steps", "duration")]
        rows.append(("total", SplitSummary(*sums, windows=total)))
        for name, s in rows:
            share = f"{100 * s.windows / total:.1f} %" if total else "-"
            lines.append(
                f"{name:<8}{s.flights:>8}{s.steps:>9}{s.duration:>10.1f} s{s.windows:>10}{share:>9}"
            )
        lines += ["", f"{'quantity':<28}{'min':>9}{'median':>9}{'max':>9}"]
        for name, (lo, mid, hi) in self.ranges.items():
            lines.append(f"{name:<28}{lo:>9.3f}{mid:>9.3f}{hi:>9.3f}")
        if "train" in self.splits:
            lines.append("")
            unseen = [f"{k}: {', '.join(v)}" for k, v in self.unseen.items() if v]
            if unseen:
                lines.append("maneuvers not in train: " + "; ".join(unseen))
            else:
                lines.append("every maneuver of val and test also has flights in train")
        if self.skipped:
            lines += [
                "",
                f"skipped (fewer than M + N = {w.length} steps): {', '.join(self.skipped)}",
            ]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def summarize(
    folder: str | Path,
    *,
    window: WindowConfig = WindowConfig(),  # noqa: B008
    params: VehicleParams | None = None,
) -> DatasetSummary:
    """Sizes and value ranges of a dataset folder (no windows are built, no cache is used).

    Without split files every flight is summarised under the split "all".
    """
    folder, paths = check_folder(folder)
    params, source = resolve_params(folder, params)
    notes: list[str] = []
    try:
        names = read_splits(folder)
    except DatasetError as exc:
        if any((folder / f"{s}.txt").is_file() for s in SPLITS):
            raise
        names = {"all": sorted(paths)}
        notes.append(str(exc))
    splits: dict[str, SplitSummary] = {}
    skipped: list[str] = []
    samples: dict[str, list[np.ndarray]] = {k: [] for k in _RANGES}
    for split, split_names in names.items():
        flights = [load_flight(paths[n], params, notes) for n in split_names]
        skipped += [f.name for f in flights if len(f) < window.length]
        splits[split] = SplitSummary(
            flights=len(flights),
            steps=sum(len(f) for f in flights),
            duration=sum(f.duration for f in flights),
            windows=sum(window_count(len(f), window) for f in flights),
        )
        for f in flights:
            for key, fn in _RANGES.items():
                samples[key].append(fn(f))
    for note in notes:
        warnings.warn(note, DataWarning, stacklevel=2)
    ranges = {}
    for key, parts in samples.items():
        if parts:
            values = np.concatenate(parts)
            ranges[key] = (float(values.min()), float(np.median(values)), float(values.max()))
    trained = {maneuver_of(n) for n in names.get("train", ())}
    unseen = {
        split: tuple(sorted({maneuver_of(n) for n in split_names} - trained))
        for split, split_names in names.items()
        if split != "train" and "train" in names
    }
    return DatasetSummary(
        folder, params, source, window, splits, ranges, tuple(skipped), tuple(notes), unseen
    )


def maneuver_of(flight: str) -> str:
    """A flight's maneuver: its name without the repetition number ("xy_step_04" -> "xy_step")."""
    return re.sub(r"_\d+$", "", flight)


def _swing_deg(f: Flight) -> np.ndarray:
    """Angle between the cable (vehicle -> load) and straight down, degrees."""
    p, _, _, p_load = split_state(f.states)
    rel = p_load - p
    cos = -rel[:, 2] / np.maximum(np.linalg.norm(rel, axis=1), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


_RANGES = {  # quantity -> samples of one flight
    "vehicle speed (m/s)": lambda f: np.linalg.norm(split_state(f.states)[1], axis=1),
    "swing angle (deg)": _swing_deg,
    "commanded thrust (N)": lambda f: f.inputs[:, THRUST][:, 0],
    "cable length |pL - p| (m)": lambda f: np.linalg.norm(
        split_state(f.states)[3] - split_state(f.states)[0], axis=1
    ),
}
