"""What ``slungload control`` measured and its statistics: the typed ``ControlComparison`` (one
row of ``closed_loop.flight_metrics`` per flight), the rows of one controller by flight
(``by_flight``) and the flights two flew to the end (``both_completed``), the means over the
seeds per group (``summary``) and each network's MPC against MPC + physics at the same K
(``versus_physics``). Plain numbers, no files: ``comparison`` and ``study`` fly, ``report``
and ``study_report`` write. The statistics every report shares (``paired_interval``,
``gap_share``, ``gap_interval``) live in ``slungload.reporting``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ...control.closed_loop import FlightLog
from ...models.prediction import PHYSICS

METRICS = {  # a flight's figures (``closed_loop.flight_metrics``): key -> (header, format)
    "vehicle_rmse": ("vehicle RMSE (m)", "{:.3f}"),
    "load_rmse": ("load RMSE (m)", "{:.3f}"),
    "swing_rms": ("swing RMS (deg)", "{:.1f}"),
    "swing_max": ("swing max (deg)", "{:.1f}"),
    "at_limit": ("at a limit (%)", "{:.1f}"),
}


def columns(*keys: str) -> tuple[tuple[str, str, str], ...]:
    """(key, header, format) of each of ``keys`` (of ``METRICS``), in that order."""
    return tuple((key, *METRICS[key]) for key in keys)


COLUMNS = columns(*METRICS)  # the error columns of ``control``'s tables, means over seeds
PAIRED = ("load_rmse", "swing_rms", "vehicle_rmse")  # compared flight by flight with physics
# the figures the control study reports per controller and pair (``study_report``)
KEYS = columns("load_rmse", "swing_rms", "swing_max", "vehicle_rmse")

Row = dict[str, Any]  # one flight's figures (``flight_metrics``) and how it was flown
Flight = tuple[str, int]  # (maneuver, seed): what pairs two controllers' flights


def mpc_label(model: str, horizon: int) -> str:
    """The control study's label of an MPC over ``model`` at N = ``horizon``: "mpc-learned N=25"."""
    return f"mpc-{model} N={horizon}"


def label_model(label: str) -> str:
    """The prediction model of a controller label: "mpc-learned N=25" and "mpc-net K=32" ->
    "learned", "net"; a label without an MPC ("pid") is its own."""
    return re.sub(r"^mpc-| [KN]=\d+$", "", label)


def label_horizon(label: str) -> int | None:
    """The N of a control study's MPC label ("mpc-learned N=25" -> 25); None for the others."""
    found = re.search(r" N=(\d+)$", label)
    return int(found.group(1)) if found else None


def ratio(numerator: float, denominator: float) -> float:
    """numerator / denominator, NaN unless both are finite and the denominator is not zero."""
    if denominator == 0 or not (math.isfinite(numerator) and math.isfinite(denominator)):
        return math.nan
    return numerator / denominator


def by_flight(rows: Sequence[Row], **match: Any) -> dict[Flight, Row]:
    """The rows whose fields equal ``match`` (e.g. ``controller=``, ``plant=``), by flight."""
    return {
        (r["maneuver"], r["seed"]): r
        for r in rows
        if all(r.get(key) == value for key, value in match.items())
    }


def both_completed(a: dict[Flight, Row], b: dict[Flight, Row]) -> list[tuple[Row, Row]]:
    """(a's row, b's row) of each flight both flew to the end (``by_flight`` dicts)."""
    return [(a[k], b[k]) for k in a if k in b and a[k]["completed"] and b[k]["completed"]]


@dataclass
class ControlComparison:
    """What ``compare`` flew and measured; ``rows`` are ``flight_metrics`` dicts plus "K" (None
    for the PID) and "wall_s"; ``logs`` the flights, in the same order."""

    rows: list[dict[str, Any]]
    settings: dict[str, Any]
    out: Path | None = None
    logs: list[FlightLog] = field(default_factory=list, repr=False)


def mean_of(rows: Sequence[Row], key: str) -> float:
    """The mean of ``key`` over the rows where it is finite (NaN when it is nowhere)."""
    finite = [v for r in rows if (v := r[key]) is not None and math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan


def fmt(value: float | None, spec: str) -> str:
    """A table cell: ``spec`` applied to ``value``, "-" when it is missing or not finite."""
    return "-" if value is None or not math.isfinite(value) else spec.format(value)


def fmt_interval(mean: float, low: float, high: float, spec: str) -> str:
    """A paired difference's cell: "mean [low, high]", each with ``spec`` ("-" if missing)."""
    return f"{fmt(mean, spec)} [{fmt(low, spec)}, {fmt(high, spec)}]"


def summary(rows: list[dict[str, Any]], by: tuple[str, ...]) -> list[dict[str, Any]]:
    """Means over the seeds (completed flights only for the errors) grouped by ``by``."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in by), []).append(row)
    out = []
    for key, group in groups.items():
        done = [r for r in group if r["completed"]]
        entry = dict(zip(by, key, strict=True))
        entry.update({k: mean_of(done, k) for k, _, _ in COLUMNS})
        entry["flights"] = len(group)
        entry["failed"] = len(group) - len(done)
        entry["fallbacks"] = sum(r.get("fallback_steps", 0) for r in group)
        entry["K"] = group[0].get("K")  # the study's labels name their N instead
        compute = [r["compute_median"] for r in group]
        entry["compute_median"] = float(np.median(compute))
        entry["compute_p99"] = float(np.max([r["compute_p99"] for r in group]))
        out.append(entry)
    return out


def step_share(rows: list[dict[str, Any]], key: str) -> float | None:
    """The share of the MPC steps of ``rows`` that the flight rows' ``key`` counts, e.g.
    "physics_only_steps" (``PhysicsPaired``'s trust window gave physics alone the say) or
    "surprised_steps" (a calibrated ensemble's tracked interval, ``control.tracked``); None when
    the rows count no MPC step."""
    steps = sum(r.get("mpc_steps", 0) for r in rows)
    return sum(r.get(key, 0) for r in rows) / steps if steps else None


@dataclass(frozen=True)
class VersusPhysics:
    """One network's MPC against MPC + physics at the same K, over every maneuver flown.

    The means (``network``, ``physics``: key of ``PAIRED`` -> mean; m, deg, m) are over the
    flights both flew to the end, paired by maneuver and seed; empty when there is none.
    """

    controller: str
    samples: int  # K
    flights: int  # the network's flights
    failed: int  # of them, ended early
    stopped: str | None  # why the first of those ended
    paired: int  # flights both flew to the end
    physics_failed: int  # flights the network flew to the end and MPC + physics did not
    network: dict[str, float]
    physics: dict[str, float]
    # share of the network's control steps priced by physics alone (``PhysicsPaired``'s window)
    physics_only: float = 0.0
    # share of its control steps on which a calibrated ensemble's tracked interval was surprised
    surprised: float = 0.0

    def lower(self, key: str) -> float:
        """How much lower the network's mean of ``key`` is, as a fraction of physics's."""
        return 1.0 - ratio(self.network[key], self.physics[key])


def versus_physics(rows: list[dict[str, Any]]) -> list[VersusPhysics]:
    """Every network flown in the MPC against MPC + physics at the same K (see
    ``VersusPhysics``), by K, then by controller name."""
    out = []
    mpc = [r for r in rows if r["K"] is not None]
    for k in sorted({r["K"] for r in mpc}):
        reference = f"mpc-{PHYSICS} K={k}"  # ``control``'s labels name K, the study's N
        physics = by_flight(mpc, K=k, controller=reference)
        for net in sorted({r["controller"] for r in mpc if r["K"] == k} - {reference}):
            mine = by_flight(mpc, K=k, controller=net)
            flown = list(mine.values())
            both = both_completed(mine, physics)
            means = [{key: mean_of([pair[i] for pair in both], key) for key in PAIRED} if both
                     else {} for i in (0, 1)]  # fmt: skip
            failed = [r for r in flown if not r["completed"]]
            physics_failed = sum(r["completed"] and f in physics and not physics[f]["completed"]
                                 for f, r in mine.items())  # fmt: skip
            out.append(VersusPhysics(
                net, k, len(mine), len(failed), failed[0]["stopped"] if failed else None,
                len(both), physics_failed, *means, step_share(flown, "physics_only_steps") or 0.0,
                step_share(flown, "surprised_steps") or 0.0,
            ))  # fmt: skip
    return out
