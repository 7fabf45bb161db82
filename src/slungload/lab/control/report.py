"""The closed-loop comparison's report: ``report.md`` (the tables, each network against the
physics model in the same MPC, the stopped flights) and the figures ``paths_3d.png`` (reference
vs flown vehicle paths, first seed of each maneuver), ``swing.png`` (load swing angle over
time, same flights) and ``table.png`` (the tracking-error table as bars), each controller in
its model's colour (``reporting.model_colors``; a second K dashed). It shows results only.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ...control.closed_loop import FlightLog
from ...control.cost import cost_words
from ...control.mppi import MPCConfig
from ...fileio import write_text
from ...frames import swing_angle
from ...reporting import markdown_table, model_colors, networks_banner, save_figure
from ...run_config import SMOKE_PRESET
from ...sim.config import SimConfig
from .results import (
    COLUMNS,
    ControlComparison,
    VersusPhysics,
    fmt,
    label_model,
    summary,
    versus_physics,
)

LINESTYLES = ("-", "--", ":", "-.")  # one per K of a model, in the order flown
# the MPCConfig fields the report names the cost by (an older results.json lacks them: the defaults)
COST_FIELDS = ("cost", "lean", "shape")


def write_report(result: ControlComparison, out: str | Path) -> Path:
    """report.md and the three figures into ``out``; returns report.md's path."""
    out = Path(out)
    looks = controller_looks([r["controller"] for r in result.rows])
    plot_paths(result.logs, out / "paths_3d.png", looks)
    plot_swing(result.logs, out / "swing.png", looks)
    plot_table(result.rows, out / "table.png", looks)
    write_text(out / "report.md", report_markdown(result))
    return out / "report.md"


# --- markdown ----------------------------------------------------------------------------


def summary_table(entries: list[dict[str, Any]], first: tuple[str, ...]) -> str:
    """The means of ``results.summary`` as a Markdown table, ``first`` its leading columns."""
    head = [*first, *(h for _, h, _ in COLUMNS), "failed", "fallback steps",
            "compute median / p99 (ms)"]  # fmt: skip
    rows = [
        [*(e[k] for k in first), *(fmt(e[k], spec) for k, _, spec in COLUMNS),
         f"{e['failed']} / {e['flights']}", e["fallbacks"],
         f"{e['compute_median']:.2f} / {e['compute_p99']:.2f}"]
        for e in entries
    ]  # fmt: skip
    return markdown_table(head, rows)


def _lower(fraction: float) -> str:
    """A fraction lower as words: "30 % lower", or "93 % higher" for -0.93."""
    return f"{100 * abs(fraction):.0f} % {'lower' if fraction >= 0 else 'higher'}"


def versus_lines(comparisons: list[VersusPhysics]) -> list[str]:
    """One bullet per network and K: its early ends and its means against physics's."""
    lines = []
    for v in comparisons:
        parts = []
        if v.failed:
            parts.append(f"{v.failed} of {v.flights} flights ended early ({v.stopped})")
        if not v.paired:
            parts.append("no flight that MPC + physics also flew to the end")
        else:
            got, ref = v.network, v.physics
            parts.append(
                f"load RMSE {got['load_rmse']:.3f} vs {ref['load_rmse']:.3f} m "
                f"({_lower(v.lower('load_rmse'))}), swing RMS {got['swing_rms']:.1f} "
                f"vs {ref['swing_rms']:.1f} deg ({_lower(v.lower('swing_rms'))}), "
                f"vehicle RMSE {got['vehicle_rmse']:.3f} vs {ref['vehicle_rmse']:.3f} m, over "
                f"the {v.paired} flights both flew to the end"
                + (f" (MPC + physics ended {v.physics_failed} more early)" if v.physics_failed
                   else "")
            )  # fmt: skip
        if v.physics_only:
            parts.append(f"physics alone priced {100 * v.physics_only:.0f} % of its steps (the "
                         "network predicted the steps just flown worse)")  # fmt: skip
        if v.surprised:
            parts.append(f"its ensemble was surprised on {100 * v.surprised:.0f} % of its steps "
                         "(its errors on the steps just flown beyond its calibration's: this "
                         "vehicle is off what it was calibrated on; calibrate it on this "
                         "vehicle's flights, `slungload calibrate`, or fly it with "
                         "--with-physics)")  # fmt: skip
        lines.append(f"- {v.controller}: " + "; ".join(parts) + ".")
    return lines or ["- no network was flown in the MPC"]


def report_markdown(result: ControlComparison) -> str:
    rows, s = result.rows, result.settings
    per_man = sorted(summary(rows, ("maneuver", "controller")), key=lambda e: e["maneuver"])
    mpc, machine = s["mpc"], s["machine"]
    load = machine["load_average"]
    stopped = [f"- {r['maneuver']} seed {r['seed']} {r['controller']}: {r['stopped']}"
               for r in rows if not r["completed"]]  # fmt: skip
    smoke = [m for m, preset in s.get("presets", {}).items() if preset == SMOKE_PRESET]
    parts = [
        "# Closed-loop control: PID vs sampling MPC",
        "",
        *networks_banner(smoke, SMOKE_PRESET),
        f"{s['date']}; maneuvers {', '.join(s['maneuvers'])}; sim seeds "
        f"{', '.join(map(str, s['seeds']))}; every unmodelled effect on; MPC horizon N = "
        f"{mpc['horizon']} ({mpc['horizon'] * SimConfig.control_dt:.2f} s), K = "
        f"{', '.join(map(str, s['samples']))}, "
        f"{cost_words(**{k: mpc.get(k, getattr(MPCConfig, k)) for k in COST_FIELDS})}"
        f"; torch threads {s['threads']}; prediction "
        f"backend {s.get('backend', 'eager')}; {machine['cpu']} ({machine['cores']} cores, load "
        f"average at the end {', '.join(f'{x:.1f}' for x in load) if load else 'unknown'})"
        + (f"; GPU {machine['gpu']}" if machine.get("gpu") else "")
        + ".",
        "",
        "Errors are means over the seeds of the flights that flew to the end; `failed` counts "
        "the flights that ended early (the reason is in results.json). The load's reference is "
        "the vehicle's minus the cable length along z. Compute: the controller call per "
        "control step (median of the flights' medians / largest p99).",
        "",
        "## All maneuvers",
        "",
        summary_table(summary(rows, ("controller",)), ("controller",)),
        "",
        "## Per maneuver",
        "",
        summary_table(per_man, ("maneuver", "controller")),
        "",
        "## A network vs the physics model in the same MPC",
        "",
        "Means over every maneuver flown, on the flights both flew to the end (paired by "
        "maneuver and seed), at the same K:",
        "",
        *versus_lines(versus_physics(rows)),
        "",
        "## Stopped flights",
        "",
        *(stopped or ["- none"]),
        "",
        "Figures: `paths_3d.png` (reference vs flown vehicle paths), `swing.png` (swing "
        "angle over time), `table.png` (the table as bars).",
        "",
    ]
    return "\n".join(parts)


# --- figures ---------------------------------------------------------------------------


def controller_looks(controllers: list[str]) -> dict[str, dict[str, Any]]:
    """Line keywords per controller label ("pid", "mpc-<model> K=<k>"): its model's colour,
    and a line style per K of that model (solid for the first flown)."""
    model = {c: label_model(c) for c in dict.fromkeys(controllers)}
    colors = model_colors(model.values())
    looks, styles_used = {}, {}
    for controller, name in model.items():
        index = styles_used[name] = styles_used.get(name, -1) + 1
        looks[controller] = {"color": colors[name],
                             "linestyle": LINESTYLES[index % len(LINESTYLES)]}  # fmt: skip
    return looks


def _first_flights(logs: list[FlightLog]) -> dict[str, list[FlightLog]]:
    """Per maneuver, the flights of its first seed (one per controller)."""
    out: dict[str, list[FlightLog]] = {}
    for log in logs:
        first = next(lg.seed for lg in logs if lg.maneuver == log.maneuver)
        if log.seed == first:
            out.setdefault(log.maneuver, []).append(log)
    return out


def plot_paths(
    logs: list[FlightLog], path: Path, looks: dict[str, dict[str, Any]] | None = None
) -> Path:
    """Reference (black) and flown vehicle paths, one 3D panel per maneuver (first seed);
    ``looks``: ``controller_looks`` over every controller (default: over these flights)."""
    looks = looks or controller_looks([log.controller for log in logs])
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
            ax.plot(*p.T, lw=1.0, label=label, **looks.get(log.controller, {}))
        ax.set_title(f"{maneuver} (seed {group[0].seed})", fontsize=9)
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.set_zlabel("z (m)")
        if i == 0:
            ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_swing(
    logs: list[FlightLog], path: Path, looks: dict[str, dict[str, Any]] | None = None
) -> Path:
    """Swing angle over time per controller, one panel per maneuver (first seed)."""
    looks = looks or controller_looks([log.controller for log in logs])
    flights = _first_flights(logs)
    fig = Figure(figsize=(9.0, 2.6 * len(flights)))
    for i, (maneuver, group) in enumerate(flights.items()):
        ax = fig.add_subplot(len(flights), 1, i + 1)
        for log in group:
            rec = log.t >= 0
            label = log.controller + ("" if log.stopped is None else " (stopped)")
            ax.plot(log.t[rec], np.degrees(swing_angle(log.states[rec])), lw=0.9, label=label,
                    **looks.get(log.controller, {}))  # fmt: skip
        ax.set_title(f"{maneuver} (seed {group[0].seed})", fontsize=9)
        ax.set_ylabel("swing (deg)")
        ax.grid(alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7, ncol=3)
    fig.axes[-1].set_xlabel("t (s)")
    fig.tight_layout()
    return save_figure(fig, path)


def plot_table(
    rows: list[dict[str, Any]], path: Path, looks: dict[str, dict[str, Any]] | None = None
) -> Path:
    """Bars of the table: vehicle RMSE, load RMSE and swing RMS per maneuver and controller
    (means over the completed flights; a failed controller shows no bar); a second K of a
    model hatched."""
    entries = summary(rows, ("maneuver", "controller"))
    maneuvers = list(dict.fromkeys(e["maneuver"] for e in entries))
    controllers = list(dict.fromkeys(e["controller"] for e in entries))
    looks = looks or controller_looks(controllers)
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
            look = looks.get(ctrl, {})
            hatch = None if look.get("linestyle", "-") == "-" else "//"
            ax.bar(np.arange(len(maneuvers)) + j * width, values, width, label=ctrl,
                   color=look.get("color"), hatch=hatch, edgecolor="white")  # fmt: skip
        ax.set_xticks(np.arange(len(maneuvers)) + 0.4 - width / 2, maneuvers, fontsize=7,
                      rotation=15)  # fmt: skip
        ax.set_title(title, fontsize=9)
        ax.grid(axis="y", alpha=0.3)
        if i == 0:
            ax.legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)
