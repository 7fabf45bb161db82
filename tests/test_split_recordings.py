"""Pieces of one recording stay in one split; one or two recordings are cut in time.

The logs are CSV files of the ``truth`` flight (``log_files``); a motion-capture dropout (the
vehicle's position blank for 0.2 s) splits a log into two pieces, as a real one does.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from log_files import PARAMS, default_columns, truth, write_csv

from slungload.cli import main
from slungload.config import WindowConfig
from slungload.data.dataset import load_dataset
from slungload.data.folder import read_splits
from slungload.data.importing import ImportOptions, import_logs
from slungload.data.split import split_dataset, split_flights, time_blocks

WINDOW = WindowConfig(history=10, horizon=5)


def log_with_dropout(folder, name, steps=500, dropout=(200, 207)):
    """A CSV log whose vehicle position is missing for ``dropout`` rows (0.21 s at 30 ms)."""
    columns = default_columns(truth(PARAMS.dt * np.arange(steps)))
    if dropout is not None:
        for a in "xyz":
            columns[f"p_{a}"][dropout[0] : dropout[1]] = np.nan
    return write_csv(folder / f"{name}.csv", columns)


def import_folder(tmp_path, logs, **options):
    out = tmp_path / "ds"
    result = import_logs(logs, out, params=PARAMS, options=ImportOptions(**options), progress=False)
    return out, result


def split_of(splits):
    return {name: s for s, names in splits.items() for name in names}


def test_pieces_of_a_recording_land_in_one_split(tmp_path):
    logs = [log_with_dropout(tmp_path, f"rec{i}", steps=400 + 60 * i) for i in range(4)]
    for seed in range(6):
        out, result = import_folder(tmp_path / str(seed), logs, seed=seed)
        assert len(result.flights) == 8  # every log split at its dropout
        where = split_of(result.splits)
        for i in range(4):
            assert where[f"rec{i}_00"] == where[f"rec{i}_01"], (seed, result.splits)
        assert all(result.splits.values())
        # slungload split keeps them together too, by share or by name
        again = split_of(split_dataset(out, seed=seed, overwrite=True))
        assert all(again[f"rec{i}_00"] == again[f"rec{i}_01"] for i in range(4))
    named = split_dataset(out, val=["rec1_00", "rec1_01"], test=["rec2_00", "rec2_01"],
                          overwrite=True)  # fmt: skip
    assert named["val"] == ["rec1_00", "rec1_01"] and len(named["train"]) == 4
    with pytest.raises(ValueError, match=r"rec1_00 is one piece of a recording .* \['rec1_01'\]"):
        split_dataset(out, val=["rec1_00"], overwrite=True)


def test_split_flights_by_recording_keeps_the_shares():
    names = [f"r{i}_{k}" for i in range(30) for k in range(2)]
    steps = list(np.random.default_rng(0).integers(200, 600, size=60))
    recordings = [n.split("_")[0] for n in names]
    splits = split_flights(names, steps, np.random.default_rng(1), recordings=recordings)
    where = split_of(splits)
    assert all(where[f"r{i}_0"] == where[f"r{i}_1"] for i in range(30))
    total = sum(max(s - 74, 0) for s in steps)
    train = sum(max(steps[names.index(n)] - 74, 0) for n in splits["train"])
    assert train / total == pytest.approx(0.58, abs=0.05)


def test_one_recording_names_the_block_split_and_blocks_do_not_touch(tmp_path):
    log = log_with_dropout(tmp_path, "session", steps=1200)
    _, result = import_folder(tmp_path / "seeded", [log])
    assert set(result.splits["train"]) == {"session_00", "session_01"}
    assert any("--split blocks" in n and "slungload split --blocks" in n for n in result.notes)
    out, result = import_folder(tmp_path / "blocks", [log], split="blocks", block_gap=40)
    assert all(result.splits.values())
    meta = json.loads((out / "vehicle.json").read_text())["import"]
    starts = {n: (f["start"], f["steps"]) for n, f in meta["flights"].items()}
    spans = sorted((a, a + (n - 1) * PARAMS.dt, name) for name, (a, n) in starts.items())
    for (_, end, first), (start, _, second) in zip(spans, spans[1:], strict=False):
        if first.rsplit("_", 1)[1] != second.rsplit("_", 1)[1]:  # another block
            assert start - end >= 40 * PARAMS.dt - 1e-9, (first, second)
    assert meta["options"]["split"] == "blocks" and meta["options"]["block_gap"] == 40
    ds = load_dataset(out, window=WINDOW, use_cache=False)
    assert all(len(ds.splits[s]) > 0 for s in ("train", "val", "test"))


def test_slungload_split_blocks_rewrites_a_one_recording_dataset(tmp_path, capsys):
    log = log_with_dropout(tmp_path, "session", steps=900, dropout=None)
    out, _ = import_folder(tmp_path, [log])
    assert read_splits(out)["val"] == []
    code = main(["split", str(out), "--overwrite"])
    assert code == 2 and "slungload split --blocks" in capsys.readouterr().err
    assert main(["split", str(out), "--blocks", "--gap", "30"]) == 0
    lists = read_splits(out)
    assert lists == {"train": ["session_train"], "val": ["session_val"], "test": ["session_test"]}
    meta = json.loads((out / "vehicle.json").read_text())
    assert meta["blocks"]["gap"] == 30 and "import" in meta  # the import's record is kept
    blocks = meta["blocks"]["flights"]
    assert (
        blocks["session_val"]["start"]
        - (blocks["session_train"]["start"] + blocks["session_train"]["steps"])
        == 30
    )
    ds = load_dataset(out, window=WINDOW, use_cache=False)
    assert all(len(ds.splits[s]) > 0 for s in ("train", "val", "test"))
    assert not [p for p in out.parent.iterdir() if p.name.startswith(".")]  # no temp left


def test_time_blocks_cut_in_order_with_gaps():
    segments = time_blocks([300, 700], gap=75)
    by_split = {}
    offset = {0: 0, 1: 300}
    for piece, a, b, split in segments:
        by_split.setdefault(split, []).append((offset[piece] + a, offset[piece] + b))
    assert list(by_split) == ["train", "val", "test"]
    ends = [max(b for _, b in v) for v in by_split.values()]
    starts = [min(a for a, _ in v) for v in by_split.values()]
    assert starts[1] - ends[0] == 75 and starts[2] - ends[1] == 75 and ends[2] == 1000
    assert sum(b - a for v in by_split.values() for a, b in v) == 1000 - 150
    with pytest.raises(ValueError, match="too short for a time-block split"):
        time_blocks([400], gap=75)


def test_training_without_val_windows_points_to_slungload_split():
    from slungload.config import TrainConfig
    from slungload.data.windows import make_windows
    from slungload.training.batches import WindowData

    empty = make_windows([], WINDOW)
    with pytest.raises(ValueError, match="slungload split"):
        WindowData(empty, empty, TrainConfig())
