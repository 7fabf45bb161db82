"""The commands that need no torch start without it: --help, maneuvers, simulate, inspect,
split and import run in a process where torch, Lightning and Ray cannot be imported; and a
flight read without torch is the flight read before, to the bit."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from log_files import PARAMS, default_columns, truth, write_csv

from slungload import frames, state
from slungload.data.readers import load_flight
from slungload.data.readers.npz import from_arrays
from slungload.fileio import read_npz
from slungload.load_state import estimate_load_state
from slungload.sim import simulate_dataset

BLOCK = """
import importlib.abc, sys
class Blocked(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split(".")[0] in ("torch", "lightning", "ray", "roma"):
            raise ImportError(f"{name} is blocked in this test")
sys.meta_path.insert(0, Blocked())
"""


def run_blocked(body: str, tmp_path: Path) -> str:
    """``body`` in a fresh interpreter that cannot import torch, Lightning, Ray or roma."""
    code = BLOCK + textwrap.dedent(body)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=tmp_path, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


@pytest.mark.slow
def test_the_commands_that_need_no_torch_run_without_it(tmp_path):
    a = truth(PARAMS.dt * np.arange(400))
    log = write_csv(tmp_path / "flight.csv", default_columns(a))
    out = run_blocked(
        f"""
        from slungload.cli import main
        try:
            main(["--help"])
        except SystemExit as e:
            assert e.code == 0
        assert main(["maneuvers"]) == 0
        assert main(["simulate", "--flights", "4", "--out", "sim", "--quiet"]) == 0
        assert main(["inspect", "sim"]) == 0
        assert main(["split", "sim", "--val", "0.25", "--test", "0.25", "--overwrite"]) == 0
        assert main(["import", "/nonexistent", "--out", "x"]) == 2
        assert main(["import", {str(log)!r}, "--out", "imported", "--quiet"]) == 0
        assert main(["inspect", "imported"]) == 0
        import sys
        print("loaded:", sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "roma")))
        """,
        tmp_path,
    )
    assert "loaded: []" in out
    assert (tmp_path / "sim" / "train.txt").is_file() and (tmp_path / "imported").is_dir()


def test_a_flight_read_without_torch_is_the_flight_read_with_it(tmp_path):
    simulate_dataset(tmp_path, flights=3, seed=1, workers=1, progress=False)
    for path in sorted(tmp_path.glob("*.npz")):
        raw = read_npz(path)
        light = from_arrays(raw, path, PARAMS)
        assert light.aux is None
        # the construction of before: torch's quaternion order, continuity and join
        quat = torch.from_numpy(raw["attitude"] / np.linalg.norm(raw["attitude"], axis=1)[:, None])
        before = state.join_state(
            torch.from_numpy(raw["p"]), torch.from_numpy(raw["v"]),
            state.quat_continuous(state.quat_xyzw_to_wxyz(quat)), torch.from_numpy(raw["p_load"]),
        ).numpy()  # fmt: skip
        assert np.array_equal(light.states, before)
        read = load_flight(path, PARAMS, [])
        assert np.array_equal(read.states, before)
        assert np.array_equal(read.aux, estimate_load_state(before, PARAMS))


def test_numpy_and_torch_keep_quaternions_continuous_alike():
    rng = np.random.default_rng(0)
    q = rng.normal(size=(2, 50, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q *= rng.choice([-1.0, 1.0], size=(2, 50, 1))  # sign jumps
    got = frames.quat_continuous(q)
    assert np.array_equal(got, state.quat_continuous(torch.from_numpy(q)).numpy())
    assert ((got[:, 1:] * got[:, :-1]).sum(-1) >= 0).all()
    assert np.array_equal(np.abs(got), np.abs(q)) and np.array_equal(got[:, 0], q[:, 0])


def test_windows_refuse_a_flight_read_without_its_load_state(tmp_path):
    from slungload.config import WindowConfig
    from slungload.data.windows import make_windows

    simulate_dataset(tmp_path, flights=3, seed=1, workers=1, progress=False)
    path = sorted(tmp_path.glob("*.npz"))[0]
    light = load_flight(path, PARAMS, [], load_state=False)
    with pytest.raises(ValueError, match="read without its load-state estimate"):
        make_windows([light], WindowConfig(history=5, horizon=5))
    windows = make_windows([light.with_load_state(PARAMS)], WindowConfig(history=5, horizon=5))
    assert len(windows.states) == len(light) - 9
