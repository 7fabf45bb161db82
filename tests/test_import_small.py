"""The small things of ``slungload import`` a new user meets: one-key mapping changes on the
command line (``--set``), a CSV without a header or without commands, a split of few
recordings, ``inspect`` on imported recordings, progress bars kept out of redirected output.
CSV written by hand (``log_files.write_csv``), ULogs by ``log_files.write_ulog``."""

from __future__ import annotations

import json

import numpy as np
import pytest
from log_files import (
    HOVER,
    PARAMS,
    default_columns,
    imported,
    px4_topics,
    truth,
    write_csv,
    write_ulog,
)

from slungload.cli import main
from slungload.data.readers.logs import LogError, override


def csv_log(path, steps=200, rename=None, drop=()):
    columns = default_columns(truth(PARAMS.dt * np.arange(steps)))
    for old, new in (rename or {}).items():
        columns[new] = columns.pop(old)
    for name in drop:
        del columns[name]
    return write_csv(path, columns)


def test_set_changes_one_key_without_a_mapping_file(tmp_path, capsys):
    rename = {f"attitude_{a}": f"q{a}" for a in "xyzw"} | {"T_ref": "thrust_n"}
    log = csv_log(tmp_path / "f.csv", rename=rename)
    argv = ["import", str(log), "--quiet", "--split", "train"]
    assert main([*argv, "--out", str(tmp_path / "a")]) == 2
    assert "no column 'attitude_x' (mapping key 'attitude')" in capsys.readouterr().err
    code = main([*argv, "--out", str(tmp_path / "b"), "--set", "attitude=qx,qy,qz,qw",
                 "--set", "T_ref=thrust_n"])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    got = imported(tmp_path / "b")["f"]
    assert np.allclose(got["attitude"], truth(got["time"])["attitude"], atol=1e-9)
    settings = json.loads((tmp_path / "b" / "vehicle.json").read_text())["import"]["logs"]
    assert settings[str(log)]["attitude"] == ["qx", "qy", "qz", "qw"]
    # ULog: the load's topic, no mapping file
    us = {k: np.arange(0, 3_000_000, 10_000) for k in
          ("position", "attitude", "rates", "thrust", "load")}  # fmt: skip
    ulg = write_ulog(tmp_path / "px4.ulg", px4_topics(us), {"MPC_THR_HOVER": HOVER})
    code = main(["import", str(ulg), "--out", str(tmp_path / "c"), "--quiet", "--set",
                 "load=vehicle_mocap_odometry:1"])  # fmt: skip
    assert code == 0, capsys.readouterr().err


def test_set_refuses_what_it_cannot_place(tmp_path, capsys):
    sections = ("ros", "ulog", "csv")
    assert override({"csv": {"time": "t"}}, ["csv.T_ref=thr"], sections) == {
        "csv": {"time": "t", "T_ref": "thr"}
    }
    with pytest.raises(LogError, match=r"the mapping is in sections .* --set SECTION\.T_ref"):
        override({"csv": {}}, ["T_ref=thr"], sections)
    with pytest.raises(LogError, match=r"the mapping has no sections; give --set T_ref="):
        override({"time": "t"}, ["csv.T_ref=thr"], sections)
    with pytest.raises(LogError, match=r"expected KEY=VALUE"):
        override(None, ["T_ref"], sections)
    log = csv_log(tmp_path / "f.csv")
    code = main(["import", str(log), "--out", str(tmp_path / "a"), "--set", "thrust_col=x"])
    err = capsys.readouterr().err
    assert code == 2 and "unknown mapping keys ['thrust_col']" in err and "Traceback" not in err
    assert not (tmp_path / "a").exists()


def test_a_headerless_csv_is_told_it_has_no_header(tmp_path, capsys):
    log = csv_log(tmp_path / "f.csv")
    lines = log.read_text().splitlines()
    log.write_text("\n".join(lines[1:]) + "\n")  # the header row gone
    code = main(["import", str(log), "--out", str(tmp_path / "a"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "f.csv: has no header row: its first row holds 18 numbers" in err, err
    assert "no column" not in err and not (tmp_path / "a").exists()


def test_a_csv_without_commands_is_told_they_are_required_and_why(tmp_path, capsys):
    log = csv_log(tmp_path / "f.csv", drop=("w_ref_x", "w_ref_y", "w_ref_z", "T_ref"))
    code = main(["import", str(log), "--out", str(tmp_path / "a"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "no column 'w_ref_x' (mapping key 'w_ref')" in err, err
    assert "commanded thrust and body rates are required: the model predicts" in err, err


def three_recordings(tmp_path, capsys, *extra):
    logs = [str(csv_log(tmp_path / f"{n}.csv")) for n in ("alpha", "beta", "gamma")]
    code = main(["import", *logs, "--out", str(tmp_path / "ds"), *extra])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    return captured


def test_few_equal_recordings_get_a_split_note_and_no_maneuver_warning(tmp_path, capsys):
    out = three_recordings(tmp_path, capsys, "--quiet").out
    assert "3 recordings split whole give 33/33/33 % of the windows" in out, out
    assert "not 58/17/25 %" in out and "--split blocks" in out
    assert main(["inspect", str(tmp_path / "ds")]) == 0
    table = capsys.readouterr().out
    assert "maneuvers not in train" not in table, table
    assert "imported recordings (vehicle.json): split by recording" in table


def test_progress_bars_stay_out_of_redirected_output(tmp_path, capsys):
    err = three_recordings(tmp_path, capsys).err  # no --quiet; stderr is not a terminal
    assert "importing logs" not in err and "it/s" not in err, err
