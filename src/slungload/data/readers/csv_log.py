"""Flight logs as CSV: one header row, one column per number, mapped by a column map.

The mapping keys (defaults in ``CSV_DEFAULTS``: the published schema's keys with ``_x``,
``_y``, ``_z``, ``_w`` suffixes) name the columns of time, ``p`` (3), ``v`` (3, optional:
``""`` or absent columns give finite differences of ``p``), ``attitude`` (4, in the order
x, y, z, w), ``p_load`` (3), ``w_ref`` (3) and ``T_ref`` (1); ``time_unit`` ("s", "ms", "us",
"ns") scales the time column (not given: seconds, unless the median step is too long for a
flight log, over ``ConsistencyLimits.max_step``; then ms, us or ns, with a note); ``thrust``
says whether ``T_ref`` is in newtons ("N") or a normalised throttle ("normalized", converted
by the thrust map); ``world`` ("enu" or "ned"), ``body`` (the attitude's body axes) and
``rates`` (the body rates' axes) are "flu" or "frd". The load's columns must not be the
vehicle's (its position would be the vehicle's: refused by name).

Streams may be logged at different rates in one file: a blank cell means "not sampled in this
row", and each quantity uses the rows where all its columns hold a number. A cell that is
neither blank nor a number is an error naming the row and the column.
"""

from __future__ import annotations

import csv
from collections.abc import Collection
from pathlib import Path
from typing import Any

import numpy as np

from ... import frames
from .logs import ROLES, LogError, RawLog, Stream, choice, merge_settings


def _cols(key: str, axes: str) -> list[str]:
    return [f"{key}_{a}" for a in axes]


CSV_DEFAULTS: dict[str, Any] = {
    "time": "time",
    "time_unit": "s",
    "p": _cols("p", "xyz"),
    "v": _cols("v", "xyz"),
    "attitude": _cols("attitude", "xyzw"),
    "p_load": _cols("p_load", "xyz"),
    "w_ref": _cols("w_ref", "xyz"),
    "T_ref": "T_ref",
    "thrust": "N",
    "world": "enu",
    "body": "flu",
    "rates": "flu",
}
TIME_UNITS = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
_SIZES = {"p": 3, "v": 3, "attitude": 4, "p_load": 3, "w_ref": 3, "T_ref": 1}
_ROLE = {
    "p": "position",
    "v": "velocity",
    "attitude": "attitude",
    "p_load": "load",
    "w_ref": "rates",
    "T_ref": "thrust",
}


def read_csv(
    path: str | Path,
    mapping: dict[str, Any] | None = None,
    *,
    progress: bool = False,
    roles: Collection[str] | None = None,
) -> RawLog:
    """The streams of one CSV log (``progress`` is unused: one quick pass); only the columns
    of ``roles`` (None: every role) are read, so a motion-capture CSV of positions alone
    serves as a second log."""
    path = Path(path)
    wanted = set(ROLES if roles is None else roles)
    what = str(path)
    settings = merge_settings(CSV_DEFAULTS, mapping, what)
    world = choice(settings, "world", frames.WORLD_FRAMES, what)
    body = choice(settings, "body", frames.BODY_FRAMES, what)
    rates_frame = choice(settings, "rates", frames.BODY_FRAMES, what)
    unit = choice(settings, "time_unit", tuple(TIME_UNITS), what)
    thrust_unit = choice(settings, "thrust", ("n", "normalized"), what)
    header, body_rows = _read_rows(path)
    notes: list[str] = []

    def numbers(name: str, key: str) -> np.ndarray:
        return _numbers(path, header, body_rows, name, key)

    if {"load", "position"} <= wanted and _columns(settings, "p_load", path) == _columns(
        settings, "p", path
    ):
        raise LogError(
            f"{path}: the load's columns (mapping key 'p_load') are the vehicle's own ('p': "
            f"{', '.join(_columns(settings, 'p', path) or [])}): |pL - p| would be 0; map "
            "p_load to the load's position columns"
        )
    time_col = _columns(settings, "time", path)
    if time_col is None:
        raise LogError(f"{path}: mapping key 'time' must name the time column")
    time = numbers(time_col[0], "time")
    if "time_unit" not in (mapping or {}):
        unit = _detect_unit(time, path, notes)
    time = time * TIME_UNITS[unit]
    stamped = np.isfinite(time)
    streams: dict[str, Stream] = {}
    for key, role in _ROLE.items():
        if role not in wanted:
            continue
        names = _columns(settings, key, path)
        if key == "v":  # optional: absent default columns, or "", mean finite differences
            explicit = bool((mapping or {}).get("v"))
            if names is None or (not explicit and not all(n in header for n in names)):
                notes.append(f"{path}: no velocity columns: the velocity is a finite difference")
                continue
        if names is None:
            raise LogError(f"{path}: mapping key {key!r} must name its columns")
        values = np.stack([numbers(n, key) for n in names], axis=1)
        rows_of = stamped & np.isfinite(values).all(axis=1)
        v = _to_frames(key, values[rows_of], world, body, rates_frame)
        source = f"column{'s' if len(names) > 1 else ''} {', '.join(names)}"
        streams[role] = Stream(source, time[rows_of], v)
    return RawLog(path, "csv", streams, thrust_unit == "normalized", settings, notes)


def _detect_unit(time: np.ndarray, path: Path, notes: list[str]) -> str:
    """The time unit when the mapping gives none: seconds, unless the median step is too long
    for a flight log (``ConsistencyLimits.max_step``); then the first of ms, us, ns that puts
    it within the limits, with a note."""
    from ..consistency import ConsistencyLimits

    limits = ConsistencyLimits()
    steps = np.diff(time[np.isfinite(time)])
    step = float(np.median(steps)) if len(steps) else 0.0
    if step <= limits.max_step:
        return "s"
    for unit in ("ms", "us", "ns"):
        if limits.min_step <= step * TIME_UNITS[unit] <= limits.max_step:
            notes.append(
                f"{path}: no time_unit given and the time column's median step is {step:g}: "
                f'read as {unit} (a step of {step * TIME_UNITS[unit]:g} s); set time_unit = "s" '
                "in the mapping if it is seconds"
            )
            return unit
    return "s"


def _read_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    """The header's column names (stripped) and the rows below it, as text cells."""
    try:
        with path.open(newline="", encoding="utf-8-sig") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise LogError(f"{path}: cannot be read as CSV text ({exc})") from None
    if not rows:
        raise LogError(f"{path}: empty file, expected a header row of column names")
    header = [h.strip() for h in rows[0]]
    if header and all(_is_number(h) for h in header if h) and any(header):
        raise LogError(
            f"{path}: has no header row: its first row holds {len(header)} numbers "
            f"({', '.join(header[:4])}{', ...' if len(header) > 4 else ''}), not column names; "
            "add a first row naming the columns (the defaults: time, p_x, p_y, p_z, ..., T_ref; "
            "or any names, mapped with --map)"
        )
    return header, rows[1:]


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def _columns(settings: dict[str, Any], key: str, path: Path) -> list[str] | None:
    """The column names the mapping gives ``key`` (None: not mapped), as many as it needs."""
    value = settings[key]
    if value in ("", None, []):
        return None
    names = [value] if isinstance(value, str) else list(value)
    size = _SIZES.get(key, 1)
    if len(names) != size:
        raise LogError(f"{path}: mapping key {key!r} names {len(names)} columns, needs {size}")
    return names


def _numbers(
    path: Path, header: list[str], rows: list[list[str]], name: str, key: str
) -> np.ndarray:
    """Column ``name`` as (rows,) floats, NaN where a cell is blank (not sampled in that row)."""
    if name not in header:
        why = ""
        if key in ("w_ref", "T_ref"):
            why = (
                ". The commanded thrust and body rates are required: the model predicts the "
                "flight from them (its inputs u = (T, omega)); a log without the commands cannot "
                "train it. Map their columns with 'T_ref' (and 'thrust': \"N\" or "
                "\"normalized\") and 'w_ref'"
            )
        raise LogError(
            f"{path}: no column {name!r} (mapping key {key!r}); columns: {', '.join(header)}{why}"
        )
    j = header.index(name)
    out = np.full(len(rows), np.nan)
    for i, row in enumerate(rows):
        cell = row[j].strip() if j < len(row) else ""
        if cell:
            try:
                out[i] = float(cell)
            except ValueError:
                raise LogError(
                    f"{path}: row {i + 2}, column {name!r}: {cell!r} is not a number"
                ) from None
    return out


def _to_frames(key: str, v: np.ndarray, world: str, body: str, rates: str) -> np.ndarray:
    """One quantity's (n, size) values converted into the package's frames."""
    if key in ("p", "v", "p_load"):
        return frames.world_vectors(v, world)
    if key == "attitude":
        return frames.attitudes(v[:, [3, 0, 1, 2]], world, body)  # x-y-z-w -> w-x-y-z
    if key == "w_ref":
        return frames.body_vectors(v, rates)
    return v
