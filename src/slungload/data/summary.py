"""What ``slungload inspect`` prints: per split, flights, steps, seconds and windows; value
ranges (speed, swing, thrust); the physical consistency checks of every flight
(``consistency.flight_checks``: their range over the flights, and each flight outside them);
validation or test maneuvers without a flight in training. No windows are built and no cache
is used.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..config import VehicleParams, WindowConfig
from ..fileio import SPLITS
from ..frames import swing_angle
from ..layout import THRUST, split_state
from ..vehicle_file import VEHICLE_FILE
from .consistency import Check, flight_checks
from .flight import DatasetError, DataWarning, Flight
from .folder import check_folder, read_splits, resolve_params
from .readers import load_flight


@dataclass(frozen=True)
class SplitSummary:
    """Size of one split: flights listed, their steps and seconds, windows cut."""

    flights: int
    steps: int
    duration: float  # s
    windows: int


@dataclass(frozen=True)
class CheckSummary:
    """One consistency figure over a dataset's flights: its range, its limit, the flights
    outside it (with the likely cause)."""

    low: float
    high: float
    limit: str
    outside: tuple[str, ...] = ()
    cause: str = ""


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
    checks: dict[str, CheckSummary] = field(default_factory=dict)  # quantity -> over flights
    imported: bool = False  # recordings of `slungload import` (vehicle.json), not maneuvers

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
        lines += _check_lines(self.checks)
        if "train" in self.splits and self.imported:
            lines += ["", "imported recordings (vehicle.json): split by recording, not maneuvers"]
        elif "train" in self.splits:
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
    record = _import_record(folder)
    checked = record.get("checks", {}) if isinstance(record, dict) else {}
    cable = checked.get("cable_reference") if isinstance(checked, dict) else None
    own_cable = source != "paper defaults" and cable != "own median"
    found: list[tuple[str, Check]] = []
    for split, split_names in names.items():
        flights = [load_flight(paths[n], params, notes, load_state=False) for n in split_names]
        skipped += [f.name for f in flights if len(f) < window.length]
        splits[split] = SplitSummary(
            flights=len(flights),
            steps=sum(len(f) for f in flights),
            duration=sum(f.duration for f in flights),
            windows=sum(window.count(len(f)) for f in flights),
        )
        for f in flights:
            for key, fn in _RANGES.items():
                samples[key].append(fn(f))
            found += [(f.name, c) for c in _flight_checks(f, params, own_cable)]
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
        if split != "train" and "train" in names and record is None  # recordings: no families
    }
    return DatasetSummary(
        folder, params, source, window, splits, ranges, tuple(skipped), tuple(notes), unseen,
        _gather(found), imported=record is not None,
    )  # fmt: skip


def _flight_checks(f: Flight, params: VehicleParams, own_cable: bool) -> tuple[Check, ...]:
    """The flight's figures, held to its own constants where its file records them."""
    p, _, q, p_load = split_state(f.states)
    thrust = f.inputs[:, THRUST][:, 0]
    dt = float(np.median(np.diff(f.time))) if len(f) > 1 else None  # the file's own step
    return flight_checks(p, q, p_load, thrust, f.constants or params, own_cable=own_cable, dt=dt)


def _gather(found: list[tuple[str, Check]]) -> dict[str, CheckSummary]:
    """Per quantity: the range over the flights and the flights outside the limit."""
    out: dict[str, CheckSummary] = {}
    for quantity in dict.fromkeys(c.quantity for _, c in found):
        mine = [(name, c) for name, c in found if c.quantity == quantity]
        values = [c.value for _, c in mine]
        bad = [(name, c) for name, c in mine if not c.ok]
        limits = [c.limit for _, c in mine]  # per flight where flights have their own constants
        limit = limits[0] if len(set(limits)) == 1 else f"{limits[0].split(' = ')[0]} per flight"
        out[quantity] = CheckSummary(
            min(values),
            max(values),
            limit,
            tuple(name for name, _ in bad),
            bad[0][1].cause if bad else "",
        )
    return out


def _check_lines(checks: dict[str, CheckSummary]) -> list[str]:
    if not checks:
        return []
    width = max(38, *(len(q) + 1 for q in checks))
    lines = [
        "",
        f"{'consistency check':<{width}}{'min':>9}{'max':>9}  {'expected':<28}outside",
    ]
    for quantity, c in checks.items():
        lines.append(
            f"{quantity:<{width}}{c.low:>9.3f}{c.high:>9.3f}  {c.limit:<28}{len(c.outside) or '-'}"
        )
    for quantity, c in checks.items():
        if c.outside:
            names = ", ".join(c.outside[:5]) + (" ..." if len(c.outside) > 5 else "")
            lines.append(f"outside: {quantity}: {names}; likely {c.cause}")
    return lines


def _import_record(folder: Path) -> dict | None:
    """How ``slungload import`` made the dataset (``vehicle.json``'s "import": how it checked
    the cable length, ...), or None for a dataset not imported (simulated maneuvers)."""
    import json

    try:
        data = json.loads((folder / VEHICLE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    record = data.get("import") if isinstance(data, dict) else None
    return record if isinstance(record, dict) else None


def maneuver_of(flight: str) -> str:
    """A flight's maneuver: its name without the repetition number ("xy_step_04" -> "xy_step")."""
    return re.sub(r"_\d+$", "", flight)


def _swing_deg(f: Flight) -> np.ndarray:
    """Angle between the cable (vehicle -> load) and straight down, degrees."""
    return np.degrees(swing_angle(f.states))


_RANGES = {  # quantity -> samples of one flight
    "vehicle speed (m/s)": lambda f: np.linalg.norm(split_state(f.states)[1], axis=1),
    "swing angle (deg)": _swing_deg,
    "commanded thrust (N)": lambda f: f.inputs[:, THRUST][:, 0],
    "cable length |pL - p| (m)": lambda f: np.linalg.norm(
        split_state(f.states)[3] - split_state(f.states)[0], axis=1
    ),
}
