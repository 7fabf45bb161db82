"""The control study's gap to the oracle (the MPC over the simulator's own plant): the share of
the physics-to-oracle gap the learned model closes, per maneuver, with its bootstrap interval,
and the learned MPC against the oracle in the MPC's own cost, term by term (``study.md``'s
sections "The gap to the oracle", ``study_report``)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...control.closed_loop import COST_TERMS, realized_cost
from ...control.mpc import MPCConfig, knots_for
from ...reporting import gap_interval, gap_share, markdown_table, paired_interval
from ...sim.config import tuples_from_json, vehicle_params
from ...sim.flight import flight_reference
from ...sim.plants import plant_config
from .config import NOMINAL, StudyConfig
from .results import KEYS, by_flight, fmt_interval, mpc_label
from .study import load_log

GAP_COLUMNS = ("maneuver", "seeds", "physics", "learned", "oracle", "gap closed [95 %]",
               "learned - oracle")  # fmt: skip


def oracle_gap_section(
    rows, labels: Sequence[str], n: int, settings: dict[str, Any], config: StudyConfig, out: Path
) -> list[str]:
    """study.md's lines on the gap to the oracle at N = ``n`` (none unless the physics and
    learned MPCs and the oracle all flew at that N): the gap closed per maneuver and figure,
    and the MPC's own cost where the learned MPC's settings are known."""
    trio = [mpc_label(m, n) for m in ("physics", "learned", "oracle")]
    if not all(label in labels for label in trio):
        return []
    parts = [
        f"## The gap to the oracle, N = {n}",
        "",
        f"(physics - learned) / (physics - oracle) at N = {n}, per maneuver (the oracle "
        "flies the learned MPC's settings at its own K; - where it is no better than "
        "physics), with its 95 % bootstrap interval over the seeds (the seeds resampled "
        "together; inf where some resamples leave no gap).",
        "",
    ]
    for key, head, _ in KEYS[:2]:
        parts += [
            f"{head}:",
            "",
            markdown_table(list(GAP_COLUMNS), gap_closed(rows, *trio, key)),
            "",
        ]
    chosen = settings.get("mpc", {}).get("learned", {}).get(str(n))
    if chosen is not None:
        mpc = config.mpc(**tuples_from_json(chosen), horizon=n, knots=knots_for(n))
        parts += [
            f"The MPC's own cost over each flight at N = {n} (the learned MPC's settings, "
            "which the oracle flies; terms by weight group, no terminal weight):",
            "",
            cost_table(out, rows, n, mpc, config),
            "",
        ]
    return parts


def gap_closed(rows, physics: str, learned: str, oracle: str, key: str) -> list[list[str]]:
    """Per maneuver: means over the seeds all three flew to the end, (physics - learned) /
    (physics - oracle) ("-" where the oracle is no better than physics: no gap to close) with
    its 95 % bootstrap interval over those seeds (``reporting.gap_interval``; "inf" where some
    resamples leave no gap), and learned - oracle paired over those seeds with its 95 %
    t-interval: both say whether a ratio is more than the seeds' spread."""
    sets = [by_flight(rows, plant=NOMINAL, controller=c) for c in (physics, learned, oracle)]
    out = []
    for maneuver in dict.fromkeys(m for m, _ in sets[0]):
        keys = [
            k
            for k in sets[0]
            if k[0] == maneuver
            and all(k in s and s[k]["completed"] and math.isfinite(s[k][key]) for s in sets)
        ]
        if not keys:
            out.append([maneuver, "0", "-", "-", "-", "-", "-"])
            continue
        figures = [[s[k][key] for k in keys] for s in sets]
        p, learn, o = (float(np.mean(f)) for f in figures)
        gap = float(gap_share(*np.asarray(figures)))
        mean, lo, hi = paired_interval([a - b for a, b in zip(*figures[1:], strict=True)])
        spec = "{:+.3f}"
        out.append(
            [
                maneuver,
                str(len(keys)),
                f"{p:.3f}",
                f"{learn:.3f}",
                f"{o:.3f}",
                share_cell(gap, *gap_interval(*figures)),
                fmt_interval(mean, lo, hi, spec),
            ]
        )
    return out


def share_cell(share: float, low: float, high: float) -> str:
    """ "78 % [64 %, 95 %]": a share of the gap and its interval ("-" alone where there is no
    gap; a bound beyond any finite share written "inf")."""
    if not math.isfinite(share):
        return "-"

    def cell(v: float) -> str:
        return f"{100 * v:.0f} %" if math.isfinite(v) else ("inf" if v > 0 else "-inf")

    bounds = "" if math.isnan(low) else f" [{cell(low)}, {cell(high)}]"
    return cell(share) + bounds


def cost_table(out: Path, rows, n: int, mpc: MPCConfig, config: StudyConfig) -> str:
    """The MPC's own cost at N = ``n`` (``closed_loop.realized_cost`` under ``mpc``, the
    settings the learned MPC and the oracle fly) summed over each flight of the physics, learned
    and oracle MPCs that all three flew to the end: means per term, the learned MPC against the
    oracle paired, and the share of the physics-to-oracle gap in this cost the learned one
    closes. The oracle minimises this cost with a perfect model: it is the ceiling of the cost,
    not of any one error."""
    labels = [mpc_label(m, n) for m in ("physics", "learned", "oracle")]
    sets = [by_flight(rows, plant=NOMINAL, controller=label) for label in labels]
    keys = [k for k in sets[0] if all(k in s and s[k]["completed"] for s in sets)]
    if not keys:
        return "(no flight all three finished)"
    nominal = plant_config(config.plant)
    params = vehicle_params(nominal)
    refs = {k: flight_reference(k[0], seed=k[1], config=nominal, steps=config.steps)
            for k in keys}  # fmt: skip
    costs = [{k: realized_cost(load_log(out, s[k]), refs[k], mpc, params) for k in keys}
             for s in sets]  # fmt: skip
    heads = ["total", *COST_TERMS]
    table = [[label, str(len(keys)), *(f"{np.mean([c[k][h] for k in keys]):.1f}" for h in heads)]
             for label, c in zip(labels, costs, strict=True)]  # fmt: skip
    spec = "{:+.1f}"
    difference = ["learned - oracle", str(len(keys))]
    for h in heads:
        mean, lo, hi = paired_interval([costs[1][k][h] - costs[2][k][h] for k in keys])
        difference.append(fmt_interval(mean, lo, hi, spec))
    totals = np.asarray([[c[k]["total"] for k in keys] for c in costs])
    gap = float(gap_share(*totals))
    return "\n".join([
        markdown_table(["controller", "flights", *heads], [*table, difference]),
        "",
        "learned - oracle: paired per flight, mean [95 % interval]; "
        + (f"the learned MPC closes {share_cell(gap, *gap_interval(*totals))} (95 % bootstrap "
           "interval) of the physics-to-oracle gap in this cost."
           if math.isfinite(gap) else "the oracle is no better than physics in this cost: no "
           "gap to close."),
    ])  # fmt: skip
