"""``slungload study control-loads``: the MPC flying loads its model never saw, with one
network (adaptive or with f fixed) or an ensemble of them."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from flights import ADAPTIVE
from flights import ADAPTIVE_WINDOW as WINDOW

torch.set_num_threads(1)


def test_the_mpc_flies_an_unseen_load_in_flight_and_given_it(adaptive_run, tiny_run, tmp_path):
    from slungload.lab.control.config import UnseenLoadsConfig
    from slungload.lab.control.unseen_loads import fly_loads, plant_name, write_loads_report

    cfg = UnseenLoadsConfig(loads=((0.3, 0.95),), maneuvers=("xy_step",), seeds=(100,),
                            samples=16, steps=12, backend="eager")  # fmt: skip
    rows = fly_loads(adaptive_run, tmp_path, cfg, progress=None)
    assert {r["controller"] for r in rows} == {
        "pid", "mpc-physics (in-flight)", "mpc-physics (true constants)",
        "mpc-adaptive (in-flight)", "mpc-adaptive (true constants)",
    }  # fmt: skip
    assert all(r["plant"] == plant_name(0.3, 0.95) and r["completed"] for r in rows)
    assert all(np.isfinite(r["load_rmse"]) for r in rows)
    report = write_loads_report(rows, cfg, tmp_path).read_text()
    assert "| 0.30 kg, 0.95 m | " in report and (tmp_path / "control-loads.png").exists()
    flown = f"swing bound {np.degrees(cfg.max_swing):.0f} deg, floor {cfg.min_height} m"
    assert flown in report  # the settings flown
    # the network's training preset is kept beside its flights; a smoke run's is bannered
    from slungload.fileio import read_json, write_json
    from slungload.models.checkpoints import load_checkpoint
    from slungload.run_config import SMOKE_PRESET

    kept = tmp_path / "loads-mpc-adaptive.json"
    assert read_json(kept)["preset"] == load_checkpoint(adaptive_run).meta.get("preset")
    assert (read_json(kept)["preset"] == SMOKE_PRESET) == ("Smoke run" in report)
    write_json(kept, read_json(kept) | {"preset": SMOKE_PRESET})
    bannered = write_loads_report(rows, cfg, tmp_path).read_text()
    assert "Smoke run: these numbers are not results" in bannered.split("| load |")[0]
    write_json(kept, read_json(kept) | {"preset": "default"})
    assert "Smoke run" not in write_loads_report(rows, cfg, tmp_path).read_text()
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("flights/*/*/*.json")}
    assert fly_loads(adaptive_run, tmp_path, cfg, progress=None) == rows  # nothing flown again
    assert stamps == {p: p.stat().st_mtime_ns for p in tmp_path.glob("flights/*/*/*.json")}
    with pytest.raises(ValueError, match="not a physics-step network"):
        fly_loads(tiny_run.out, tmp_path / "other", cfg, progress=None)
    # a folder holding flights of a network with another nominal vehicle is refused: its PID
    # and physics flights (built on that nominal) would be reused
    other = tmp_path / "other_nominal"
    other.mkdir()
    (other / "loads-mpc-fixed.json").write_text('{"nominal": {"mass_load": 0.5}}')
    with pytest.raises(ValueError, match="another nominal vehicle"):
        fly_loads(adaptive_run, other, cfg, progress=None)


def test_control_loads_refuses_a_zero_horizon_instead_of_flying_the_default(
    adaptive_run, run_cli, tmp_path
):
    fast = ("--load", "0.3,0.95", "--maneuvers", "xy_step", "--seeds", "100", "--samples", "4",
            "--steps", "2", "--backend", "eager", "--quiet")  # fmt: skip
    code, _, err = run_cli("study", "control-loads", "--model", str(adaptive_run), "--horizon", "0",
                           "--out", str(tmp_path / "x"), *fast)  # fmt: skip
    assert code == 2 and "got 4, 0, " in err and "Traceback" not in err
    assert not (tmp_path / "x").exists()
    code, _, err = run_cli("study", "control-loads", "--model", str(adaptive_run), *fast,
                           "--maneuvers", ",", "--out", str(tmp_path / "y"))  # fmt: skip
    assert code == 2 and "--maneuvers: give at least one value" in err


def test_a_network_with_f_fixed_flies_the_same_loads_beside_the_adaptive_one(
    varied, train_tiny, adaptive_run, tmp_path
):
    from slungload.lab.control.config import UnseenLoadsConfig
    from slungload.lab.control.unseen_loads import fly_loads, write_loads_report

    ds, _ = varied
    fixed = dataclasses.replace(ADAPTIVE, constants="dataset")
    train_tiny(ds, tmp_path / "fixed", variant="no-physics", model=fixed, window=WINDOW,
               max_epochs=1)  # fmt: skip
    cfg = UnseenLoadsConfig(loads=((0.3, 0.95),), maneuvers=("xy_step",), seeds=(100,),
                            samples=16, steps=12, backend="eager")  # fmt: skip
    rows = fly_loads(tmp_path / "fixed", tmp_path / "flown", cfg, progress=None)
    fixed_labels = {"mpc-fixed (in-flight)", "mpc-fixed (true constants)"}
    assert {r["controller"] for r in rows} >= fixed_labels
    in_flight = next(r for r in rows if r["controller"] == "mpc-fixed (in-flight)")
    given = next(r for r in rows if r["controller"] == "mpc-fixed (true constants)")
    assert in_flight["load_rmse"] != given["load_rmse"]  # its f runs its own constants in flight
    report = write_loads_report(rows, cfg, tmp_path / "flown").read_text()
    assert "fixed: load RMSE" in report and "adaptive: load RMSE" not in report
    both = fly_loads(adaptive_run, tmp_path / "flown", cfg, progress=None)  # into the same folder
    assert [r for r in both if r["controller"] in {r["controller"] for r in rows}] == rows
    report = write_loads_report(both, cfg, tmp_path / "flown").read_text()
    assert "| mpc-adaptive (in-flight) - mpc-fixed (in-flight) | 1 |" in report


def test_an_ensemble_of_adaptive_networks_flies_priced_beside_its_member(
    varied, train_tiny, adaptive_run, tmp_path
):
    from slungload.fileio import read_json
    from slungload.lab.control.config import UnseenLoadsConfig
    from slungload.lab.control.unseen_loads import fly_loads, write_loads_report
    from slungload.models.ensemble import write_manifest

    ds, _ = varied
    train_tiny(ds, tmp_path / "seed1", variant="no-physics", model=ADAPTIVE, window=WINDOW,
               max_epochs=1, seed=1)  # fmt: skip
    write_manifest(tmp_path / "ens", [adaptive_run, tmp_path / "seed1"])
    cfg = UnseenLoadsConfig(loads=((0.3, 0.95),), maneuvers=("xy_step",), seeds=(100,),
                            samples=16, steps=12, backend="eager")  # fmt: skip
    with pytest.raises(ValueError, match="one network; give an ensemble folder"):
        fly_loads(adaptive_run, tmp_path / "flown", dataclasses.replace(cfg, risk=0.5),
                  progress=None)  # fmt: skip
    assert not (tmp_path / "flown").exists()  # refused before anything is written
    single = fly_loads(adaptive_run, tmp_path / "flown", cfg, progress=None)
    priced = dataclasses.replace(cfg, risk=0.5, samples=8)  # fewer samples: equal compute
    rows = fly_loads(tmp_path / "ens", tmp_path / "flown", priced, progress=None)
    ours = {"mpc-adaptive ensemble risk 0.5 (in-flight)",
            "mpc-adaptive ensemble risk 0.5 (true constants)"}  # fmt: skip
    assert {r["controller"] for r in rows} == {r["controller"] for r in single} | ours
    assert [r for r in rows if r["controller"] not in ours] == single  # nothing flown again
    kept = read_json(tmp_path / "flown" / "loads-mpc-adaptive-ensemble-risk-0.5.json")
    assert kept["model"] == "mpc-adaptive ensemble risk 0.5" and kept["config"]["risk"] == 0.5
    report = write_loads_report(rows, cfg, tmp_path / "flown").read_text()
    assert "adaptive ensemble risk 0.5: load RMSE" in report.split("\n## ")[0]
    pair = "| mpc-adaptive ensemble risk 0.5 (in-flight) - mpc-adaptive (in-flight) | 1 |"
    assert pair in report
    # the shared rows were flown with the first network's K, and the report says so
    ks = "mpc-adaptive: K = 16; mpc-adaptive ensemble risk 0.5: K = 8; physics: K = 16."
    assert ks in write_loads_report(rows, priced, tmp_path / "flown").read_text()
    # its members must be of one kind: an adaptive and a fixed network are refused
    fixed = dataclasses.replace(ADAPTIVE, constants="dataset")
    train_tiny(ds, tmp_path / "fixed", variant="no-physics", model=fixed, window=WINDOW,
               max_epochs=1)  # fmt: skip
    write_manifest(tmp_path / "mixed", [adaptive_run, tmp_path / "fixed"])
    with pytest.raises(ValueError, match="an ensemble of adaptive and fixed networks"):
        fly_loads(tmp_path / "mixed", tmp_path / "other", cfg, progress=None)
