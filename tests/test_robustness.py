"""Bad input, untrusted files, interruptions and numerical faults, seen from the outside.

The library-level checks of each bad flight live in ``test_data.py``; here the same faults go
through the command line (``slungload.cli.main``), which must print one line naming the file
or option and exit with status 2, never a traceback. Then: pickled code in checkpoints,
atomic outputs, killed and interrupted training, and non-finite losses.
"""

from __future__ import annotations

import csv
import importlib
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import SMALL, WINDOW_ARGS, flight_arrays

from slungload.fileio import write_npz
from slungload.models.checkpoints import load_checkpoint
from slungload.run_config import PRESETS, Preset
from slungload.training.runtime import AtomicCheckpointIO
from slungload.training.trainer import TrainingInterrupted

# `slungload.training` the attribute is the function; the module is needed for monkeypatching.
train_module = importlib.import_module("slungload.training.module")  # where the loss is called
torch.set_num_threads(1)


def assert_one_line_error(code: int, err: str, *names: str) -> str:
    """Exit 2, one line on stderr naming each of ``names``, no traceback."""
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    for name in names:
        assert name in lines[0], (name, lines[0])
    return lines[0]


# --- bad datasets through `slungload inspect` and `slungload train` -------------------------


def _replace(key: str, value: Callable[[np.ndarray], np.ndarray]) -> Callable[[dict], None]:
    def change(arrays: dict) -> None:
        arrays[key] = value(arrays[key].copy())

    return change


def _set(key: str, index: tuple | int, new: float | list) -> Callable[[dict], None]:
    def value(a: np.ndarray) -> np.ndarray:
        a[index] = new
        return a

    return _replace(key, value)


def _drop(key: str) -> Callable[[dict], None]:
    return lambda arrays: arrays.pop(key)


def _time_back(t: np.ndarray) -> np.ndarray:
    t[20] = t[18]
    return t


def _time_gap(t: np.ndarray) -> np.ndarray:
    t[25:] += 0.05
    return t


# case -> (change to the arrays of flight f0, words the error line must hold)
BAD_FLIGHT = {
    "missing key": (_drop("p_load"), ["missing keys", "p_load"]),
    "shape": (_replace("v", lambda a: a[:, :2]), ["v has shape", "expected"]),
    "length": (_replace("w_ref", lambda a: a[:-1]), ["w_ref has 39 steps", "time has 40"]),
    "nan": (_set("p", (7, 1), np.nan), ["p holds nan at step 7"]),
    "inf": (_set("T_ref", (3, 0), np.inf), ["T_ref holds inf at step 3"]),
    "time back": (_replace("time", _time_back), ["not strictly increasing at index 20"]),
    "time gap": (_replace("time", _time_gap), ["time step from index 24 to 25", "dt = 0.03"]),
    "quaternion": (_set("attitude", 12, [0, 0, 0, 1.5]), ["attitude at step 12", "unit"]),
}


@pytest.mark.parametrize("command", ["inspect", "train"])
@pytest.mark.parametrize("case", BAD_FLIGHT)
def test_bad_flight_is_one_line_naming_the_file(tmp_path, case, command, write_dataset, run_cli):
    folder = write_dataset(tmp_path / "ds")
    arrays = flight_arrays(40, seed=0)
    change, words = BAD_FLIGHT[case]
    change(arrays)
    write_npz(folder / "f0.npz", arrays)
    if command == "inspect":
        argv = ["inspect", folder, *WINDOW_ARGS]
    else:
        argv = ["train", "--data", folder, "--out", tmp_path / "run", "--preset", "quick"]
        argv += ["--quiet", *WINDOW_ARGS]
    code, _, err = run_cli(*argv)
    assert_one_line_error(code, err, str(folder / "f0.npz"), *words)
    assert not (tmp_path / "run").exists()  # nothing half-made left behind


def _random_bytes(path: Path) -> None:
    path.write_bytes(np.random.default_rng(0).bytes(300))


def _truncated(path: Path) -> None:
    path.write_bytes(path.read_bytes()[:500])


def _pickled(path: Path) -> None:
    np.savez(path, **flight_arrays(40), extra=np.array([{"a": 1}], dtype=object))


def _empty(path: Path) -> None:
    path.write_bytes(b"")


def _unknown_compression(path: Path) -> None:
    raw = bytearray(path.read_bytes())
    entry = raw.find(b"PK\x01\x02")  # first central-directory entry
    raw[entry + 10] = 99  # its compression method: none that exists
    path.write_bytes(bytes(raw))


BAD_FILE = {
    "random bytes": (_random_bytes, "not a zip archive"),
    "truncated": (_truncated, "cannot be read as .npz"),
    "empty": (_empty, "cannot be read as .npz"),
    "unknown compression": (_unknown_compression, "compression method is not supported"),
    "pickled objects": (_pickled, "pickled objects, which are refused"),
}


@pytest.mark.parametrize("case", BAD_FILE)
def test_unreadable_flight_file_is_one_line(tmp_path, case, write_dataset, run_cli):
    folder = write_dataset(tmp_path / "ds")
    spoil, words = BAD_FILE[case]
    spoil(folder / "f1.npz")
    code, _, err = run_cli("inspect", folder, *WINDOW_ARGS)
    assert_one_line_error(code, err, str(folder / "f1.npz"), words)


def _write(name: str, text: str | bytes) -> Callable[[Path], None]:
    def spoil(folder: Path) -> None:
        path = folder / name
        path.write_bytes(text) if isinstance(text, bytes) else path.write_text(text)

    return spoil


def _remove_flights(folder: Path) -> None:
    for path in folder.glob("*.npz"):
        path.unlink()


# case -> (spoil the dataset folder, what the error line names)
BAD_FOLDER = {
    "no flights": (_remove_flights, ["holds no flight files"]),
    "split names a missing flight": (_write("val.txt", "f2\nghost\n"), ["val.txt", "ghost"]),
    "flight listed twice": (_write("train.txt", "f0\nf1\nf0\n"), ["train.txt", "listed twice"]),
    "flight in two splits": (_write("test.txt", "f0\n"), ["test.txt", "also listed in train"]),
    "split list not text": (_write("train.txt", b"\xff\xfe\x00bad"), ["train.txt", "text"]),
    "vehicle.json not JSON": (_write("vehicle.json", "{mass"), ["vehicle.json", "JSON"]),
    "vehicle.json bad value": (
        _write("vehicle.json", json.dumps({"dt": -0.03})),
        ["vehicle.json", "dt must be > 0"],
    ),
    "vehicle.json unknown key": (
        _write("vehicle.json", json.dumps({"mass": 1.0})),
        ["vehicle.json", "unknown keys", "mass"],
    ),
}


@pytest.mark.parametrize("case", BAD_FOLDER)
def test_bad_dataset_folder_is_one_line(tmp_path, case, write_dataset, run_cli):
    folder = write_dataset(tmp_path / "ds")
    spoil, words = BAD_FOLDER[case]
    spoil(folder)
    code, _, err = run_cli("inspect", folder, *WINDOW_ARGS)
    assert_one_line_error(code, err, *words)


def test_missing_path_and_file_instead_of_folder(tmp_path, run_cli):
    code, _, err = run_cli("inspect", tmp_path / "nowhere")
    assert_one_line_error(code, err, str(tmp_path / "nowhere"), "does not exist")
    (tmp_path / "file.npz").write_bytes(b"")
    code, _, err = run_cli("inspect", tmp_path / "file.npz")
    assert_one_line_error(code, err, str(tmp_path / "file.npz"), "not a folder")


def test_unknown_keys_are_a_note_not_an_error(tmp_path, write_dataset, run_cli):
    folder = write_dataset(tmp_path / "ds")
    write_npz(folder / "f0.npz", {**flight_arrays(40), "battery_voltage": np.ones(40)})
    with pytest.warns(UserWarning, match="battery_voltage"):
        code, out, _ = run_cli("inspect", folder, *WINDOW_ARGS)
    assert code == 0
    assert "note:" in out and "battery_voltage" in out


def test_flights_shorter_than_a_window(tmp_path, write_dataset, run_cli):
    folder = write_dataset(tmp_path / "ds", {"f0": 40, "f1": 8, "f2": 40, "f3": 40})
    # inspect lists the short flight; train skips it with a warning and trains on the rest.
    code, out, _ = run_cli("inspect", folder, *WINDOW_ARGS)
    assert code == 0 and "skipped (fewer than M + N = 10 steps): f1" in out
    # None left: one line naming the folder and the longest flight.
    argv = ["train", "--data", folder, "--out", tmp_path / "run", "--quiet"]
    code, _, err = run_cli(*argv, "--history", "30", "--horizon", "20")
    assert_one_line_error(code, err, str(folder), "no flight left", "M + N = 50", "longest has 40")


BAD_OPTIONS = {
    "history 0": (["--history", "0"], ["history", ">= 1"]),
    "resume without a run": (["--resume"], ["cannot resume", "last.ckpt"]),
    "devices 0": (["--devices", "0"], ["devices", ">= 1"]),
    "threads 0": (["--threads", "0"], ["thread"]),
    "epochs 0": (["--epochs", "0"], ["epochs"]),
}


@pytest.mark.parametrize("case", BAD_OPTIONS)
def test_bad_train_options_are_one_line(tmp_path, case, write_dataset, run_cli):
    folder = write_dataset(tmp_path / "ds")
    extra, words = BAD_OPTIONS[case]
    argv = ["train", "--data", folder, "--out", tmp_path / "run", "--preset", "quick", "--quiet"]
    code, _, err = run_cli(*argv, *WINDOW_ARGS, *extra)
    assert_one_line_error(code, err, *words)


# --- untrusted checkpoints ------------------------------------------------------------------


class _Marker:
    """Unpickling this creates ``path`` (opens it for writing): proof that code ran."""

    def __init__(self, path: Path) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (str(self.path), "w"))


def test_checkpoint_with_pickled_code_is_refused_and_never_run(tmp_path, tiny_run, run_cli):
    marker = tmp_path / "code_ran"
    run = tmp_path / "evil_run"
    run.mkdir()
    ckpt = torch.load(tiny_run.out / "best.ckpt", weights_only=True)
    torch.save({**ckpt, "slungload": {**ckpt["slungload"], "extra": _Marker(marker)}},
               run / "best.ckpt")  # fmt: skip
    (run / "last.ckpt").write_bytes((run / "best.ckpt").read_bytes())

    with pytest.raises(ValueError, match="pickled Python objects.*refused") as info:
        load_checkpoint(run)
    assert str(run / "best.ckpt") in str(info.value) and "it calls io.open" in str(info.value)
    code, _, err = run_cli("evaluate", run, "--out", tmp_path / "report", "--no-timing")
    assert_one_line_error(code, err, str(run / "best.ckpt"), "refused")
    argv = ["train", "--data", tiny_run.data, "--out", run, "--resume", "--quiet"]
    code, _, err = run_cli(*argv, *WINDOW_ARGS)
    assert_one_line_error(code, err, str(run / "last.ckpt"), "refused")
    assert not marker.exists()


def test_dataset_cache_with_pickled_code_is_rebuilt_never_run(tmp_path, write_dataset):
    from slungload.data.dataset import load_dataset
    from slungload.data.flight import DataWarning

    marker = tmp_path / "code_ran"
    data = write_dataset(tmp_path / "ds")
    first = load_dataset(data, window=SMALL, cache_dir=tmp_path / "cache")
    torch.save({"version": 1, "key": "x", "payload": _Marker(marker)}, first.cache_path)
    with pytest.warns(DataWarning, match="bad cache"):
        again = load_dataset(data, window=SMALL, cache_dir=tmp_path / "cache")
    assert not again.from_cache and not marker.exists()
    assert torch.equal(again.splits["train"].states, first.splits["train"].states)


def _edit_meta(src: Path, dst: Path, edit: Callable[[dict], None]) -> Path:
    ckpt = torch.load(src, weights_only=True)
    edit(ckpt["slungload"])
    torch.save(ckpt, dst)
    return dst


BAD_META = {
    "format": (lambda m: m.update(format=99), "uses checkpoint format 99.*reads format 1"),
    "unknown model key": (
        lambda m: m["model"].update(attention_heads=4),
        r"written by slungload .* does not fit .*unknown keys \['attention_heads'\]",
    ),
    "missing section": (lambda m: m.pop("window"), "does not fit.*KeyError: 'window'"),
    "other network size": (
        lambda m: m["model"].update(hidden_size=9),
        "does not fit.*size mismatch",
    ),
}


@pytest.mark.parametrize("case", BAD_META)
def test_checkpoint_of_another_version_or_config_says_what_differs(tmp_path, tiny_run, case):
    edit, problem = BAD_META[case]
    path = _edit_meta(tiny_run.out / "best.ckpt", tmp_path / "other.ckpt", edit)
    with pytest.raises(ValueError, match=problem) as info:
        load_checkpoint(path)
    assert str(path) in str(info.value) and len(str(info.value).splitlines()) == 1


def test_resume_with_other_settings_names_them(tmp_path, tiny_run, run_cli):
    run = tmp_path / "run"
    run.mkdir()
    (run / "last.ckpt").write_bytes((tiny_run.out / "last.ckpt").read_bytes())
    argv = ["train", "--data", tiny_run.data, "--out", run, "--resume", "--quiet"]
    code, _, err = run_cli(*argv, "--variant", "no-physics", "--history", "6", "--horizon", "5")
    line = assert_one_line_error(code, err, "cannot resume", str(run / "last.ckpt"))
    assert "variant: 'proposed' -> 'no-physics'" in line and "window.horizon: 4 -> 5" in line


# --- atomic outputs -------------------------------------------------------------------------


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "flight.npz"
    write_npz(path, flight_arrays(40))
    before = path.read_bytes()

    class Boom:
        def __array__(self, *args, **kwargs):
            raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_npz(path, {**flight_arrays(40), "zz_last": Boom()})  # fails after other members
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flight.npz"]


def test_checkpoints_are_written_through_a_temporary_name(tmp_path, monkeypatch, tiny_run):
    path = tmp_path / "last.ckpt"
    path.write_bytes((tiny_run.out / "last.ckpt").read_bytes())
    before = path.read_bytes()

    def dies_half_way(obj, f, *args, **kwargs):
        Path(f).write_bytes(before[: len(before) // 2])
        raise KeyboardInterrupt  # killed while writing

    monkeypatch.setattr(torch, "save", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        AtomicCheckpointIO().save_checkpoint({"state_dict": {}}, path)
    assert path.read_bytes() == before and load_checkpoint(path).variant == "proposed"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.ckpt"]


# --- interruptions --------------------------------------------------------------------------


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    end = time.monotonic() + timeout
    while not path.is_file():
        assert proc.poll() is None, proc.communicate()[1][-3000:]
        assert time.monotonic() < end, f"{path} did not appear"
        time.sleep(0.02)


@pytest.mark.slow
def test_sigkill_mid_run_then_resume_gives_the_uninterrupted_weights(
    tmp_path, subprocess_env, write_dataset, train_command, weights_of
):
    data = write_dataset(tmp_path / "ds")
    epochs = ("--epochs", "6")
    killed = tmp_path / "killed"
    proc = subprocess.Popen(train_command(data, killed, *epochs), env=subprocess_env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    _wait_for(killed / "last.ckpt", proc)
    proc.kill()  # SIGKILL: no handler runs, no file is finished
    proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    at_kill = torch.load(killed / "last.ckpt", weights_only=True)["epoch"]

    env = subprocess_env
    done = subprocess.run(train_command(data, killed, *epochs, "--resume"), env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads((killed / "run.json").read_text())["epochs"] == 6
    straight = tmp_path / "straight"
    done = subprocess.run(train_command(data, straight, *epochs), env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    # The killed run resumed from an epoch boundary: same seed, same windows, same weights.
    a, b = weights_of(killed / "last.ckpt"), weights_of(straight / "last.ckpt")
    assert all(torch.allclose(a[k], b[k], atol=1e-6) for k in a), f"killed after epoch {at_kill}"
    loaded = load_checkpoint(killed)
    x = torch.zeros(1, SMALL.history, 13), torch.zeros(1, SMALL.history, 4)
    x[0][..., 6] = 1.0  # unit quaternions
    assert torch.isfinite(loaded.model(*x, torch.zeros(1, SMALL.horizon, 4)).states).all()


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_signal_saves_last_checkpoint_and_resume_finishes(
    tmp_path, subprocess_env, signum, write_dataset, train_command
):
    data = write_dataset(tmp_path / "ds")
    out = tmp_path / "run"
    # Many windows per epoch so that the signal lands in the middle of one.
    epochs = ("--epochs", "3")
    proc = subprocess.Popen(train_command(data, out, *epochs), env=subprocess_env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    _wait_for(out / "last.ckpt", proc)
    step_before = torch.load(out / "last.ckpt", weights_only=True)["global_step"]
    proc.send_signal(signum)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 128 + signum, err[-3000:]
    assert f"stopped by {signal.Signals(signum).name}" in err and "resume" in err
    assert "Traceback" not in err
    saved = torch.load(out / "last.ckpt", weights_only=True)
    assert saved["global_step"] >= step_before
    assert not (out / "run.json").exists()  # not a finished run

    done = subprocess.run(train_command(data, out, *epochs, "--resume"), env=subprocess_env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert json.loads((out / "run.json").read_text())["epochs"] == 3
    assert load_checkpoint(out).variant == "proposed"


# --- numerical faults -----------------------------------------------------------------------


def _nan_loss_on(steps: Callable[[int], bool], monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Make the training loss NaN on the calls ``steps(call)`` picks; returns the call log."""
    calls: list[int] = []
    original = train_module.compute_loss

    def compute_loss(*args, **kwargs):
        terms = original(*args, **kwargs)
        training = torch.is_grad_enabled()
        if training:
            calls.append(len(calls))
            if steps(calls[-1]):
                return terms._replace(total=terms.total * float("nan"))
        return terms

    monkeypatch.setattr(train_module, "compute_loss", compute_loss)
    return calls


@pytest.mark.filterwarnings("ignore:non-finite training loss")  # one is checked below
def test_non_finite_loss_steps_are_skipped_and_counted(
    tmp_path, monkeypatch, write_dataset, train_tiny, weights_of
):
    data = write_dataset(tmp_path / "ds")
    calls = _nan_loss_on(lambda i: i % 3 == 1, monkeypatch)
    with pytest.warns(UserWarning, match="non-finite training loss at epoch 0, batch 1"):
        run = train_tiny(data, tmp_path / "run")
    assert run.skipped_steps == sum(1 for i in calls if i % 3 == 1) > 0
    assert "steps skipped (loss or gradients not finite)" in run.summary()
    assert np.isfinite(run.best_val_loss)
    assert all(torch.isfinite(w).all() for w in weights_of(run.last_checkpoint).values())
    rows = csv.DictReader((tmp_path / "run" / "csv" / "metrics.csv").open())
    logged = [(float(r["train/skipped_steps"]), float(r["train/total"])) for r in rows
              if r.get("train/skipped_steps")]  # fmt: skip
    assert sum(s for s, _ in logged) == run.skipped_steps
    assert all(np.isfinite(total) for _, total in logged)  # the skipped steps are not averaged in


@pytest.mark.filterwarnings("ignore:non-finite gradients")  # one is checked below
def test_non_finite_gradients_of_a_finite_loss_are_dropped(
    tmp_path, monkeypatch, write_dataset, train_tiny, weights_of
):
    original = train_module.compute_loss
    calls: list[int] = []

    def compute_loss(pred, *args, **kwargs):
        terms = original(pred, *args, **kwargs)
        if torch.is_grad_enabled():
            calls.append(len(calls))
            if calls[-1] % 3 == 1:  # + sqrt(0): the value is unchanged, the gradient is NaN
                return terms._replace(total=terms.total + (pred.states * 0.0).sum().sqrt())
        return terms

    monkeypatch.setattr(train_module, "compute_loss", compute_loss)
    data = write_dataset(tmp_path / "ds")
    with pytest.warns(UserWarning, match="non-finite gradients at epoch 0"):
        run = train_tiny(data, tmp_path / "run")
    assert run.skipped_steps == sum(1 for i in calls if i % 3 == 1) > 0
    assert np.isfinite(run.best_val_loss)
    assert all(torch.isfinite(w).all() for w in weights_of(run.last_checkpoint).values())


@pytest.mark.filterwarnings("ignore:non-finite training loss")
def test_persistently_non_finite_loss_stops_with_a_clear_message(
    tmp_path, monkeypatch, write_dataset, run_cli
):
    data = write_dataset(tmp_path / "ds")
    _nan_loss_on(lambda i: i >= 2, monkeypatch)
    argv = ["train", "--data", data, "--out", tmp_path / "run", "--preset", "quick", "--quiet"]
    with pytest.warns(UserWarning, match="non-finite"):
        code, _, err = run_cli(*argv, *WINDOW_ARGS, "--epochs", "20")
    line = assert_one_line_error(code, err, "not finite for 10 steps in a row")
    assert "learning rate" in line and "grad_clip" in line


def test_gradient_clipping_is_on_by_default_and_off_only_in_the_paper_preset():
    clip = {name: preset.config.grad_clip for name, preset in PRESETS.items()}
    assert clip.pop("paper") == 0.0
    assert all(value > 0 for value in clip.values()), clip


def _alive(pid: int) -> bool:
    """Running (not gone, not a zombie waiting for its new parent to reap it)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, IndexError):
        return False


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="reads /proc")
def test_a_pool_worker_stops_when_reproduce_is_killed(tmp_path):
    # A parent runs a job in the package's pool (``process_pool``, ``run_watched``), prints the
    # worker's pid and is killed, as `kill <reproduce pid>` does. The job stops on SIGTERM the
    # way a training run does (it raises); the orphaned worker must then exit, not linger.
    tests, marker = str(Path(__file__).parent), tmp_path / "running"
    parent_code = (
        "import os, sys, time\n"
        f"sys.path.insert(0, {tests!r})\n"
        "from flights import stop_gracefully_on_sigterm\n"
        "from slungload.workers import process_pool, run_watched\n"
        "pool = process_pool(1)\n"
        f"pool.submit(run_watched, stop_gracefully_on_sigterm, {str(marker)!r}, os.getpid())\n"
        "print(*pool._processes, flush=True)\n"
        "time.sleep(120)\n"
    )
    parent = subprocess.Popen(
        [sys.executable, "-c", parent_code], stdout=subprocess.PIPE, text=True
    )
    (pid,) = map(int, parent.stdout.readline().split())
    deadline = time.monotonic() + 120  # the worker first imports torch (slow on a busy machine)
    while not marker.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    assert marker.exists() and _alive(pid)
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 30
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(pid)


def test_resume_after_a_stop_during_validation(tmp_path, monkeypatch, write_dataset, train_tiny):
    # A SIGTERM that lands in the middle of an epoch's validation (seen in session 3) saves a
    # checkpoint whose epoch has all its training batches and part of its validation; the
    # resumed run skips the rest of that validation (Lightning does), so that epoch has no
    # val/total, and the run must go on rather than fail the early-stopping check.
    data = write_dataset(tmp_path / "ds", {"f0": 40, "f1": 40, "f2": 200, "f3": 40})
    quick = PRESETS["quick"]
    preset = Preset("all-val", replace(quick.config, val_windows=None))
    args = dict(variant="proposed", preset=preset, max_epochs=3)
    sent: list[int] = []

    def on_validation_batch_start(self, batch, batch_idx, dataloader_idx=0):
        if self.current_epoch == 1 and batch_idx == 1 and not sent:  # of 6 batches
            sent.append(batch_idx)
            os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(train_module.SlungLoadModule, "on_validation_batch_start",
                        on_validation_batch_start)  # fmt: skip
    out = tmp_path / "run"
    with pytest.raises(TrainingInterrupted, match="SIGTERM at epoch 1"):
        train_tiny(data, out, **args)
    assert sent
    monkeypatch.undo()
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*could not find the monitored key")
        run = train_tiny(data, out, resume=True, **args)
    assert run.epochs == 3 and (out / "run.json").is_file()
