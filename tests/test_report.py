"""Report files (markdown, CSVs, JSON, figures) from a small Report built with stand-ins, and
one end-to-end ``evaluate`` of a briefly trained run."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor, nn

from slungload.config import LossWeights, VehicleParams, WindowConfig
from slungload.data.windows import make_windows
from slungload.deploy.timing import evaluate_runs, time_models
from slungload.evaluation.evaluator import Candidate, evaluate, evaluate_predictors
from slungload.evaluation.metrics import METRIC_KEYS
from slungload.evaluation.report import write_report
from slungload.evaluation.results import PAPER_RMSE_N50, PHYSICS, Report
from slungload.models.base import Prediction
from slungload.models.prediction import NetworkModel, PhysicsModel
from slungload.state import GROUPS, VEL

torch.set_num_threads(1)
PARAMS = VehicleParams()
M, N = 6, 8


class OffsetNet(nn.Module):
    """Stand-in network: holds the last measured state plus a learnable velocity offset."""

    def __init__(self, offset: float) -> None:
        super().__init__()
        self.offset = nn.Parameter(torch.tensor(offset))
        self.layer = nn.Linear(17, 13)  # some work to time

    def forward(self, x_hist: Tensor, u_hist: Tensor, u_future: Tensor) -> Prediction:
        n = u_future.shape[1]
        last = x_hist[:, -1:] + 0 * self.layer(torch.cat([x_hist, u_hist], -1))[:, -1:]
        states = last.repeat(1, n, 1).clone()
        states[..., VEL] += self.offset
        return Prediction(states, None)


@pytest.fixture(scope="module")
def report(physics_flight) -> Report:
    flights = [physics_flight(f"test_{i}", seed=i, steps=40 + 7 * i) for i in range(3)]
    windows = {n: make_windows(flights, WindowConfig(history=M, horizon=n)) for n in (N, 2 * N)}
    # A physics model with the wrong load mass, so that it has an error like the real one.
    mismatched = dataclasses.replace(PARAMS, mass_load=0.2, cable_length=0.6)
    candidates = [Candidate(PHYSICS, PhysicsModel(mismatched))]
    for label, seed, offset in (("proposed", 0, 0.1), ("proposed", 1, 0.2), ("no-physics", 0, 0.5)):
        net = OffsetNet(offset)
        candidates.append(
            Candidate(label, NetworkModel(net, M), seed, net, {"run": f"runs/{label}-{seed}"})
        )
    return evaluate_predictors(
        candidates,
        windows,
        params=PARAMS,
        training_horizon=N,
        dataset="synthetic",
        timer=lambda networks, w, params: time_models(networks, w, params=params, repeats=3),
        environment={"slungload": "test"},
    )


@pytest.fixture(scope="module")
def written(report, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("report")
    write_report(report, out)
    return out


def read_csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


def test_every_file_exists_and_is_not_empty(written, report):
    names = ["report.md", "report.json", "rmse.csv", "rmse_table.csv", "timing.csv"]
    names += [f"mae_{la}_N{n}.csv" for la in report.labels for n in report.horizons]
    for name in names:
        assert (written / name).stat().st_size > 0, name
    pngs = sorted((written / "figures").glob("*.png"))
    assert {p.name for p in pngs} == {  # the MAE figures of every evaluated horizon
        *(f"mae_proposed_vs_physics_N{n}.png" for n in report.horizons),
        *(f"mae_proposed_vs_no-physics_N{n}.png" for n in report.horizons),
        *(f"mae_all_N{n}.png" for n in report.horizons),
        "prediction.png",
        "paths_3d.png",
    }
    for p in pngs:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000, p.name
    assert not list(written.rglob("*.tmp")), "atomic writes left temporary files"


def test_rmse_csv_matches_report(written, report):
    rows = read_csv(written / "rmse.csv")
    assert len(rows) == len(report.results)
    for row, r in zip(rows, report.results, strict=True):
        assert row["label"] == r.label and int(row["horizon"]) == r.metrics.horizon
        for k in METRIC_KEYS:
            value = float(row[k])
            assert math.isfinite(value) and value == r.metrics.rmse[k]
    rows = read_csv(written / "rmse_table.csv")
    assert len(rows) == len(report.table)
    for row, r in zip(rows, report.table, strict=True):
        assert int(row["seeds"]) == r.seeds
        for k in METRIC_KEYS:
            assert float(row[f"{k}_mean"]) == r.mean[k] and float(row[f"{k}_std"]) == r.std[k]
    assert report.row("proposed", 2 * N).seeds == 2


def test_mae_csv_matches_report(written, report):
    for label in report.labels:
        for n in report.horizons:
            rows = read_csv(written / f"mae_{label}_N{n}.csv")
            assert [int(r["step"]) for r in rows] == list(range(1, n + 1))
            for g in GROUPS:
                curve = report.curves[label][n][g]
                for stat in ("mean", "q1", "median", "q3"):
                    values = np.array([float(r[f"{g}_{stat}"]) for r in rows])
                    assert np.all(np.isfinite(values))
                    np.testing.assert_array_equal(values, getattr(curve, stat))
            np.testing.assert_allclose(
                [float(r["time_s"]) for r in rows], np.arange(1, n + 1) * PARAMS.dt
            )


def test_timing_csv_matches_report(written, report, tmp_path):
    rows = read_csv(written / "timing.csv")
    assert len(rows) == len(report.timings) == 3 * len(report.horizons)  # 3 networks
    for row, t in zip(rows, report.timings, strict=True):
        assert float(row["mean_ms"]) == t.timing.mean_ms > 0
        assert math.isfinite(float(row["std_ms"])) and int(row["threads"]) >= 1
        assert row["backend"] == "torch eager"  # stand-in networks: no compiled path
    # untimed (no --timing): no timing.csv, and none listed among the files
    from slungload.evaluation.report import write_csvs

    untimed = dataclasses.replace(report, timings=[])
    names = {p.name for p in write_csvs(untimed, tmp_path)}
    assert "timing.csv" not in names and not (tmp_path / "timing.csv").exists()


def test_markdown_has_both_tables_ratios_and_figures(written, report):
    text = (written / "report.md").read_text()
    for values in PAPER_RMSE_N50.values():  # the paper's table
        assert f"{values['combined']:.3f}" in text
    assert "Proposed model (w/o physics)" in text and "59.44" in text and "115.26" in text
    ours = report.row("proposed", 2 * N)
    assert f"{ours.mean['combined']:.3f} ± {ours.std['combined']:.3f}" in text
    ratio = ours.mean["combined"] / report.row(PHYSICS, 2 * N).mean["combined"]
    assert "| proposed / physics | " in text and f"{ratio:.3f}" in text
    paper_ratio = PAPER_RMSE_N50["proposed"]["combined"] / PAPER_RMSE_N50["physics"]["combined"]
    assert f"{paper_ratio:.3f}" in text
    links = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text)
    assert len(links) >= 4
    for link in links:
        assert not Path(link).is_absolute() and (written / link).is_file(), link


def test_json_round_trips(written, report):
    data = json.loads((written / "report.json").read_text())
    assert data["horizons"] == list(report.horizons)
    assert data["curves"]["proposed"][str(N)]["position"]["mean"] == list(
        report.curves["proposed"][N]["position"].mean
    )
    assert data["paper"]["rmse_n50"]["physics"]["combined"] == 1.879


# --- end to end ----------------------------------------------------------------------------


def test_evaluate_end_to_end(tmp_path, monkeypatch, tiny_run):
    monkeypatch.setenv("SLUNGLOAD_CACHE", str(tmp_path / "cache"))
    assert tiny_run.dataset.window.history == M
    out = tmp_path / "eval"
    report = evaluate_runs([tiny_run.out], out=out, horizons=(4, 8), timing=True,
                           timing_repeats=3, progress=False)  # fmt: skip
    assert report.labels == (PHYSICS, "proposed") and report.training_horizon == 4
    assert report.test_flights == ("test_3", "test_4")
    windows = {(r.label, r.metrics.horizon): r.metrics.windows for r in report.results}
    # Stride-1 windows of the two test flights (49 and 52 steps): T - (M + N) + 1 each.
    assert windows[(PHYSICS, 8)] == windows[("proposed", 8)] == (49 - 14 + 1) + (52 - 14 + 1)
    assert all(math.isfinite(v) for r in report.results for v in r.metrics.rmse.values())
    assert (out / "report.md").is_file() and (out / "figures" / "prediction.png").is_file()
    assert "**Smoke run" in (out / "report.md").read_text()  # the run's preset was "quick"
    assert {(t.timing.history, t.timing.horizon) for t in report.timings} == {(M, 4), (M, 8)}


def test_evaluate_on_the_validation_split(tmp_path, monkeypatch, tiny_run):
    monkeypatch.setenv("SLUNGLOAD_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "val"
    report = evaluate([tiny_run.out], out=out, horizons=(4,), split="val", progress=False)
    assert report.split == "val" and report.test_flights == ("val_2",)
    text = (out / "report.md").read_text()
    assert "validation flights (1): val_2" in text and "RMSE over the validation set" in text
    with pytest.raises(ValueError, match="split must be one of"):
        evaluate([tiny_run.out], horizons=(4,), split="train", progress=False)
    # every flight: a dataset the run never saw (here its own five, train included)
    report = evaluate([tiny_run.out], out=tmp_path / "all", horizons=(4,), split="all",
                      progress=False)  # fmt: skip
    assert len(report.test_flights) == 5
    assert "RMSE over every flight, N = 4" in (tmp_path / "all" / "report.md").read_text()


def test_labels_name_the_step_weighting_and_another_training_horizon(
    tmp_path, monkeypatch, tiny_run, train_tiny
):
    monkeypatch.setenv("SLUNGLOAD_CACHE", str(tmp_path / "cache"))
    other = train_tiny(
        tiny_run.data,
        tmp_path / "rel",
        window=WindowConfig(history=M, horizon=6),
        loss=LossWeights(steps="physics-relative"),
        max_epochs=1,
    )
    report = evaluate([tiny_run.out, other.out], horizons=(4,), progress=False)
    assert report.labels == (PHYSICS, "proposed", "proposed+relative+N6")
    assert report.training_horizon == 4  # the first run's


def test_evaluate_refuses_nothing_to_do(tmp_path):
    with pytest.raises(ValueError, match="nothing|no run"):
        evaluate([], data=tmp_path, include_physics=False, progress=False)
    with pytest.raises(ValueError, match="horizons"):
        evaluate([], data=tmp_path, horizons=(0,), progress=False)


# --- figures: every horizon, one look per label, nothing hidden ----------------------------


@pytest.fixture
def figures(monkeypatch) -> list:
    """The matplotlib Figures the plot functions save, in order (they still write the PNGs)."""
    from slungload.evaluation import plots

    saved = []
    save = plots.save_figure

    def capture(fig, path):
        saved.append(fig)
        return save(fig, path)

    monkeypatch.setattr(plots, "save_figure", capture)
    return saved


def line_look(line) -> tuple:
    return (line.get_color(), line.get_linestyle(), line.get_marker())


def test_label_styles_stay_distinct_for_many_labels():
    from slungload.evaluation.plots import label_styles

    labels = [PHYSICS, "proposed", "no-slack", "no-physics"]
    labels += [f"{arch}/{variant}" for arch in ("physics-step", "gru") for variant in labels[1:]]
    labels += [f"extra-{i}" for i in range(30)]
    styles = label_styles(labels)
    looks = [(s.color, str(s.linestyle), s.marker) for s in styles.values()]
    assert len(set(looks)) == len(labels) == 40
    networks = [s for la, s in styles.items() if la != PHYSICS]
    assert len({s.color for s in networks[:9]}) == 9  # the first nine networks differ in colour
    assert all(s.linestyle not in ("-", "solid") and s.marker for s in networks)  # solid: truth
    assert styles[PHYSICS].color not in {s.color for s in networks} and not styles[PHYSICS].marker
    # The same label keeps its look whatever the other labels are.
    assert label_styles(labels[:3])["no-slack"] == styles["no-slack"]


def test_mae_figures_bands_and_training_horizon(report, figures, tmp_path):
    from slungload.evaluation.report import write_figures

    written = write_figures(report, tmp_path)
    captions = [caption for caption, _ in written]
    assert [c for c in captions if c.startswith("MAE")] == [
        f"MAE per horizon step, {what} (N = {n})"
        for n in sorted(report.horizons)  # neither is the paper's 50: ascending
        for what in ("proposed vs physics", "proposed vs no-physics", "all models")
    ]
    by_name = {path.name: fig for (_, path), fig in zip(written, figures, strict=True)}
    for name, bands in ((f"mae_proposed_vs_physics_N{2 * N}.png", 2), (f"mae_all_N{2 * N}.png", 1)):
        fig = by_name[name]
        legend = [t.get_text() for t in fig.legends[0].get_texts()]
        for ax in fig.axes[:4]:
            fills = ax.collections
            assert len(fills) == bands  # all models: the reference's band only
            assert fills[0].get_facecolor()[0][3] < 0.25  # light
            if bands == 2:  # the second band is hatched, not a second fill: no mixed colour
                face = fills[1].get_facecolor()
                assert fills[1].get_hatch() and (len(face) == 0 or face[0][3] == 0)
            curves = [ln for ln in ax.lines if len(ln.get_xdata()) == 2 * N]
            assert len({line_look(ln) for ln in curves}) == len(curves) == len(legend) - bands - 1
            # Later curves are drawn above and narrower, so no curve hides an earlier one.
            widths = [ln.get_linewidth() for ln in sorted(curves, key=lambda ln: ln.zorder)]
            assert widths == sorted(widths, reverse=True)
        assert sum("Q1-Q3" in t for t in legend) == bands
        assert f"training horizon N = {N}" in legend


def test_prediction_figure_training_horizon_looks_like_no_predictor(report, figures, tmp_path):
    from slungload.evaluation import plots

    plots.plot_prediction(report.example, tmp_path / "p.png", dt=report.dt,
                          training_horizon=report.training_horizon)  # fmt: skip
    handles = figures[-1].legends[0].legend_handles
    names = [h.get_label() for h in handles]
    horizon = handles[names.index(f"training horizon N = {N}")]
    predictors = [h for h in handles if h.get_label() in report.example.predictions]
    assert len(predictors) == len(report.example.predictions) == 3
    for h in [handles[names.index("truth")], *predictors]:
        look = (h.get_linestyle(), h.get_marker())
        assert look != (horizon.get_linestyle(), horizon.get_marker()), h.get_label()
    assert len({(h.get_linestyle(), h.get_marker()) for h in predictors}) == len(predictors)


def test_paths_3d_zooms_on_the_predicted_window(report, figures, tmp_path):
    from slungload.evaluation import plots
    from slungload.state import LOAD_POS, POS

    ex = report.example
    plots.plot_paths_3d(ex, tmp_path / "p.png")
    overview, vehicle, load = figures[-1].axes[:3]
    for ax, sl in ((vehicle, POS), (load, LOAD_POS)):
        # Every predictor's path is drawn in the zoom, with markers, and the zoom frames the
        # predicted window far more tightly than the whole flight.
        marked = [ln for ln in ax.lines if ln.get_marker() not in ("None", None, "", ".")]
        assert len(marked) == len(ex.predictions) - 1 + (PHYSICS not in ex.predictions)
        span = np.ptp(ex.flight_states[:, sl], axis=0).max()
        assert (ax.get_xlim()[1] - ax.get_xlim()[0]) < span
    labels = [t.get_text() for t in figures[-1].legends[0].get_texts()]
    assert all(any(t.startswith(la) for t in labels) for la in ex.predictions)


def test_quick_runs_get_a_smoke_banner_at_the_top(report, tmp_path):
    from slungload.evaluation.report import render_markdown

    def markdown(models) -> str:
        return render_markdown(dataclasses.replace(report, models=tuple(models)), figures=[],
                               csvs=[], out=tmp_path)  # fmt: skip

    assert "Smoke run" not in markdown(report.models)
    quick = [{**m, "configs": {"preset": "quick"}} for m in report.models]
    text = markdown(quick)
    assert text.index("**Smoke run: these numbers are not results.**") < text.index("## Dataset")
    assert "Every run trained with the `quick` preset" in text
    mixed = [quick[0], *({**m, "configs": {"preset": "default"}} for m in report.models[1:])]
    text = markdown(mixed)
    assert f"The runs `{quick[0]['run']}` trained with the `quick` preset" in text
