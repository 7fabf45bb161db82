"""Flights on disk -> validated arrays -> estimated load state -> windows per split.

One flight is one ``.npz`` file in the published schema (``fileio.FLIGHT_KEYS``); a dataset is
a folder of them with ``train.txt`` / ``val.txt`` / ``test.txt`` naming the flights of each
split and, optionally, ``vehicle.json`` with the constants. See ``docs/data.md``.

The load velocity vL and load angular velocity Omega_L are not measured; they are estimated
causally from the positions (``estimate_load_state``) so that a prediction made at step k
never uses a sample after k.
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from .config import VehicleParams, WindowConfig, load_vehicle
from .fileio import FLIGHT_KEYS, IGNORED_KEYS, OPTIONAL_KEYS, SPLITS, read_npz
from .state import (
    AUX_DIM,
    INPUT_DIM,
    LOAD_RATE,
    LOAD_VEL,
    RATES,
    THRUST,
    join_state,
    quat_continuous,
    quat_xyzw_to_wxyz,
    split_state,
)
from .windows import (
    Windows,
    cache_key,
    default_cache_dir,
    load_cache,
    make_windows,
    save_cache,
    window_count,
)

DT_TOLERANCE = 0.2  # each time step must be within this fraction of params.dt
QUAT_NORM_TOLERANCE = 0.1  # | |q| - 1 | allowed before renormalising


class DatasetError(ValueError):
    """A dataset folder that cannot be used (no flights, bad split lists, ...)."""


class FlightFormatError(DatasetError):
    """A flight file that does not follow the published schema; the message names the file."""


class DataWarning(UserWarning):
    """Something in a dataset was ignored or replaced by a default."""


@dataclass(frozen=True)
class Flight:
    """One validated flight, float64, in the layout of ``state.py``.

    time (T,) s; states (T, 13) = p, v, q (w-x-y-z, unit, sign-continuous), pL;
    inputs (T, 4) = commanded thrust T_ref (N), commanded body rates w_ref (rad/s);
    aux (T, 6) = estimated vL (m/s), Omega_L (rad/s), see ``estimate_load_state``.
    """

    name: str
    path: Path
    time: np.ndarray
    states: np.ndarray
    inputs: np.ndarray
    aux: np.ndarray

    def __len__(self) -> int:
        return len(self.time)

    @property
    def duration(self) -> float:
        """Seconds from the first to the last sample."""
        return float(self.time[-1] - self.time[0])


# --- one flight -----------------------------------------------------------------------------


def read_flight(path: str | Path, params: VehicleParams | None = None) -> Flight:
    """Read and validate one flight file; raises ``FlightFormatError`` naming the file.

    ``params.dt`` is the expected time step; ``params`` also feeds the load-state estimate.
    Unknown keys are ignored with a ``DataWarning``.
    """
    notes: list[str] = []
    flight = _read_flight(Path(path), params or VehicleParams(), notes)
    for note in notes:
        warnings.warn(note, DataWarning, stacklevel=2)
    return flight


def _read_flight(path: Path, params: VehicleParams, notes: list[str]) -> Flight:
    try:
        raw = read_npz(path)
    except ValueError as exc:  # message already names the file
        raise FlightFormatError(str(exc)) from exc
    missing = [key for key in FLIGHT_KEYS if key not in raw]
    if missing:
        raise FlightFormatError(f"{path}: missing keys {missing} (has {sorted(raw)})")
    unknown = sorted(set(raw) - set(FLIGHT_KEYS) - set(OPTIONAL_KEYS) - set(IGNORED_KEYS))
    if unknown:
        notes.append(f"{path}: ignoring unknown keys {unknown}")

    time = _numeric(raw["time"], "time", path)
    if time.ndim == 2 and 1 in time.shape:  # (T, 1) or (1, T), as MATLAB writes vectors
        time = time.reshape(-1)
    if time.ndim != 1:
        raise FlightFormatError(f"{path}: time has shape {time.shape}, expected (T,)")
    steps = len(time)
    if steps < 2:
        raise FlightFormatError(f"{path}: {steps} samples, need at least 2")
    arrays = {"time": time}
    for key, trailing in FLIGHT_KEYS.items():
        if key != "time":
            arrays[key] = _series(raw[key], key, trailing or (), steps, path)
    for key, arr in arrays.items():
        bad = np.argwhere(~np.isfinite(arr))
        if len(bad):
            value = arr[tuple(bad[0])]
            raise FlightFormatError(f"{path}: {key} holds {value} at step {bad[0][0]}")
    _check_time(time, params.dt, path)

    quat = torch.from_numpy(_unit_quaternions(arrays["attitude"], path))
    states = join_state(
        torch.from_numpy(arrays["p"]),
        torch.from_numpy(arrays["v"]),
        quat_continuous(quat_xyzw_to_wxyz(quat)),
        torch.from_numpy(arrays["p_load"]),
    ).numpy()
    inputs = np.empty((steps, INPUT_DIM))
    inputs[:, THRUST] = arrays["T_ref"]
    inputs[:, RATES] = arrays["w_ref"]
    return Flight(path.stem, path, time, states, inputs, estimate_load_state(states, params))


def _numeric(arr: np.ndarray, key: str, path: Path) -> np.ndarray:
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise FlightFormatError(f"{path}: {key} has dtype {arr.dtype}, expected real numbers")
    return arr.astype(np.float64)


def _series(
    arr: np.ndarray, key: str, trailing: tuple[int, ...], steps: int, path: Path
) -> np.ndarray:
    """(T, *trailing) float64; a (T,) array is accepted where trailing is (1,)."""
    arr = _numeric(arr, key, path)
    if trailing == (1,) and arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 1 + len(trailing) or arr.shape[1:] != trailing:
        expected = ("T", *trailing)
        raise FlightFormatError(f"{path}: {key} has shape {arr.shape}, expected {expected}")
    if arr.shape[0] != steps:
        raise FlightFormatError(f"{path}: {key} has {arr.shape[0]} steps but time has {steps}")
    return arr


def _check_time(time: np.ndarray, dt: float, path: Path) -> None:
    steps = np.diff(time)
    back = np.flatnonzero(steps <= 0)
    if len(back):
        i = back[0]
        raise FlightFormatError(
            f"{path}: time is not strictly increasing at index {i + 1} "
            f"(t[{i}] = {time[i]:.6g} s, t[{i + 1}] = {time[i + 1]:.6g} s)"
        )
    off = np.flatnonzero(np.abs(steps - dt) > DT_TOLERANCE * dt)
    if len(off):
        i = off[0]
        raise FlightFormatError(
            f"{path}: time step from index {i} to {i + 1} is {steps[i]:.6g} s, expected "
            f"dt = {dt} s within {DT_TOLERANCE:.0%} (vehicle.json sets dt)"
        )


def _unit_quaternions(q: np.ndarray, path: Path) -> np.ndarray:
    norms = np.linalg.norm(q, axis=-1)
    bad = np.flatnonzero(np.abs(norms - 1.0) > QUAT_NORM_TOLERANCE)
    if len(bad):
        i = bad[0]
        raise FlightFormatError(
            f"{path}: attitude at step {i} has norm {norms[i]:.4g}, expected a unit quaternion"
        )
    return q / norms[:, None]


def estimate_load_state(states: np.ndarray | Tensor, params: VehicleParams) -> np.ndarray | Tensor:
    """Causal estimate of the unmeasured load state from positions, (..., T, 13) -> (..., T, 6).

    vL_k = (pL_k - pL_{k-1}) / h. With r = pL - p and xi_k = r_k / |r_k|,
    Omega_L,k = xi_k x (r_k - r_{k-1}) / (h l): the pendulum kinematics xi_dot = Omega_L x xi
    with Omega_L perpendicular to the cable. The relative velocity is the backward difference of
    r (not vL minus the measured v) so both positions carry the same half-step lag. Only
    samples k and k-1 are used; step 0 repeats step 1's difference (a forward difference).
    Returns numpy for numpy input, torch (same dtype/device) for torch input.
    """
    x = (
        torch.from_numpy(np.asarray(states, np.float64))
        if isinstance(states, np.ndarray)
        else states
    )
    if x.shape[-2] < 2:
        raise ValueError(f"estimate_load_state: need at least 2 time steps, got {x.shape[-2]}")
    p, _, _, p_load = split_state(x)
    rel = p_load - p
    xi = rel / rel.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    aux = x.new_empty(*x.shape[:-1], AUX_DIM)
    aux[..., LOAD_VEL] = _backward_difference(p_load, params.dt)
    rel_rate = _backward_difference(rel, params.dt)
    aux[..., LOAD_RATE] = torch.linalg.cross(xi, rel_rate) / params.cable_length
    return aux.numpy() if isinstance(states, np.ndarray) else aux


def _backward_difference(y: Tensor, h: float) -> Tensor:
    """(y_k - y_{k-1}) / h along axis -2, the first step repeating the second."""
    d = (y[..., 1:, :] - y[..., :-1, :]) / h
    return torch.cat([d[..., :1, :], d], dim=-2)


# --- a dataset folder -----------------------------------------------------------------------


@dataclass(frozen=True)
class Dataset:
    """Windows per split ("train", "val", "test") and the flights they were cut from."""

    folder: Path
    params: VehicleParams
    params_source: str  # "vehicle.json" | "override" | "paper defaults"
    window: WindowConfig
    splits: dict[str, Windows]
    flights: dict[str, Flight]
    cache_path: Path | None = None
    from_cache: bool = False
    notes: tuple[str, ...] = field(default=())  # what was skipped or ignored while reading


def resolve_params(folder: Path, params: VehicleParams | None) -> tuple[VehicleParams, str]:
    """Constants to use and where they come from: explicit > vehicle.json > paper defaults."""
    if params is not None:
        return params, "override"
    found = load_vehicle(folder)
    if found is not None:
        return found, "vehicle.json"
    defaults = VehicleParams()
    warnings.warn(
        f"{folder}: no vehicle.json, using the paper's default constants {defaults}",
        DataWarning,
        stacklevel=3,
    )
    return defaults, "paper defaults"


def _check_folder(folder: str | Path) -> Path:
    folder = Path(folder).expanduser()
    if folder.exists() and not folder.is_dir():
        raise NotADirectoryError(
            f"dataset folder {folder} is not a folder (expected a folder of .npz flights)"
        )
    if not folder.is_dir():
        raise FileNotFoundError(f"dataset folder {folder} does not exist")
    if not any(folder.glob("*.npz")):
        raise DatasetError(f"dataset folder {folder} holds no flight files (*.npz)")
    return folder


def read_splits(folder: str | Path) -> dict[str, list[str]]:
    """Flight names per split from train.txt / val.txt / test.txt (with or without ``.npz``).

    One name a line; blank lines and lines starting with '#' are skipped. Raises
    ``DatasetError`` for no split files, names missing on disk or listed twice; a missing list
    is an empty split and flights in no list are ignored, each with a ``DataWarning``.
    """
    folder = Path(folder)
    present = [s for s in SPLITS if (folder / f"{s}.txt").is_file()]
    if not present:
        raise DatasetError(
            f"{folder}: no split files. Write train.txt, val.txt and test.txt beside the flights, "
            "one flight name a line, e.g. slungload.fileio.write_splits(folder, "
            "{'train': [...], 'val': [...], 'test': [...]})"
        )
    on_disk = {p.stem for p in folder.glob("*.npz")}
    names: dict[str, list[str]] = {s: [] for s in SPLITS}
    owner: dict[str, str] = {}
    for split in SPLITS:
        list_path = folder / f"{split}.txt"
        if split not in present:
            warnings.warn(f"{list_path} is missing: split '{split}' is empty", DataWarning, 2)
            continue
        for line in _read_list(list_path):
            name = line.strip().removesuffix(".npz")
            if not name or name.startswith("#"):
                continue
            if name in owner:
                where = (
                    "listed twice" if owner[name] == split else f"also listed in {owner[name]}.txt"
                )
                raise DatasetError(f"{list_path}: flight '{name}' is {where}")
            owner[name] = split
            names[split].append(name)
        absent = [n for n in names[split] if n not in on_disk]
        if absent:
            raise DatasetError(f"{list_path}: flights not found in {folder}: {absent}")
    unlisted = sorted(on_disk - set(owner))
    if unlisted:
        warnings.warn(f"{folder}: flights in no split list are ignored: {unlisted}", DataWarning, 2)
    return names


def _read_list(path: Path) -> list[str]:
    """Lines of a split list; a file that is not UTF-8 text is a ``DatasetError``."""
    try:
        return path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as exc:
        raise DatasetError(
            f"{path}: not a text file ({exc.reason} at byte {exc.start}); expected one flight "
            "name a line"
        ) from None


def load_dataset(
    folder: str | Path,
    *,
    window: WindowConfig = WindowConfig(),  # noqa: B008 (frozen, so a shared default is safe)
    params: VehicleParams | None = None,
    cache_dir: str | Path | None = None,
    use_cache: bool = True,
) -> Dataset:
    """Read, validate and window every flight of a dataset folder, split by flight file.

    ``params`` overrides ``vehicle.json``; without either the paper's defaults apply (with a
    warning). Flights shorter than one window are skipped with a warning. The windows are
    cached in ``cache_dir`` (default ``$SLUNGLOAD_CACHE`` or ``~/.cache/slungload``) under a
    hash of the files' bytes, the window config and the constants.
    """
    folder = _check_folder(folder)
    params, source = resolve_params(folder, params)
    names = read_splits(folder)
    files = [folder / f"{n}.npz" for s in SPLITS for n in names[s]]
    files += [folder / f"{s}.txt" for s in SPLITS if (folder / f"{s}.txt").is_file()]
    key = cache_key(files, window, params)
    cache_path = (
        Path(cache_dir or default_cache_dir()).expanduser() / f"{folder.name}-{key[:24]}.pt"
    )
    common = {"folder": folder, "params": params, "params_source": source, "window": window}

    if use_cache:
        try:
            payload = load_cache(cache_path, key)
            if payload is not None:
                dataset = _from_payload(payload, common, cache_path)
                for note in dataset.notes:
                    warnings.warn(note, DataWarning, stacklevel=2)
                return dataset
        except (ValueError, KeyError, TypeError, AttributeError) as exc:
            warnings.warn(f"ignoring a bad cache file, rebuilding: {exc}", DataWarning, 2)

    notes: list[str] = []
    flights = _read_flights(folder, names, window, params, notes)
    for note in notes:
        warnings.warn(note, DataWarning, stacklevel=2)
    splits = {
        s: make_windows([flights[n] for n in names[s] if n in flights], window) for s in SPLITS
    }
    dataset = Dataset(**common, splits=splits, flights=flights, notes=tuple(notes))
    if not use_cache:
        return dataset
    try:
        save_cache(cache_path, key, _to_payload(dataset))
    except (OSError, RuntimeError) as exc:  # torch.save reports a full disk as RuntimeError
        warnings.warn(f"cannot write the cache {cache_path}: {exc}", DataWarning, stacklevel=2)
        return dataset
    return replace(dataset, cache_path=cache_path)


def _read_flights(
    folder: Path,
    names: dict[str, list[str]],
    window: WindowConfig,
    params: VehicleParams,
    notes: list[str],
) -> dict[str, Flight]:
    flights: dict[str, Flight] = {}
    longest = 0
    for split in SPLITS:
        for name in names[split]:
            flight = _read_flight(folder / f"{name}.npz", params, notes)
            longest = max(longest, len(flight))
            if len(flight) < window.length:
                notes.append(
                    f"{flight.path}: skipped, {len(flight)} steps is shorter than one window "
                    f"(M + N = {window.length})"
                )
                continue
            flights[name] = flight
    if not flights:
        raise DatasetError(
            f"{folder}: no flight left; each needs at least M + N = {window.length} steps "
            f"and the longest has {longest}"
        )
    return flights


_ARRAYS = ("time", "states", "inputs", "aux")


def _to_payload(dataset: Dataset) -> dict:
    """The flights and which split each belongs to. Windows are not stored: they are ~40x the
    flights' size (every step repeated in M + N windows) and re-cut in well under a second."""
    flights = {
        n: {k: torch.from_numpy(getattr(f, k)) for k in _ARRAYS} for n, f in dataset.flights.items()
    }
    members = {s: list(dataset.splits[s].names) for s in SPLITS}  # the flights, in order
    return {"flights": flights, "splits": members, "notes": list(dataset.notes)}


def _from_payload(payload: dict, common: dict, cache_path: Path) -> Dataset:
    folder = common["folder"]
    flights = {
        name: Flight(name, folder / f"{name}.npz", *(f[k].numpy() for k in _ARRAYS))
        for name, f in payload["flights"].items()
    }
    splits = {
        s: make_windows([flights[str(n)] for n in payload["splits"][s]], common["window"])
        for s in SPLITS
    }
    notes = tuple(str(n) for n in payload["notes"])
    return Dataset(
        **common,
        splits=splits,
        flights=flights,
        cache_path=cache_path,
        from_cache=True,
        notes=notes,
    )


# --- summary (``slungload inspect``) --------------------------------------------------------


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
    folder = _check_folder(folder)
    params, source = resolve_params(folder, params)
    notes: list[str] = []
    try:
        names = read_splits(folder)
    except DatasetError as exc:
        if any((folder / f"{s}.txt").is_file() for s in SPLITS):
            raise
        names = {"all": sorted(p.stem for p in folder.glob("*.npz"))}
        notes.append(str(exc))
    splits: dict[str, SplitSummary] = {}
    skipped: list[str] = []
    samples: dict[str, list[np.ndarray]] = {k: [] for k in _RANGES}
    for split, split_names in names.items():
        flights = [_read_flight(folder / f"{n}.npz", params, notes) for n in split_names]
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
