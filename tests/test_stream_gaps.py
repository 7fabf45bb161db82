"""Gaps per stream: each stream's own ``--max-gap`` (``ImportOptions.max_gaps``), its rate
detected and recorded, rounding of the stamps tolerated, and a dropout interpolated within a
raised max gap noted. ULogs written by ``log_files.write_ulog`` (PX4's layout)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from log_files import HOVER, PARAMS, imported, px4_topics, truth, write_ulog

from slungload.cli import main
from slungload.data.alignment import align_tracks
from slungload.data.import_options import GAP_STREAMS, ImportOptions, parse_gap
from slungload.data.importing import import_logs
from slungload.data.readers.logs import ROLES, LogError, Stream

LOAD_TOPIC = {"load": "vehicle_mocap_odometry:1"}


def px4_log(path, position_us=200_000, load_hole=None, duration_us=6_000_000):
    """A PX4 log of the truth flight: the position every ``position_us``, the rest at 100 Hz or
    more, the load without samples in ``load_hole`` (s, s)."""
    periods = {"position": position_us, "attitude": 4_000, "rates": 20_000, "thrust": 20_000,
               "load": 10_000}  # fmt: skip
    us = {k: np.arange(0, duration_us, r) for k, r in periods.items()}
    if load_hole is not None:
        t = us["load"] * 1e-6
        us["load"] = us["load"][(t <= load_hole[0]) | (t >= load_hole[1])]
    return write_ulog(path, px4_topics(us), {"MPC_THR_HOVER": HOVER})


def run(log, out, **options):
    return import_logs([log], out, params=PARAMS, mapping=LOAD_TOPIC, progress=False,
                       options=ImportOptions(split="train", **options))  # fmt: skip


def test_the_streams_of_a_per_stream_gap_are_the_readers_roles():
    assert GAP_STREAMS == tuple(ROLES)


def test_parse_gap_takes_a_plain_value_streams_and_groups():
    assert parse_gap("0.2") == [("", 0.2)]
    assert parse_gap("load=0.3") == parse_gap("load:0.3") == [("load", 0.3)]
    assert parse_gap("position,velocity=0.3") == [("position", 0.3), ("velocity", 0.3)]
    assert parse_gap("commands=0.5") == [("rates", 0.5), ("thrust", 0.5)]
    with pytest.raises(ValueError, match=r"unknown stream 'pL'.*streams: position"):
        parse_gap("pL=0.3")
    with pytest.raises(ValueError, match=r"expected S or STREAM=S"):
        parse_gap("load=abc")
    with pytest.raises(ValueError, match=r"max gap of the load must be > 0"):
        ImportOptions(max_gaps=(("load", 0.0),))
    options = ImportOptions(max_gap=0.1, max_gaps=(("load", 0.3), ("load", 0.2)))
    assert options.gap("load") == 0.2 and options.gap("position") == 0.1  # the last given
    assert options.gaps_record() == {"load": 0.2}


def test_a_sparse_position_raised_alone_keeps_the_loads_dropout(tmp_path):
    """5 Hz positions beside a 100 Hz load that drops out for 0.23 s."""
    log = px4_log(tmp_path / "px4.ulg", load_hole=(3.0, 3.23))
    with pytest.raises(LogError) as err:  # every 0.2 s position step is a gap at 0.1
        run(log, tmp_path / "a")
    text = str(err.value)
    assert "topic vehicle_local_position:0 is sampled every 0.200 s" in text, text
    assert "--max-gap position,velocity=0.3" in text, text
    # the position's own max gap: the load's dropout still splits the flight
    got = run(log, tmp_path / "b", max_gaps=(("position", 0.3), ("velocity", 0.3)))
    assert sorted(got.flights) == ["px4_00", "px4_01"], got.flights
    split = [n for n in got.notes if "split at 1 gap(s)" in n]
    assert split and "topic vehicle_mocap_odometry:1: 1 gap(s), the longest 0.230 s" in split[0]
    p = imported(tmp_path / "b")["px4_00"]
    assert np.abs(p["p"] - truth(p["time"])["p"]).max() < 0.04 / 8 * 0.26  # h^2/8 |a|
    recorded = json.loads((tmp_path / "b" / "vehicle.json").read_text())["import"]
    assert recorded["max_gap_by_stream"] == {"position": 0.3, "velocity": 0.3}
    steps = recorded["logs"][str(log)]["median_step_s"]
    assert steps["position"] == pytest.approx(0.2) and steps["load"] == pytest.approx(0.01)
    # one max gap for every stream: the dropout is interpolated, and said so
    every = run(log, tmp_path / "c", max_gap=0.3)
    assert list(every.flights) == ["px4"]
    dropout = [n for n in every.notes if "dropout" in n]
    assert len(dropout) == 1, every.notes
    assert "topic vehicle_mocap_odometry:1: 1 dropout(s) up to 0.230 s interpolated" in dropout[0]
    assert "--max-gap load=S" in dropout[0]


def test_a_clean_log_at_the_default_max_gap_has_no_gap_note(tmp_path):
    log = px4_log(tmp_path / "px4.ulg", position_us=100_000)  # 10 Hz: steps of 0.1 s
    got = run(log, tmp_path / "a")
    assert list(got.flights) == ["px4"]
    assert not any("gap" in n or "dropout" in n for n in got.notes), got.notes


def test_the_cli_takes_per_stream_gaps_and_refuses_an_unknown_stream(tmp_path, capsys):
    log = px4_log(tmp_path / "px4.ulg", load_hole=(3.0, 3.23))
    mapping = tmp_path / "map.json"
    mapping.write_text(json.dumps(LOAD_TOPIC))
    argv = ["import", str(log), "--map", str(mapping), "--split", "train", "--quiet"]
    code = main([*argv, "--out", str(tmp_path / "a"), "--max-gap", "0.1", "--max-gap",
                 "position,velocity=0.3"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0 and "into 2 pieces" in out, out
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--out", str(tmp_path / "b"), "--max-gap", "pL=0.3"])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "unknown stream 'pL'" in err and "Traceback" not in err
    assert not (tmp_path / "b").exists()


def test_a_10_hz_track_from_microsecond_stamps_aligns_at_the_default_max_gap():
    """The second-log path: 0.1 s steps that round a hair over 0.1 s are no gap."""
    slow = np.arange(0, 20_000_000, 100_000) * 1e-6  # a ULog's 10 Hz position
    fast = np.arange(0.0, 20.0, 0.01) + 0.0004
    assert (np.diff(slow) > 0.1).any()  # the rounding the comparison must tolerate
    first = Stream("topic vehicle_local_position:0", slow, truth(slow)["p"])
    second = Stream("columns p_x, p_y, p_z", fast, truth(fast)["p"])
    got = align_tracks(first, second, max_gap=0.1)
    assert abs(got.offset) < 0.002 and got.residual < 0.002
    with pytest.raises(LogError, match=r"every 0\.2 s .*--max-gap position=0\.3"):
        align_tracks(Stream("pose", slow[::2], truth(slow[::2])["p"]), second, max_gap=0.1)
