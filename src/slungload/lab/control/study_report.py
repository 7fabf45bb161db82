"""The control study's report (``study.run_study``'s rows): ``study.md`` and its figures.

- the nominal plant: every controller's means (completed flights) and lost flights, and its
  load RMSE per maneuver (where a mean's error sits: a step the load cannot follow weighs
  the same under every model and cost);
- error against horizon (``horizons.png``): load RMSE and swing RMS of each MPC model per N;
- paired differences (``paired.png`` and tables): the learned MPC against the physics MPC at
  each N, against itself at the first N, against the geometric controller at each N and the
  PID at the first, against the oracle, and the oracle against physics; means over the flights
  both flew to the end with a 95 % t-interval and the mean as a share of the second's;
- the learned MPC against the physics MPC each at its own best horizon, chosen on the tuning
  seeds (a study tuned at two horizons or more);
- the share of the physics-to-oracle gap the learned model closes, per maneuver at each horizon
  the oracle flew, and the learned MPC against the oracle, paired; in the MPC's own cost, term
  by term, paired as well;
- the shifted plants: lost flights and errors per controller, and the learned MPC against the
  physics MPC at each N flown there, paired;
- the paths of the first seed of each maneuver (``paths_3d.png``, ``report.plot_paths``).

Results only; the acceptance rule lives in docs/BENCHMARKS.md.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Any, NamedTuple

from matplotlib.figure import Figure

from ...control import paired as pairing
from ...control.cost import cost_words
from ...fileio import read_json, write_text
from ...models.prediction import PHYSICS
from ...reporting import (
    markdown_table,
    model_colors,
    paired_interval,
    save_figure,
    smoke_banner,
)
from ...run_config import SMOKE_PRESET
from ...sim.config import SimConfig
from .config import LEARNED, NOMINAL, STUDY_KINDS, UNSAFE_SWING, StudyConfig
from .oracle_gap import oracle_gap_section
from .report import plot_paths
from .results import (
    KEYS,
    Row,
    both_completed,
    by_flight,
    fmt,
    fmt_interval,
    label_horizon,
    label_model,
    mean_of,
    mpc_label,
    ratio,
    step_share,
    summary,
)
from .study import best_horizons, load_log


def ordered_labels(labels) -> list[str]:
    """Controller labels in reading order: the PID, geometric, then each MPC model by N."""
    order = STUDY_KINDS

    def rank(label: str) -> tuple[int, str, int]:
        model = label_model(label)
        return (order.index(model) if model in order else len(order), model,
                label_horizon(label) or 0)  # fmt: skip

    return sorted(labels, key=rank)


def controller_means(rows: Sequence[Row], plant: str) -> dict[str, dict[str, Any]]:
    """``results.summary`` of each controller on ``plant``: means over its completed flights,
    flights, failed (lost), compute; by label."""
    on_plant = [r for r in rows if r["plant"] == plant]
    return {e["controller"]: e for e in summary(on_plant, ("controller",))}


def means_table(rows: list[Row], plant: str) -> str:
    """Per controller on ``plant``: means over its completed flights, lost / flown, compute."""
    entries = controller_means(rows, plant)
    table = [
        [
            label,
            *(fmt(e[k], spec) for k, _, spec in KEYS),
            f"{e['failed']} / {e['flights']}",
            fmt(e["compute_median"], "{:.1f}"),
        ]
        for label in ordered_labels(entries)
        for e in [entries[label]]
    ]
    return markdown_table(["controller", *(h for _, h, _ in KEYS), "lost", "compute (ms)"], table)


def maneuver_table(rows: list[Row], plant: str) -> str:
    """Per controller on ``plant``: the load RMSE (m) of each maneuver, the mean over its
    completed flights, with the flights lost after a slash where there are any."""
    entries = summary([r for r in rows if r["plant"] == plant], ("controller", "maneuver"))
    maneuvers = list(dict.fromkeys(e["maneuver"] for e in entries))
    cells = {(e["controller"], e["maneuver"]): e for e in entries}
    key, _, spec = KEYS[0]
    table = [
        [label, *(fmt(e[key], spec) + (f" / {e['failed']} lost" if e["failed"] else "")
                  if (e := cells.get((label, m))) else "-" for m in maneuvers)]
        for label in ordered_labels({e["controller"] for e in entries})
    ]  # fmt: skip
    return markdown_table(["controller", *maneuvers], table)


class Paired(NamedTuple):
    """a - b of one figure over the flights both flew to the end (``paired``)."""

    pairs: int  # flights with a finite difference
    mean: float
    low: float  # 95 % t-interval
    high: float
    base: float  # b's mean over those flights

    @property
    def share(self) -> float:
        """The mean difference as a fraction of b's mean (NaN where that is not defined)."""
        return ratio(self.mean, self.base)


def paired(rows, plant: str, a: str, b: str, key: str) -> Paired:
    """a - b of ``key`` over the flights on ``plant`` both flew to the end."""
    both = [(x, y) for x, y in completed_pairs(rows, plant, a, b)
            if math.isfinite(x[key] - y[key])]  # fmt: skip
    mean, low, high = paired_interval([x[key] - y[key] for x, y in both])
    return Paired(len(both), mean, low, high, mean_of([y for _, y in both], key))


def completed_pairs(rows, plant: str, a: str, b: str) -> list[tuple[Row, Row]]:
    """(a's row, b's row) of each flight on ``plant`` both flew to the end."""
    return both_completed(
        by_flight(rows, plant=plant, controller=a), by_flight(rows, plant=plant, controller=b)
    )


def paired_table(rows, plant: str, pairs: Sequence[tuple[str, str]]) -> str:
    """a - b per pair and figure (``paired``): mean [95 % interval] and, in brackets, the mean
    as a share of b's mean over the same flights; "pairs": the flights both flew to the end (a
    figure not finite on some of them is over fewer: its cell says how many)."""
    out = []
    for a, b in pairs:
        both = len(completed_pairs(rows, plant, a, b))
        cells = []
        for key, _, unsigned in KEYS:
            spec = unsigned.replace("{:", "{:+")  # a difference carries its sign
            d = paired(rows, plant, a, b, key)
            share = "" if math.isnan(d.share) else f" ({100 * d.share:+.0f} %)"
            fewer = f", {d.pairs} pairs" if d.pairs < both else ""
            cells.append(fmt_interval(d.mean, d.low, d.high, spec) + share + fewer)
        out.append([f"{a} - {b}", both, *cells])
    return markdown_table(["difference", "pairs", *(h for _, h, _ in KEYS)], out)


def plot_horizons(rows, path: Path) -> Path:
    """Load RMSE and swing RMS (means over completed nominal flights) against N per model."""
    mpc = [r for r in rows if r["plant"] == NOMINAL and label_horizon(r["controller"])]
    means = controller_means(rows, NOMINAL)
    models = list(dict.fromkeys(label_model(r["controller"]) for r in mpc))
    colors = model_colors(models)
    fig = Figure(figsize=(9.0, 3.4))
    for i, (key, head, _) in enumerate(KEYS[:2]):
        ax = fig.add_subplot(1, 2, i + 1)
        for model in models:
            labels = sorted({r["controller"] for r in mpc if label_model(r["controller"]) == model},
                            key=label_horizon)  # fmt: skip
            ns = [label_horizon(label) * SimConfig.control_dt for label in labels]
            ys = [means[label][key] for label in labels]
            ax.plot(ns, ys, "o-", color=colors[model], label=model)
        ax.set_xlabel("MPC horizon (s)")
        ax.set_ylabel(head)
        ax.grid(alpha=0.3)
    fig.axes[0].legend(fontsize=8)
    fig.tight_layout()
    return save_figure(fig, path)


def plot_paired(rows, pairs: Sequence[tuple[str, str]], path: Path) -> Path:
    """The paired differences of the load RMSE and swing RMS with their 95 % intervals."""
    fig = Figure(figsize=(9.0, 0.5 + 0.45 * len(pairs)))
    for i, (key, head, _) in enumerate(KEYS[:2]):
        ax = fig.add_subplot(1, 2, i + 1)
        for j, (a, b) in enumerate(pairs):
            d = paired(rows, NOMINAL, a, b, key)
            if math.isfinite(d.mean):
                err = [[d.mean - d.low], [d.high - d.mean]] if math.isfinite(d.low) else None
                ax.errorbar(d.mean, j, xerr=err, fmt="o", color="C0", capsize=3)
        ax.axvline(0.0, color="grey", lw=0.8)
        ax.set_yticks(range(len(pairs)))
        ax.set_yticklabels([f"{a} - {b}" for a, b in pairs] if i == 0 else [], fontsize=7)
        ax.set_xlabel(f"difference in {head}")
        ax.invert_yaxis()
    fig.tight_layout()
    return save_figure(fig, path)


def write_study_report(
    rows: list[dict[str, Any]], config: StudyConfig, out: Path, learned: str | None = None
) -> Path:
    """study.md and the figures into ``out`` (the MPC settings from its settings.json when a
    real MPC was flown; ``learned``: the learned model's run folder, named in the report);
    returns study.md's path."""
    out = Path(out)
    settings = read_json(out / "settings.json") if (out / "settings.json").exists() else {}
    labels = list(dict.fromkeys(r["controller"] for r in rows if r["plant"] == NOMINAL))
    horizons = sorted({label_horizon(lb) for lb in labels if label_horizon(lb)})
    first = horizons[0] if horizons else None
    pairs = _nominal_pairs(labels, horizons)
    network = settings.get("learned_network") or {}
    parts = [
        "# Closed-loop control study",
        "",
        *(
            smoke_banner(f"The learned network `{network['checkpoint']}`", SMOKE_PRESET)
            if network.get("preset") == SMOKE_PRESET
            else []
        ),  # fmt: skip
        _settings_line(config, settings, sorted({r["seed"] for r in rows})),
        "",
        _learned_line(settings, learned, config, rows),
        "",
        _settings_table(settings),
        "",
        "Means over the flights each controller flew to the end; `lost`: flights that left the "
        "arena or went non-finite, of the flights it flew (a controller flown on fewer seeds, "
        "such as the oracle on a subset, is averaged over its own). Differences: paired by "
        "maneuver and seed over the flights both flew to the end, mean [95 % t-interval] (the "
        "mean as a share of the second controller's mean over the same flights).",
        "",
        "## Nominal plant",
        "",
        means_table(rows, NOMINAL),
        "",
        "![error against horizon](horizons.png)",
        "",
        f"{KEYS[0][1]} per maneuver (completed flights; lost flights after a slash):",
        "",
        maneuver_table(rows, NOMINAL),
        "",
        "## Paired differences",
        "",
        paired_table(rows, NOMINAL, pairs) if pairs else "(no pair flown)",
        "",
        "![paired differences](paired.png)",
        "",
        *best_horizon_section(rows, settings),
    ]
    for n in horizons:
        parts += oracle_gap_section(rows, labels, n, settings, config, out)
    if "geometric" in labels:
        parts += [f"## Swings past {UNSAFE_SWING:g} deg", "", _past_limit(rows, labels), ""]
    parts += _shifted_sections(rows)
    write_text(out / "study.md", "\n".join(parts))
    plot_horizons(rows, out / "horizons.png")
    if pairs:
        plot_paired(rows, pairs, out / "paired.png")
    seed = min(r["seed"] for r in rows)
    shown = [
        r
        for r in rows
        if r["plant"] == NOMINAL
        and r["seed"] == seed
        and label_horizon(r["controller"]) in (None, first)
    ]
    plot_paths([load_log(out, r) for r in shown], out / "paths_3d.png")
    return out / "study.md"


def _nominal_pairs(labels: Sequence[str], horizons: Sequence[int]) -> list[tuple[str, str]]:
    """The pairs compared on the nominal plant (those flown of ``labels``): the learned MPC
    against the physics MPC at each N, each against itself at the first N, the geometric
    controller and the PID against the learned MPC, and the oracle against both."""
    first = horizons[0] if horizons else None
    return _flown(
        labels,
        [(mpc_label("learned", n), mpc_label("physics", n)) for n in horizons]
        + [(mpc_label(m, n), mpc_label(m, first)) for m in ("learned", "physics")
           for n in horizons[1:]]
        # the payload-aware controller against the learned MPC at every horizon, the PID at
        # the first
        + [(mpc_label("learned", n), c)
           for c, ns in (("geometric", horizons), ("pid", horizons[:1])) for n in ns]
        # what is left between the learned model and the perfect one (same MPC settings), and
        # what the perfect one gains over physics
        + [(mpc_label(m, n), mpc_label(b, n)) for n in horizons
           for m, b in (("learned", "oracle"), ("oracle", "physics"))],
    )  # fmt: skip


def best_horizon_section(rows, settings: dict[str, Any]) -> list[str]:
    """study.md's lines on the learned MPC against the physics MPC, each at its own best
    horizon (``best_horizons``: by the tuning score of its chosen settings on the tuning
    seeds, so the evaluation seeds choose nothing); none unless both were tuned at two
    horizons or more."""
    best = best_horizons(settings)
    if not {"learned", PHYSICS} <= set(best):
        return []
    pair = mpc_label("learned", best["learned"]), mpc_label(PHYSICS, best[PHYSICS])
    if not set(pair) <= {r["controller"] for r in rows if r["plant"] == NOMINAL}:
        return []

    def shown(kind: str) -> str:
        lost, unsafe, load = settings["tuning_score"][kind][str(best[kind])]
        return (f"{mpc_label(kind, best[kind])} ({lost} lost, {unsafe} past {UNSAFE_SWING:g} deg, "
                f"load RMSE {load:.3f} m on the tuning seeds)")  # fmt: skip

    return [
        "## Each model at its own best horizon",
        "",
        f"Chosen on the tuning seeds: {shown('learned')}; {shown(PHYSICS)}.",
        "",
        paired_table(rows, NOMINAL, [pair]),
        "",
    ]


def _shifted_sections(rows) -> list[str]:
    """study.md's lines on each shifted plant: the means per controller and the learned MPC
    against the physics MPC at each N flown there, paired."""
    parts = []
    for plant in dict.fromkeys(r["plant"] for r in rows):
        if plant != NOMINAL:
            parts += [f"## Shifted plant: {plant}", "", means_table(rows, plant), ""]
            flown = {r["controller"] for r in rows if r["plant"] == plant}
            ns = sorted({label_horizon(c) for c in flown} - {None})
            shifted = _flown(flown, [(mpc_label("learned", n), mpc_label("physics", n))
                                     for n in ns])  # fmt: skip
            if shifted:
                parts += [paired_table(rows, plant, shifted), ""]
    return parts


def _flown(labels, pairs: Sequence[tuple[str, str]]) -> list[tuple[str, str]]:
    """The pairs both of whose controllers are among ``labels``."""
    flown = set(labels)
    return [(a, b) for a, b in pairs if a in flown and b in flown]


def _learned_line(
    settings: dict[str, Any], learned: str | None, config: StudyConfig, rows: Sequence[dict] = ()
) -> str:
    """The learned network flown (the one the folder's settings were tuned for, else as
    given), how its plans were priced, and with a trust window how often physics priced them
    alone (over ``rows``' learned flights)."""
    network = settings.get("learned_network")
    if network:
        line = f"The learned network: `{network['checkpoint']}` (SHA-256 {network['sha256'][:12]})."
    elif learned:
        line = f"The learned model: `{learned}`."
    else:
        return "No learned model was flown."
    if config.with_physics:
        line += (f" Its plans priced under it and under the physics model (`--with-physics`): "
                 f"their mean cost + {config.risk:g} x their spread; tuned, timed and matched "
                 "as that pair.")  # fmt: skip
    if config.pair_window:
        share = step_share(
            [r for r in rows if label_model(r["controller"]) == LEARNED], "physics_only_steps"
        )
        line += (f" The network had no say while it predicted the last {config.pair_window} "
                 "steps flown (at most N) worse than physics (`--trust-window`)"
                 + (f": physics priced alone {100 * share:.0f} % of its steps." if share is not None
                    else "."))  # fmt: skip
        if pairing.WEIGH_BY_RECORD:
            line += (" Otherwise each model's cost was weighted by 1 / (its error over those "
                     f"steps + {pairing.TRUST_FLOOR * 100:g} cm)^2.")  # fmt: skip
    return line


def _past_limit(rows, labels: Sequence[str], limit: float = UNSAFE_SWING) -> str:
    """Per MPC: flights whose swing passed ``limit`` deg where the geometric controller's did
    not (the same maneuver and seed; a lost flight counts with the swing it reached)."""
    geo = by_flight(rows, plant=NOMINAL, controller="geometric")
    lines = []
    for label in ordered_labels(lb for lb in labels if lb.startswith("mpc-")):
        mine = by_flight(rows, plant=NOMINAL, controller=label)
        worse = [f"{m} s{seed}" for (m, seed), r in mine.items() if (m, seed) in geo
                 and r["swing_max"] > limit >= geo[(m, seed)]["swing_max"]]  # fmt: skip
        lines.append(f"- {label}: {len(worse)} of {len(mine)}" + (f" ({', '.join(worse)})"
                     if worse else ""))  # fmt: skip
    return "\n".join(lines)


def _settings_line(config: StudyConfig, settings: dict[str, Any], seeds: list[int]) -> str:
    """What was flown; ``seeds``: the evaluation seeds of the flights reported (a folder may hold
    more than one configuration's, ``SETTINGS_FIELDS``)."""
    cfg = asdict(config)
    learned = "learned" in settings.get("mpc", {})
    oracle = f"; the oracle flies the learned one's at K={cfg['oracle_samples']}" if learned else ""
    chosen = (f"MPC settings chosen per horizon on seeds "
              f"{', '.join(map(str, cfg['tuning_seeds']))} (below{oracle})" if cfg["tune"]
              else f"MPC settings: the defaults, not tuned (below{oracle})")  # fmt: skip
    return (
        f"Maneuvers {', '.join(cfg['maneuvers'])}; evaluation seeds "
        f"{', '.join(map(str, seeds))}; {chosen}; "
        f"{cfg['steps'] or 'all'} recorded steps per flight; "
        f"{cost_words(cfg['cost'], cfg['lean'], cfg['shape'])}; "
        f"backend {cfg['backend']}; every unmodelled effect on."
    )


def _settings_table(settings: dict[str, Any]) -> str:
    """Each real MPC's settings and K per horizon (``settings.json``)."""
    mpc, samples = settings.get("mpc", {}), settings.get("samples", {})
    rows = [
        [kind, n, str(samples.get(kind, {}).get(n, "")),
         ", ".join(f"{k} {v}" for k, v in chosen.items()) or "defaults"]
        for kind, per_horizon in mpc.items()
        for n, chosen in per_horizon.items()
    ]  # fmt: skip
    return markdown_table(["model", "N", "K", "settings"], rows) if rows else "(defaults)"
