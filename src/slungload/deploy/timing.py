"""Batch-1 inference time: the one timing loop (``time_calls``), used by the evaluation report
(eager network and compiled predictor beside the paper's Table II) and by ``benchmark``."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch
from torch import nn
from tqdm.auto import tqdm

from ..config import VehicleParams
from ..data.windows import Windows
from ..evaluation.evaluator import evaluate
from ..evaluation.results import Report, Timing, TimingResult
from ..reporting import device_name, load_average
from .compiled import CompiledPredictor, unsupported
from .predictor import Predictor, states_to_file


def time_calls(
    call: Callable[[int], object],
    repeats: int,
    warmup: int,
    sync: Callable[[], None] = lambda: None,
) -> tuple[list[float], list[float]]:
    """Wall-clock and calling-thread CPU seconds of ``call(i)`` for i = 0 ... repeats-1, after
    ``warmup`` untimed calls. ``sync`` waits for the device before and after each call (CUDA
    runs asynchronously). On one thread the two agree on an idle machine; on a shared one the
    CPU time leaves out the time other processes held the core."""
    for i in range(warmup):
        call(i)
    wall, cpu = [], []
    for i in range(repeats):
        sync()
        t0, c0 = time.perf_counter(), time.thread_time()
        call(i)
        sync()
        cpu.append(time.thread_time() - c0)
        wall.append(time.perf_counter() - t0)
    return wall, cpu


def _timing(
    windows: Windows,
    seconds: list[float],
    *,
    threads: int,
    device: torch.device,
    backend: str = "torch eager",
) -> Timing:
    """The record of one timed backend: mean and std (ms) of ``seconds``, where and how."""
    ms = [1e3 * s for s in seconds]
    return Timing(
        history=windows.window.history,
        horizon=windows.window.horizon,
        mean_ms=statistics.fmean(ms),
        std_ms=statistics.stdev(ms),
        repeats=len(ms),
        threads=threads,
        device=device_name(device),
        backend=backend,
        load_average=load_average(),
    )


def time_inference(
    model: nn.Module,
    windows: Windows,
    *,
    repeats: int = 100,
    warmup: int = 10,
    device: str | torch.device = "cpu",
) -> Timing:
    """Time ``model`` on the first window of ``windows`` (batch 1), after ``warmup`` calls."""
    m, w = _timing_window("time_inference", windows, repeats)
    dev = torch.device(device)
    w = w.to(dev)
    args = (w.states[:, :m], w.inputs[:, :m], w.inputs[:, m:])
    sync: Callable[[], None] = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    model.eval()
    model.to(dev)
    with torch.inference_mode():
        wall, _ = time_calls(lambda i: model(*args), repeats, warmup, sync)
    return _timing(windows, wall, threads=torch.get_num_threads(), device=dev)


def time_compiled(
    compiled: CompiledPredictor, windows: Windows, *, repeats: int = 100, warmup: int = 10
) -> Timing:
    """Time ``compiled.predict`` on the first window of ``windows`` (batch 1, one thread),
    numpy in and out in the file layout, as a controller calls it."""
    m, w = _timing_window("time_compiled", windows, repeats)
    history = torch.cat([states_to_file(w.states[:, :m]), w.inputs[:, :m]], -1)[0].numpy()
    future = w.inputs[0, m:].numpy()
    wall, _ = time_calls(lambda i: compiled.predict(history, future), repeats, warmup)
    return _timing(windows, wall, threads=1, device=torch.device("cpu"), backend="numba compiled")


def _timing_window(caller: str, windows: Windows, repeats: int) -> tuple[int, Windows]:
    """History length M and the first window (batch 1) to time on, after checking both."""
    if repeats < 2:
        raise ValueError(f"{caller}: repeats must be >= 2, got {repeats}")
    if len(windows) == 0:
        raise ValueError(f"{caller}: no window to time on")
    return windows.window.history, windows[0]


def time_models(
    models: Sequence[tuple[str, int | None, nn.Module]],
    windows: dict[int, Windows],
    *,
    params: VehicleParams,
    repeats: int = 100,
    device: str | torch.device = "cpu",
    progress: bool = False,
) -> tuple[TimingResult, ...]:
    """Batch-1 time of each (label, seed, network) at every horizon of ``windows``: the eager
    network on ``device`` and, for the architectures it supports, the compiled predictor (one
    CPU thread) beside it, ``repeats`` timed calls each. An architecture the compiled predictor
    does not support is timed eager only (``compiled.unsupported`` says why)."""
    horizons = sorted(windows)
    bar = tqdm(total=len(models) * len(horizons), desc=f"timing ({repeats} calls each)",
               disable=None if progress else True)  # fmt: skip
    out = []
    for label, seed, model in models:
        compiled = None
        if unsupported(model) is None:  # compiles once per network, not per horizon
            window = windows[horizons[0]].window
            compiled = CompiledPredictor(Predictor(model, window, params, label))
        for n in horizons:
            timing = time_inference(model, windows[n], repeats=repeats, device=device)
            out.append(TimingResult(label, seed, timing))
            if compiled is not None:
                timing = time_compiled(compiled, windows[n], repeats=repeats)
                out.append(TimingResult(label, seed, timing))
            bar.update()
    bar.close()
    return tuple(out)


def evaluate_runs(
    runs: Sequence[str | Path],
    *,
    timing: bool = False,
    timing_repeats: int = 100,
    device: str = "cpu",
    progress: bool = True,
    **options: Any,
) -> Report:
    """``evaluation.evaluate`` with, if ``timing``, the batch-1 time of every network (eager
    on ``device`` and the compiled predictor, ``timing_repeats`` calls each) in its report.
    ``options`` go to ``evaluate`` (data, out, horizons, include_physics, ...)."""
    timer = None
    if timing:

        def timer(networks, windows, params):  # an evaluator.Timer
            return time_models(
                networks,
                windows,
                params=params,
                repeats=timing_repeats,
                device=device,
                progress=progress,
            )

    return evaluate(runs, timer=timer, device=device, progress=progress, **options)
