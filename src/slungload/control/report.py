"""``slungload control``: the PID, MPC + physics model and MPC + each network, flown and compared.

``compare(models, maneuvers, seeds, samples, out)`` flies every controller on every maneuver
and seed (every unmodelled effect on), one MPC per prediction model and K in ``samples``, and
writes into ``out``: ``results.json`` (one row of ``closed_loop.flight_metrics`` per flight,
the settings and the machine), ``flights/*.npz`` (each flight's log), ``report.md`` (the
tables, each network against the physics model, the timing), and the figures ``paths_3d.png``
(reference vs flown vehicle paths, first seed of each maneuver), ``swing.png`` (load swing
angle over time, same flights) and ``table.png`` (the tracking-error table as bars).
"""

from __future__ import annotations

import math
import os
import platform
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from datetime import date
from pathlib import Path
from typing import Any

import numpy as np
import torch
from matplotlib.figure import Figure

from ..config import VehicleParams
from ..deploy.batched import load_model
from ..evaluation.machine import cpu_model
from ..fileio import atomic_path, write_json, write_npz, write_text
from ..models.prediction import PHYSICS, PredictionModel
from ..sim.config import SimConfig
from ..sim.controller import PIDController
from ..sim.dataset import vehicle_params
from ..sim.maneuvers import MANEUVERS
from .closed_loop import Arena, FlightLog, flight_metrics, fly, swing_angle
from .mpc import InputLimits, MPCConfig, SamplingMPC

AGGRESSIVE = ("baf_very_fast", "roll_35", "fast_8_lap_xyz")  # the default aggressive maneuvers
DEFAULT_MANEUVERS = AGGRESSIVE
PID = "pid"
COLUMNS = (  # (key, header, format)
    ("vehicle_rmse", "vehicle RMSE (m)", "{:.3f}"),
    ("load_rmse", "load RMSE (m)", "{:.3f}"),
    ("swing_rms", "swing RMS (deg)", "{:.1f}"),
    ("swing_max", "swing max (deg)", "{:.1f}"),
    ("at_limit", "at a limit (%)", "{:.1f}"),
)


@dataclass
class ControlComparison:
    """What ``compare`` flew and measured; ``rows`` are ``flight_metrics`` dicts plus "K"."""

    rows: list[dict[str, Any]]
    settings: dict[str, Any]
    out: Path | None = None


def compare(
    models: Sequence[str | Path] = (),
    maneuvers: Sequence[str] = DEFAULT_MANEUVERS,
    seeds: Sequence[int] = (100, 101, 102),
    samples: Sequence[int] = (32,),
    out: str | Path | None = None,
    *,
    horizon: int | None = None,
    steps: int | None = None,
    config: SimConfig | None = None,
    threads: int = 1,
    backend: str = "eager",
    progress: Callable[[str], None] | None = print,
) -> ControlComparison:
    """Fly the PID, MPC + physics and MPC + each network (run folders) and write the report.

    samples: K values; each prediction model runs once per K. horizon: the MPC's N (default
    ``MPCConfig.horizon``). steps: cut every flight to this many recorded steps (smoke runs).
    threads: torch threads while flying (restored after). backend: what the prediction models
    run on (``deploy.batched.BACKENDS``: "eager" torch, or "compiled" kernels).
    """
    unknown = [m for m in maneuvers if m not in MANEUVERS]
    if unknown:
        raise ValueError(f"unknown maneuvers {unknown}; known: {sorted(MANEUVERS)}")
    cfg = config or SimConfig()
    params = vehicle_params(cfg)
    limits = InputLimits.from_sim(cfg)
    predictors: list[PredictionModel] = [load_model(PHYSICS, params, backend=backend)]
    predictors += [load_model(m, backend=backend) for m in models]
    base = MPCConfig() if horizon is None else MPCConfig(horizon=horizon)
    out_dir = Path(out) if out is not None else None
    if out_dir is not None:
        (out_dir / "flights").mkdir(parents=True, exist_ok=True)
    plans = _plans(cfg, predictors, samples, base, limits, params)
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        rows, logs = _fly_all(maneuvers, seeds, plans, cfg, limits, steps, out_dir, progress)
    finally:
        torch.set_num_threads(previous)
    settings = _settings(models, maneuvers, seeds, samples, base, limits, steps, threads)
    settings["backend"] = backend
    result = ControlComparison(rows, settings, out_dir)
    if out_dir is not None:
        write_json(out_dir / "results.json", {"settings": settings, "rows": rows})
        plot_paths(logs, out_dir / "paths_3d.png")
        plot_swing(logs, out_dir / "swing.png")
        plot_table(rows, out_dir / "table.png")
        write_text(out_dir / "report.md", report_markdown(result))
    return result


_Plan = tuple[str, int | None, Callable[[int], Any]]  # (label, K or None, seed -> controller)


def _plans(
    cfg: SimConfig,
    predictors: list[PredictionModel],
    samples: Sequence[int],
    base: MPCConfig,
    limits: InputLimits,
    params: VehicleParams,
) -> list[_Plan]:
    """The controllers to fly: the PID, then one MPC per K and prediction model."""
    plans: list[_Plan] = [(PID, None, lambda seed: PIDController(cfg))]
    for k in samples:
        for model in predictors:
            mpc_cfg = replace(base, samples=int(k))
            plans.append(
                (f"mpc-{model.name}", int(k), _mpc_factory(model, limits, mpc_cfg, params))
            )
    return plans


def _fly_all(
    maneuvers: Sequence[str],
    seeds: Sequence[int],
    plans: list[_Plan],
    cfg: SimConfig,
    limits: InputLimits,
    steps: int | None,
    out_dir: Path | None,
    progress: Callable[[str], None] | None,
) -> tuple[list[dict[str, Any]], list[FlightLog]]:
    """Every plan on every maneuver and seed: the metric rows (with "K" and the wall time in
    s) and the flight logs, each log saved under ``out_dir/flights`` as it lands."""
    rows, logs = [], []
    for maneuver in maneuvers:
        for seed in seeds:
            for label, k, make in plans:
                name = label if k is None else f"{label} K={k}"
                start = time.perf_counter()
                log = fly(maneuver, seed, make(seed), label=name, config=cfg, steps=steps)
                row = flight_metrics(log, limits, cfg.cable_length)
                row["K"] = k
                row["wall_s"] = time.perf_counter() - start
                rows.append(row)
                logs.append(log)
                if out_dir is not None:
                    _save_log(out_dir / "flights", log)
                if progress:
                    progress(_progress_line(row))
    return rows, logs


def _settings(
    models: Sequence[str | Path],
    maneuvers: Sequence[str],
    seeds: Sequence[int],
    samples: Sequence[int],
    base: MPCConfig,
    limits: InputLimits,
    steps: int | None,
    threads: int,
) -> dict[str, Any]:
    """What was flown and where, for ``results.json`` and the report."""
    return {
        "models": [str(m) for m in models],
        "maneuvers": list(maneuvers),
        "seeds": list(seeds),
        "samples": [int(k) for k in samples],
        "mpc": {k: v for k, v in vars(base).items() if k != "samples"},
        "limits": vars(limits),
        "arena": vars(Arena()),
        "steps": steps,
        "threads": threads,
        "machine": _machine(),
        "date": date.today().isoformat(),
    }


def _machine() -> dict[str, Any]:
    """The CPU, its cores and the load average while the report is written (timings depend
    on them)."""
    return {
        "cpu": cpu_model() or platform.processor(),
        "cores": os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


def _mpc_factory(model, limits, mpc_cfg, params):
    return lambda seed: SamplingMPC(model, limits, replace(mpc_cfg, seed=seed), params)


def _save_log(folder: Path, log: FlightLog) -> None:
    name = f"{log.maneuver}_s{log.seed}_{log.controller.replace(' ', '_').replace('=', '')}.npz"
    write_npz(folder / name, {
        "t": log.t, "states": log.states, "p_ref": log.p_ref, "inputs": log.inputs,
        "compute": log.compute,
    })  # fmt: skip


def _progress_line(row: dict[str, Any]) -> str:
    status = "ok" if row["completed"] else f"STOPPED: {row['stopped']}"
    return (
        f"{row['maneuver']} seed {row['seed']} {row['controller']}: vehicle "
        f"{row['vehicle_rmse']:.3f} m, load {row['load_rmse']:.3f} m, swing RMS "
        f"{row['swing_rms']:.1f} deg, compute median {row['compute_median']:.1f} ms ({status})"
    )


# --- tables ----------------------------------------------------------------------------


def _mean(values: list[float]) -> float:
    values = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(values)) if values else math.nan


def summary(rows: list[dict[str, Any]], by: tuple[str, ...]) -> list[dict[str, Any]]:
    """Means over the seeds (completed flights only for the errors) grouped by ``by``."""
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for row in rows:
        groups.setdefault(tuple(row[k] for k in by), []).append(row)
    out = []
    for key, group in groups.items():
        done = [r for r in group if r["completed"]]
        entry = dict(zip(by, key, strict=True))
        entry.update({k: _mean([r[k] for r in done]) for k, _, _ in COLUMNS})
        entry["flights"] = len(group)
        entry["failed"] = len(group) - len(done)
        entry["fallbacks"] = sum(r.get("fallback_steps", 0) for r in group)
        entry["K"] = group[0]["K"]
        compute = [r["compute_median"] for r in group]
        entry["compute_median"] = float(np.median(compute))
        entry["compute_p99"] = float(np.max([r["compute_p99"] for r in group]))
        out.append(entry)
    return out


def _fmt(value: float, spec: str) -> str:
    return "-" if value is None or not math.isfinite(value) else spec.format(value)


def markdown_table(entries: list[dict[str, Any]], first: tuple[str, ...]) -> str:
    head = [*first, *(h for _, h, _ in COLUMNS), "failed", "fallback steps"]
    head.append("compute median / p99 (ms)")
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for e in entries:
        cells = [str(e[k]) for k in first]
        cells += [_fmt(e[k], spec) for k, _, spec in COLUMNS]
        cells += [f"{e['failed']} / {e['flights']}", str(e["fallbacks"])]
        cells.append(f"{e['compute_median']:.2f} / {e['compute_p99']:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def target_check(rows: list[dict[str, Any]]) -> list[str]:
    """Whether each network, per K, beats the physics model in the same MPC: >= 25 % lower load
    RMSE, or >= 25 % lower swing RMS at equal vehicle tracking (within 10 %), than MPC + physics
    at the same K, on the aggressive maneuvers flown, means over seeds. A network flight that
    ended early fails the target; the means are over the flights both controllers flew to the
    end (paired by maneuver and seed), and physics flights that ended early are counted beside
    them."""
    lines = []
    aggressive = [r for r in rows if r["maneuver"] in AGGRESSIVE and r["K"] is not None]
    for k in sorted({r["K"] for r in aggressive}):
        at_k = [r for r in aggressive if r["K"] == k]
        physics = {
            (r["maneuver"], r["seed"]): r for r in at_k if r["controller"] == f"mpc-{PHYSICS} K={k}"
        }
        nets = sorted({r["controller"] for r in at_k} - {f"mpc-{PHYSICS} K={k}"})
        for net in nets:
            mine = [r for r in at_k if r["controller"] == net]
            failed = sum(not r["completed"] for r in mine)
            if failed:
                lines.append(
                    f"- {net}: **not met**: {failed} of {len(mine)} aggressive flights ended "
                    f"early ({mine[0]['stopped'] or 'see the table'})."
                )
                continue
            pairs = [(r, physics.get((r["maneuver"], r["seed"]))) for r in mine]
            both = [(r, q) for r, q in pairs if q is not None and q["completed"]]
            lost = sum(q is not None and not q["completed"] for _, q in pairs)
            if not both:
                lines.append(f"- {net}: no flight that MPC + physics also flew to the end.")
                continue
            got, ref = ({key: _mean([pair[i][key] for pair in both])
                         for key in ("load_rmse", "swing_rms", "vehicle_rmse")}
                        for i in (0, 1))  # fmt: skip
            load = 1.0 - got["load_rmse"] / ref["load_rmse"]
            swing = 1.0 - got["swing_rms"] / ref["swing_rms"]
            equal = got["vehicle_rmse"] <= 1.1 * ref["vehicle_rmse"]
            met = load >= 0.25 or (swing >= 0.25 and equal)
            lines.append(
                f"- {net}: load RMSE {got['load_rmse']:.3f} vs {ref['load_rmse']:.3f} m "
                f"({100 * load:.0f} % lower), swing RMS {got['swing_rms']:.1f} vs "
                f"{ref['swing_rms']:.1f} deg ({100 * swing:.0f} % lower), vehicle RMSE "
                f"{got['vehicle_rmse']:.3f} vs {ref['vehicle_rmse']:.3f} m, over the "
                f"{len(both)} flights both flew to the end"
                + (f" (MPC + physics ended {lost} more early)" if lost else "")
                + f": **{'met' if met else 'not met'}**."
            )
    return lines or ["- no network was flown on an aggressive maneuver"]


def report_markdown(result: ControlComparison) -> str:
    rows, s = result.rows, result.settings
    per_man = sorted(summary(rows, ("maneuver", "controller")), key=lambda e: e["maneuver"])
    overall = summary(rows, ("controller",))
    mpc = s["mpc"]
    load = s["machine"]["load_average"]
    parts = [
        "# Closed-loop control: PID vs sampling MPC",
        "",
        f"{s['date']}; maneuvers {', '.join(s['maneuvers'])}; sim seeds "
        f"{', '.join(map(str, s['seeds']))}; every unmodelled effect on; MPC horizon N = "
        f"{mpc['horizon']} ({mpc['horizon'] * 0.03:.2f} s), K = "
        f"{', '.join(map(str, s['samples']))}; torch threads {s['threads']}; prediction "
        f"backend {s.get('backend', 'eager')}; "
        f"{s['machine']['cpu']} ({s['machine']['cores']} cores, load average at the end "
        f"{', '.join(f'{x:.1f}' for x in load) if load else 'unknown'}).",
        "",
        "Errors are means over the seeds of the flights that flew to the end; `failed` counts "
        "the flights that ended early (the reason is in results.json). The load's reference is "
        "the vehicle's minus the cable length along z. Compute: the controller call per "
        "control step (median of the flights' medians / largest p99).",
        "",
        "## All maneuvers",
        "",
        markdown_table(overall, ("controller",)),
        "",
        "## Per maneuver",
        "",
        markdown_table(per_man, ("maneuver", "controller")),
        "",
        "## A network vs the physics model in the same MPC",
        "",
        *target_check(rows),
        "",
        "## Stopped flights",
        "",
        *(
            [
                f"- {r['maneuver']} seed {r['seed']} {r['controller']}: {r['stopped']}"
                for r in rows
                if not r["completed"]
            ]
            or ["- none"]
        ),  # fmt: skip
        "",
        "Figures: `paths_3d.png` (reference vs flown vehicle paths), `swing.png` (swing "
        "angle over time), `table.png` (the table as bars).",
        "",
    ]
    return "\n".join(parts)


# --- figures ---------------------------------------------------------------------------

DPI = 110


def _first_flights(logs: list[FlightLog]) -> dict[str, list[FlightLog]]:
    """Per maneuver, the flights of its first seed (one per controller)."""
    out: dict[str, list[FlightLog]] = {}
    for log in logs:
        first = next(lg.seed for lg in logs if lg.maneuver == log.maneuver)
        if log.seed == first:
            out.setdefault(log.maneuver, []).append(log)
    return out


def _save(fig: Figure, path: Path) -> Path:
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return path


def plot_paths(logs: list[FlightLog], path: Path) -> Path:
    """Reference (black) and flown vehicle paths, one 3D panel per maneuver (first seed)."""
    flights = _first_flights(logs)
    fig = Figure(figsize=(5.0 * len(flights), 4.6))
    for i, (maneuver, group) in enumerate(flights.items()):
        ax = fig.add_subplot(1, len(flights), i + 1, projection="3d")
        rec = group[0].t >= 0
        ref = group[0].p_ref[rec]
        ax.plot(*ref.T, color="black", lw=1.5, label="reference")
        for log in group:
            p = log.states[log.t >= 0, 0:3]
            label = log.controller + ("" if log.stopped is None else " (stopped)")
            ax.plot(*p.T, lw=1.0, label=label)
        ax.set_title(f"{maneuver} (seed {group[0].seed})", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        if i == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return _save(fig, path)


def plot_swing(logs: list[FlightLog], path: Path) -> Path:
    """Swing angle over time per controller, one panel per maneuver (first seed)."""
    flights = _first_flights(logs)
    fig = Figure(figsize=(9.0, 2.6 * len(flights)))
    for i, (maneuver, group) in enumerate(flights.items()):
        ax = fig.add_subplot(len(flights), 1, i + 1)
        for log in group:
            rec = log.t >= 0
            ax.plot(
                log.t[rec],
                np.degrees(swing_angle(log.states[rec])),
                lw=0.9,
                label=log.controller + ("" if log.stopped is None else " (stopped)"),
            )
        ax.set_title(f"{maneuver} (seed {group[0].seed})", fontsize=9)
        ax.set_ylabel("swing (deg)")
        ax.grid(alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7, ncol=3)
    fig.axes[-1].set_xlabel("t (s)")
    fig.tight_layout()
    return _save(fig, path)


def plot_table(rows: list[dict[str, Any]], path: Path) -> Path:
    """Bars of the table: vehicle RMSE, load RMSE and swing RMS per maneuver and controller
    (means over the completed flights; a failed controller shows no bar)."""
    entries = summary(rows, ("maneuver", "controller"))
    maneuvers = list(dict.fromkeys(e["maneuver"] for e in entries))
    controllers = list(dict.fromkeys(e["controller"] for e in entries))
    keys = (("vehicle_rmse", "vehicle RMSE (m)"), ("load_rmse", "load RMSE (m)"),
            ("swing_rms", "swing RMS (deg)"))  # fmt: skip
    fig = Figure(figsize=(4.2 * len(keys), 3.6))
    width = 0.8 / max(1, len(controllers))
    for i, (key, title) in enumerate(keys):
        ax = fig.add_subplot(1, len(keys), i + 1)
        for j, ctrl in enumerate(controllers):
            values = [
                next((e[key] for e in entries if e["maneuver"] == m and e["controller"] == ctrl),
                     math.nan)
                for m in maneuvers
            ]  # fmt: skip
            ax.bar(np.arange(len(maneuvers)) + j * width, values, width, label=ctrl)
        ax.set_xticks(np.arange(len(maneuvers)) + 0.4 - width / 2, maneuvers, fontsize=7,
                      rotation=15)  # fmt: skip
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    return _save(fig, path)
