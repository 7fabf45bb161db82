"""Figures of an evaluation (PNG): MAE per horizon step, one predicted window, 3D paths.

Figures are built on ``matplotlib.figure.Figure`` directly (PNG through Agg), so this module
never touches pyplot's global state or the user's backend. Each function writes one file
atomically and returns its path.

- ``plot_mae``: MAE vs horizon step per state group, 2x2, Q1-Q3 bands for the labels asked
  for, a solid vertical line at the training horizon (the paper's Figs 3 and 5, for any number
  of labels).
- ``plot_prediction``: one test window, truth (solid) vs each predictor (its own dash pattern
  and markers) for the four groups (the paper's Fig 4).
- ``plot_paths_3d``: vehicle and load paths of the example flight, and a zoom on the predicted
  window of each, where the predicted paths are visible.

Every label keeps one look in every figure (``label_styles``): physics grey and dotted, the
networks their colour (``reporting.model_colors``), a dash pattern and a marker each, none
solid (solid is the truth). Labels such as ``physics-step/proposed`` (architecture/variant) are
labels like any other; no two looks repeat within hundreds of labels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator

from ..reporting import model_colors, save_figure
from ..state import GROUP_UNITS, GROUPS, LOAD_POS, POS
from .metrics import Curve
from .results import PHYSICS, Example

GROUP_TITLES = {
    "position": "vehicle position",
    "velocity": "vehicle velocity",
    "quaternion": "attitude quaternion",
    "load_position": "load position",
}
COMPONENTS = {
    "position": ("x", "y", "z"),
    "velocity": ("x", "y", "z"),
    "quaternion": ("w", "x", "y", "z"),
    "load_position": ("x", "y", "z"),
}
TRUTH_COLOR = "k"
LOAD_TRUTH_COLOR = "0.55"  # the load's measured path in the 3D figure (the vehicle's is black)
HISTORY_LINE_COLOR = "0.55"
HORIZON_LINE = {"color": "k", "linewidth": 1.0, "linestyle": "-"}  # the training horizon
# Network dash patterns: none solid (the truth) and none dotted (physics).
NETWORK_LINESTYLES = (
    (0, (6, 2)),  # dashed
    (0, (6, 2, 1.5, 2)),  # dash-dot
    (0, (6, 1.5, 1.5, 1.5, 1.5, 1.5)),  # dash-dot-dot
    (0, (12, 3)),  # long dash
    (0, (3, 1.5, 3, 1.5, 1, 1.5)),  # dash-dash-dot
)
NETWORK_MARKERS = ("o", "s", "^", "D", "v", "P", "X")
REFERENCE_BAND_ALPHA = 0.18


@dataclass(frozen=True)
class LabelStyle:
    """How one label is drawn in every figure."""

    color: str
    linestyle: object  # a matplotlib line style
    marker: str | None
    linewidth: float  # earlier labels are drawn wider, so that later ones never hide them

    def line(self, **overrides: object) -> dict[str, object]:
        """Keyword arguments for ``Axes.plot``."""
        kwargs: dict[str, object] = {
            "color": self.color,
            "linestyle": self.linestyle,
            "linewidth": self.linewidth,
            "marker": self.marker,
            "markersize": 5,
            "markeredgewidth": 0.8,
            "markeredgecolor": "white" if self.marker else None,
        }
        kwargs.update(overrides)
        return kwargs


def label_styles(labels: Sequence[str]) -> dict[str, LabelStyle]:
    """A distinct look per label, stable in the order given: physics grey and dotted; each
    network its colour (``reporting.model_colors``) and the i-th network the i-th dash pattern
    and marker of their cycles (5 and 7 long; a look already taken moves on to the next
    marker), lines narrowing with i."""
    colors = model_colors(labels)
    styles: dict[str, LabelStyle] = {}
    looks: set[tuple[str, int, int]] = set()
    for i, label in enumerate(la for la in colors if la != PHYSICS):
        dash, mark = i % len(NETWORK_LINESTYLES), i % len(NETWORK_MARKERS)
        for shift in range(len(NETWORK_MARKERS)):
            if (colors[label], dash, (mark + shift) % len(NETWORK_MARKERS)) not in looks:
                mark = (mark + shift) % len(NETWORK_MARKERS)
                break
        looks.add((colors[label], dash, mark))
        styles[label] = LabelStyle(colors[label], NETWORK_LINESTYLES[dash],
                                   NETWORK_MARKERS[mark], max(1.2, 2.6 - 0.4 * i))  # fmt: skip
    if PHYSICS in colors:
        styles[PHYSICS] = LabelStyle(colors[PHYSICS], (0, (1, 1.5)), None, 2.0)
    return {label: styles[label] for label in colors}


def _markevery(steps: int, index: int, count: int) -> tuple[int, int]:
    """About ten markers along a line of ``steps`` points, staggered between the ``count``
    lines of a panel so that markers of overlapping lines sit side by side."""
    every = max(1, steps // 10)
    return (index * every) // max(count, 1) % every, every


def plot_mae(
    curves: Mapping[str, Mapping[str, Curve]],
    path: str | Path,
    *,
    dt: float,
    training_horizon: int | None,
    title: str | None = None,
    bands: Sequence[str] | None = None,
    styles: Mapping[str, LabelStyle] | None = None,
) -> Path:
    """MAE_k per group, 2x2, one line per label, with Q1-Q3 bands for ``bands``.

    curves: label -> group -> ``Curve`` of N steps; dt (s) gives the top time axis;
    training_horizon draws a solid black vertical line, named (None: no line). bands: labels whose
    Q1-Q3 band is drawn, the first filled lightly and the others hatched, each in its
    label's colour and named in the legend (default: the first label's only). styles: from
    ``label_styles`` over every label of the report, so that a label looks the same in every
    figure (default: over ``curves``).
    """
    if not curves:
        raise ValueError("plot_mae: no curves to plot")
    labels = list(curves)
    styles = dict(styles or label_styles(labels))
    bands = [b for b in (labels[:1] if bands is None else bands) if b in curves]
    fig = Figure(figsize=(11, 8), layout="constrained")
    axes = fig.subplots(2, 2)
    steps = max(len(by_group[g].mean) for by_group in curves.values() for g in GROUPS)
    for ax, group in zip(axes.flat, GROUPS, strict=True):
        if training_horizon is not None and training_horizon < steps:
            _vertical(ax, training_horizon, "training horizon", **HORIZON_LINE)
        by_label = {label: curves[label][group] for label in labels}
        _mae_bands(ax, by_label, bands, styles)
        _mae_lines(ax, by_label, styles)
        ax.set_title(GROUP_TITLES[group])
        ax.set_xlabel("horizon step k")
        unit = GROUP_UNITS[group]
        ax.set_ylabel(f"MAE ({unit})" if unit != "-" else "MAE (-)")
        ax.set_xlim(0, steps + 0.5)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        top = ax.secondary_xaxis("top", functions=(lambda k: k * dt, lambda t: t / dt))
        top.set_xlabel("time ahead (s)")
    handles = _mae_handles(labels, bands, styles)
    if training_horizon is not None and training_horizon < steps:
        handles.append(_vertical_handle(f"training horizon N = {training_horizon}", **HORIZON_LINE))
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 3),
               fontsize="small")  # fmt: skip
    named = f": {' vs '.join(labels)}" if len(labels) <= 3 else f", {len(labels)} models"
    fig.suptitle(title or f"Test-set MAE per horizon step, N = {steps}{named}")
    return save_figure(fig, path)


def _mae_bands(
    ax, curves: Mapping[str, Curve], bands: Sequence[str], styles: Mapping[str, LabelStyle]
) -> None:
    """The Q1-Q3 band of each label in ``bands`` in one panel: the first filled lightly, the
    others hatched, so that overlapping bands stay readable."""
    for j, label in enumerate(bands):
        c = curves[label]
        k = np.arange(1, len(c.mean) + 1)
        color = styles[label].color
        if j == 0:
            ax.fill_between(k, c.q1, c.q3, color=color, alpha=REFERENCE_BAND_ALPHA,
                            linewidth=0, zorder=1)  # fmt: skip
        else:
            ax.fill_between(k, c.q1, c.q3, facecolor="none", edgecolor=color, hatch="////",
                            alpha=0.45, linewidth=0, zorder=1.5)  # fmt: skip


def _mae_lines(ax, curves: Mapping[str, Curve], styles: Mapping[str, LabelStyle]) -> None:
    """Each label's MAE_k line in one panel (``curves``: label -> that panel's curve)."""
    labels = list(curves)
    # Wide lines first: a later, narrower one lies on top and never hides an earlier one.
    order = sorted(labels, key=lambda label: -styles[label].linewidth)
    for i, label in enumerate(labels):
        c = curves[label]
        k = np.arange(1, len(c.mean) + 1)
        every = _markevery(len(k), i, len(labels))
        ax.plot(k, c.mean, zorder=3 + order.index(label), **styles[label].line(markevery=every))


def _mae_handles(
    labels: Sequence[str], bands: Sequence[str], styles: Mapping[str, LabelStyle]
) -> list:
    """Legend entries of ``plot_mae``: one line per label, then one patch per band."""
    handles: list = [Line2D([], [], label=f"{la} (MAE)", **styles[la].line()) for la in labels]
    for j, label in enumerate(bands):
        color = styles[label].color
        if j == 0:
            patch = Patch(color=color, alpha=REFERENCE_BAND_ALPHA, linewidth=0)
        else:
            patch = Patch(facecolor="none", edgecolor=color, hatch="////", alpha=0.6)
        patch.set_label(f"{label}: Q1-Q3 over the windows")
        handles.append(patch)
    return handles


def plot_prediction(
    example: Example,
    path: str | Path,
    *,
    dt: float,
    training_horizon: int | None,
    title: str | None = None,
    styles: Mapping[str, LabelStyle] | None = None,
) -> Path:
    """One test window: M history steps and N predicted steps, one panel per group.

    Colour is the component (x, y, z, w); the truth is solid, each predictor has its label's
    dash pattern and markers (physics dotted). The prediction lines start at the last measured
    state. Vertical lines, named at their top, at the end of the history (thick grey) and at
    the training horizon (thin black).
    """
    m = example.history
    truth = example.window_states
    t = np.arange(len(truth)) * dt  # s from the window's first step
    labels = list(example.predictions)
    styles = dict(styles or label_styles(labels))
    trained = training_horizon is not None and m - 1 + training_horizon < len(truth) - 1
    fig = Figure(figsize=(10, 11.5), layout="constrained")
    axes = fig.subplots(len(GROUPS), 1, sharex=True)
    for row, (ax, (group, sl)) in enumerate(zip(axes, GROUPS.items(), strict=True)):
        if trained:  # named in the top panel only: the names would cover data below
            _vertical(ax, (m - 1 + training_horizon) * dt, "training horizon" if row == 0 else None,
                      **HORIZON_LINE)  # fmt: skip
        _prediction_lines(ax, example, group, sl, dt, styles)
        _vertical(ax, (m - 1) * dt, "end of history" if row == 0 else None,
                  color=HISTORY_LINE_COLOR, linewidth=2.0)  # fmt: skip
        ax.set_xlim(t[0], t[-1] + dt)
        unit = GROUP_UNITS[group]
        ax.set_ylabel(f"{GROUP_TITLES[group]}" + (f" ({unit})" if unit != "-" else " (-)"))
        ax.grid(alpha=0.3)
        comp_handles = [
            Line2D([], [], color=f"C{i}", label=c) for i, c in enumerate(COMPONENTS[group])
        ]
        ax.legend(handles=comp_handles, loc="best", fontsize="small", ncols=4)
    axes[-1].set_xlabel("time from window start (s)")
    source_handles = _prediction_handles(labels, styles, training_horizon if trained else None)
    fig.legend(handles=source_handles, loc="outside lower center",
               ncols=min(len(source_handles), 4), fontsize="small")  # fmt: skip
    fig.suptitle(
        title
        or f"Flight {example.flight}, window from step {example.start}: "
        f"M = {m} history steps, N = {len(truth) - m} predicted"
    )
    return save_figure(fig, path)


def _prediction_lines(
    ax, example: Example, group: str, sl: slice, dt: float, styles: Mapping[str, LabelStyle]
) -> None:
    """One group's panel: per component (its colour), the truth solid over the window and each
    label's prediction from the last measured state on."""
    m = example.history
    truth = example.window_states
    t = np.arange(len(truth)) * dt  # s from the window's first step
    t_pred = np.arange(m - 1, len(truth)) * dt
    labels = list(example.predictions)
    for i in range(len(COMPONENTS[group])):
        color = f"C{i}"
        ax.plot(t, truth[:, sl][:, i], color=color, linewidth=1.5, zorder=2)
        for j, label in enumerate(labels):
            pred = np.concatenate([truth[m - 1 : m, sl], example.predictions[label][:, sl]])
            every = _markevery(len(pred), j, len(labels))
            ax.plot(t_pred, pred[:, i], zorder=3 + j, **styles[label].line(
                color=color, linewidth=1.4, markersize=4, markeredgecolor=color,
                markevery=every))  # fmt: skip


def _prediction_handles(
    labels: Sequence[str], styles: Mapping[str, LabelStyle], training_horizon: int | None
) -> list:
    """Legend entries of ``plot_prediction``: the truth, each label (in black: colour is the
    component there), the end of the history and the training horizon (None: not drawn)."""
    source_handles: list = [Line2D([], [], color=TRUTH_COLOR, linewidth=1.5, label="truth")]
    source_handles += [
        Line2D([], [], label=la, **styles[la].line(color=TRUTH_COLOR, linewidth=1.4))
        for la in labels
    ]
    source_handles.append(_vertical_handle("end of history", color=HISTORY_LINE_COLOR,
                                           linewidth=2.0))  # fmt: skip
    if training_horizon is not None:
        source_handles.append(
            _vertical_handle(f"training horizon N = {training_horizon}", **HORIZON_LINE)
        )
    return source_handles


def plot_paths_3d(
    example: Example,
    path: str | Path,
    *,
    title: str | None = None,
    styles: Mapping[str, LabelStyle] | None = None,
) -> Path:
    """3D paths: the whole flight with the example window, then a zoom on the predicted window
    of the vehicle and of the load, each with every label's predicted path (its colour, dash
    pattern and markers) beside the measured one.

    The zooms frame the measured path and the networks' predictions; a prediction that leaves
    the frame (the open-loop physics model often does) is cut at its edge, and the legend
    says so.
    """
    labels = list(example.predictions)
    styles = dict(styles or label_styles(labels))
    m = example.history
    window = example.window_states
    future = window[m - 1 :]  # from the last measured state
    recent = window[max(0, m - len(future)) : m]  # as many history steps, for the zooms
    paths = {
        label: np.concatenate([future[:1], pred]) for label, pred in example.predictions.items()
    }
    fig = Figure(figsize=(16, 5.2), layout="constrained")
    axes = [fig.add_subplot(1, 3, i + 1, projection="3d") for i in range(3)]
    clipped: set[str] = set()
    _whole_flight_panel(axes[0], example.flight_states, future, paths, styles, clipped)
    for ax, sl, name, color in (
        (axes[1], POS, "vehicle", TRUTH_COLOR),
        (axes[2], LOAD_POS, "load", LOAD_TRUTH_COLOR),
    ):
        networks = [xyz[:, sl] for label, xyz in paths.items() if label != PHYSICS]
        lo, hi = _frame(ax, np.concatenate([recent[:, sl], future[:, sl], *networks]), margin=0.08)
        ax.plot(*recent[:, sl].T, color=color, linewidth=1.0, alpha=0.7)
        ax.plot(*future[:, sl].T, color=color, linewidth=2.5, marker=".", markersize=4)
        ax.scatter(*future[0, sl], color="k", s=30, depthshade=False, zorder=10)
        _predicted_paths(ax, paths, styles, sl, lo, hi, clipped, linewidth=2.0)
        ax.set_title(f"{name}, zoomed: the {len(future) - 1} predicted steps", fontsize="medium")
    handles = _paths_handles(labels, styles, clipped)
    fig.legend(handles=handles, loc="outside lower center", ncols=min(len(handles), 4),
               fontsize="small")  # fmt: skip
    fig.suptitle(title or f"Flight {example.flight}: vehicle and load paths, window from step "
                 f"{example.start}")  # fmt: skip
    return save_figure(fig, path)


def _whole_flight_panel(
    ax,
    flight: np.ndarray,
    future: np.ndarray,
    paths: Mapping[str, np.ndarray],
    styles: Mapping[str, LabelStyle],
    clipped: set[str],
) -> None:
    """The left panel: the flight's vehicle and load paths (flight: (T, state)), the predicted
    window thick, and every label's predicted paths (paths: label -> (N + 1, state))."""
    networks = [
        xyz[:, sl] for label, xyz in paths.items() if label != PHYSICS for sl in (POS, LOAD_POS)
    ]
    lo, hi = _frame(ax, np.concatenate([flight[:, POS], flight[:, LOAD_POS], *networks]))
    ax.plot(*flight[:, POS].T, color=TRUTH_COLOR, linewidth=0.7, alpha=0.45)
    ax.plot(*flight[:, LOAD_POS].T, color=LOAD_TRUTH_COLOR, linewidth=0.7, alpha=0.6)
    for sl, color in ((POS, TRUTH_COLOR), (LOAD_POS, LOAD_TRUTH_COLOR)):
        ax.plot(*future[:, sl].T, color=color, linewidth=2.5)
        ax.scatter(*future[0, sl], color="k", s=18, depthshade=False)
        # the whole flight is no zoom: a path cut here is not noted in the legend
        _predicted_paths(ax, paths, styles, sl, lo, hi, None, marker=None, linewidth=1.6)
    ax.set_title("whole flight, the window thick", fontsize="medium")


def _predicted_paths(
    ax,
    paths: Mapping[str, np.ndarray],
    styles: Mapping[str, LabelStyle],
    sl: slice,
    lo: np.ndarray,
    hi: np.ndarray,
    clipped: set[str] | None,
    **line: object,
) -> None:
    """Each label's predicted path (columns ``sl`` of (N + 1, state)) inside the frame
    [lo, hi] (m); the labels whose path is cut are added to ``clipped`` (None: not noted)."""
    # 3D axes do not clip: a path leaving the frame is cut at its edge (NaN outside).
    for i, (label, xyz) in enumerate(paths.items()):
        inside = np.all((xyz[:, sl] >= lo) & (xyz[:, sl] <= hi), axis=1)
        if clipped is not None and not inside.all():
            clipped.add(label)
        if inside.sum() >= 2:
            cut = np.where(inside[:, None], xyz[:, sl], np.nan)
            every = _markevery(len(cut), i, len(paths))
            ax.plot(*cut.T, **styles[label].line(markevery=every, **line))


def _paths_handles(
    labels: Sequence[str], styles: Mapping[str, LabelStyle], clipped: set[str]
) -> list:
    """Legend entries of ``plot_paths_3d``; a label cut at a zoom's edge says so."""
    handles: list = [
        Line2D([], [], color=TRUTH_COLOR, linewidth=2.5, label="vehicle, measured"),
        Line2D([], [], color=LOAD_TRUTH_COLOR, linewidth=2.5, label="load, measured"),
        Line2D([], [], color="0.3", linewidth=1.0, label="history (zooms), flight (left)"),
        Line2D([], [], color="k", marker="o", linestyle="none", label="prediction start"),
    ]
    for label in labels:
        note = " (cut at the zoom's edge)" if label in clipped else ""
        handles.append(Line2D([], [], label=f"{label}{note}", **styles[label].line(linewidth=2)))
    return handles


def _vertical(ax, x: float, text: str | None, **line: object) -> None:
    """A vertical line at ``x`` (solid: no predictor's line is), named at its top."""
    ax.axvline(x, zorder=1, **line)
    if text:
        ax.annotate(text, xy=(x, 1), xycoords=("data", "axes fraction"), xytext=(3, -3),
                    textcoords="offset points", ha="left", va="top", fontsize="x-small",
                    color=line.get("color", "k"))  # fmt: skip


def _vertical_handle(label: str, **line: object) -> Line2D:
    """A legend entry for a vertical line: a vertical tick, so that it never reads as one of
    the (horizontal) data lines."""
    width = line.get("linewidth", 1.0)
    return Line2D([], [], color=line.get("color", "k"), marker="|", linestyle="none",
                  markersize=14, markeredgewidth=width, label=label)  # fmt: skip


def _frame(ax, points: np.ndarray, margin: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """Axis limits around the finite ``points`` (P, 3) with equal scales (flat directions
    get at least a fifth of the largest span); returns the limits (lo, hi)."""
    pts = points[np.isfinite(points).all(axis=1)]
    if len(pts) == 0:
        pts = np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    span = np.maximum(hi - lo, 0.2 * (hi - lo).max() + 1e-3)
    mid = (lo + hi) / 2
    lo, hi = mid - span * (0.5 + margin), mid + span * (0.5 + margin)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo, zoom=0.8)  # room for the z label beside the next panel
    for axis in (ax.xaxis, ax.yaxis, ax.zaxis):
        axis.set_major_locator(MaxNLocator(4))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z, up (m)")
    return lo, hi
