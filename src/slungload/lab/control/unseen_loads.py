"""``slungload study control-loads``: the MPC flying loads its model never saw.

One command flies, on every load of ``UnseenLoadsConfig.loads`` (each a plant of its own, every
unmodelled effect on) x maneuver x evaluation seed:

- ``mpc-adaptive (in-flight)``: an adaptive physics-step network (``train --constants window``)
  as trained: its f and the MPC's cost (load reference, hover thrust) run with the cable length
  and load mass estimated from the controller's history at every step (``MPCConfig.constants =
  "window"``), the network's own constants as the prior. Nothing is told of the load.
- ``mpc-adaptive (true constants)``: the same network and MPC given the flight's true load
  (``load_model(..., constants=truth)``; the cost likewise): the reference it is held to.
- ``mpc-physics (in-flight)`` and ``mpc-physics (true constants)``: the physics model, the same
  two ways.
- In place of the adaptive network, a physics-step network whose f keeps the constants it was
  trained with (``mpc-fixed``, e.g. one trained on one load): "in flight" its f runs those,
  the MPC's cost the estimate, so that it differs from the adaptive MPC only in its model;
  "true constants" as above. Flown into the same folder as an adaptive network, the report
  pairs the two.
- In place of one network, an ensemble of them (``models.ensemble``; every member adaptive or
  every member fixed): ``mpc-adaptive ensemble`` (or ``mpc-fixed ensemble``), with
  ``UnseenLoadsConfig.risk`` its pricing (``MPCConfig.risk``; "... risk 0.5" in the label),
  flown into the folder of one of its members to be paired with it.
- ``pid``: the simulator's PID built for the network's nominal vehicle.

Every MPC flies the same settings (``UnseenLoadsConfig``: K, N, temperature, swing bound,
floor). Flights land as in the control study (``closed_loop.log_path``; the plant named by its
load), so a second run flies only what is missing. ``write_loads_report`` writes
``control-loads.md`` and ``control-loads.png``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

from ...config import VehicleParams
from ...control.controllers import PID, reference_maker
from ...control.mpc import InputLimits, MPCConfig, mpc_maker
from ...deploy.backends import load_model
from ...deploy.compiled.batched import with_backend
from ...deploy.predictor import torch_threads
from ...fileio import read_json, write_json, write_text
from ...models.ensemble import model_meta
from ...models.prediction import PHYSICS, PhysicsModel, load_prediction_model
from ...reporting import markdown_table, networks_banner, save_figure
from ...run_config import SMOKE_PRESET
from ...sim.config import SimConfig
from ...sim.dataset import vehicle_params
from .config import UnseenLoadsConfig
from .results import KEYS, fmt, mean_of, ratio
from .study import Flown, collect_rows, fly_once
from .study_report import (
    completed_pairs,
    controller_means,
    means_table,
    ordered_labels,
    paired_table,
)

ADAPTIVE, FIXED = "mpc-adaptive", "mpc-fixed"  # the networks' MPCs: f on the estimate, f fixed
NETWORKS = (ADAPTIVE, FIXED)
IN_FLIGHT, TRUE = "in-flight", "true constants"


def plant_name(load_mass: float, cable_length: float) -> str:
    """A load's plant in the tables and folders: "0.22 kg, 0.85 m"."""
    return f"{load_mass:.2f} kg, {cable_length:.2f} m"


def label(model: str, constants: str) -> str:
    """A controller's label: "mpc-adaptive (in-flight)"."""
    return f"{model} ({constants})"


def network_name(kind: str, ensemble: bool, risk: float | None) -> str:
    """The MPC of a network (``kind``: ``ADAPTIVE`` or ``FIXED``) or of an ensemble of them
    priced with ``risk``: "mpc-adaptive", "mpc-adaptive ensemble", "mpc-adaptive ensemble
    risk 0.5" (no commas: a CSV cell)."""
    if not ensemble:
        return kind
    return f"{kind} ensemble" + ("" if risk is None else f" risk {risk:g}")


def _networks(model: Any) -> list[Any]:
    """The physics-step networks of a loaded model: its own, or each ensemble member's."""
    return [m.net for m in getattr(model, "members", (model,))]


def fly_loads(
    network: str | Path,
    out: str | Path,
    config: UnseenLoadsConfig | None = None,
    *,
    threads: int = 1,
    progress: Callable[[str], None] | None = print,
) -> list[dict[str, Any]]:
    """Fly what is missing into ``out`` and return every row flown so far (see the module).

    network: a run folder of a physics-step network: adaptive (``--constants window``,
    flown as ``mpc-adaptive``) or with f on its training constants (``mpc-fixed``); or an
    ensemble folder of such networks, all of one kind (priced with ``config.risk``).
    threads: torch threads while flying (restored after).
    """
    cfg = config or UnseenLoadsConfig()
    network = Path(network)
    eager = load_prediction_model(network)
    nets = _networks(eager)
    if any(getattr(n, "architecture", None) != "physics-step" for n in nets):
        raise ValueError(
            f"{network}: not a physics-step network (or an ensemble of them); the loads flights "
            "give its f the true constants, which only a physics-step network runs"
        )
    kinds = {ADAPTIVE if n.config.adapts_constants else FIXED for n in nets}
    if len(kinds) > 1:
        raise ValueError(f"{network}: an ensemble of adaptive and fixed networks; fly each kind "
                         "as an ensemble of its own")  # fmt: skip
    ensemble = hasattr(eager, "members")
    if cfg.risk is not None and not ensemble:
        raise ValueError(f"{network}: --risk prices an ensemble's members, and this is one "
                         "network; give an ensemble folder (slungload ensemble)")  # fmt: skip
    name = network_name(kinds.pop(), ensemble, cfg.risk)
    trained = with_backend(eager, cfg.backend)
    nominal: VehicleParams = nets[0].params  # the prior of the in-flight estimate
    nominal_sim = SimConfig().with_load(
        load_mass=nominal.mass_load, cable_length=nominal.cable_length
    )
    mpc = MPCConfig(samples=cfg.samples, horizon=cfg.horizon, temperature=cfg.temperature,
                    max_swing=cfg.max_swing, min_height=cfg.min_height)  # fmt: skip
    priced = replace(mpc, risk=cfg.risk)  # the network's MPCs (a single one refuses a risk)
    physics = with_backend(PhysicsModel(nominal, constants="window"), cfg.backend)
    out = Path(out)
    for other in out.glob("loads-*.json"):  # the PID and physics rows are shared by the networks
        if read_json(other)["nominal"] != asdict(nominal):
            raise ValueError(
                f"{other} holds flights built for another nominal vehicle than {network}'s "
                "(its PID and physics flights would be reused for this one); use another --out"
            )
    preset = model_meta(network).get("preset")  # for the report's smoke banner
    mine = out / f"loads-{name.replace(' ', '-')}.json"
    # the first network flown into the folder flies the shared rows (PID, physics) with its K
    earlier = read_json(mine) if mine.is_file() else {"first": not any(out.glob("loads-*.json"))}
    first = earlier.get("first", False)
    write_json(mine, {"network": str(network), "model": name, "config": asdict(cfg),
                      "nominal": asdict(nominal), "preset": preset, "first": first})  # fmt: skip
    with torch_threads(threads):
        for load_mass, cable_length in cfg.loads:
            plant = SimConfig().with_load(load_mass=load_mass, cable_length=cable_length)
            truth = vehicle_params(plant)
            limits = InputLimits.from_sim(plant)  # scored against; and the MPCs given the truth
            told_nothing = InputLimits.from_sim(nominal_sim)  # thrust floor from the nominal mass
            plant_label = plant_name(load_mass, cable_length)
            flown = [Flown(plant_label, PID, reference_maker(PID, nominal_sim))]
            for model, in_flight, given, config in (
                (f"mpc-{PHYSICS}", physics, load_model(PHYSICS, truth, backend=cfg.backend), mpc),
                (name, trained, load_model(network, backend=cfg.backend, constants=truth), priced),
            ):  # fmt: skip
                flown += [
                    Flown(plant_label, label(model, IN_FLIGHT),
                          mpc_maker(in_flight, told_nothing, replace(config, constants="window"),
                                    nominal)),
                    Flown(plant_label, label(model, TRUE),
                          mpc_maker(given, limits, config, truth)),
                ]  # fmt: skip
            for f in flown:
                for maneuver in cfg.maneuvers:
                    for seed in cfg.seeds:
                        fly_once(out, f, maneuver, seed, plant, limits, cfg.steps, progress)
    return [r for r in collect_rows(out) if r["plant"] in {plant_name(*x) for x in cfg.loads}]


# --- the report -------------------------------------------------------------------------


def ratio_to_truth(rows: list[dict[str, Any]], plant: str, model: str, key: str) -> float:
    """Mean ``key`` of ``model`` in flight over its mean given the true constants, over the
    flights both flew to the end (1.0: as good as knowing the load)."""
    both = completed_pairs(rows, plant, label(model, IN_FLIGHT), label(model, TRUE))
    if not both:
        return math.nan
    return ratio(mean_of([a for a, _ in both], key), mean_of([b for _, b in both], key))


def write_loads_report(rows: list[dict[str, Any]], config: UnseenLoadsConfig, out: Path) -> Path:
    """``control-loads.md`` and ``control-loads.png`` into ``out`` from ``fly_loads``' rows;
    returns the path of control-loads.md."""
    out = Path(out)
    plants = [plant_name(*load) for load in config.loads]
    flown = {r["controller"] for r in rows}
    # each network flown into the folder, by its MPC's name (files before "model": the stem)
    kept = {path: read_json(path) for path in sorted(out.glob("loads-*.json"))}
    flown_with = {f.get("model", path.stem.removeprefix("loads-")): f for path, f in kept.items()}
    # single networks first (NETWORKS is in order), then the ensembles
    networks = sorted((m for m in flown_with if label(m, IN_FLIGHT) in flown),
                      key=lambda m: (m not in NETWORKS, m))  # fmt: skip
    models = [*networks, f"mpc-{PHYSICS}"]
    header = ["load"]
    for model in models:
        header += [f"{model.removeprefix('mpc-')}: load RMSE", "swing RMS", "lost"]
    summary = []
    for plant in plants:
        cells = [plant]
        means = controller_means(rows, plant)
        for model in models:
            cells += [fmt(ratio_to_truth(rows, plant, model, key), "{:.2f}")
                      for key in ("load_rmse", "swing_rms")]  # fmt: skip
            lost = [means[c]["failed"] if c in means else 0
                    for c in (label(model, IN_FLIGHT), label(model, TRUE))]  # fmt: skip
            cells.append(f"{lost[0]} / {lost[1]}")
        summary.append(cells)
    pairs = [(label(m, IN_FLIGHT), label(m, TRUE)) for m in models]
    pairs += [(label(m, IN_FLIGHT), label(f"mpc-{PHYSICS}", TRUE)) for m in networks]
    if {ADAPTIVE, FIXED} <= set(networks):  # what adapting f buys, both MPCs in flight
        pairs.append((label(ADAPTIVE, IN_FLIGHT), label(FIXED, IN_FLIGHT)))
    pairs += [(label(m, IN_FLIGHT), label(kind, IN_FLIGHT)) for m in networks for kind in NETWORKS
              if m.startswith(f"{kind} ensemble") and kind in networks]  # fmt: skip
    smoke = [f["network"] for f in flown_with.values() if f.get("preset") == SMOKE_PRESET]
    ks = {m: f["config"]["samples"] for m, f in flown_with.items()}
    shared = [f["config"]["samples"] for f in flown_with.values() if f.get("first")]
    if len(set(ks.values()) | {config.samples}) > 1:  # flown at several K: say which
        ks_line = ("K per MPC: " + "; ".join(f"{m}: K = {ks[m]}" for m in networks)
                   + (f"; physics: K = {shared[0]}" if shared else "") + ". ")  # fmt: skip
    else:
        ks_line = f"K = {config.samples}, "
    lines = [
        "# The MPC on loads its model never saw",
        "",
        *networks_banner(smoke, SMOKE_PRESET),
        f"{ks_line}N = {config.horizon} "
        f"({config.horizon * SimConfig.control_dt:.2f} s), temperature {config.temperature}, "
        f"swing bound {math.degrees(config.max_swing):.0f} deg, floor {config.min_height} m; "
        f"maneuvers {', '.join(config.maneuvers)} x seeds "
        f"{', '.join(map(str, config.seeds))}, "
        f"{config.steps or 'all'} recorded steps each, every unmodelled effect on, "
        f"{config.backend} backend.",
        "",
        "Each MPC in flight / the same MPC given the true constants: means over the flights both "
        "flew to the end (1.00: as good as knowing the load), and the flights each lost (in "
        "flight / given the truth):",
        "",
        markdown_table(header, summary),
        "",
        "![load RMSE per load](control-loads.png)",
    ]
    for plant in plants:
        lines += ["", f"## {plant}", "", means_table(rows, plant), "",
                  "Paired differences (mean [95 % interval], and the mean as a share of the "
                  "second's):", "",
                  paired_table(rows, plant, pairs)]  # fmt: skip
    plot_loads(rows, plants, out / "control-loads.png")
    write_text(out / "control-loads.md", "\n".join(lines) + "\n")
    return out / "control-loads.md"


def plot_loads(rows: list[dict[str, Any]], plants: Sequence[str], path: Path) -> Path:
    """Mean load RMSE and swing RMS (completed flights) per load, one bar per controller."""
    labels = ordered_labels({r["controller"] for r in rows if r["plant"] in plants})
    colors = dict(zip(labels, (f"C{i}" for i in range(len(labels))), strict=True))
    means = {p: controller_means(rows, p) for p in plants}
    fig = Figure(figsize=(9.0, 3.6))
    width = 0.8 / max(len(labels), 1)
    for i, (key, head, _) in enumerate(KEYS[:2]):
        ax = fig.add_subplot(1, 2, i + 1)
        for j, lb in enumerate(labels):
            ys = [means[p][lb][key] if lb in means[p] else np.nan for p in plants]
            ax.bar(np.arange(len(plants)) + (j - (len(labels) - 1) / 2) * width, ys, width,
                   color=colors[lb], label=lb)  # fmt: skip
        ax.set_xticks(range(len(plants)))
        ax.set_xticklabels(plants, fontsize=8)
        ax.set_ylabel(head)
        ax.grid(alpha=0.3, axis="y")
    fig.axes[0].legend(fontsize=7)
    fig.tight_layout()
    return save_figure(fig, path)
