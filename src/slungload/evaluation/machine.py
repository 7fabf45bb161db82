"""The machine a measurement ran on: device and CPU names, for reports and benchmarks."""

from __future__ import annotations

import platform
from pathlib import Path

import torch


def device_name(device: torch.device) -> str:
    """A readable name of a torch device, e.g. "cpu (AMD EPYC 7B13)" or the CUDA GPU's name."""
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return f"cpu ({cpu_model() or platform.machine()})"


def cpu_model() -> str | None:
    """The CPU model name from /proc/cpuinfo (Linux), else ``platform.processor()``, or None."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or None
