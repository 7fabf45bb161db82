"""The load from a second log (``data/alignment.py``, ``slungload import --second``).

The usual real set-up: a PX4 ULog for the vehicle and a separate motion-capture recording for
the load. The ULog is written by ``log_files.write_ulog`` (no load topic), the recording by
rosbags' writer (a ROS 1 bag in Unix time) or as a CSV, both of the ``truth`` flight; the
recording's clock is shifted and its frame rotated and moved by known amounts, with 0.5 mm of
motion-capture noise, and the import must find them back.
"""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest
from log_files import (
    HOVER,
    LOAD,
    PARAMS,
    POSE,
    T0_NS,
    Msgs,
    imported,
    px4_topics,
    rotation_angle,
    truth,
    typestore,
    write_bag,
    write_csv,
    write_ulog,
)

from slungload import frames
from slungload.data.alignment import RESIDUAL, SPREAD, align_tracks
from slungload.data.consistency import ConsistencyError, ConsistencyLimits
from slungload.data.importing import ImportOptions, SecondLog, import_logs
from slungload.data.readers.logs import LogError, Stream
from slungload.data.track_offset import fit_rigid

SHIFT = 12.34  # s, the recording's clock behind the ULog's: t_ulog = t_mocap + SHIFT
YAW = math.radians(40.0)  # the recording's frame, turned about z ...
MOVE = np.array([1.5, -2.0, 0.3])  # ... and moved: p_ulog = R p_mocap + MOVE
NOISE = 0.0005  # m, motion-capture noise (standard deviation per axis)
ULOG_SPAN = (5.0, 25.0)  # s since boot: the ULog, armed to disarmed
MOCAP_SPAN = (2.0, 28.0)  # s on the ULog's clock: the recording runs before and after


def yaw_matrix(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def flight_ulog(path, span=ULOG_SPAN):
    """The vehicle's PX4 log of the truth flight (position, attitude, commands; no load)."""
    periods = {"position": 10_000, "attitude": 4_000, "rates": 20_000, "thrust": 20_000}
    us = {k: np.arange(int(span[0] * 1e6), int(span[1] * 1e6), r) for k, r in periods.items()}
    return write_ulog(path, px4_topics(us, with_load=False), {"MPC_THR_HOVER": HOVER})


def mocap_track(rate=120.0, *, rotation=None, shift=SHIFT, flight=truth, seed=0):
    """(stamps on the recording's clock (n,) s, vehicle (n, 3) and load (n, 3) positions in
    its frame, noisy) of ``flight`` over MOCAP_SPAN on the ULog's clock."""
    rotation = yaw_matrix(YAW) if rotation is None else rotation
    t = np.arange(*MOCAP_SPAN, 1.0 / rate)
    a = flight(t)
    rng = np.random.default_rng(seed)

    def seen(p):  # R^T (p - c), the inverse of p = R q + c, rows
        return (p - MOVE) @ rotation + NOISE * rng.standard_normal(p.shape)

    return t - shift, seen(a["p"]), seen(a["p_load"])


def mocap_bag(path, track, t0_ns=T0_NS):
    """A ROS 1 bag of the vrpn poses of vehicle and load, stamped ``t0_ns`` + the track's
    stamps (Unix time, as a recording computer stamps it)."""
    store = typestore(ros1=True)
    m = Msgs(store, ros1=True)
    t, p, p_load = track
    ns = t0_ns + np.round(t * 1e9).astype(np.int64)

    def poses(positions):
        return [(int(n), m.pose(int(n), q)) for n, q in zip(ns, positions, strict=True)]

    topics = {
        POSE: ("geometry_msgs/msg/PoseStamped", poses(p)),
        LOAD: ("geometry_msgs/msg/PoseStamped", poses(p_load)),
    }
    return write_bag(path, topics, store, ros1=True)


def mocap_csv(path, track, attitude=None):
    """A CSV of the recording: time (s from its own start), p_*, p_load_* (and attitude_*)."""
    t, p, p_load = track
    columns = {"time": t, **{f"p_{a}": p[:, i] for i, a in enumerate("xyz")}}
    columns.update({f"p_load_{a}": p_load[:, i] for i, a in enumerate("xyz")})
    if attitude is not None:
        columns.update({f"attitude_{a}": attitude[:, i] for i, a in enumerate("xyzw")})
    return write_csv(path, columns)


def load_error(folder, name="flight"):
    """Largest |pL - truth| (m) and the dataset's flight, on the ULog's clock."""
    got = imported(folder)[name]
    start = json.loads((folder / "vehicle.json").read_text())["import"]["flights"][name]["start"]
    true = truth(start + got["time"])
    return float(np.linalg.norm(got["p_load"] - true["p_load"], axis=1).max()), got, true


def second_record(folder, log):
    return json.loads((folder / "vehicle.json").read_text())["import"]["logs"][str(log)]["second"]


# --- the load from a motion-capture bag, through the command line ----------------------------


def test_load_from_a_mocap_bag_on_another_clock_and_frame(tmp_path, run_cli):
    logs = tmp_path / "session"
    logs.mkdir()
    ulog = flight_ulog(logs / "flight.ulg")
    bag = mocap_bag(logs / "mocap.bag", mocap_track())  # no command topic: read for p, pL
    out = tmp_path / "ds"
    code, stdout, err = run_cli("import", logs, "--second", bag, "--out", out, "--quiet",
                                "--cable-length", "0.7", "--split", "train")  # fmt: skip
    assert code == 0, err
    assert f"{bag}: the second log is not imported on its own" in stdout  # the folder holds both
    assert f"load from {bag}, time offset " in stdout and "(estimated)" in stdout
    record = second_record(out, ulog)
    found = record["alignment"]
    true_offset = SHIFT - T0_NS * 1e-9  # t_ulog = t_bag + offset
    # measured: 3.6e-5 s (the 120 Hz recording's period is 8.3e-3 s)
    assert abs(found["time_offset_s"] - true_offset) < 5e-4, found["time_offset_s"] - true_offset
    assert found["time_offset_from"] == "estimated"
    assert abs(found["yaw_deg"] - 40.0) < 0.02 and found["tilt_deg"] == 0.0
    np.testing.assert_allclose(found["rotation"], yaw_matrix(YAW), atol=4e-4)
    np.testing.assert_allclose(found["translation_m"], MOVE, atol=1e-3)
    assert found["residual_m"] < 1.5 * NOISE * math.sqrt(3)  # the noise, nothing more
    assert found["overlap_s"] == pytest.approx(ULOG_SPAN[1] - ULOG_SPAN[0], abs=0.02)
    assert record["roles"] == ["load"] and record["format"] == "ros1"
    assert record["checks"][RESIDUAL] == pytest.approx(found["residual_m"], abs=1e-6)
    worst, got, true = load_error(out)
    assert worst < 3e-3, worst  # measured 1.7 mm (0.7 mm RMS): the 0.5 mm noise per axis
    rms = float(np.sqrt(np.mean(np.sum((got["p_load"] - true["p_load"]) ** 2, axis=1))))
    assert rms < 1.5 * NOISE * math.sqrt(3), rms
    # the flight is the ULog's: 20 s, the vehicle's own streams untouched
    assert got["time"][-1] == pytest.approx(ULOG_SPAN[1] - ULOG_SPAN[0], abs=0.05)
    np.testing.assert_allclose(got["p"], true["p"], atol=1e-4)


def test_time_offset_given_is_used_and_the_frame_still_fitted(tmp_path, run_cli):
    ulog = flight_ulog(tmp_path / "flight.ulg")
    csv = mocap_csv(tmp_path / "mocap.csv", mocap_track())
    out = tmp_path / "ds"
    code, _, err = run_cli("import", ulog, "--second", csv, "--time-offset", "12.345", "--out",
                           out, "--quiet", "--split", "train")  # fmt: skip
    assert code == 0, err
    found = second_record(out, ulog)["alignment"]
    assert found["time_offset_s"] == 12.345 and found["time_offset_from"] == "given"
    assert abs(found["yaw_deg"] - 40.0) < 0.1
    # 5 ms off: the vehicle (about 0.5 m/s) is 2.5 mm away from where the ULog has it
    assert 1e-3 < found["residual_m"] < 5e-3
    worst, _, _ = load_error(out)
    assert worst < 8e-3, worst  # measured 6.3 mm: 5 ms of a load moving at up to 1.1 m/s


def test_wrong_time_offset_is_refused_and_no_overlap_said(tmp_path, run_cli):
    ulog = flight_ulog(tmp_path / "flight.ulg")
    csv = mocap_csv(tmp_path / "mocap.csv", mocap_track())
    out = tmp_path / "ds"
    code, _, err = run_cli("import", ulog, "--second", csv, "--time-offset", "10", "--out", out,
                           "--quiet")  # fmt: skip
    assert code == 2 and "alignment residual, RMS (m) = " in err and "(given)" in err, err
    code, _, err = run_cli("import", ulog, "--second", csv, "--time-offset", "1000", "--out", out,
                           "--quiet")  # fmt: skip
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert f"{ulog} and {csv}: with the time offset 1000 s the vehicle tracks do not overlap" in err
    assert "leave --time-offset out" in err
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "flight.ulg",
        "mocap.csv",
    ]


def short_csv(path):
    t, p, p_load = mocap_track()
    keep = t < t[0] + 3.0  # the recording stopped after 3 s
    return mocap_csv(path, (t[keep], p[keep], p_load[keep]))


def csv_without_load(path):
    t, p, _ = mocap_track()
    return write_csv(path, {"time": t, **{f"p_{a}": p[:, i] for i, a in enumerate("xyz")}})


BAD_SECOND = {
    "3 s recording": (short_csv, [], ["covers 3.00 s, shorter than the 5 s", "align_duration"]),
    "no load in it": (csv_without_load, [], ["no column 'p_load_x' (mapping key 'p_load')"]),
    "only attitude missing": (
        lambda path: mocap_csv(path, mocap_track()),
        ["--from-second", "load,attitude"],
        ["no column 'attitude_x' (mapping key 'attitude')"],
    ),
}


@pytest.mark.parametrize("case", list(BAD_SECOND))
def test_bad_second_log_is_named(tmp_path, run_cli, case):
    write, extra, words = BAD_SECOND[case]
    ulog = flight_ulog(tmp_path / "flight.ulg")
    csv = write(tmp_path / "mocap.csv")
    code, _, err = run_cli("import", ulog, "--second", csv, *extra, "--out", tmp_path / "ds")
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "mocap.csv" in err and all(w in err for w in words), err
    assert not (tmp_path / "ds").exists()


def other_flight(t):
    """Another flight over the same room: a slow loop, climbing."""
    a = truth(t)
    a["p"] = np.stack([0.8 * np.cos(0.4 * t), 0.6 * np.sin(0.25 * t), 1.2 + 0.05 * t], axis=1)
    a["p_load"] = a["p"] + np.array([0.0, 0.0, -0.7])
    return a


def scrambled(t):
    """The same flight, its 1 s blocks in another order (a recording's chunks mixed up)."""
    blocks = np.random.default_rng(1).permutation(int(np.ceil(t[-1] - t[0])) + 1)
    k = np.floor(t - t[0]).astype(int)
    return truth(t[0] + blocks[k] + (t - t[0] - k))


@pytest.mark.parametrize("flight", [other_flight, scrambled], ids=["other flight", "scrambled"])
def test_second_log_of_another_flight_is_refused_and_nothing_written(tmp_path, run_cli, flight):
    ulog = flight_ulog(tmp_path / "flight.ulg")
    bag = mocap_bag(tmp_path / "mocap.bag", mocap_track(flight=flight))
    out = tmp_path / "ds"
    code, stdout, err = run_cli("import", ulog, "--second", bag, "--out", out, "--quiet")
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    line = lines[0]
    assert line.startswith(f"slungload import: error: {ulog} + {bag} (time offset "), line
    tolerance = ConsistencyLimits().align_floor  # 0.5 mm of noise: the floor rules
    for word in (RESIDUAL, f"(expected <= {tolerance:g}: ", "different flights",
                 "--align-tolerance", "--force"):  # fmt: skip
        assert word in line, (word, line)
    residual = float(line.split(f"{RESIDUAL} = ")[1].split(" ")[0])
    assert residual > 40 * tolerance, line  # measured: 0.43 m (other flight), 1.07 m (scrambled)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == [
        "flight.ulg",
        "mocap.bag",
    ]


# --- the library: more of the second log, a full rotation, the estimate's limits -------------


def test_position_attitude_and_load_from_a_csv_with_any_rotation(tmp_path):
    """The recording's frame tilted as well as turned (``rotation="full"``, Kabsch); its
    attitude is brought back by the same rotation."""
    tilt = frames.rotation_matrix(frames.quat_from_rotvec(np.array([0.2, -0.1, 2.5])))
    t, p, p_load = track = mocap_track(rotation=tilt)
    q = truth(t + SHIFT)["attitude"][:, [3, 0, 1, 2]]  # w-x-y-z, body -> ULog world
    q_mocap = frames.quat_multiply(frames.quat_conjugate(frames.quat_from_matrix(tilt)), q)
    csv = mocap_csv(tmp_path / "mocap.csv", track, attitude=q_mocap[:, [1, 2, 3, 0]])
    ulog = flight_ulog(tmp_path / "flight.ulg")
    second = SecondLog(csv, roles=("load", "position", "attitude"), rotation="full")
    import_logs([ulog], tmp_path / "ds", params=PARAMS, options=ImportOptions(split="train"),
                second=second, progress=False)  # fmt: skip
    found = second_record(tmp_path / "ds", ulog)["alignment"]
    assert abs(found["time_offset_s"] - SHIFT) < 5e-4
    np.testing.assert_allclose(found["rotation"], tilt, atol=1e-3)
    assert found["tilt_deg"] > 5.0
    worst, got, true = load_error(tmp_path / "ds")
    assert worst < 3e-3, worst
    assert np.abs(got["p"] - true["p"]).max() < 3e-3  # the vehicle from the recording too
    assert rotation_angle(got["attitude"], true["attitude"]).max() < 1e-3  # rad


def test_repeated_maneuver_is_ambiguous_until_the_offset_is_given():
    """A figure eight flown again and again fits every few seconds: the offset is refused as
    ambiguous and a given one is used."""
    t1 = np.arange(0.0, 30.0, 0.01)
    t2 = np.arange(-5.0, 35.0, 1 / 120)

    def eight(t):
        return np.stack([np.sin(0.8 * t), 0.5 * np.sin(1.6 * t), 1.0 + 0 * t], axis=1)

    first = Stream("first", t1, eight(t1))
    second = Stream("second", t2 - SHIFT, (eight(t2) - MOVE) @ yaw_matrix(YAW))
    with pytest.raises(LogError, match=r"fit at several time offsets .*--time-offset SECONDS"):
        align_tracks(first, second, what="a and b")
    found = align_tracks(first, second, time_offset=SHIFT)
    assert found.residual < 1e-5 and abs(math.degrees(found.yaw) - 40.0) < 1e-4  # h^2/8 |a|

    def line(t):  # a straight line at one speed: nothing to correlate
        return np.stack([0.5 * t, 0 * t, 1.0 + 0 * t], axis=1)

    with pytest.raises(LogError, match=r"no stretch of 15\.0 s .* in which the speed varies"):
        align_tracks(Stream("a", t1, line(t1)), Stream("b", t2, line(t2)), what="a and b")


def test_a_vehicle_that_hardly_moves_cannot_fix_the_frame(tmp_path):
    def hover(t):
        a = truth(t)
        a["p"] = np.stack([0.02 * np.sin(t), 0.01 * np.cos(t), 1.0 + 0 * t], axis=1)
        a["p_load"] = a["p"] + np.array([0.0, 0.0, -0.7])
        return a

    ulog = tmp_path / "flight.ulg"
    periods = {"position": 10_000, "attitude": 4_000, "rates": 20_000, "thrust": 20_000}
    us = {k: np.arange(5_000_000, 25_000_000, r) for k, r in periods.items()}
    topics = px4_topics(us, with_load=False)
    p = hover(us["position"] * 1e-6)["p"]  # the ULog's vehicle hovers too
    for i, axis in enumerate("yxz"):  # ENU -> NED
        topics[("vehicle_local_position", 0)][axis] = p[:, i] * (-1 if axis == "z" else 1)
    write_ulog(ulog, topics, {"MPC_THR_HOVER": HOVER})
    csv = mocap_csv(tmp_path / "mocap.csv", mocap_track(flight=hover))
    with pytest.raises(LogError, match="fit at several time offsets"):
        import_logs([ulog], tmp_path / "a", second=SecondLog(csv), progress=False)
    second = SecondLog(csv, time_offset=SHIFT)
    with pytest.raises(
        ConsistencyError, match=rf"{re.escape(SPREAD)} = 0\.01.*hardly moves.*--force"
    ):
        import_logs([ulog], tmp_path / "b", second=second, progress=False)
    result = import_logs([ulog], tmp_path / "c", second=second, progress=False,
                         options=ImportOptions(force=True, split="train"))  # fmt: skip
    assert any(n.startswith("forced: ") and SPREAD in n for n in result.notes)
    assert second_record(tmp_path / "c", ulog)["forced"]


def test_rigid_fit_and_rotation_quaternion_on_known_transforms():
    rng = np.random.default_rng(0)
    b = rng.normal(size=(50, 3))
    for r in (yaw_matrix(math.pi), yaw_matrix(-2.0)):  # half a turn: no small divisor
        r_found, c_found = fit_rigid(b @ r.T + MOVE, b, "yaw")
        np.testing.assert_allclose(r_found, r, atol=1e-12)
        np.testing.assert_allclose(c_found, MOVE, atol=1e-12)
        q = frames.quat_from_matrix(r)
        np.testing.assert_allclose(frames.rotation_matrix(q), r, atol=1e-12)
    r = frames.rotation_matrix(frames.quat_from_rotvec(np.array([0.3, -2.0, 1.0])))
    r_found, _ = fit_rigid(b @ r.T, b, "full")
    np.testing.assert_allclose(r_found, r, atol=1e-12)
    assert np.linalg.det(fit_rigid(-b, b, "full")[0]) == pytest.approx(1.0)  # no reflection


def test_second_log_options_are_checked(tmp_path, run_cli):
    with pytest.raises(ValueError, match="some of position, attitude, velocity, load"):
        SecondLog(tmp_path / "x.bag", roles=("pL",))
    with pytest.raises(ValueError, match="rotation must be one of"):
        SecondLog(tmp_path / "x.bag", rotation="pitch")
    code, _, err = run_cli("import", tmp_path, "--time-offset", "3", "--out", tmp_path / "o")
    assert code == 2 and "need --second LOG" in err
