"""``slungload import``: real flight logs (ROS 1 / ROS 2 bags, PX4 ULog, CSV) into a dataset.

Each log is read by its source module in ``data/readers/`` into streams by role, already in the
package's frames (``readers/logs.py``); ``resample.resample_log`` checks, cleans and resamples
them into pieces on the dataset's time grid (the thrust map, the gaps, the interpolation: see
that module). Each piece is validated with the ``.npz`` reader's own checks
(``readers.npz.from_arrays``) and held to the physical consistency checks
(``consistency.flight_checks``: the cable length, the load below the vehicle, the attitude
upright, the thrust against hover); a piece outside them stops the import with a
``ConsistencyError`` naming the file, the quantity, the value and the likely cause, unless
``force`` (then noted and recorded in ``vehicle.json``, beside every figure).

Each log's format comes from ``readers.LOG_READERS`` (by suffix; a rosbag2 folder by its
``metadata.yaml``), which also names its reader and its section of a mapping file.

A second log (``SecondLog``: typically motion capture beside a PX4 ULog) gives some streams
of every flight, the load by default: it is read once, and put on each first log's clock and
frame by ``alignment.attach_second`` (the time offset and rigid transform fitted on the
vehicle track both hold, refused when the residual is above
``ConsistencyLimits.align_residual``) before resampling; ``vehicle.json`` records it.

Then the flights are split by recording (``split``: the pieces of one log stay in one split)
and written by ``writer.DatasetWriter`` in the authors' release layout (``OUT/data/NAME.npz``,
``OUT/train.txt`` ... naming files with ``.npz``, ``OUT/vehicle.json`` with the constants and
how the import was made), all or nothing: a failure leaves nothing behind. A log that cannot be
imported raises ``LogError`` (a ``ValueError``) naming the file and the topic or column.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._version import __version__
from ..config import VehicleParams
from ..fileio import SPLITS
from .alignment import attach_second
from .consistency import ConsistencyLimits, flight_checks, refuse_unless_forced
from .flight import FlightFormatError
from .import_options import ImportOptions, SecondLog
from .readers import DATA_SUBFOLDER, LOG_READERS, log_format, log_suffixes
from .readers.logs import ROLES, LogError, RawLog
from .readers.npz import from_arrays
from .resample import backward_velocity, resample_log
from .split import SPLIT_FRACTIONS, shares_text, split_flights, time_blocks, windows_of
from .writer import DatasetWriter

__all__ = ["ImportOptions", "ImportResult", "SecondLog", "backward_velocity", "find_logs",
           "import_logs", "read_log", "resample_log"]  # fmt: skip


@dataclass(frozen=True)
class ImportedFlight:
    name: str
    log: Path
    start: float  # s, the log's stamp of the first sample
    arrays: dict[str, np.ndarray] = field(repr=False)

    @property
    def steps(self) -> int:
        return len(self.arrays["time"])


@dataclass(frozen=True)
class ImportResult:
    """What ``import_logs`` wrote."""

    folder: Path
    flights: dict[str, int]  # name -> steps
    logs: dict[str, Path]  # name -> the log it came from
    splits: dict[str, list[str]]
    params: VehicleParams
    notes: tuple[str, ...]

    def summary(self) -> str:
        steps = sum(self.flights.values())
        sizes = ", ".join(f"{s} {len(self.splits[s])}" for s in SPLITS)
        seconds = steps * self.params.dt
        lines = [
            f"imported {len(self.flights)} flight(s) ({steps} steps, {seconds:.1f} s at "
            f"dt = {self.params.dt} s) from {len(set(self.logs.values()))} log(s) into "
            f"{self.folder} ({sizes})"
        ]
        lines += [f"note: {n}" for n in self.notes]
        return "\n".join(lines)


def find_logs(inputs: list[str | Path]) -> list[tuple[Path, str]]:
    """(path, format) of every log named: files by suffix, a rosbag2 folder (holding
    ``metadata.yaml``), or a folder of such logs (not recursive)."""
    found: list[tuple[Path, str]] = []
    for item in inputs:
        path = Path(item).expanduser()
        if not path.exists():
            raise FileNotFoundError(f"{path}: no such log file or folder")
        kind = log_format(path)
        if kind is not None:
            found.append((path, kind))
        elif path.is_dir():
            inside = [(p, log_format(p)) for p in sorted(path.iterdir())]
            if not any(k for _, k in inside):
                raise LogError(
                    f"{path}: holds no logs ({', '.join(f'*{s}' for s in log_suffixes())}, "
                    "rosbag2 folders)"
                )
            found += [(p, k) for p, k in inside if k is not None]
        else:
            raise LogError(
                f"{path}: unknown log format '{path.suffix}'; known: "
                f"{', '.join(log_suffixes())} and rosbag2 folders"
            )
    if not found:
        raise LogError("no log given")
    return found


def read_log(
    path: Path,
    kind: str,
    mapping: dict[str, Any] | None = None,
    *,
    preset: str | None = None,
    progress: bool = False,
    roles: Collection[str] | None = None,
) -> RawLog:
    """One log's streams by its format (``readers.LOG_READERS``). ``mapping`` holds the
    source's settings, or sections "ros", "ulog", "csv" of them; ``preset`` names the bags'
    defaults ("mavros", "px4"); ``roles``: the streams to read (None: every one)."""
    return LOG_READERS[kind].read(path, mapping, preset=preset, progress=progress, roles=roles)


def import_logs(
    inputs: list[str | Path],
    out: str | Path,
    *,
    params: VehicleParams | None = None,
    mapping: dict[str, Any] | None = None,
    preset: str | None = None,
    options: ImportOptions = ImportOptions(),  # noqa: B008 (frozen)
    second: SecondLog | None = None,
    overwrite: bool = False,
    progress: bool = True,
) -> ImportResult:
    """Import flight logs into the dataset folder ``out`` (see the module's docstring).

    ``params``: the vehicle constants (``dt`` is the dataset step; the masses and gravity enter
    the thrust map); None uses the paper's, with a note. ``mapping``: topics, columns and frames
    (``load_mapping`` reads a file), ``preset``: the bags' defaults ("mavros" or "px4").
    ``second``: a second log giving some streams of every flight, aligned to each log.
    Refuses a non-empty ``out`` unless ``overwrite``. Nothing is written unless every log
    imports.
    """
    writer = DatasetWriter(out, overwrite=overwrite, subfolder=DATA_SUBFOLDER)
    logs = find_logs(inputs)
    notes: list[str] = []
    own_cable = params is not None
    if params is None:
        params = VehicleParams()
        notes.append(
            f"no vehicle constants given: the paper's are used and written to vehicle.json "
            f"({params}); the cable length |pL - p| is checked only for its spread"
        )
    flights, settings = _import_flights(
        logs, params, mapping, preset, options, second, progress, notes
    )
    _check_flights(flights, params)
    checks = _consistency(flights, params, options, own_cable, notes)

    flights, splits = split_by_recording(flights, options, params, notes)
    with writer:
        for f in flights:
            writer.write_flight(f.name, f.arrays)
        about = _about(params, options, settings, flights)
        about["import"]["checks"] = checks
        writer.finish(splits, params, about)
    return ImportResult(
        writer.out,
        {f.name: f.steps for f in flights},
        {f.name: f.log for f in flights},
        splits,
        params,
        tuple(notes),
    )


def _import_flights(
    logs: list[tuple[Path, str]],
    params: VehicleParams,
    mapping: dict[str, Any] | None,
    preset: str | None,
    options: ImportOptions,
    second: SecondLog | None,
    progress: bool,
    notes: list[str],
) -> tuple[list[ImportedFlight], dict[str, Any]]:
    """Every log read (with the second log's streams, aligned) and resampled into flights
    (named after the log, with ``_00``, ``_01`` ... when it splits into pieces), and each
    log's import settings by path; the logs' notes are appended to ``notes``."""
    from tqdm.auto import tqdm

    flights: list[ImportedFlight] = []
    settings: dict[str, Any] = {}
    roles: Collection[str] | None = None
    other = None
    if second is not None:
        logs, other = _read_second(logs, second, mapping, preset, progress, notes)
        roles = [r for r in ROLES if r not in second.roles or r == "position"]  # p aligns
    bar = tqdm(
        logs,
        desc="importing logs",
        unit="log",
        disable=None if progress and len(logs) > 1 else True,
    )
    for path, kind in bar:
        raw = read_log(path, kind, mapping, preset=preset, progress=progress, roles=roles)
        record = None
        if other is not None:
            raw, record = attach_second(raw, other, second, options, notes)
        got = resample_log(raw, params, options)
        notes += raw.notes + got.notes
        settings[str(path)] = {"format": raw.format, **raw.settings, **got.thrust_map,
                               "median_step_s": got.steps}  # fmt: skip
        if got.forced:
            settings[str(path)]["forced"] = got.forced
        if record is not None:
            settings[str(path)]["second"] = record
        stem = path.stem if path.is_file() else path.name
        for k, (start, arrays) in enumerate(got.pieces):
            name = stem if len(got.pieces) == 1 else f"{stem}_{k:02d}"
            flights.append(ImportedFlight(name, path, start, arrays))
    return flights, settings


def _read_second(
    logs: list[tuple[Path, str]],
    second: SecondLog,
    mapping: dict[str, Any] | None,
    preset: str | None,
    progress: bool,
    notes: list[str],
) -> tuple[list[tuple[Path, str]], RawLog]:
    """The first logs without the second (a folder may hold both) and the second log's
    streams: the vehicle's position (to align on) and ``second.roles``."""
    found = find_logs([second.path])
    if len(found) != 1:
        raise LogError(f"{second.path}: the second log must be one log, not {len(found)}")
    path, kind = found[0]
    first = [(p, k) for p, k in logs if p.resolve() != path.resolve()]
    if not first:
        raise LogError(f"{path}: the second log is the only log given; name the first as well")
    if len(first) < len(logs):
        notes.append(f"{path}: the second log is not imported on its own")
    own = second.mapping if second.mapping is not None else mapping
    raw = read_log(path, kind, own, preset=preset, progress=progress,
                   roles=("position", *second.roles))  # fmt: skip
    notes += raw.notes
    return first, raw


def _check_flights(flights: list[ImportedFlight], params: VehicleParams) -> None:
    """Refuse two flights of one name (one file would overwrite the other) and anything the
    ``.npz`` reader would refuse later."""
    names = [f.name for f in flights]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise LogError(f"two logs give flights of the same name {twice}: rename one of the logs")
    for f in flights:  # the .npz reader's own checks, on exactly what is written
        try:
            from_arrays(f.arrays, f.log, params, f.name)
        except FlightFormatError as exc:
            raise LogError(f"{exc} (flight {f.name} after resampling)") from None


def _consistency(
    flights: list[ImportedFlight],
    params: VehicleParams,
    options: ImportOptions,
    own_cable: bool,
    notes: list[str],
) -> dict[str, Any]:
    """Every flight held to the physical consistency checks: the first flight outside them
    stops the import (``ConsistencyError``) unless ``options.force``; the figures, and what
    was forced, for ``vehicle.json``."""
    figures: dict[str, dict[str, float]] = {}
    forced: list[str] = []
    for f in flights:
        a = f.arrays
        q = np.asarray(a["attitude"])[:, [3, 0, 1, 2]]  # x-y-z-w -> w-x-y-z
        found = flight_checks(a["p"], q, a["p_load"], a["T_ref"], params, options.limits,
                              own_cable=own_cable)  # fmt: skip
        figures[f.name] = {c.quantity: round(c.value, 6) for c in found}
        refuse_unless_forced(f"{f.log}: flight {f.name}", found, options.force, forced, notes)
    return {
        "limits": _limits(options.limits),
        "cable_reference": "vehicle constants" if own_cable else "own median",
        "force": options.force,
        "forced": forced,
        "figures": figures,
    }


def _limits(limits: ConsistencyLimits) -> dict[str, float]:
    from dataclasses import asdict

    return asdict(limits)


def _about(
    params: VehicleParams,
    options: ImportOptions,
    settings: dict[str, Any],
    flights: list[ImportedFlight],
) -> dict[str, Any]:
    """How the import was made, for ``vehicle.json`` beside the constants."""
    return {
        "import": {
            "version": __version__,
            "dt": params.dt,
            "interpolation": {
                "position, velocity, load": "linear",
                "attitude": "slerp",
                "commands": options.commands,
                "missing velocity": "backward difference (3 p_k - 4 p_k-1 + p_k-2) / 2h",
            },
            "thrust_map": "T = throttle / hover_throttle * (mQ + mL) g, or throttle * "
            "newtons_per_throttle",
            "options": {
                k: getattr(options, k)
                for k in (
                    "max_gap",
                    "on_gap",
                    "min_duration",
                    "split",
                    "block_gap",
                    "seed",
                    "force",
                )
            },
            "max_gap_by_stream": options.gaps_record(),
            "logs": settings,
            "flights": {
                f.name: {"log": str(f.log), "start": f.start, "steps": f.steps} for f in flights
            },
        },
    }


# --- splits -----------------------------------------------------------------------------


def split_by_recording(
    flights: list[ImportedFlight], options: ImportOptions, params: VehicleParams, notes: list[str]
) -> tuple[list[ImportedFlight], dict[str, list[str]]]:
    """The flights and their split lists: all in train; the seeded draw of
    ``split.split_flights`` by recording (the pieces of one log stay in one split; each
    recording, largest first, goes to the split furthest below its share of the windows,
    ``SPLIT_FRACTIONS``; every split gets one when there are three or more); or each recording
    cut in time (``split.time_blocks``: the flights become ``NAME_train``, ``NAME_val``,
    ``NAME_test``)."""
    names = [f.name for f in flights]
    logs = [str(f.log) for f in flights]
    count = len(set(logs))
    if options.split == "blocks":
        return _time_blocks(flights, options, params)
    if options.split == "train" or count < 3:
        if options.split == "seeded":
            notes.append(
                f"{count} recording(s) ({len(flights)} flight(s)): all in train.txt; a split by "
                "recording needs 3 or more. Cut each recording in time instead: --split blocks "
                "(or slungload split --blocks on the dataset)"
            )
        return flights, {"train": sorted(names), "val": [], "test": []}
    steps = [f.steps for f in flights]
    rng = np.random.default_rng(options.seed)
    splits = split_flights(names, steps, rng, recordings=logs)
    _uneven_split(splits, dict(zip(names, steps, strict=True)), count, options, notes)
    return flights, {s: list(v) for s, v in splits.items()}


def _uneven_split(
    splits: dict[str, tuple[str, ...]],
    steps: dict[str, int],
    count: int,
    options: ImportOptions,
    notes: list[str],
) -> None:
    """A note when whole recordings cannot come near the shares of the windows
    (``SPLIT_FRACTIONS``): three equal recordings give a third each."""
    windows = {s: sum(windows_of(steps[n]) for n in names) for s, names in splits.items()}
    total = sum(windows.values())
    if not total:
        return
    shares = {s: windows[s] / total for s in SPLIT_FRACTIONS}
    if max(abs(shares[s] - f) for s, f in SPLIT_FRACTIONS.items()) <= options.split_tolerance:
        return
    got = "/".join(f"{round(100 * shares[s])}" for s in SPLIT_FRACTIONS)
    notes.append(
        f"{count} recordings split whole give {got} % of the windows to train/val/test, not "
        f"{shares_text()} %: too few recordings to come nearer; --split blocks cuts each "
        "recording in time into the shares instead"
    )


def _time_blocks(
    flights: list[ImportedFlight], options: ImportOptions, params: VehicleParams
) -> tuple[list[ImportedFlight], dict[str, list[str]]]:
    out: list[ImportedFlight] = []
    splits: dict[str, list[str]] = {s: [] for s in SPLITS}
    for log in dict.fromkeys(f.log for f in flights):
        pieces = [f for f in flights if f.log == log]
        try:
            blocks = time_blocks([f.steps for f in pieces], options.block_gap)
        except ValueError as exc:
            raise LogError(f"{log}: {exc}") from None
        for i, a, b, split in blocks:
            f = pieces[i]
            arrays = {k: v[a:b] for k, v in f.arrays.items()}
            arrays["time"] = arrays["time"] - arrays["time"][0]
            name = f"{f.name}_{split}"
            out.append(ImportedFlight(name, log, f.start + a * params.dt, arrays))
            splits[split].append(name)
    return out, splits
