"""Bags from a killed recorder: an MCAP file without its summary and footer is read up to the
damage, with a note of what was lost; an unindexed ROS 1 bag is refused with the command that
repairs it. Bags written by rosbags' own writers, then cut or unindexed as a killed recorder
leaves them."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
from log_files import (
    CMD,
    LOAD,
    POSE,
    VEL,
    Msgs,
    import_to_train,
    imported,
    mavros_topics,
    truth,
    typestore,
    write_bag,
)

from slungload.cli import main
from slungload.data.readers import mcap_salvage
from slungload.data.readers.logs import LogError

SECONDS = 6.0


def mcap_file(tmp_path):
    """A bare .mcap of the truth flight at 100 Hz, as ``ros2 bag record`` leaves it."""
    store = typestore(False)
    t = np.arange(0, SECONDS, 0.01)
    topics = mavros_topics(Msgs(store, False), {}, dict.fromkeys((POSE, LOAD, VEL, CMD), t))
    folder = write_bag(tmp_path / "folder", topics, store, ros1=False)
    out = tmp_path / "rec.mcap"
    shutil.copy(next(folder.glob("*.mcap")), out)
    return out


def cut(path, share, out):
    data = path.read_bytes()
    out.write_bytes(data[: int(share * len(data))])
    return out


def test_an_mcap_cut_in_its_data_is_read_up_to_the_damage(tmp_path):
    whole = mcap_file(tmp_path)
    damaged = cut(whole, 0.6, tmp_path / "killed.mcap")
    assert mcap_salvage.is_cut(damaged) and not mcap_salvage.is_cut(whole)
    got = import_to_train(damaged, tmp_path / "ds")
    note = [n for n in got.notes if "without its summary and footer" in n]
    assert len(note) == 1, got.notes
    assert f"of {damaged.stat().st_size}" in note[0] and "a chunk cut short" in note[0], note
    flight = imported(tmp_path / "ds")["killed"]
    duration = flight["time"][-1]
    assert 0.4 * SECONDS < duration < 0.7 * SECONDS, duration  # about 60 % of the bytes
    expected = truth(flight["time"])  # every topic starts at 0
    assert np.abs(flight["p"] - expected["p"]).max() < 1e-3
    assert np.abs(flight["p_load"] - expected["p_load"]).max() < 1e-3


def test_an_mcap_cut_in_its_summary_keeps_every_message(tmp_path):
    whole = mcap_file(tmp_path)
    reference = import_to_train(whole, tmp_path / "a")
    damaged = cut(whole, 0.97, tmp_path / "summary.mcap")  # the data section is whole
    got = import_to_train(damaged, tmp_path / "b")
    assert any("without its summary and footer" in n for n in got.notes)
    assert list(got.flights.values()) == list(reference.flights.values())
    a, b = imported(tmp_path / "a")["rec"], imported(tmp_path / "b")["summary"]
    assert all(np.array_equal(a[k], b[k]) for k in a)


def test_an_mcap_cut_in_its_header_is_an_error_naming_it(tmp_path, capsys):
    damaged = cut(mcap_file(tmp_path), 0.0001, tmp_path / "stub.mcap")
    with pytest.raises(LogError, match=r"stub\.mcap: an MCAP file cut before its header ends"):
        import_to_train(damaged, tmp_path / "ds")


def unindexed(bag):
    """A ROS 1 bag as a killed ``rosbag record`` leaves it: index_pos 0 in the bag header."""
    data = bytearray(bag.read_bytes())
    at = data.index(b"index_pos=") + len(b"index_pos=")
    data[at : at + 8] = bytes(8)
    bag.write_bytes(bytes(data))
    return bag


def test_an_unindexed_ros1_bag_is_refused_with_the_repair_command(tmp_path, capsys):
    store = typestore(True)
    t = np.arange(0, 3, 0.01)
    topics = mavros_topics(Msgs(store, True), {}, dict.fromkeys((POSE, LOAD, VEL, CMD), t))
    bag = write_bag(tmp_path / "killed.bag", topics, store, ros1=True)
    import_to_train(bag, tmp_path / "fine")  # indexed: reads
    unindexed(bag)
    code = main(["import", str(bag), "--out", str(tmp_path / "ds"), "--hover-throttle", "0.42",
                 "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert "killed.bag: the ROS 1 bag has no readable index" in err, err
    assert f"rosbag reindex {bag}" in err, err
    assert not (tmp_path / "ds").exists()


def test_an_mcap_cut_before_its_first_message_is_an_error_naming_it(tmp_path):
    damaged = cut(mcap_file(tmp_path), 0.0003, tmp_path / "early.mcap")  # in the first chunk
    with pytest.raises(LogError, match=r"early\.mcap: an MCAP file cut before its first whole "
                       r"message"):  # fmt: skip
        import_to_train(damaged, tmp_path / "ds")
    assert not (tmp_path / "ds").exists()
