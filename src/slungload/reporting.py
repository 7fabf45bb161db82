"""What every report shares: its Markdown tables, its figure files, each model's colour, and the
stamp of the machine and the versions a measurement ran with.

- ``markdown_table(header, rows)``: one GitHub-flavoured table, cells as given.
- ``save_figure(fig, path)``: a ``matplotlib.figure.Figure`` as a PNG at ``DPI``, atomically.
- ``model_colors(labels)``: label -> colour, the same for a label in every figure: the physics
  model grey, every other label the colour its name picks, moved on only where an earlier label
  of the same figure holds it.
- ``write_csv(path, header, rows)``: one CSV, atomically, floats as their round-trip repr and
  None as an empty cell.
- ``mean_std(values)``: mean, sample std (0.0 for one value) and count: the mean ± std over
  seeds of every table.
- ``t975``, ``paired_interval``: Student's t at 97.5 % and the 95 % t-interval of paired
  differences; ``gap_share``, ``gap_interval``: the share of the physics-to-oracle gap a
  learned model closes and its paired bootstrap interval.
- ``cpu_model``, ``cpu_name``, ``device_name``, ``load_average``, ``machine``, ``versions``: the
  machine, the 1-min load average (None where the OS has none) and the package versions.

Used by the evaluation report, the benchmarks, the control comparison and the studies; torch-
free at import (matplotlib and torch are imported by the functions that need them).
"""

from __future__ import annotations

import csv
import importlib
import io
import math
import os
import platform
import statistics
import sys
import zlib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ._version import __version__
from .fileio import atomic_path, write_text

if TYPE_CHECKING:
    import torch
    from matplotlib.figure import Figure

DPI = 120  # every PNG the package writes
PHYSICS_LABEL = "physics"  # the physics model's label (``models.prediction.PHYSICS``)
PHYSICS_COLOR = "0.4"  # grey
# Colours of every other model: tab10 without its grey (C7), which is the physics model's.
MODEL_COLORS = ("C0", "C1", "C2", "C3", "C4", "C5", "C6", "C8", "C9")
GAP_RESAMPLES = 4000  # bootstrap resamples of the gap closed's interval (``gap_interval``)
GAP_MIN_FLIGHTS = 3  # flights below which ``gap_interval`` gives none


# --- tables and figures ------------------------------------------------------------------


def markdown_table(header: Sequence[object], rows: Iterable[Sequence[object]]) -> str:
    """A Markdown table (no trailing newline): ``header`` cells, then one line per row; cells
    are written with ``str`` (None as "-"), so format numbers before."""

    def line(cells: Sequence[object]) -> str:
        return "| " + " | ".join("-" if c is None else str(c) for c in cells) + " |"

    return "\n".join([line(header), "|" + "---|" * len(header), *(line(r) for r in rows)])


def smoke_banner(which: str, preset: str) -> list[str]:
    """The lines at the top of a report whose networks (``which``: "Every run", "The runs
    `a`, `b`", "The learned network `x`") trained with the smoke-test ``preset``."""
    return [
        "> **Smoke run: these numbers are not results.** "
        f"{which} trained with the `{preset}` preset: a few epochs on a few windows, to check "
        "that every stage runs. Their errors, ratios and figures say nothing about the method "
        "or the paper; train with `--preset default` (or `--preset paper`) for that.",
        "",
    ]


def networks_banner(networks: Sequence[str], preset: str) -> list[str]:
    """``smoke_banner`` for the networks named (no lines for none)."""
    if not networks:
        return []
    return smoke_banner("The networks " + ", ".join(f"`{n}`" for n in networks), preset)


def save_figure(fig: Figure, path: str | Path) -> Path:
    """Write ``fig`` as a PNG at ``DPI`` atomically (nothing at ``path`` on failure)."""
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=DPI)
    return path


def model_colors(labels: Iterable[str]) -> dict[str, str]:
    """One colour per model label (repeated labels once), for every figure that draws models.

    The physics model is ``PHYSICS_COLOR``; any other label takes the colour of
    ``MODEL_COLORS`` that its name picks (CRC-32, so the same in every figure, report and
    process), or, when an earlier label of ``labels`` holds that one, the next free one. No two
    labels share a colour until the palette is used up; then a new round starts. Build it
    once over all the labels of a report, so that every figure of it agrees.
    """
    colors: dict[str, str] = {}
    taken: set[str] = set()
    for label in labels:
        if label in colors:
            continue
        if label == PHYSICS_LABEL:
            colors[label] = PHYSICS_COLOR
            continue
        if len(taken) == len(MODEL_COLORS):
            taken.clear()
        first = zlib.crc32(label.encode())
        free = (MODEL_COLORS[(first + j) % len(MODEL_COLORS)] for j in range(len(MODEL_COLORS)))
        colors[label] = next(c for c in free if c not in taken)
        taken.add(colors[label])
    return colors


def write_csv(path: str | Path, header: Sequence[str], rows: Iterable[Sequence[object]]) -> Path:
    """Write a CSV atomically (``fileio.write_text``: the whole text is built first, so a row
    that cannot be written leaves the old file as it was and nothing beside it): ``header``,
    then one line per row, "\n" line ends; floats as their ``repr`` (which round-trips, so the
    file holds the numbers exactly), None as an empty cell, anything else as ``str``."""
    path = Path(path)
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(header)
    for row in rows:
        writer.writerow([_csv_cell(v) for v in row])
    write_text(path, buf.getvalue())
    return path


def _csv_cell(value: object) -> object:
    # repr of a float round-trips exactly, so the CSVs hold the Report's numbers.
    return repr(float(value)) if isinstance(value, float) else value


# --- statistics ----------------------------------------------------------------------------


def mean_std(values: Iterable[float]) -> tuple[float, float, int]:
    """(mean, sample standard deviation, count) of ``values`` (at least one): the mean ± std
    over seeds of every report; the std is 0.0 for a single value."""
    v = list(values)
    return statistics.fmean(v), statistics.stdev(v) if len(v) > 1 else 0.0, len(v)


# Student's t at 97.5 % for 1 .. 30 degrees of freedom (beyond: ``t975``'s expansion).
_T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
         2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
         2.060, 2.056, 2.052, 2.048, 2.045, 2.042)  # fmt: skip


def t975(dof: int) -> float:
    """Student's t at 97.5 % for ``dof`` >= 1 degrees of freedom: the table to 30, beyond it
    the Cornish-Fisher expansion about the normal's 1.96 (within 1e-4 of t from 30 on)."""
    if dof <= len(_T975):
        return _T975[dof - 1]
    z = 1.959963984540054
    return (z + (z**3 + z) / (4 * dof) + (5 * z**5 + 16 * z**3 + 3 * z) / (96 * dof**2)
            + (3 * z**7 + 19 * z**5 + 17 * z**3 - 15 * z) / (384 * dof**3))  # fmt: skip


def gap_share(physics: np.ndarray, learned: np.ndarray, oracle: np.ndarray) -> np.ndarray:
    """(physics - learned) / (physics - oracle) of means along the last axis: the share of the
    physics-to-oracle gap the learned model closes. Where the oracle is no better than physics
    there is no gap: +inf where the learned model is better than physics there, -inf where not
    (so that percentiles over resamples stay ordered)."""
    p, learn, o = (np.mean(x, axis=-1) for x in (physics, learned, oracle))
    closed, gap = p - learn, p - o
    with np.errstate(divide="ignore", invalid="ignore"):
        share = closed / gap
    return np.where(gap > 1e-12, share, np.where(closed > 0, np.inf, -np.inf))


def gap_interval(
    physics: Sequence[float],
    learned: Sequence[float],
    oracle: Sequence[float],
    resamples: int = GAP_RESAMPLES,
) -> tuple[float, float]:
    """95 % paired percentile-bootstrap interval of ``gap_share`` over flights (the three
    sequences hold one figure per flight, in the same order; flights are resampled together,
    with a fixed seed so a report is reproduced to the digit). Approximate: with the study's
    five seeds a percentile bootstrap tends to be narrow. NaN for fewer than
    ``GAP_MIN_FLIGHTS`` flights (two give three distinct resamples); a bound may be infinite
    where resamples leave no gap."""
    x = np.asarray([physics, learned, oracle], dtype=float)
    if x.shape[1] < GAP_MIN_FLIGHTS:
        return math.nan, math.nan
    picks = np.random.default_rng(0).integers(0, x.shape[1], size=(resamples, x.shape[1]))
    shares = gap_share(*x[:, picks])
    low, high = np.percentile(shares, (2.5, 97.5), method="inverted_cdf")
    return float(low), float(high)


def paired_interval(differences: Sequence[float]) -> tuple[float, float, float]:
    """Mean of paired differences and its 95 % t-interval (mean, low, high); NaN for none, the
    mean alone (an interval of zero width is never claimed) for one."""
    d = np.asarray([x for x in differences if math.isfinite(x)], dtype=float)
    if d.size == 0:
        return math.nan, math.nan, math.nan
    mean = float(d.mean())
    if d.size == 1:
        return mean, math.nan, math.nan
    t = t975(d.size - 1)
    half = t * float(d.std(ddof=1)) / math.sqrt(d.size)
    return mean, mean - half, mean + half


# --- the machine and the versions --------------------------------------------------------


def cpu_model() -> str | None:
    """The CPU model name from /proc/cpuinfo (Linux), else ``platform.processor()``, or None."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None


def cpu_name() -> str:
    """The CPU model, or the machine type where the OS names no model (e.g. "x86_64")."""
    return cpu_model() or platform.machine()


def device_name(device: torch.device) -> str:
    """A readable name of a torch device, e.g. "cpu (AMD EPYC 7B13)" or the CUDA GPU's name."""
    if device.type == "cuda":
        import torch

        return torch.cuda.get_device_name(device)
    return f"cpu ({cpu_name()})"


def load_averages() -> tuple[float, float, float] | None:
    """The machine's 1-, 5- and 15-min load averages; None where the OS has none (no
    ``os.getloadavg``, or it fails)."""
    try:
        one, five, fifteen = os.getloadavg()
    except (AttributeError, OSError):
        return None
    return one, five, fifteen


def load_average() -> float | None:
    """The machine's 1-min load average, or None where the OS has none."""
    loads = load_averages()
    return None if loads is None else loads[0]


def gpu_name() -> str | None:
    """The CUDA GPU's name where torch is loaded and sees one, else None (torch is not loaded
    for it: a process that never imported torch ran nothing on a GPU)."""
    torch = sys.modules.get("torch")
    if torch is None or not torch.cuda.is_available():
        return None
    return torch.cuda.get_device_name()


def machine() -> dict[str, Any]:
    """The stamp of a measurement: CPU, core count, the GPU (None where there is none), load
    averages (1, 5, 15 min; None where unknown), as plain data for a results file."""
    loads = load_averages()
    return {
        "cpu": cpu_name(),
        "cores": os.cpu_count(),
        "gpu": gpu_name(),
        "load_average": None if loads is None else list(loads),
    }


def machine_line() -> str:
    """The CPU and its cores in words, and the GPU where there is one, e.g. "AMD EPYC 7B13,
    2 cores"."""
    gpu = gpu_name()
    return f"{cpu_name()}, {os.cpu_count()} cores" + (f", GPU {gpu}" if gpu else "")


def versions(*packages: str) -> dict[str, str]:
    """slungload's version, then each package's ``__version__`` ("unknown" where it has none),
    in the order given; the packages must be importable."""
    found = {"slungload": __version__}
    for name in packages:
        found[name] = str(getattr(importlib.import_module(name), "__version__", "unknown"))
    return found
