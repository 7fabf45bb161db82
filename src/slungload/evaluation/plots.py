"""Figures of an evaluation (PNG): MAE per horizon step, one predicted window, 3D paths.

Figures are built on ``matplotlib.figure.Figure`` directly (PNG through Agg), so this module
never touches pyplot's global state or the user's backend. Each function writes one file
atomically and returns its path.

- ``plot_mae``: MAE vs horizon step per state group, 2x2, Q1-Q3 bands, dashed line at the
  training horizon (the paper's Figs 3 and 5, for any two or more labels).
- ``plot_prediction``: one test window, truth (solid) vs network (dashed) and physics (dotted)
  predictions for the four groups (the paper's Fig 4).
- ``plot_paths_3d``: vehicle and load paths of the example flight, with the predicted ones.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from ..fileio import atomic_path
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
PHYSICS_COLOR = "0.35"
HISTORY_LINE_COLOR = "0.55"
NETWORK_LINESTYLES = ("--", "-.", (0, (5, 1, 1, 1, 1, 1)), (0, (1, 1)))
DPI = 120


def label_colors(labels: Sequence[str], first: int = 0) -> dict[str, str]:
    """A stable colour per label: grey for physics, the tab10 cycle from ``first`` for the
    networks."""
    colors, i = {}, first
    for label in labels:
        if label == PHYSICS:
            colors[label] = PHYSICS_COLOR
        else:
            colors[label] = f"C{i % 10}"
            i += 1
    return colors


def label_linestyles(labels: Sequence[str]) -> dict[str, object]:
    """Dotted for physics, dashed (then dash-dot, ...) for the networks, as in the paper."""
    styles, i = {}, 0
    for label in labels:
        if label == PHYSICS:
            styles[label] = ":"
        else:
            styles[label] = NETWORK_LINESTYLES[i % len(NETWORK_LINESTYLES)]
            i += 1
    return styles


def plot_mae(
    curves: Mapping[str, Mapping[str, Curve]],
    path: str | Path,
    *,
    dt: float,
    training_horizon: int | None,
    title: str | None = None,
) -> Path:
    """MAE_k with Q1-Q3 bands per group, 2x2, one line per label.

    curves: label -> group -> ``Curve`` of N steps; dt (s) gives the top time axis;
    training_horizon draws the dashed vertical line (None: no line).
    """
    if not curves:
        raise ValueError("plot_mae: no curves to plot")
    colors = label_colors(list(curves))
    fig = Figure(figsize=(11, 7.5), layout="constrained")
    axes = fig.subplots(2, 2)
    for ax, group in zip(axes.flat, GROUPS, strict=True):
        for label, by_group in curves.items():
            c = by_group[group]
            k = np.arange(1, len(c.mean) + 1)
            ax.fill_between(k, c.q1, c.q3, color=colors[label], alpha=0.2, linewidth=0)
            ax.plot(k, c.mean, color=colors[label], label=f"{label} (MAE, Q1-Q3 band)")
        if training_horizon is not None:
            ax.axvline(training_horizon, color="k", linestyle="--", linewidth=1,
                       label=f"training horizon N = {training_horizon}")  # fmt: skip
        ax.set_title(GROUP_TITLES[group])
        ax.set_xlabel("horizon step k")
        unit = GROUP_UNITS[group]
        ax.set_ylabel(f"MAE ({unit})" if unit != "-" else "MAE (-)")
        ax.set_xlim(left=0)
        ax.set_ylim(bottom=0)
        ax.grid(alpha=0.3)
        top = ax.secondary_xaxis("top", functions=(lambda k: k * dt, lambda t: t / dt))
        top.set_xlabel("time ahead (s)")
    axes.flat[0].legend(loc="upper left", fontsize="small")
    fig.suptitle(title or f"Test-set MAE per horizon step: {' vs '.join(curves)}")
    return _save(fig, path)


def plot_prediction(
    example: Example,
    path: str | Path,
    *,
    dt: float,
    training_horizon: int | None,
    title: str | None = None,
) -> Path:
    """One test window: M history steps and N predicted steps, one panel per group.

    Truth solid, networks dashed, physics dotted; the prediction lines start at the last
    measured state. Vertical lines at the end of the history and at the training horizon.
    """
    m = example.history
    truth = example.window_states
    t = np.arange(len(truth)) * dt  # s from the window's first step
    t_pred = np.arange(m - 1, len(truth)) * dt
    labels = list(example.predictions)
    styles = label_linestyles(labels)
    fig = Figure(figsize=(10, 11), layout="constrained")
    axes = fig.subplots(len(GROUPS), 1, sharex=True)
    for ax, (group, sl) in zip(axes, GROUPS.items(), strict=True):
        for i in range(len(COMPONENTS[group])):
            color = f"C{i}"
            ax.plot(t, truth[:, sl][:, i], color=color, linewidth=1.5)
            for label in labels:
                pred = np.concatenate([truth[m - 1 : m, sl], example.predictions[label][:, sl]])
                ax.plot(t_pred, pred[:, i], color=color, linestyle=styles[label], linewidth=1.5)
        ax.axvline((m - 1) * dt, color=HISTORY_LINE_COLOR, linewidth=1.2)
        if training_horizon is not None and m - 1 + training_horizon < len(truth):
            ax.axvline((m - 1 + training_horizon) * dt, color="k", linestyle="--", linewidth=1)
        unit = GROUP_UNITS[group]
        ax.set_ylabel(f"{GROUP_TITLES[group]}" + (f" ({unit})" if unit != "-" else " (-)"))
        ax.grid(alpha=0.3)
        comp_handles = [
            Line2D([], [], color=f"C{i}", label=c) for i, c in enumerate(COMPONENTS[group])
        ]
        ax.legend(handles=comp_handles, loc="upper left", fontsize="small", ncols=4)
    axes[-1].set_xlabel("time from window start (s)")
    source_handles = [Line2D([], [], color="k", label="truth")]
    source_handles += [Line2D([], [], color="k", linestyle=styles[la], label=la) for la in labels]
    source_handles.append(
        Line2D([], [], color=HISTORY_LINE_COLOR, linewidth=1.2, label="end of history")
    )
    if training_horizon is not None:
        source_handles.append(
            Line2D(
                [],
                [],
                color="k",
                linestyle="--",
                linewidth=1,
                label=f"training horizon N = {training_horizon}",
            )  # fmt: skip
        )
    fig.legend(handles=source_handles, loc="outside lower center", ncols=len(source_handles))
    fig.suptitle(
        title
        or f"Flight {example.flight}, window from step {example.start}: "
        f"M = {m} history steps, N = {len(truth) - m} predicted"
    )
    return _save(fig, path)


def plot_paths_3d(example: Example, path: str | Path, *, title: str | None = None) -> Path:
    """3D vehicle and load paths of the example flight, with each label's predicted paths."""
    fig = Figure(figsize=(9, 8), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    flight = example.flight_states
    ax.plot(*flight[:, POS].T, color="C0", linewidth=0.8, alpha=0.5, label="vehicle (flight)")
    ax.plot(*flight[:, LOAD_POS].T, color="C1", linewidth=0.8, alpha=0.5, label="load (flight)")
    m = example.history
    future = example.window_states[m - 1 :]
    ax.plot(*future[:, POS].T, color="C0", linewidth=2.5, label="vehicle (window truth)")
    ax.plot(*future[:, LOAD_POS].T, color="C1", linewidth=2.5, label="load (window truth)")
    ax.scatter(*future[0, POS], color="k", s=20, label="prediction start")
    ax.scatter(*future[0, LOAD_POS], color="k", s=20)
    labels = list(example.predictions)
    styles, colors = label_linestyles(labels), label_colors(labels, first=2)
    for label, pred in example.predictions.items():
        for sl, legend in ((POS, f"{label} (vehicle and load)"), (LOAD_POS, None)):
            xyz = np.concatenate([future[:1, sl], pred[:, sl]])
            ax.plot(*xyz.T, color=colors[label], linestyle=styles[label], linewidth=1.8,
                    label=legend)  # fmt: skip
    finite = flight[np.isfinite(flight).all(axis=1)]
    pts = np.concatenate([finite[:, POS], finite[:, LOAD_POS]])
    span = np.ptp(pts, axis=0) if len(pts) else np.ones(3)
    ax.set_box_aspect(np.maximum(span, 0.05 * span.max() + 1e-9))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z, up (m)")
    ax.legend(loc="upper left", fontsize="small")
    ax.set_title(title or f"Flight {example.flight}: vehicle and load paths")
    return _save(fig, path)


def _save(fig: Figure, path: str | Path) -> Path:
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return path
