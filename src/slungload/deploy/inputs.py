"""The one gate every whole-window predictor calls (``Predictor``, ``CompiledPredictor``,
``OnnxPredictor``): numpy only, so the onboard install runs it without torch.

``check_inputs`` checks ``predict``'s history (M, 17) or (B, M, 17) and future inputs (N, 4)
or (B, N, 4), in the data files' layout (``layout.HISTORY_COLUMNS``, quaternion x-y-z-w):
shapes, M equal to the trained history (unless any M is accepted), finite numbers (the error
names the row and the column), unit quaternions, and a guard against w-x-y-z quaternions in
the x-y-z-w columns.
"""

from __future__ import annotations

import numpy as np

from ..layout import HISTORY_COLUMNS, HISTORY_DIM, INPUT_DIM, INPUT_NAMES, QUAT

# A history quaternion whose norm is further than this from 1 is refused (the network
# normalises it, but a zero or far-off quaternion means wrong columns or a broken estimator).
QUAT_NORM_TOLERANCE = 0.1
# w-x-y-z in the x-y-z-w slot, seen in near-level flight: the file's w column (index 9) is near
# 0 in every history row while its qx column (index 6) is near +-1 (a level attitude's w).
_SWAPPED_W_BELOW, _SWAPPED_X_ABOVE = 0.3, 0.9


def check_inputs(
    history: np.ndarray,
    future_inputs: np.ndarray,
    *,
    caller: str = "Predictor.predict",
    history_rows: int | None = None,
) -> tuple[np.ndarray, np.ndarray, bool]:
    """Check ``predict``'s arguments; return them batched, (B, M, 17) and (B, N, 4), and
    whether they came unbatched. Errors start with ``caller``: shapes show expected and
    actual; history_rows (the trained M; None: any M >= 1) must match the history's rows;
    NaN / infinite values name the row and column; quaternions must be unit and x-y-z-w."""
    hist = np.asarray(history)
    fut = np.asarray(future_inputs)
    _check(hist, fut, caller)
    if history_rows is not None and hist.shape[-2] != history_rows:
        raise ValueError(
            f"{caller}: history has {hist.shape[-2]} rows, but the model was trained on "
            f"M = {history_rows} (window.history); pass the last {history_rows} rows"
        )
    single = hist.ndim == 2
    if single:
        hist, fut = hist[None], fut[None]
    _check_values(hist, fut, caller, single)
    return hist, fut, single


def unbatch(states: np.ndarray, single: bool) -> np.ndarray:
    """Network output (B, N, 13) -> float64, (N, 13) when the call was unbatched."""
    out = np.asarray(states, dtype=np.float64)
    return out[0] if single else out


def _check(history: np.ndarray, future: np.ndarray, caller: str) -> None:
    """Shape and value checks with the expected and the actual shapes in the message."""
    expected = (
        f"expected history (M, {HISTORY_DIM}) with future_inputs (N, {INPUT_DIM}), or "
        f"(B, M, {HISTORY_DIM}) with (B, N, {INPUT_DIM})"
    )
    got = f"got history {history.shape} and future_inputs {future.shape}"
    ok = (
        history.ndim in (2, 3)
        and future.ndim == history.ndim
        and history.shape[-1] == HISTORY_DIM
        and future.shape[-1] == INPUT_DIM
        and history.shape[-2] >= 1
        and future.shape[-2] >= 1
        and (history.ndim == 2 or history.shape[0] == future.shape[0])
    )
    if not ok:
        raise ValueError(f"{caller}: {expected}; {got}")
    for name, arr in (("history", history), ("future_inputs", future)):
        if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
            raise ValueError(f"{caller}: {name} has dtype {arr.dtype}, expected real numbers")


def _check_values(hist: np.ndarray, fut: np.ndarray, caller: str, single: bool) -> None:
    """Batched (B, M, 17) and (B, N, 4): finite, unit quaternions, x-y-z-w order."""

    def where(b: int, k: int) -> str:
        return f"row {k}" if single else f"window {b}, row {k}"

    for name, arr, columns in (
        ("history", hist, HISTORY_COLUMNS),
        ("future_inputs", fut, INPUT_NAMES),
    ):
        bad = ~np.isfinite(arr)
        if bad.any():
            b, k, c = (int(i) for i in np.argwhere(bad)[0])
            raise ValueError(
                f"{caller}: {name} holds NaN or infinite values: {where(b, k)}, column {c} "
                f"({columns[c]}) is {arr[b, k, c]} ({int(bad.sum())} such value(s) in all)"
            )
    quat = hist[..., QUAT].astype(np.float64)
    norm = np.linalg.norm(quat, axis=-1)  # (B, M)
    off = np.abs(norm - 1.0) > QUAT_NORM_TOLERANCE
    if off.any():
        b, k = (int(i) for i in np.argwhere(off)[0])
        cols = ", ".join(HISTORY_COLUMNS[QUAT])
        raise ValueError(
            f"{caller}: history {where(b, k)} has a quaternion of norm {norm[b, k]:.3g} in "
            f"columns {QUAT.start}-{QUAT.stop - 1} ({cols}, x-y-z-w order); expected a unit "
            f"quaternion (|norm - 1| <= {QUAT_NORM_TOLERANCE})"
        )
    unit = quat / norm[..., None]
    swapped = (np.abs(unit[..., 3]) < _SWAPPED_W_BELOW) & (np.abs(unit[..., 0]) > _SWAPPED_X_ABOVE)
    for b in np.flatnonzero(swapped.all(axis=-1)):
        raise ValueError(
            f"{caller}: history{'' if single else f' window {b}'} looks like w-x-y-z "
            f"quaternions in the x-y-z-w columns: column {QUAT.start} "
            f"({HISTORY_COLUMNS[QUAT.start]}) is near +-1 and column {QUAT.stop - 1} "
            f"({HISTORY_COLUMNS[QUAT.stop - 1]}) near 0 in every row (read as x-y-z-w: a "
            "vehicle upside down). The order is x-y-z-w, as in the data files: move w to the "
            "last quaternion column"
        )
