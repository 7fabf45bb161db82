"""An ensemble's spread against its errors: the calibration fit, coverage, and its report.

- ``member_predictions``: each member's prediction over windows and the truth, float64.
- ``fit_calibration``: the ``models.ensemble.Calibration`` of a level (default 0.9): per
  horizon step and state group, the level quantile of |error| / std over the windows and the
  group's components (split-conformal), divided by the level's Gaussian z; the novelty
  reference (median std per step and component) and threshold (the 0.99 quantile of the
  windows' novelty score).
- ``uncertainty_stats``: per group and step, the mean's RMSE, the calibrated spread (RMS of
  the interval's sigma), the interval's coverage (pooled over the group's components); and
  the share of windows flagged novel.
- ``tracked_multipliers``: the interval as tracked in flight (``online_interval``), replayed
  over each flight's windows in time order; ``uncertainty_stats(..., tracked_in=windows)``
  measures it, with the share of windows issued while the tracker was surprised.
- ``calibrate`` and ``assess``: the same on a dataset folder's split for an ensemble folder
  (``slungload calibrate`` / ``slungload uncertainty``, which measures the interval as
  calibrated and as tracked); ``write_assessment`` writes the tables (markdown),
  ``coverage.csv`` and ``calibration.png``. ``evaluate`` adds the same
  table and figure to its report for every calibrated ensemble it evaluates.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from matplotlib.figure import Figure
from torch import Tensor

from ..config import ESTIMATE_MIN_STEPS, WindowConfig
from ..data.dataset import load_dataset
from ..data.windows import Windows
from ..fileio import write_text
from ..layout import GROUPS, QUAT, STATE_DIM
from ..models.ensemble import (
    LEVEL,
    Calibration,
    EnsembleModel,
    group_index,
    is_ensemble,
    load_members,
    set_calibration,
    spread,
    widened,
    z_of,
)
from ..models.prediction import ensemble_model
from ..online_interval import OnlineInterval, OnlineIntervalConfig, group_of_component
from ..reporting import markdown_table, save_figure
from .windows import horizon_windows, split_name

NOVELTY_QUANTILE = 0.99  # the share of in-distribution windows not flagged novel
REPORT_STEPS = (1, 5, 10, 25, 50, 75, 100)  # the table's horizon steps (those within N)
TRACKED_FROM = {  # where the tracked interval of each flight starts (``UncertaintyStats.carried``)
    False: "each flight from the calibration",
    True: "the flights one after another, each from where the last left it",
}


def member_predictions(model: EnsembleModel, windows: Windows) -> tuple[Tensor, Tensor]:
    """(E, W, N, 13) members' predictions and (W, N, 13) truth, float64; the truth's
    quaternion turned to the first member's hemisphere."""
    members = model.predict_windows_members(windows).double()
    truth = windows.future.states.double().clone()
    q = truth[..., QUAT]
    sign = torch.where((q * members[0][..., QUAT]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    truth[..., QUAT] = q * sign.to(q.dtype)
    return members, truth


def _ratio_quantiles(ratio: Tensor, q: float) -> np.ndarray:
    """ratio (W, N, 13) -> (N, G): the q quantile over windows and each group's components."""
    out = np.empty((ratio.shape[1], len(GROUPS)))
    for g, sl in enumerate(GROUPS.values()):
        flat = ratio[..., sl].permute(1, 0, 2).reshape(ratio.shape[1], -1).numpy()
        out[:, g] = np.quantile(flat, q, axis=1)
    return out


def fit_calibration(
    members: Tensor,
    truth: Tensor,
    *,
    level: float = LEVEL,
    fitted_on: str = "",
    shift: Tensor | None = None,
) -> Calibration:
    """The ``Calibration`` of members (E, W, N, 13) against truth (W, N, 13) at ``level``;
    given the windows' constants shift (W, N, 13, ``window_shift``), one that widens the
    members' spread by it (``Calibration.constants_shift``)."""
    mean, std = spread(members)
    if shift is not None:
        std = widened(std, shift)
    std = std.clamp_min(1e-12)
    ratio = (truth - mean).abs() / std
    scale = _ratio_quantiles(ratio, level) / z_of(level)
    reference = std.median(dim=0).values
    provisional = Calibration(
        scale=tuple(map(tuple, scale.tolist())),
        reference_std=tuple(map(tuple, reference.tolist())),
        novelty_threshold=float("inf"),
        level=level,
    )
    scores = provisional.novelty_score(std)
    threshold = float(np.quantile(scores.numpy(), NOVELTY_QUANTILE))
    return Calibration(
        scale=provisional.scale,
        reference_std=provisional.reference_std,
        novelty_threshold=threshold,
        level=level,
        novelty_quantile=NOVELTY_QUANTILE,
        fitted_on=fitted_on,
        windows=int(truth.shape[0]),
        constants_shift=shift is not None,
    )


def window_shift(model: EnsembleModel, windows: Windows, batch: int = 4096) -> Tensor:
    """(W, N, 13) float64: each window's ``constants_estimate.constants_shift`` against the
    members' constants (``EnsembleModel.constants_shift``), ``batch`` windows at a time."""
    m = windows.window.history
    parts = [torch.zeros(0, windows.window.horizon, STATE_DIM, dtype=torch.float64)]
    for i in range(0, len(windows), batch):
        w = windows[i : i + batch]
        parts.append(model.constants_shift(w.states[:, :m], w.inputs[:, :m], w.inputs[:, m:]))
    return torch.cat(parts)


def shift_if_asked(model: EnsembleModel, windows: Windows) -> Tensor | None:
    """``window_shift`` where the model's calibration widens its spread by it, else None."""
    cal = model.calibration
    return window_shift(model, windows) if cal is not None and cal.constants_shift else None


@dataclass(frozen=True)
class UncertaintyStats:
    """Per group (``layout.GROUPS`` order) and horizon step 1..N, arrays (G, N)."""

    rmse: np.ndarray  # the members' mean against the truth (norm over the group's components)
    sigma: np.ndarray  # the calibrated sigma (scale x std), RMS over windows, norm over group
    coverage: np.ndarray  # share of (window, component) inside the interval
    novel: float  # share of windows flagged novel
    level: float
    windows: int
    surprised: float | None = None  # tracked in flight: share of windows issued surprised
    carried: bool = False  # tracked from flight to flight (``tracked_multipliers``'s carry)


def tracked_multipliers(
    ratio: Tensor,
    flight: Tensor,
    start: Tensor,
    level: float,
    config: OnlineIntervalConfig | None = None,
    carry: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """The multipliers (W, N, G) each window's interval had in flight, and (W,) bool whether
    the tracker was surprised when it was issued.

    ratio (W, N, 13): |error| / the calibrated half width; flight, start (W,): each window's
    flight and first step. Per flight in time order the tracker starts at the calibration
    (multiplier 1) and, before window s is issued, takes every window up to s - N not taken
    yet: the predictions whose every step has been flown (with stride 1, window s - N alone; a
    vehicle re-predicts it from the state then under the inputs since applied). ``carry``: one
    tracker for the flights flown one after another in index order, as one vehicle keeping its
    ``EnsemblePredictor`` between flights; a flight's last N windows resolve at its end."""
    r = ratio.double().numpy()
    n = r.shape[1]
    out = np.ones((r.shape[0], n, len(GROUPS)))
    surprised = np.zeros(r.shape[0], bool)
    fl, st = flight.numpy(), start.numpy()
    tracker = OnlineInterval(n, level, config)
    for f in np.unique(fl):
        rows = np.flatnonzero(fl == f)
        rows = rows[np.argsort(st[rows], kind="stable")]
        if not carry:
            tracker = OnlineInterval(n, level, config)
        taken = 0  # rows[:taken] are resolved and fed
        for row in rows:
            while taken < len(rows) and st[rows[taken]] <= st[row] - n:
                tracker.update(r[rows[taken]])
                taken += 1
            out[row] = tracker.multiplier
            surprised[row] = tracker.surprised
        for row in rows[taken:] if carry else ():  # flown by the flight's end
            tracker.update(r[row])
    return out, surprised


def uncertainty_stats(
    members: Tensor,
    truth: Tensor,
    calibration: Calibration,
    level: float | None = None,
    tracked_in: Windows | None = None,
    online: OnlineIntervalConfig | None = None,
    carry: bool = False,
    shift: Tensor | None = None,
) -> UncertaintyStats:
    """Coverage, error and spread of members (E, W, N, 13) against truth (W, N, 13); with
    ``tracked_in`` (the windows they are of) the interval as tracked in flight over their
    flights (``tracked_multipliers``, ``online`` its constants, ``carry`` from flight to
    flight); ``shift``: the windows' constants shift, where the calibration widens by it."""
    lvl = calibration.level if level is None else level
    mean, std = spread(members)
    half = calibration.half_width(std, lvl, shift)
    surprised = None
    if tracked_in is not None:
        ratio = (truth - mean).abs() / half.clamp_min(1e-12)
        factor, flagged = tracked_multipliers(ratio, tracked_in.flight, tracked_in.start, lvl,
                                              online, carry)  # fmt: skip
        half = half * torch.as_tensor(factor[..., group_of_component()]).to(half.dtype)
        surprised = float(flagged.mean())
    inside = ((truth - mean).abs() <= half).double()
    sigma = half / z_of(lvl)  # the calibrated scale times std
    sq_err, sq_sig = (truth - mean) ** 2, sigma**2
    idx = group_index()
    n_groups = len(GROUPS)
    rmse, sig, cov = (np.empty((n_groups, truth.shape[1])) for _ in range(3))
    for g in range(n_groups):
        cols = idx == g
        rmse[g] = sq_err[..., cols].sum(-1).mean(0).sqrt().numpy()
        sig[g] = sq_sig[..., cols].sum(-1).mean(0).sqrt().numpy()
        cov[g] = inside[..., cols].mean(dim=(0, 2)).numpy()
    novel = float(calibration.novel(std, shift).double().mean())
    carried = carry and tracked_in is not None
    return UncertaintyStats(rmse, sig, cov, novel, lvl, int(truth.shape[0]), surprised, carried)


def ensemble_and_windows(
    ensemble: str | Path, data: str | Path | None, split: str, horizon: int | None
) -> tuple[EnsembleModel, Windows, str]:
    """The ensemble folder's model, the split's windows (stride 1) at ``horizon`` (default:
    the members' training horizon) and a description of them."""
    if not is_ensemble(ensemble):
        raise ValueError(f"{ensemble} is not an ensemble folder (train --ensemble K writes one)")
    manifest, loaded = load_members(ensemble)
    first = loaded[0]
    folder = data if data is not None else first.meta.get("data")
    if folder is None:
        raise ValueError(f"{ensemble}: no dataset folder recorded in its members; pass --data")
    n = horizon or first.window.horizon
    window = WindowConfig(history=first.window.history, horizon=n, stride=1)
    dataset = load_dataset(folder, window=window, params=first.params)
    windows = horizon_windows(dataset, history=window.history, horizons=(n,), split=split)[n]
    about = f"{split_name(split)} of {Path(folder)}, N = {n}"
    return ensemble_model(manifest, loaded), windows, about


def calibrate(
    ensemble: str | Path,
    data: str | Path | None = None,
    *,
    split: str = "val",
    horizon: int | None = None,
    level: float = LEVEL,
    constants_shift: bool = False,
) -> tuple[Calibration, UncertaintyStats]:
    """Fit the ensemble folder's calibration on a split (default val), store it in its
    manifest, and return it with its in-sample stats. ``constants_shift``: widen the members'
    spread by each window's constants shift (members of fixed constants only)."""
    model, windows, about = ensemble_and_windows(ensemble, data, split, horizon)
    shift = None
    if constants_shift:
        if model.history < ESTIMATE_MIN_STEPS:
            raise ValueError(
                f"{ensemble}: --constants-shift estimates the load from each window's history, "
                f"which needs M >= {ESTIMATE_MIN_STEPS} steps; its members keep M = {model.history}"
            )
        adapting = [m.name for m in model.members if _adapts(m)]
        if adapting:
            raise ValueError(
                f"{ensemble}: --constants-shift widens the interval of members trained on one "
                "vehicle's constants; these adapt theirs in flight (constants='window'), so "
                "their spread already follows the load: calibrate without it"
            )
        shift = window_shift(model, windows)
    members, truth = member_predictions(model, windows)
    calibration = fit_calibration(members, truth, level=level, fitted_on=about, shift=shift)
    set_calibration(ensemble, calibration)
    return calibration, uncertainty_stats(members, truth, calibration, shift=shift)


def _adapts(member: object) -> bool:
    """Whether a member network runs f with each window's estimated constants."""
    config = getattr(getattr(member, "net", None), "config", None)
    return bool(getattr(config, "adapts_constants", False))


def assess(
    ensemble: str | Path,
    data: str | Path | None = None,
    *,
    split: str = "test",
    horizon: int | None = None,
    level: float | None = None,
    online: OnlineIntervalConfig | None = None,
    carry: bool = False,
) -> tuple[UncertaintyStats, UncertaintyStats, str]:
    """The calibrated ensemble folder's stats on a dataset's split: the interval as
    calibrated, as tracked in flight (``online``, default ``OnlineIntervalConfig()``; ``carry``:
    from flight to flight), and what they are of."""
    model, windows, about = ensemble_and_windows(ensemble, data, split, horizon)
    if model.calibration is None:
        raise ValueError(f"{ensemble}: not calibrated; run `slungload calibrate {ensemble}`")
    members, truth = member_predictions(model, windows)
    shift = shift_if_asked(model, windows)
    if shift is not None:
        about += " (the members' spread widened by the constants shift)"
    fixed = uncertainty_stats(members, truth, model.calibration, level, shift=shift)
    tracked = uncertainty_stats(members, truth, model.calibration, level, windows, online, carry,
                                shift)  # fmt: skip
    return fixed, tracked, about


def stats_table(stats: UncertaintyStats) -> str:
    """Markdown: per report step and group, RMSE / calibrated sigma / coverage."""
    steps = [n for n in REPORT_STEPS if n <= stats.rmse.shape[1]]
    header = ["step", *(f"{g}: RMSE / sigma / cover" for g in GROUPS)]
    rows = [
        [n, *(
            f"{stats.rmse[g, n - 1]:.3f} / {stats.sigma[g, n - 1]:.3f} / "
            f"{100 * stats.coverage[g, n - 1]:.0f} %"
            for g in range(len(GROUPS))
        )]
        for n in steps
    ]  # fmt: skip
    return markdown_table(header, rows)


def summary_line(stats: UncertaintyStats) -> str:
    """One sentence: the coverage range over every step and group, the share flagged."""
    lo, hi = stats.coverage.min(), stats.coverage.max()
    flag = (
        f"{100 * stats.novel:.1f} % of windows flagged novel"
        if stats.surprised is None
        else f"{100 * stats.surprised:.1f} % of windows issued surprised"
    )
    return (
        f"the {stats.level:.0%} interval covers {100 * lo:.1f}-{100 * hi:.1f} % of the errors "
        f"over every step and group (pooled over each group's components); {flag}"
    )


def spread_section(spreads: dict[str, dict[int, UncertaintyStats]]) -> list[str]:
    """``evaluate``'s report lines: each calibrated ensemble's interval at its longest N."""
    lines = []
    for label, by_n in spreads.items():
        n = max(by_n)
        stats = by_n[n]
        lines += [f"## The interval of {label}, N = {n}", "",
                  f"Calibrated on its own held-out flights; here {summary_line(stats)}. Per "
                  "step: the mean's RMSE, the calibrated sigma and the share of errors inside "
                  "the interval.", "", stats_table(stats), ""]  # fmt: skip
    return lines


def write_assessment(
    stats: UncertaintyStats, tracked: UncertaintyStats, about: str, out: str | Path
) -> list[Path]:
    """``out/uncertainty.md`` (the interval as calibrated and as tracked in flight),
    ``out/coverage.csv`` (every step, both) and ``out/calibration.png``."""
    out = Path(out).expanduser()
    text = (
        f"# Ensemble uncertainty\n\n{about}, {stats.windows} windows.\n\n"
        f"As calibrated: {summary_line(stats)}.\n\n" + stats_table(stats) + "\n\n"
        f"Tracked in flight ({TRACKED_FROM[tracked.carried]}, moved by the predictions it "
        f"resolves; docs/uncertainty.md): {summary_line(tracked)}.\n\n"
        + stats_table(tracked)
        + "\n"
    )
    write_text(out / "uncertainty.md", text)
    kinds = ("rmse", "sigma", "coverage", "tracked_sigma", "tracked_coverage")
    lines = ["step," + ",".join(f"{g}_{k}" for g in GROUPS for k in kinds)]
    for n in range(stats.rmse.shape[1]):
        values = [
            f"{a[g, n]:.6g}"
            for g in range(len(GROUPS))
            for a in (stats.rmse, stats.sigma, stats.coverage, tracked.sigma, tracked.coverage)
        ]
        lines.append(f"{n + 1}," + ",".join(values))
    write_text(out / "coverage.csv", "\n".join(lines) + "\n")
    return [
        out / "uncertainty.md",
        out / "coverage.csv",
        plot_calibration(stats, out, tracked=tracked),
    ]


def plot_calibration(
    stats: UncertaintyStats,
    out: Path,
    name: str = "calibration.png",
    *,
    tracked: UncertaintyStats | None = None,
) -> Path:
    """Two panels: coverage per step and group beside the level; RMSE against sigma. With
    ``tracked``: its curves dashed in the same colours."""
    fig = Figure(figsize=(10, 4))
    ax_cov, ax_sig = fig.subplots(1, 2)
    steps = np.arange(1, stats.rmse.shape[1] + 1)
    for g, group in enumerate(GROUPS):
        (line,) = ax_cov.plot(steps, 100 * stats.coverage[g], label=group)
        ratio = stats.rmse[g] / np.maximum(stats.sigma[g], 1e-12)
        ax_sig.plot(steps, ratio, color=line.get_color(), label=group)
        if tracked is not None:
            colour = line.get_color()
            ax_cov.plot(steps, 100 * tracked.coverage[g], color=colour, linestyle="--")
            ratio = tracked.rmse[g] / np.maximum(tracked.sigma[g], 1e-12)
            ax_sig.plot(steps, ratio, color=colour, linestyle="--")
    ax_cov.axhline(100 * stats.level, color="k", linestyle=":", label=f"{stats.level:.0%} level")
    if tracked is not None:
        ax_cov.plot([], [], color="k", linestyle="--", label="tracked in flight")
    ax_cov.set(xlabel="horizon step", ylabel="coverage (%)", ylim=(0, 100))
    ax_cov.legend(fontsize=8)
    ax_sig.axhline(1.0, color="k", linestyle=":")
    ax_sig.set(xlabel="horizon step", ylabel="RMSE / calibrated sigma (1: matched)")
    fig.tight_layout()
    return save_figure(fig, out / name)
