"""``slungload import``: real flight logs (ROS 1 / ROS 2 bags, PX4 ULog, CSV) into a dataset.

Each log is read by its source module in ``data/readers/`` into streams by role, already in the
package's frames (``readers/logs.py``); this module then, per log:

1. cleans each stream: samples with a NaN (a motion-capture dropout) or a zero quaternion are
   dropped, repeated stamps keep their first sample, and stamps that go back in time are an
   error; a stream left empty is an error (for the load: "the load is never seen");
2. turns a normalised thrust into newtons with the thrust map
   ``T = throttle / hover_throttle * (mass_quad + mass_load) * gravity`` (the hover throttle
   holds the vehicle *with its load*; PX4's ``MPC_THR_HOVER``);
3. keeps the time where every stream has samples, and splits it where any stream has no sample
   for longer than ``max_gap`` (or stops with an error, ``on_gap="error"``); pieces shorter
   than ``min_duration`` are dropped with a note;
4. resamples each piece on a grid of step ``params.dt`` from its first instant: positions and
   velocities linearly, the attitude by slerp, the commands by holding the last set-point
   (``commands="hold"``, a set-point holds until the next one; or linearly); without a
   velocity stream, v is the causal second-order backward difference
   (3 p_k - 4 p_{k-1} + p_{k-2}) / (2 h) of the resampled position (first order at step 1,
   step 0 repeats step 1), exact for a quadratic and never looking ahead, like the load-state
   estimate;
5. validates the arrays with the ``.npz`` reader's own checks (``readers.npz.from_arrays``).

Each log's format comes from ``readers.LOG_READERS`` (by suffix; a rosbag2 folder by its
``metadata.yaml``), which also names its reader and its section of a mapping file.

Then the flights are split by flight (``split.split_flights``: a seeded draw towards the
paper's shares of the windows, ``split.SPLIT_FRACTIONS``, or all in ``train``) and written by
``writer.DatasetWriter`` in the authors' release layout (``OUT/data/NAME.npz``,
``OUT/train.txt`` ... naming files with ``.npz``, ``OUT/vehicle.json`` with the constants and
how the import was made), all or nothing: a failure leaves nothing behind. A log that cannot be
imported raises ``LogError`` (a ``ValueError``) naming the file and the topic or column.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .. import frames
from .._version import __version__
from ..config import VehicleParams
from ..fileio import SPLITS
from .flight import FlightFormatError
from .readers import DATA_SUBFOLDER, LOG_READERS, log_format, log_suffixes
from .readers.logs import ROLES, LogError, RawLog, Stream
from .readers.npz import from_arrays
from .split import split_flights
from .writer import DatasetWriter

STAMP_EPS = 1e-6  # s: a sample stamped this close after a grid instant counts as at it


@dataclass(frozen=True)
class ImportOptions:
    """How logs become flights (defaults stated in the module's docstring)."""

    hover_throttle: float | None = None  # None: the log's own (ULog), else an error if needed
    max_gap: float = 0.1  # s, longest time a stream may go without a sample
    on_gap: str = "split"  # "split" the flight at a longer gap, or "error"
    min_duration: float = 1.0  # s, shorter pieces are dropped
    commands: str = "hold"  # "hold" the last set-point, or "linear"
    split: str = "seeded"  # "seeded" draw by flight, or "train" (every flight in train.txt)
    seed: int = 0

    def __post_init__(self) -> None:
        if self.hover_throttle is not None and not 0.0 < self.hover_throttle <= 1.0:
            raise ValueError(f"hover throttle must be in (0, 1], got {self.hover_throttle}")
        if not self.max_gap > 0:
            raise ValueError(f"max gap must be > 0 s, got {self.max_gap}")
        if self.min_duration < 0:
            raise ValueError(f"min duration must be >= 0 s, got {self.min_duration}")
        for name, known in (
            ("on_gap", ("split", "error")),
            ("commands", ("hold", "linear")),
            ("split", ("seeded", "train")),
        ):
            if getattr(self, name) not in known:
                raise ValueError(f"{name} must be one of {known}, got {getattr(self, name)!r}")


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
) -> RawLog:
    """One log's streams by its format (``readers.LOG_READERS``). ``mapping`` holds the
    source's settings, or sections "ros", "ulog", "csv" of them; ``preset`` names the bags'
    defaults ("mavros", "px4")."""
    return LOG_READERS[kind].read(path, mapping, preset=preset, progress=progress)


def import_logs(
    inputs: list[str | Path],
    out: str | Path,
    *,
    params: VehicleParams | None = None,
    mapping: dict[str, Any] | None = None,
    preset: str | None = None,
    options: ImportOptions = ImportOptions(),  # noqa: B008 (frozen)
    overwrite: bool = False,
    progress: bool = True,
) -> ImportResult:
    """Import flight logs into the dataset folder ``out`` (see the module's docstring).

    ``params``: the vehicle constants (``dt`` is the dataset step; the masses and gravity enter
    the thrust map); None uses the paper's, with a note. ``mapping``: topics, columns and frames
    (``load_mapping`` reads a file), ``preset``: the bags' defaults ("mavros" or "px4").
    Refuses a non-empty ``out`` unless ``overwrite``. Nothing is written unless every log
    imports.
    """
    writer = DatasetWriter(out, overwrite=overwrite, subfolder=DATA_SUBFOLDER)
    logs = find_logs(inputs)
    notes: list[str] = []
    if params is None:
        params = VehicleParams()
        notes.append(
            f"no vehicle constants given: the paper's are used and written to vehicle.json "
            f"({params})"
        )
    flights, settings = _import_flights(logs, params, mapping, preset, options, progress, notes)
    _check_flights(flights, params)

    names = [f.name for f in flights]
    splits = split_by_flight(names, [f.steps for f in flights], options)
    if options.split == "seeded" and len(flights) < 3:
        notes.append(f"{len(flights)} flight(s): all in train.txt (a split needs 3 or more)")
    with writer:
        for f in flights:
            writer.write_flight(f.name, f.arrays)
        writer.finish(splits, params, _about(params, options, settings, flights))
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
    progress: bool,
    notes: list[str],
) -> tuple[list[ImportedFlight], dict[str, Any]]:
    """Every log read and resampled into flights (named after the log, with ``_00``, ``_01``
    ... when it splits into pieces), and each log's import settings by path; the logs' notes
    are appended to ``notes``."""
    from tqdm.auto import tqdm

    flights: list[ImportedFlight] = []
    settings: dict[str, Any] = {}
    bar = tqdm(logs, desc="importing logs", unit="log", disable=not progress or len(logs) < 2)
    for path, kind in bar:
        raw = read_log(path, kind, mapping, preset=preset, progress=progress)
        pieces, log_notes, hover = resample_log(raw, params, options)
        notes += raw.notes + log_notes
        settings[str(path)] = {"format": raw.format, **raw.settings}
        if hover is not None:
            settings[str(path)]["hover_throttle"] = hover
        stem = path.stem if path.is_file() else path.name
        for k, (start, arrays) in enumerate(pieces):
            name = stem if len(pieces) == 1 else f"{stem}_{k:02d}"
            flights.append(ImportedFlight(name, path, start, arrays))
    return flights, settings


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
            "thrust_map": "T = throttle / hover_throttle * (mass_quad + mass_load) * gravity",
            "options": {
                k: getattr(options, k)
                for k in ("max_gap", "on_gap", "min_duration", "split", "seed")
            },
            "logs": settings,
            "flights": {
                f.name: {"log": str(f.log), "start": f.start, "steps": f.steps} for f in flights
            },
        },
    }


# --- one log -> flights ---------------------------------------------------------------------


def resample_log(
    raw: RawLog,
    params: VehicleParams,
    options: ImportOptions = ImportOptions(),  # noqa: B008
) -> tuple[list[tuple[float, dict[str, np.ndarray]]], list[str], float | None]:
    """Pieces of one log as published-schema arrays at step ``params.dt``: a list of (the log's
    stamp of the first sample, arrays), the notes, and the hover throttle used (or None)."""
    path = raw.path
    notes: list[str] = []
    missing = [r for r in ROLES if r not in raw.streams and r != "velocity"]
    if missing:
        raise LogError(f"{path}: no {', '.join(missing)} in the log")
    streams = {role: _clean(role, s, path, notes) for role, s in raw.streams.items()}

    hover = None
    if raw.thrust_normalized:
        hover = options.hover_throttle or raw.hover_throttle
        source = streams["thrust"].source
        if hover is None:
            raise LogError(
                f"{path}: {source} is a normalised throttle; give the hover throttle (the "
                "throttle that holds the vehicle with its load, PX4's MPC_THR_HOVER: "
                "--hover-throttle) to turn it into newtons"
            )
        if not 0.0 < hover <= 1.0:
            raise LogError(f"{path}: hover throttle {hover} is not in (0, 1]")
        scale = (params.mass_quad + params.mass_load) * params.gravity / hover
        thrust = streams["thrust"]
        streams["thrust"] = Stream(thrust.source, thrust.time, thrust.values * scale)
        how = "given" if options.hover_throttle else f"{path}'s MPC_THR_HOVER"
        notes.append(
            f"{path}: thrust = throttle / {hover:g} ({how}) * (mQ + mL) g = "
            f"throttle * {scale:.4g} N"
        )

    t0 = min(float(s.time[0]) for s in streams.values())
    start = max(float(s.time[0]) for s in streams.values())
    end = min(float(s.time[-1]) for s in streams.values())
    if end - start < params.dt:
        spans = "; ".join(
            f"{s.source}: {s.time[0] - t0:.3f} to {s.time[-1] - t0:.3f} s" for s in streams.values()
        )
        raise LogError(f"{path}: the streams do not overlap in time ({spans})")
    pieces = _pieces(streams, start, end, options, path, t0)
    kept = [(a, b) for a, b in pieces if b - a >= max(options.min_duration, params.dt)]
    dropped = len(pieces) - len(kept)
    if len(pieces) > 1:
        notes.append(
            f"{path}: split at {len(pieces) - 1} gaps longer than {options.max_gap} s into "
            f"{len(pieces)} pieces"
        )
    if dropped:
        notes.append(f"{path}: {dropped} pieces shorter than {options.min_duration} s dropped")
    if not kept:
        raise LogError(
            f"{path}: no piece of at least {options.min_duration} s without a gap longer than "
            f"{options.max_gap} s"
        )
    return [(a, _resample(streams, a, b, params.dt, options)) for a, b in kept], notes, hover


def _clean(role: str, stream: Stream, path: Path, notes: list[str]) -> Stream:
    t, v = np.asarray(stream.time, np.float64), np.asarray(stream.values, np.float64)
    good = np.isfinite(t) & np.isfinite(v).all(axis=1)
    if role == "attitude":
        norm = np.linalg.norm(np.where(np.isfinite(v), v, 0.0), axis=1)
        good &= norm > 0.5
        v = v / np.where(norm > 0, norm, 1.0)[:, None]
    if not good.all() and good.any():
        notes.append(f"{path}: {stream.source}: {int((~good).sum())} samples without a value")
    t, v = t[good], v[good]
    if len(t) == 0:
        if role == "load":
            raise LogError(f"{path}: the load is never seen: {stream.source} has no sample")
        raise LogError(f"{path}: {stream.source} ({role}) has no sample")
    steps = np.diff(t)
    back = np.flatnonzero(steps < 0)
    if len(back):
        i = back[0] + 1
        raise LogError(
            f"{path}: {stream.source}: stamps out of order at message {i} "
            f"({t[i]:.6f} s after {t[i - 1]:.6f} s)"
        )
    repeat = np.flatnonzero(steps == 0) + 1
    if len(repeat):
        keep = np.ones(len(t), dtype=bool)
        keep[repeat] = False
        t, v = t[keep], v[keep]
        notes.append(f"{path}: {stream.source}: {len(repeat)} repeated stamps, first sample kept")
    return Stream(stream.source, t, v)


def _pieces(
    streams: dict[str, Stream],
    start: float,
    end: float,
    options: ImportOptions,
    path: Path,
    t0: float,
) -> list[tuple[float, float]]:
    """[start, end] without the gaps (longer than max_gap) of any stream."""
    holes: list[tuple[float, float]] = []
    for s in streams.values():
        steps = np.diff(s.time)
        for i in np.flatnonzero(steps > options.max_gap):
            a, b = float(s.time[i]), float(s.time[i + 1])
            if b <= start or a >= end:
                continue
            if options.on_gap == "error":
                raise LogError(
                    f"{path}: {s.source}: no sample for {b - a:.3f} s from t = {a - t0:.3f} s "
                    f"(longer than the gap limit of {options.max_gap} s)"
                )
            holes.append((a, b))
    pieces, cursor = [], start
    for a, b in sorted(holes):
        if a > cursor:
            pieces.append((cursor, a))
        cursor = max(cursor, b)
    if end > cursor:
        pieces.append((cursor, end))
    return pieces


def _resample(
    streams: dict[str, Stream], a: float, b: float, dt: float, options: ImportOptions
) -> dict[str, np.ndarray]:
    # float stamps are rounded: a last step short of dt by under STAMP_EPS still counts
    n = int(np.floor((b - a + STAMP_EPS) / dt)) + 1
    grid = a + dt * np.arange(n)

    def linear(s: Stream) -> np.ndarray:
        return np.stack(
            [np.interp(grid, s.time, s.values[:, j]) for j in range(s.values.shape[1])], 1
        )

    def command(s: Stream) -> np.ndarray:
        if options.commands == "linear":
            return linear(s)
        i = np.searchsorted(s.time, grid + STAMP_EPS, side="right") - 1
        return s.values[np.clip(i, 0, len(s.time) - 1)]

    p = linear(streams["position"])
    if "velocity" in streams:
        v = linear(streams["velocity"])
    else:
        v = backward_velocity(p, dt)
    q = frames.slerp(grid, streams["attitude"].time, streams["attitude"].values)
    return {
        "time": dt * np.arange(n),
        "p": p,
        "v": v,
        "attitude": q[:, [1, 2, 3, 0]],  # w-x-y-z -> x-y-z-w, the files' order
        "p_load": linear(streams["load"]),
        "w_ref": command(streams["rates"]),
        "T_ref": command(streams["thrust"]),
    }


def backward_velocity(p: np.ndarray, dt: float) -> np.ndarray:
    """Causal velocity from positions (T, 3): (3 p_k - 4 p_{k-1} + p_{k-2}) / (2 dt) from step
    2, (p_1 - p_0) / dt at step 1, step 0 repeating step 1."""
    v = np.empty_like(p)
    if len(p) < 2:
        v[:] = 0.0
        return v
    v[1] = (p[1] - p[0]) / dt
    v[0] = v[1]
    v[2:] = (3 * p[2:] - 4 * p[1:-1] + p[:-2]) / (2 * dt)
    return v


# --- splits -----------------------------------------------------------------------------


def split_by_flight(
    names: list[str], steps: list[int], options: ImportOptions
) -> dict[str, list[str]]:
    """Whole flights per split: all in train, or the seeded draw of ``split.split_flights``
    (each flight, longest first, goes to the split furthest below its share of the windows,
    ``SPLIT_FRACTIONS``; every split gets one when there are three or more)."""
    if options.split == "train" or len(names) < 3:
        return {"train": sorted(names), "val": [], "test": []}
    splits = split_flights(names, steps, np.random.default_rng(options.seed))
    return {s: list(v) for s, v in splits.items()}
