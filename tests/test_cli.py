"""The command line: wiring, user errors (one line, exit 2), and the main job in its quick form."""

from __future__ import annotations

import csv
import json
import math

import pytest

from slungload.cli import main
from slungload.cli.common import seed_range
from slungload.evaluation.results import PAPER_RMSE_N50


def test_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for command in ("simulate", "inspect", "train", "evaluate", "reproduce", "maneuvers"):
        assert command in out


def test_maneuvers_lists_the_paper_families(run_cli):
    code, out, _ = run_cli("maneuvers")
    assert code == 0
    for family in ("xy_step", "fast_8_lap_xyz", "baf_very_fast", "roll_35"):
        assert family in out.split()


def test_missing_data_folder_is_one_line_and_exit_2(run_cli, tmp_path):
    code, out, err = run_cli("inspect", str(tmp_path / "nowhere"))
    assert code == 2
    assert "nowhere" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_simulate_refuses_to_overwrite(run_cli, tmp_path):
    (tmp_path / "keep.txt").write_text("precious")
    code, _, err = run_cli("simulate", "--out", str(tmp_path), "--flights", "1", "--quiet")
    assert code == 2
    assert str(tmp_path) in err
    assert (tmp_path / "keep.txt").read_text() == "precious"


@pytest.mark.parametrize("text", ["1,0.5", "1,a,0,0", "1,0.5,0.5,-0.2"])
def test_bad_excitation_is_a_user_error(capsys, tmp_path, text):
    with pytest.raises(SystemExit) as info:  # argparse's own error: usage, one line, exit 2
        main(["simulate", "--out", str(tmp_path / "d"), "--excite", text, "--quiet"])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "--excite" in err and "T,WX,WY,WZ" in err
    assert not (tmp_path / "d").exists()


def test_bad_seed_range_is_a_user_error(run_cli, tmp_path):
    code, _, err = run_cli("reproduce", "--out", str(tmp_path), "--seeds", "a..b")
    assert code == 2 and "--seeds" in err


@pytest.mark.parametrize(("text", "seeds"), [("3", (3,)), ("1..3", (1, 2, 3)), ("0,4", (0, 4))])
def test_seed_range(text, seeds):
    assert seed_range(text) == seeds


def test_simulate_then_inspect(run_cli, tmp_path):
    data = tmp_path / "data"
    code, out, _ = run_cli(
        "simulate",
        "--out",
        data,
        "--flights",
        "3",
        "--quiet",
        "--no-wind",
        "--excite",
        "1,0.5,0.5,0.2",
    )
    assert code == 0 and "wrote 3 flights" in out
    meta = json.loads((data / "vehicle.json").read_text())
    assert meta["sim"]["effects"]["wind"] is False and meta["sim"]["effects"]["drag"] is True
    assert meta["sim"]["excitation"] == {
        "thrust_std": 1.0,
        "rate_std": [0.5, 0.5, 0.2],
        "tau": 0.15,
    }
    code, out, _ = run_cli("inspect", str(data))
    assert code == 0 and "(vehicle.json)" in out


@pytest.mark.slow
def test_quick_reproduce_writes_a_plausible_report(run_cli, tmp_path):
    """The README's main job in its smoke-test form: the default 48-flight dataset, three
    variants trained for a few seconds, evaluated at N = 25 and 50 (timing left out)."""
    out = tmp_path / "out"
    code, stdout, _ = run_cli(
        "reproduce", "--out", str(out), "--preset", "quick", "--no-timing", "--quiet"
    )
    assert code == 0 and "report.md" in stdout
    report = out / "report"
    text = (report / "report.md").read_text()
    assert "The paper's RMSE" in text
    for name in ("rmse.csv", "rmse_table.csv", "mae_proposed_N50.csv", "mae_physics_N25.csv"):
        assert (report / name).stat().st_size > 0
    figures = sorted((report / "figures").glob("*.png"))
    assert len(figures) >= 3 and all(f.stat().st_size > 10_000 for f in figures)

    with open(report / "rmse.csv") as fh:
        rows = list(csv.DictReader(fh))
    labels = {row["label"] for row in rows}
    assert {"physics", "proposed", "no-slack", "no-physics"} <= labels
    assert "physics-step/no-physics+mixed+N50+smoothed" in labels  # beyond the paper
    for row in rows:
        for group in ("position", "velocity", "quaternion", "load_position"):
            value = float(row[group])
            assert math.isfinite(value) and 0.0 < value < 20.0
    # The simulated flights hold as much unmodelled physics as the real ones: the physics-only
    # predictor's RMSE at N = 50 lies within a factor 2 of the paper's, group by group.
    physics = next(r for r in rows if r["label"] == "physics" and int(r["horizon"]) == 50)
    for group, paper in PAPER_RMSE_N50["physics"].items():
        if group != "combined":
            assert 0.5 * paper < float(physics[group]) < 2.0 * paper, group


def test_export_out_names_a_file_or_an_existing_folder(run_cli, tiny_run, tmp_path):
    missing = tmp_path / "nowhere" / "deeper" / "m.onnx"
    code, _, err = run_cli("export", tiny_run.out, "--out", missing)
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"folder {missing.parent} does not exist" in err
    assert not (tmp_path / "nowhere").exists()  # not created
    code, out, err = run_cli("export", tiny_run.out, "--out", tmp_path)  # an existing folder
    assert code == 0, err
    assert (tmp_path / f"{tiny_run.out.name}-n4.onnx").is_file()
    assert (tmp_path / f"{tiny_run.out.name}-n4.json").is_file()
    assert f"{tiny_run.out.name}-n4.onnx" in out


def test_export_help_says_what_out_takes(capsys):
    with pytest.raises(SystemExit):
        main(["export", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "existing folder, to write <run name>-n<N>.onnx there" in text
    assert "A missing folder is an error, not created" in text
