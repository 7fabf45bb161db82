"""What every report shares: its Markdown tables, its figure files, each model's colour, and the
stamp of the machine and the versions a measurement ran with.

- ``markdown_table(header, rows)``: one GitHub-flavoured table, cells as given.
- ``save_figure(fig, path)``: a ``matplotlib.figure.Figure`` as a PNG at ``DPI``, atomically.
- ``model_colors(labels)``: label -> colour, the same for a label in every figure: the physics
  model grey, every other label the colour its name picks, moved on only where an earlier label
  of the same figure holds it.
- ``cpu_model``, ``cpu_name``, ``device_name``, ``load_average``, ``machine``, ``versions``: the
  machine, the 1-min load average (None where the OS has none) and the package versions.

Used by the evaluation report, the benchmarks, the control comparison and the studies; numpy-
and torch-free at import (matplotlib and torch are imported by the functions that need them).
"""

from __future__ import annotations

import importlib
import os
import platform
import sys
import zlib
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ._version import __version__
from .fileio import atomic_path

if TYPE_CHECKING:
    import torch
    from matplotlib.figure import Figure

DPI = 120  # every PNG the package writes
PHYSICS_LABEL = "physics"  # the physics model's label (``models.prediction.PHYSICS``)
PHYSICS_COLOR = "0.4"  # grey
# Colours of every other model: tab10 without its grey (C7), which is the physics model's.
MODEL_COLORS = ("C0", "C1", "C2", "C3", "C4", "C5", "C6", "C8", "C9")


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
