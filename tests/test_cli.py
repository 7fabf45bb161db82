"""The command line: wiring, user errors (one line, exit 2), and the main job in its quick form."""

from __future__ import annotations

import argparse
import csv
import dataclasses
import json
import math
import re

import pytest

from slungload.cli import build_parser, common, main
from slungload.cli.common import seed_range, vehicle_overrides
from slungload.config import VehicleParams, constant
from slungload.evaluation.results import PAPER_RMSE_N50


def test_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for command in ("simulate", "inspect", "train", "evaluate", "reproduce", "maneuvers"):
        assert command in out


def _parsers(parser: argparse.ArgumentParser):
    yield parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _parsers(sub)


def test_no_help_text_shows_an_unfilled_placeholder():
    """A help string that lost its f prefix prints "{default.x:g}" to the user."""
    helps = {p.prog: p.format_help() for p in _parsers(build_parser())}
    assert len(helps) > 20
    placeholder = re.compile(r"\{[\w.]+(:[^}]*)?\}")
    assert not [prog for prog, text in helps.items() if placeholder.search(text)]


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


@pytest.mark.parametrize("command", ["simulate", "reproduce"])
@pytest.mark.parametrize("count", ["0", "-3", "many"])
def test_a_flight_count_below_one_is_a_user_error(capsys, tmp_path, command, count):
    with pytest.raises(SystemExit) as info:
        main([command, "--out", str(tmp_path / "d"), "--flights", count])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "argument --flights" in err and repr(count) in err
    assert not (tmp_path / "d").exists()


def test_a_list_of_counts_that_is_not_one_is_a_user_error(capsys, tmp_path):
    with pytest.raises(SystemExit) as info:
        main(["control", "--samples", "abc", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert info.value.code == 2 and "argument --samples: expected whole numbers" in err
    assert "comma_ints" not in err and not (tmp_path / "d").exists()


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


# --- vehicle constants: options, help and overrides made from VehicleParams -------------------


def _commands_with_vehicle_options() -> dict[str, argparse.ArgumentParser]:
    (sub,) = (a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    return {
        name: p
        for name, p in sub.choices.items()
        if any("--mass-quad" in a.option_strings for a in p._actions)
    }


def test_every_command_with_vehicle_options_prints_the_real_defaults(capsys):
    commands = _commands_with_vehicle_options()
    assert {"train", "identify", "import", "inspect"} <= set(commands)
    defaults = VehicleParams()
    for command in commands:
        with pytest.raises(SystemExit):
            main([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        for field in dataclasses.fields(VehicleParams):
            value, unit = getattr(defaults, field.name), field.metadata["unit"]
            symbol = field.metadata["symbol"]
            # The group's description lists every default with its symbol and unit ...
            listed = f"{symbol} {value:g}" + ("" if unit == "-" else f" {unit}")
            assert listed in text, (command, listed)
            # ... and each option's help states its own.
            option = f"--{field.name.replace('_', '-')}"
            assert option in text, (command, option)
            assert f"{symbol} = {field.metadata['text']}" in text, (command, field.name)
            assert f"(default {value:g})" in text, (command, field.name)
        assert "1.54" not in text and "0.67" not in text  # the constants the help once stated


def test_vehicle_options_keep_their_names_and_dests():
    # Users' scripts pass these: the names and dests of before the options were generated.
    legacy = {
        "--mass-quad": "mass_quad", "--mass-load": "mass_load", "--cable-length": "cable_length",
        "--load-damping": "load_damping", "--dt": "dt", "--gravity": "gravity",
        "--thrust-gain": "thrust_gain",
    }  # fmt: skip
    for command, parser in _commands_with_vehicle_options().items():
        options = {
            a.option_strings[0]: a.dest for a in parser._actions if a.dest in legacy.values()
        }
        assert options == legacy, command
    args = build_parser().parse_args(["identify", "d", "--cable-length", "0.9", "--dt", "0.02"])
    assert vehicle_overrides(args) == {"cable_length": 0.9, "dt": 0.02}


def test_a_new_vehicle_constant_is_a_new_option(monkeypatch):
    @dataclasses.dataclass(frozen=True)
    class Extended(VehicleParams):
        drag: float = constant(0.3, "N s/m", "cD", "linear drag of the load")

    monkeypatch.setattr(common, "VehicleParams", Extended)
    parser = argparse.ArgumentParser()
    common.add_vehicle_options(parser)
    text = " ".join(parser.format_help().split())
    assert "cD 0.3 N s/m" in text and "cD = linear drag of the load, N s/m (default 0.3)" in text
    args = parser.parse_args(["--drag", "0.5", "--mass-load", "0.2"])
    assert vehicle_overrides(args) == {"mass_load": 0.2, "drag": 0.5}


def test_the_option_helpers_keep_zero_refuse_empty_lists_and_write_ranges_as_typed():
    from slungload.cli.common import comma_names, given, joined

    assert given(steps=0, seeds=None, maneuvers=("a",)) == {"steps": 0, "maneuvers": ("a",)}
    with pytest.raises(ValueError, match="--front-seeds: give at least one value"):
        given(front_seeds=())
    assert joined((100, 101, 102)) == "100..102" and joined((15, 25)) == "15,25"
    assert joined((1, 2)) == "1,2" and joined((3, 5, 6)) == "3,5,6" and joined(32) == "32"
    assert comma_names("nominal, wind x2,") == ["nominal", "wind x2"]


def test_window_counts_follow_the_stride():
    from slungload.config import WindowConfig

    window = WindowConfig(history=3, horizon=2, stride=2)
    assert [window.count(t) for t in (4, 5, 6, 7, 9)] == [0, 1, 1, 2, 3]


def test_study_size_takes_none_for_no_further_seeds(monkeypatch, run_cli, tmp_path):
    import slungload.lab.study as study

    seen = {}
    monkeypatch.setattr(study, "study_size", lambda **kw: seen.update(kw))
    code, _, err = run_cli("study", "size", "--data", tmp_path, "--out", tmp_path / "x",
                           "--front-seeds", "none", "--sizes", "small, tiny")  # fmt: skip
    assert code == 0, err
    assert seen["config"].front_seeds == () and seen["config"].sizes == ("small", "tiny")
    code, _, err = run_cli("study", "size", "--data", tmp_path, "--out", tmp_path / "x",
                           "--front-seeds", "3..4")  # fmt: skip
    assert code == 0 and seen["config"].front_seeds == (3, 4)


def test_a_command_needing_what_the_install_left_out_says_which_extra(monkeypatch, run_cli):
    import slungload.cli.train as train

    def missing(args):
        raise ModuleNotFoundError("No module named 'lightning'", name="lightning")

    monkeypatch.setattr(train, "cmd_train", missing)
    code, _, err = run_cli("train", "--data", "d", "--out", "r")
    assert code == 2 and "needs lightning" in err and "'slungload[full]'" in err
    assert "'.[full]'" in err and "Traceback" not in err

    def other(args):
        raise ModuleNotFoundError("No module named 'nonesuch'", name="nonesuch")

    monkeypatch.setattr(train, "cmd_train", other)
    with pytest.raises(ModuleNotFoundError):  # not an optional dependency: a bug, shown whole
        run_cli("train", "--data", "d", "--out", "r")
