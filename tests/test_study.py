"""The data-efficiency study: nested training subsets, fixed val/test, a table and a figure."""

from __future__ import annotations

import pytest

from slungload.data.dataset import read_splits
from slungload.sim import simulate_dataset
from slungload.study import study_data


@pytest.mark.slow
def test_study_trains_on_nested_subsets_and_writes_its_table(tmp_path):
    data = tmp_path / "data"
    simulate_dataset(data, flights=10, seed=0, workers=1, progress=False)
    rows = study_data(
        out=tmp_path / "study",
        flights=(1, 3),
        data=data,
        variants=("no-physics",),
        preset="quick",
        workers=1,
        progress=False,
    )
    splits = {k: read_splits(tmp_path / "study" / "subsets" / f"train{k}") for k in (1, 3)}
    full = read_splits(data)
    assert len(splits[1]["train"]) == 1 and len(splits[3]["train"]) == 3
    assert set(splits[1]["train"]) <= set(splits[3]["train"]) <= set(full["train"])  # nested
    for k in (1, 3):  # validation and test fixed
        assert (splits[k]["val"], splits[k]["test"]) == (full["val"], full["test"])
    labels = {(r.flights, r.label) for r in rows}
    assert labels == {(1, "physics"), (1, "no-physics"), (3, "physics"), (3, "no-physics")}
    physics = {r.rmse for r in rows if r.label == "physics"}
    assert len(physics) == 1  # the same test flights for every subset
    for name in ("study.csv", "study.md", "study.png"):
        assert (tmp_path / "study" / name).is_file()
