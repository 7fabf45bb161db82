"""The data-efficiency study: nested training subsets, fixed val/test, a table and a figure."""

from __future__ import annotations

from dataclasses import replace

import pytest
from flights import SMALL

from slungload.data.folder import read_splits
from slungload.lab.study import study_data
from slungload.lab.study.config import DataStudyConfig, SizeStudyConfig
from slungload.sim import simulate_dataset


@pytest.mark.slow
def test_study_trains_on_nested_subsets_and_writes_its_table(tmp_path):
    data = tmp_path / "data"
    simulate_dataset(data, flights=10, seed=0, workers=1, progress=False)
    config = DataStudyConfig(flights=(1, 3), variants=("no-physics",), preset="quick")
    rows = study_data(out=tmp_path / "study", config=config, data=data, workers=1, progress=False)
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
    for name in ("data.csv", "data.md", "data.png"):
        assert (tmp_path / "study" / name).is_file()


# --- the size study ---------------------------------------------------------------------


def test_the_front_keeps_the_sizes_no_other_beats_on_both_counts():
    from slungload.lab.study.size import RolloutTiming, SizeRow, pareto_front

    def timing(size: str, ms: float) -> RolloutTiming:
        return RolloutTiming(size, 1, ms, ms, 256, 15, 10, None)

    rmse = {("paper", 0): 0.60, ("paper", 1): 0.70, ("medium", 0): 0.66, ("small", 0): 0.70,
            ("tiny", 0): 0.80}  # fmt: skip
    rows = [SizeRow(size, 1, seed, value) for (size, seed), value in rmse.items()]
    times = [timing("paper", 30), timing("medium", 12), timing("small", 14), timing("tiny", 5)]
    # small is slower than medium and less accurate: off the front, fastest first
    assert pareto_front(rows, times) == ("tiny", "medium", "paper")
    assert pareto_front(rows, [timing("paper", 30), timing("tiny", 40)]) == ("paper",)


def test_the_size_study_trains_times_and_writes_its_table(write_dataset, tmp_path):
    from slungload.config import ModelConfig
    from slungload.lab.study import study_size
    from slungload.run_config import RunConfig

    names = ["a", "b", "c", "d", "e"]
    data = write_dataset(
        tmp_path / "data",
        dict.fromkeys(names, 40),
        {"train": names[:3], "val": names[3:4], "test": names[4:]},
        physics=True,
    )
    template = RunConfig("no-physics", model=ModelConfig(architecture="physics-step"), window=SMALL)
    config = SizeStudyConfig(sizes=("small", "tiny"), seeds=(0,), front_seeds=(1,),
                             preset="quick", horizon=SMALL.horizon, samples=8, steps=3,
                             repeats=3)  # fmt: skip
    options = dict(data=data, out=tmp_path / "study", config=config, template=template,
                   workers=1, progress=False)  # fmt: skip
    study = study_size(**options)
    assert {t.size for t in study.timings} == {"small", "tiny"}
    assert all(t.median_ms > 0 and (t.samples, t.steps) == (8, 3) for t in study.timings)
    seeds = {(r.size, r.seed) for r in study.rows}
    assert ("physics", None) in seeds and {("small", 0), ("tiny", 0)} <= seeds
    assert set(study.front) <= {s for s, k in seeds if k == 1}  # more seeds on the front
    for name in ("size.csv", "timing.csv", "size.md", "size.png"):
        assert (tmp_path / "study" / name).is_file()
    table = (tmp_path / "study" / "size.md").read_text()
    assert "| small |" in table and "| tiny |" in table and "physics model" in table
    runs_dir = tmp_path / "study" / "runs"
    runs = sorted(p.name for p in runs_dir.iterdir())
    assert "physics-step-small-no-physics-N4-s0" in runs
    # Without training, the finished runs are evaluated again (and timed afresh).
    again = study_size(**{**options, "train": False, "config": replace(config, backend="eager")})
    assert again.rows == study.rows and sorted(p.name for p in runs_dir.iterdir()) == runs
    assert {t.backend for t in study.timings} == {"compiled"}
    assert {t.backend for t in again.timings} == {"eager"}
    assert "eager backend" in (tmp_path / "study" / "size.md").read_text()


# --- the loads study --------------------------------------------------------------------


def test_the_loads_report_counts_the_test_flights_each_model_wins(tmp_path):
    from slungload.config import VehicleParams
    from slungload.lab.study import LoadsStudyConfig
    from slungload.lab.study.config import NOMINAL_ROW, ONE_LOAD_ROW, TRUTH
    from slungload.lab.study.loads import LoadsRow, flights_better, write_loads_study

    # (set, label, flight, load mass, RMSE): the truth wins a, the adaptive network a and b
    errors = {NOMINAL_ROW: (1.0, 1.0, 1.0), TRUTH: (0.9, 1.1, 1.0),
              ONE_LOAD_ROW: (0.5, 0.6, 0.4), "adaptive": (0.4, 0.5, 0.45)}  # fmt: skip
    per_flight = [("inside", label, name, 0.2, e) for label, es in errors.items()
                  for name, e in zip("abc", es, strict=True)]  # fmt: skip
    per_flight.append(("beyond", "adaptive", "d", 0.3, 0.1))  # no reference flew it
    assert flights_better(per_flight, "inside", NOMINAL_ROW) == {
        TRUTH: (1, 3), ONE_LOAD_ROW: (3, 3), "adaptive": (3, 3)}  # fmt: skip
    assert flights_better(per_flight, "inside", ONE_LOAD_ROW) == {
        NOMINAL_ROW: (0, 3), TRUTH: (0, 3), "adaptive": (2, 3)}  # fmt: skip
    assert flights_better(per_flight, "beyond", NOMINAL_ROW) == {}
    config = LoadsStudyConfig()
    rows = [LoadsRow("inside", label, None, n, 1.0) for label in errors for n in config.horizons]
    write_loads_study(rows, per_flight, {}, tmp_path, config, VehicleParams())
    text = (tmp_path / "loads.md").read_text()
    assert f"| model | better than '{NOMINAL_ROW}' | better than '{ONE_LOAD_ROW}' |" in text
    assert "| adaptive | 3 of 3 | 2 of 3 |" in text and f"| {TRUTH} | 1 of 3 | 0 of 3 |" in text


@pytest.mark.slow
def test_the_loads_study_trains_on_one_and_many_loads_and_tests_inside_and_beyond(tmp_path):
    import csv

    from slungload.config import WindowConfig
    from slungload.data.dataset import load_dataset
    from slungload.lab.study import LoadsStudyConfig, study_loads
    from slungload.lab.study.config import NETWORK_ROWS, PHYSICS_ROWS, TRUTH
    from slungload.lab.study.loads import choose_estimate_prior

    config = LoadsStudyConfig(flights=4, beyond_flights=2, size="tiny", preset="quick", epochs=1)
    out = tmp_path / "loads"
    rows = study_loads(out=out, config=config, workers=1, progress=False)
    labels = [*PHYSICS_ROWS, *NETWORK_ROWS]
    assert {(r.test_set, r.label, r.horizon) for r in rows} == {
        (s, label, n) for s in ("inside", "beyond") for label in labels for n in (25, 50)
    }
    # Each dataset flies its loads: the nominal one, draws inside the range, beyond it.
    ranges = {"many": (config.train_mass, config.train_length),
              "beyond": (config.beyond_mass, config.beyond_length)}  # fmt: skip
    for name, ((m_lo, m_hi), (l_lo, l_hi)) in ranges.items():
        ds = load_dataset(out / "data" / name, use_cache=False)
        for flight in ds.flights.values():
            assert m_lo <= flight.constants.mass_load <= m_hi
            assert l_lo <= flight.constants.cable_length <= l_hi
    one = load_dataset(out / "data" / "one", use_cache=False)
    assert (one.params.mass_load, one.params.cable_length) == pytest.approx(config.nominal)
    # The truth helps the physics model on loads far from the nominal one.
    rmse = {(r.test_set, r.label, r.horizon): r.rmse for r in rows}
    assert rmse[("beyond", TRUTH, 25)] < rmse[("beyond", "physics (nominal)", 25)]
    with open(out / "flights.csv") as f:
        flights = list(csv.DictReader(f))
    beyond = [float(r["mass_load_kg"]) for r in flights if r["set"] == "beyond"]
    assert beyond and min(beyond) >= config.beyond_mass[0]
    for name in ("loads.md", "loads.csv", "loads.png", "inside/report.md", "beyond/report.md"):
        assert (out / name).is_file()
    # The estimate's mass prior is chosen on the validation flights of many, and said so.
    many = load_dataset(out / "data" / "many", window=WindowConfig(), params=one.params)
    chosen, scores = choose_estimate_prior(many, one.params, config)
    assert set(scores) == set(config.estimate_priors)
    assert len(set(scores.values())) == len(scores)  # the prior moves the validation error
    assert f"the prior {chosen:g} (m/s^2)^2 per equation, chosen on the validation" in (
        out / "loads.md"
    ).read_text().replace("\n", " ")
    # Every network's seed-0 run is kept in its dataset's folder (a re-run trains nothing).
    runs = sorted(p.parent.parent.name for p in (out / "runs").glob("*/*/run.json"))
    assert runs == sorted(source for source, _, _ in NETWORK_ROWS.values())


def test_every_study_config_refuses_what_it_cannot_run_and_the_cli_reads_its_defaults(run_cli):
    with pytest.raises(ValueError, match="positive counts"):
        DataStudyConfig(flights=(0, 3))
    with pytest.raises(ValueError, match="unknown network sizes"):
        SizeStudyConfig(sizes=("huge",))
    from slungload.cli import build_parser

    parser = build_parser()
    for argv in (["study", "data", "--out", "x"], ["study", "size", "--data", "d", "--out", "x"],
                 ["study", "loads", "--out", "x"], ["study", "control", "--out", "x"],
                 ["study", "control-loads", "--out", "x"], ["control", "--out", "x"],
                 ["record", "--base", "b", "--out", "x"]):  # fmt: skip
        args = parser.parse_args(argv)
        # nothing the configs hold is defaulted on the command line: argparse leaves it None
        for name in ("seeds", "preset", "samples", "steps", "horizon", "maneuvers", "flights",
                     "backend", "horizons", "sizes", "temperature"):  # fmt: skip
            assert getattr(args, name, None) is None, (argv, name)
    text = parser.parse_args(["study", "size", "--data", "d", "--out", "x"])
    assert text.front_seeds is None and text.repeats is None
    code, _, err = run_cli("study", "data", "--flights", "0,3", "--out", "x")
    assert code == 2 and "positive counts" in err
