"""Write an evaluation ``Report`` to a folder: report.md beside the paper's numbers, CSVs of
every number, report.json, and the figures. Every file is written atomically.

Layout of the output folder::

    report.md            tables (ours beside the paper's), ratios, timing, figures, configs
    report.json          the whole Report (curves included) and the paper's numbers
    rmse.csv             RMSE per run (seed) and horizon
    rmse_table.csv       RMSE mean and std across seeds per label and horizon
    mae_<label>_N<n>.csv MAE mean / q1 / median / q3 per horizon step and group
    timing.csv           batch-1 inference time per model and horizon (when timed)
    figures/*.png        MAE comparisons, one predicted window, 3D paths
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from pathlib import Path

from ..config import to_dict
from ..fileio import EVERY, write_json, write_text
from ..reporting import markdown_table, smoke_banner, write_csv
from ..run_config import SMOKE_PRESET
from ..state import GROUPS
from . import plots
from .metrics import COMBINED, METRIC_KEYS
from .results import (
    PAPER_MODEL_NAMES,
    PAPER_RMSE_N50,
    PAPER_TIMING,
    PHYSICS,
    PHYSICS_TRUTH,
    Report,
    RmseRow,
)
from .uncertainty import plot_calibration, spread_section

REFERENCE_LABEL = "proposed"  # the paper's model; ratios and pairwise figures are against it
PAPER_HORIZON = 50  # the horizon of the paper's RMSE table
BUSY_LOAD = 1.5  # 1-min load average above which timings are flagged (the timer itself is ~1)
COLUMN_TITLES = {
    "position": "Position (m)",
    "velocity": "Velocity (m/s)",
    "quaternion": "Quaternion (-)",
    "load_position": "Load position (m)",
    "combined": "Combined",
}


def write_report(report: Report, out: str | Path) -> Path:
    """Write report.md, report.json, the CSVs and the figures into ``out``; returns report.md."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    figures = write_figures(report, out / "figures")
    csvs = write_csvs(report, out)
    write_json(out / "report.json", _report_json(report))
    path = out / "report.md"
    write_text(path, render_markdown(report, figures=figures, csvs=csvs, out=out))
    return path


# --- figures -----------------------------------------------------------------------------


def reference_label(report: Report) -> str | None:
    """The label others are compared with: "proposed" if present, else the first network."""
    networks = [la for la in report.labels if la != PHYSICS]
    if REFERENCE_LABEL in networks:
        return REFERENCE_LABEL
    return networks[0] if networks else None


def write_figures(report: Report, folder: Path) -> list[tuple[str, Path]]:
    """All figures; returns (caption, path) pairs in display order: the MAE figures of every
    evaluated horizon (the paper's N = 50 first, as the tables), then the example window.

    Each label keeps one colour, dash pattern and marker in every figure. Pairwise MAE
    figures draw both Q1-Q3 bands (the reference's filled, the other's hatched); the figure of
    all models draws the reference's band only, so that no band hides a curve.
    """
    out: list[tuple[str, Path]] = []
    styles = plots.label_styles(report.labels)
    ref = reference_label(report)

    def mae_figure(labels: Sequence[str], n: int, name: str, caption: str) -> None:
        curves = {label: report.curves[label][n] for label in labels}
        bands = list(labels) if len(labels) == 2 else [ref or labels[0]]  # reference first
        path = plots.plot_mae(curves, folder / name, dt=report.dt,
                              training_horizon=report.training_horizon, bands=bands,
                              styles=styles)  # fmt: skip
        out.append((f"MAE per horizon step, {caption} (N = {n})", path))

    for n in sorted(report.horizons, key=lambda h: (h != PAPER_HORIZON, h)):
        for other in report.labels:
            if ref is not None and other != ref:
                mae_figure([ref, other], n, f"mae_{_slug(ref)}_vs_{_slug(other)}_N{n}.png",
                           f"{ref} vs {other}")  # fmt: skip
        if len(report.labels) > 2 or ref is None:
            mae_figure(report.labels, n, f"mae_all_N{n}.png", "all models")
    for label, by_n in report.spreads.items():
        n = max(by_n)
        name = f"calibration_{_slug(label)}_N{n}.png"
        path = plot_calibration(by_n[n], folder, name)
        out.append((f"The interval of {label}: coverage and RMSE / sigma per step (N = {n})", path))
    if report.example is not None:
        ex = report.example
        path = plots.plot_prediction(ex, folder / "prediction.png", dt=report.dt,
                                     training_horizon=report.training_horizon,
                                     styles=styles)  # fmt: skip
        out.append((f"Predicted vs true states, flight {ex.flight} from step {ex.start}", path))
        path = plots.plot_paths_3d(ex, folder / "paths_3d.png", styles=styles)
        out.append((f"Vehicle and load paths, flight {ex.flight}", path))
    return out


# --- CSVs ----------------------------------------------------------------------------------


def write_csvs(report: Report, out: Path) -> list[Path]:
    """rmse.csv, rmse_table.csv, mae_<label>_N<n>.csv, timing.csv (when timed); returns their
    paths."""
    paths = []
    rows = [
        [r.label, _blank(r.seed), r.metrics.horizon, r.metrics.windows]
        + [r.metrics.rmse[k] for k in METRIC_KEYS]
        for r in report.results
    ]
    paths.append(
        write_csv(out / "rmse.csv", ["label", "seed", "horizon", "windows", *METRIC_KEYS], rows)
    )

    header = ["label", "horizon", "seeds"]
    header += [f"{k}_{s}" for k in METRIC_KEYS for s in ("mean", "std")]
    rows = [
        [r.label, r.horizon, r.seeds] + [v for k in METRIC_KEYS for v in (r.mean[k], r.std[k])]
        for r in report.table
    ]
    paths.append(write_csv(out / "rmse_table.csv", header, rows))

    for label, by_horizon in report.curves.items():
        for n, curves in by_horizon.items():
            header = ["step", "time_s"]
            header += [f"{g}_{s}" for g in GROUPS for s in ("mean", "q1", "median", "q3")]
            rows = []
            for k in range(n):
                row: list[object] = [k + 1, (k + 1) * report.dt]
                for g in GROUPS:
                    c = curves[g]
                    row += [c.mean[k], c.q1[k], c.median[k], c.q3[k]]
                rows.append(row)
            paths.append(write_csv(out / f"mae_{_slug(label)}_N{n}.csv", header, rows))

    header = ["label", "seed", "backend", "history", "horizon", "mean_ms", "std_ms", "repeats",
              "threads", "device"]  # fmt: skip
    rows = [
        [
            t.label,
            _blank(t.seed),
            t.timing.backend,
            t.timing.history,
            t.timing.horizon,
            t.timing.mean_ms,
            t.timing.std_ms,
            t.timing.repeats,
            t.timing.threads,
            t.timing.device,
        ]  # fmt: skip
        for t in report.timings
    ]
    if rows:  # timed only with --timing
        paths.append(write_csv(out / "timing.csv", header, rows))
    else:  # an earlier run's into the same folder would no longer match report.md
        (out / "timing.csv").unlink(missing_ok=True)
    return paths


def _blank(value: object) -> object:
    return "" if value is None else value


def _report_json(report: Report) -> dict:
    data = report.to_dict()
    data["curves"] = {
        label: {str(n): {g: c.to_dict() for g, c in cs.items()} for n, cs in by_n.items()}
        for label, by_n in report.curves.items()
    }
    return data


# --- markdown ------------------------------------------------------------------------------


def render_markdown(
    report: Report, *, figures: Sequence[tuple[str, Path]], csvs: Sequence[Path], out: Path
) -> str:
    """The text of report.md (links relative to ``out``)."""
    p = report.params
    env = report.environment
    lines = [
        "# Evaluation report",
        "",
        *_smoke_banner(report),
        f"slungload {env.get('slungload', '?')}, torch {env.get('torch', '?')}; "
        f"inference on {env.get('device', '?')} with {env.get('threads', '?')} thread(s).",
        "",
        "## Dataset",
        "",
        f"- folder: `{report.dataset}`",
        f"- {_split_name(report)} flights ({len(report.test_flights)}): "
        f"{', '.join(report.test_flights)}",
        f"- windows: M = {report.history} history steps, stride 1; "
        + ", ".join(
            f"N = {r.metrics.horizon}: {r.metrics.windows}" for r in _first_per_horizon(report)
        ),
        "- the physics row's vehicle constants"
        + (f" ({env['params_source']})" if env.get("params_source") else "")
        + f": mQ = {p.mass_quad} kg, mL = {p.mass_load} kg, l = {p.cable_length} m, "
        f"d = {p.load_damping}, h = {p.dt} s, g = {p.gravity} m/s^2"
        + (
            f"; the row {PHYSICS_TRUTH!r} rolls each flight with its own recorded load mass "
            "and cable length"
            if PHYSICS_TRUTH in report.labels
            else ""
        ),
        f"- training horizon N = {report.training_horizon} steps "
        f"({report.training_horizon * p.dt:.2f} s)"
        + (
            f": the networks' errors past step {report.training_horizon} (at N = "
            f"{', '.join(str(n) for n in beyond)}) are extrapolation"
            if (beyond := sorted(n for n in report.horizons if n > report.training_horizon))
            else ""
        ),
        "",
        "The paper's numbers come from the authors' real flights; ours from the dataset above. "
        "Compare the ratios and trends; absolute values depend on the data.",
        "",
        "Metrics (the paper's): per group, the error norm of each test window at horizon step "
        "k (quaternion: |q_hat (x) q^-1 - q_id| with q_hat normalised); MAE_k is its mean over "
        "the windows, with the 25th / 75th percentiles (Q1 / Q3); RMSE = sqrt(sum |e|^2 / "
        "(windows N)) over all windows and steps; Combined = the sum of the four group RMSEs. "
        "Several seeds of one model: the table gives mean ± std across seeds, the MAE curves pool "
        "the windows of all seeds.",
        "",
    ]
    lines += _budget_warnings(report)
    lines += _models_section(report)
    for n in sorted(report.horizons, key=lambda h: (h != PAPER_HORIZON, h)):
        lines += _rmse_section(report, n)
    lines += _paper_rmse_section()
    lines += _ratio_section(report)
    lines += spread_section(report.spreads)
    lines += _timing_section(report)
    lines += ["## Figures", ""]
    for caption, path in figures:
        rel = path.relative_to(out).as_posix()
        lines += [f"### {caption}", "", f"![{caption}]({rel})", ""]
    lines += ["## Files", ""]
    lines += [f"- [{c.relative_to(out).as_posix()}]({c.relative_to(out).as_posix()})" for c in csvs]
    lines += ["- [report.json](report.json)", ""]
    lines += _config_section(report)
    return "\n".join(lines).rstrip() + "\n"


def _first_per_horizon(report: Report):
    seen = {}
    for r in report.results:
        seen.setdefault(r.metrics.horizon, r)
    return [seen[n] for n in sorted(seen)]


def _models_section(report: Report) -> list[str]:
    rows = [
        [m.get("label"), _dash(m.get("seed")), f"`{m.get('run', '')}`", _epochs(m),
         _dash(m.get("parameters"))]
        for m in report.models
    ]  # fmt: skip
    if PHYSICS in report.labels:
        rows.append([PHYSICS, "-", "open-loop `physics.rollout` from x_(M-1) with the estimated "
                     "(vL, Omega_L) and the true inputs", "-", "-"])  # fmt: skip
    table = markdown_table(["label", "seed", "run", "epochs", "parameters"], rows)
    return ["## Models", "", table, *_constants_lines(report), ""]


def _constants_lines(report: Report) -> list[str]:
    """The physical constants each run fitted before training (value, from its initial)."""
    runs = []
    for m in report.models:
        if m.get("constants"):
            values = ", ".join(
                f"{name} {v['value']:.4g} (from {v['initial']:.4g})"
                for name, v in m["constants"].items()
            )
            runs.append(f"- {m.get('label')} (seed {_dash(m.get('seed'))}): {values}")
    if not runs:
        return []
    return ["", "Physical constants fitted to the training flights before training:", "", *runs]


def smoke_runs(report: Report) -> list[dict]:
    """The runs trained with the ``quick`` preset (a smoke test of the pipeline)."""
    return [m for m in report.models if (m.get("configs") or {}).get("preset") == SMOKE_PRESET]


def _smoke_banner(report: Report) -> list[str]:
    """A banner at the top of report.md when any run is a smoke run: its numbers mean nothing."""
    runs = smoke_runs(report)
    if not runs:
        return []
    if len(runs) == len(report.models):
        which = "Every run"
    else:
        which = "The runs " + ", ".join(f"`{m.get('run', m.get('label'))}`" for m in runs)
    return smoke_banner(which, SMOKE_PRESET)


def time_capped(report: Report) -> list[dict]:
    """The runs that the wall-clock cap stopped before their epoch budget."""
    return [m for m in report.models if m.get("stop_reason") == "max_time"]


def _epochs(model: dict) -> str:
    """Epochs trained, and of how many when the time cap cut the budget short."""
    epochs = _dash(model.get("epochs"))
    if model.get("stop_reason") != "max_time":
        return epochs
    budget = model.get("configs", {}).get("train", {}).get("max_epochs", "?")
    return f"**{epochs} of {budget}: stopped by the time cap**"


def _budget_warnings(report: Report) -> list[str]:
    """A loud note when a run did not get its optimisation budget: its row is not comparable."""
    capped = time_capped(report)
    if not capped:
        return []
    lines = ["> **Warning: not every run got its full training budget.**", ">"]
    for m in capped:
        budget = m.get("configs", {}).get("train", {}).get("max_epochs", "?")
        lines.append(
            f"> - {m.get('label')} (seed {_dash(m.get('seed'))}) was stopped by the time cap at "
            f"epoch {_dash(m.get('epochs'))} of {budget}."
        )
    lines += [
        ">",
        "> Its numbers are not comparable with runs that trained to the end. Run the same "
        "`slungload reproduce` command again: it resumes such runs to their full budget.",
        "",
    ]
    return lines


def _split_name(report: Report) -> str:
    """'test', or 'validation' for a report made to choose a configuration."""
    return "validation" if report.split == "val" else report.split


def _rmse_section(report: Report, n: int) -> list[str]:
    rows = [r for r in report.table if r.horizon == n]
    seeds = any(r.seeds > 1 for r in rows)
    note = " (mean ± std across seeds)" if seeds else ""
    cells = [
        [
            f"{r.label} ({r.seeds} seeds)" if r.seeds > 1 else r.label,
            *(_pm(r, k) for k in METRIC_KEYS),
        ]
        for r in rows
    ]
    table = markdown_table(_table_header("Model (ours)"), cells)
    judged = "every flight" if report.split == EVERY else f"the {_split_name(report)} set"
    return [f"## RMSE over {judged}, N = {n}{note}", "", table, ""]


def _paper_rmse_section() -> list[str]:
    rows = [
        [f"{PAPER_MODEL_NAMES[key]} (`{key}`)", *(f"{values[k]:.3f}" for k in METRIC_KEYS)]
        for key, values in PAPER_RMSE_N50.items()
    ]
    table = markdown_table(_table_header("Model (paper)"), rows)
    return [f"## The paper's RMSE (Table I, real flights, N = {PAPER_HORIZON})", "", table, ""]


def _table_header(first: str) -> list[str]:
    return [first, *(COLUMN_TITLES[k] for k in METRIC_KEYS)]


def combined_ratios(report: Report) -> list[tuple[str, str, dict[int, float], float | None]]:
    """(numerator, denominator, {N: ours}, paper at N = 50) for the reference model against
    every other label, on the combined RMSE (mean across seeds)."""
    ref = reference_label(report)
    out = []
    if ref is None:
        return out
    for other in report.labels:
        if other == ref:
            continue
        ours = {}
        for n in report.horizons:
            a, b = report.row(ref, n), report.row(other, n)
            if a is not None and b is not None and b.mean[COMBINED] > 0:
                ours[n] = a.mean[COMBINED] / b.mean[COMBINED]
        paper = None
        if ref in PAPER_RMSE_N50 and other in PAPER_RMSE_N50:
            paper = PAPER_RMSE_N50[ref][COMBINED] / PAPER_RMSE_N50[other][COMBINED]
        out.append((ref, other, ours, paper))
    return out


def _ratio_section(report: Report) -> list[str]:
    ratios = combined_ratios(report)
    if not ratios:
        return []
    horizons = sorted(report.horizons)
    header = ["ratio", *(f"ours, N = {n}" for n in horizons), "paper, N = 50"]
    rows = [
        [f"{ref} / {other}", *(_ratio(ours[n]) if n in ours else "-" for n in horizons),
         _dash(paper, "{:.3f}")]
        for ref, other, ours, paper in ratios
    ]  # fmt: skip
    title = "## Combined-RMSE ratios (below 1: the first model is better)"
    return [title, "", markdown_table(header, rows), ""]


def _timing_section(report: Report) -> list[str]:
    lines = ["## Inference time, batch 1", ""]
    if report.timings:
        header = ["model", "seed", "backend", "M", "N", "mean (ms)", "std (ms)", "calls",
                  "threads", "device"]  # fmt: skip
        rows = [
            [t.label, _dash(t.seed), t.timing.backend, t.timing.history, t.timing.horizon,
             f"{t.timing.mean_ms:.2f}", f"{t.timing.std_ms:.2f}", t.timing.repeats,
             t.timing.threads, t.timing.device]
            for t in report.timings
        ]  # fmt: skip
        lines += [
            markdown_table(header, rows),
            "",
            "`torch eager`: the network as trained, called on tensors (as the paper timed its own "
            "code). `numba compiled`: `CompiledPredictor.predict`, the batch-1 deployment path, "
            "numpy in and out on one CPU thread (`docs/deployment.md`).",
        ]
        busy = [t.timing.load_average for t in report.timings if _busy(t.timing.load_average)]
        if busy:
            lines += [
                "",
                f"> **Warning: the machine was busy** (1-min load average up to {max(busy):.1f} "
                "while timing, of which about 1 is the timing itself): other processes shared "
                "the cores, so these times are inflated. Time on an idle machine "
                "(`slungload benchmark`).",
            ]
    else:
        lines.append(
            "Not measured: timing is a separate step (`slungload evaluate --timing`, or the "
            "full latency benchmark `slungload benchmark`)."
        )
    paper = [
        [t.device, t.history, t.horizon, f"{t.mean_ms:.2f}", f"{t.std_ms:.2f}"]
        for t in PAPER_TIMING
    ]
    table = markdown_table(["device", "M", "N", "mean (ms)", "std (ms)"], paper)
    return [*lines, "", "The paper's (Table II):", "", table, ""]


def _busy(load_average: float | None) -> bool:
    """Whether another process held a notable share of the cores (beyond the timer's own)."""
    return load_average is not None and load_average > BUSY_LOAD


def _config_section(report: Report) -> list[str]:
    lines = ["## Configurations", "", "Vehicle constants:", "", "```json"]
    lines += [json.dumps(to_dict(report.params), indent=2, sort_keys=True), "```", ""]
    for m in report.models:
        configs = m.get("configs")
        if not configs:
            continue
        lines += [f"Run `{m.get('run', '')}` ({m.get('label')}, seed {_dash(m.get('seed'))}):", ""]
        lines += ["```json", json.dumps(configs, indent=2, sort_keys=True, default=str), "```", ""]
    return lines


def _ratio(value: float) -> str:
    return f"{value:.3f}" if value < 1e3 else f"{value:.3g}"


def _pm(row: RmseRow, key: str) -> str:
    if row.seeds > 1:
        return f"{row.mean[key]:.3f} ± {row.std[key]:.3f}"
    return f"{row.mean[key]:.3f}"


def _dash(value: object, fmt: str = "{}") -> str:
    return "-" if value is None else fmt.format(value)


def _slug(label: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", label)
