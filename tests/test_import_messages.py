"""Messages of ``slungload import`` that send the user the right way.

ULogs are written by ``log_files.write_ulog`` and rewritten by pyulog's own writer
(``ULog.write_ulog``: a stock log's invalid flags, a log cut in half, a disarmed ending);
bags by rosbags' writers; CSV by hand.
"""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest
from log_files import (
    HOVER,
    LOAD,
    PARAMS,
    POSE,
    VEL,
    Msgs,
    default_columns,
    imported,
    mavros_topics,
    px4_topics,
    truth,
    typestore,
    write_bag,
    write_csv,
    write_ulog,
)

from slungload import frames
from slungload.cli import main
from slungload.data.importing import ImportOptions, import_logs
from slungload.data.readers.logs import LogError

LOAD_TOPIC = {"load": "vehicle_mocap_odometry:1"}


def ulog(path, rates=None, extra=None, duration_us=3_000_000):
    """A PX4 log of the truth flight: every topic at 100 Hz unless ``rates`` says otherwise
    (role -> period in us), plus ``extra`` topics."""
    periods = {"position": 10_000, "attitude": 4_000, "rates": 20_000, "thrust": 20_000,
               "load": 10_000, **(rates or {})}  # fmt: skip
    us = {k: np.arange(0, duration_us, r) for k, r in periods.items()}
    topics = {**px4_topics(us), **(extra or {})}
    return write_ulog(path, topics, {"MPC_THR_HOVER": HOVER})


def rewrite(path, out, change):
    """``change(topic name, fields)`` -> new fields, on every topic; written by pyulog."""
    from pyulog import ULog

    log = ULog(str(path))
    for d in log.data_list:
        d.data = change(d.name, d.data)
    log.write_ulog(str(out))
    return out


def test_stock_px4_position_at_5_hz_names_the_topic_and_the_option(tmp_path):
    log = ulog(tmp_path / "stock.ulg", rates={"position": 200_000})
    with pytest.raises(LogError) as err:
        import_logs([log], tmp_path / "a", params=PARAMS, mapping=LOAD_TOPIC, progress=False)
    text = str(err.value)
    for word in ("topic vehicle_local_position:0", "sampled every 0.200 s", "--max-gap 0.1",
                 "--min-duration", "--on-gap error", "h^2/8"):  # fmt: skip
        assert word in text, (word, text)
    options = ImportOptions(max_gap=0.25, split="train")
    import_logs([log], tmp_path / "b", params=PARAMS, mapping=LOAD_TOPIC, options=options,
                progress=False)  # fmt: skip
    got = imported(tmp_path / "b")["stock"]
    expected = truth(got["time"])  # every stream starts at 0
    # linear interpolation over 0.2 s: h^2 / 8 max|a| = 0.04 / 8 * 0.25 m/s^2 = 1.25 mm
    assert np.abs(got["p"] - expected["p"]).max() < 0.04 / 8 * 0.26


def test_stock_px4_position_at_10_hz_imports_at_the_default_max_gap(tmp_path):
    # its 0.1 s steps from microsecond stamps are no gap at --max-gap 0.1 (rounding aside)
    log = ulog(tmp_path / "stock.ulg", rates={"position": 100_000})
    options = ImportOptions(split="train")
    import_logs([log], tmp_path / "b", params=PARAMS, mapping=LOAD_TOPIC, options=options,
                progress=False)  # fmt: skip
    got = imported(tmp_path / "b")["stock"]
    # linear interpolation over 0.1 s: h^2 / 8 max|a| = 0.01 / 8 * 0.25 m/s^2 = 0.3 mm
    assert np.abs(got["p"] - truth(got["time"])["p"]).max() < 0.01 / 8 * 0.26


def test_load_topic_error_lists_only_topics_with_a_position(tmp_path):
    n = 30
    t = np.arange(n) * 100_000
    xyz = {a: np.zeros(n) for a in "xyz"}
    extra = {
        ("sensor_accel", 0): {"timestamp": t, **xyz},
        ("sensor_gyro", 0): {"timestamp": t, **xyz},
        ("manual_control_setpoint", 0): {"timestamp": t, **xyz, "r": np.zeros(n)},
        ("vehicle_magnetometer", 0): {"timestamp": t,
                                      **{f"magnetometer_ga[{i}]": np.zeros(n) for i in range(3)}},
    }  # fmt: skip
    pos = {"timestamp": t, **xyz, **{f"v{a}": np.zeros(n) for a in "xyz"}}
    extra[("vehicle_local_position_setpoint", 0)] = pos  # a set-point, not a body
    log = ulog(tmp_path / "px4.ulg", extra=extra)
    with pytest.raises(LogError, match=r"topics with a position \(not the vehicle's own, "
                       r"vehicle_local_position:0, nor set-points\): "
                       r"vehicle_mocap_odometry:1$"):  # fmt: skip
        import_logs([log], tmp_path / "x", params=PARAMS, progress=False)


def test_positions_all_flagged_invalid_say_so(tmp_path):
    from pyulog import ULog

    topics = px4_topics({k: np.arange(0, 3_000_000, 10_000) for k in
                         ("position", "attitude", "rates", "thrust", "load")})  # fmt: skip
    topics[("vehicle_local_position", 0)]["xy_valid"] = np.ones(300)  # declares the field
    base = write_ulog(tmp_path / "base.ulg", topics, {"MPC_THR_HOVER": HOVER})

    def invalid(name, data):  # the estimator never had a position
        if name == "vehicle_local_position":
            data = {**data, "xy_valid": np.zeros_like(data["xy_valid"])}
        return data

    log = rewrite(base, tmp_path / "stock.ulg", invalid)
    assert not ULog(str(log)).get_dataset("vehicle_local_position").data["xy_valid"].any()
    with pytest.raises(LogError, match=r"topic vehicle_local_position:0 \(position\) has 300 "
                       r"samples, all flagged invalid.*vehicle_mocap_odometry:0"):  # fmt: skip
        import_logs([log], tmp_path / "x", params=PARAMS, mapping=LOAD_TOPIC, progress=False)


def test_load_mapped_to_the_vehicles_topic_is_refused_by_name(tmp_path, capsys):
    log = ulog(tmp_path / "px4.ulg")
    with pytest.raises(LogError, match=r"load is mapped to the vehicle's own position topic "
                       r"vehicle_local_position:0.*\|pL - p\| would be 0"):  # fmt: skip
        mapping = {"load": "vehicle_local_position"}
        import_logs([log], tmp_path / "x", params=PARAMS, mapping=mapping, progress=False)
    store = typestore(False)
    t = np.arange(0, 2, 0.01)
    bag = write_bag(tmp_path / "bag", mavros_topics(Msgs(store, False), {}, dict.fromkeys(
        (POSE, LOAD, VEL, "/mavros/setpoint_raw/attitude"), t)), store, ros1=False)  # fmt: skip
    mapping = tmp_path / "map.json"
    mapping.write_text(f'{{"load_pose": "{POSE}"}}')
    code = main(["import", str(bag), "--out", str(tmp_path / "ds"), "--map", str(mapping),
                 "--hover-throttle", str(HOVER), "--quiet"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and f"load is mapped to the vehicle's own topic {POSE}" in err, err
    columns = tmp_path / "cols.json"
    columns.write_text('{"p_load": ["p_x", "p_y", "p_z"]}')
    csv = write_csv(tmp_path / "f.csv", default_columns(truth(PARAMS.dt * np.arange(60))))
    code = main(["import", str(csv), "--out", str(tmp_path / "ds"), "--map", str(columns)])
    assert code == 2 and "the load's columns (mapping key 'p_load') are the vehicle's" in (
        capsys.readouterr().err
    )


def test_one_odometry_topic_serves_pose_and_velocity(tmp_path):
    """A topic mapped to two keys (nav_msgs/Odometry: the pose and the body-frame twist)
    feeds both, instead of leaving one without a sample."""
    store = typestore(False)
    m = Msgs(store, False)
    t = np.arange(0, 2, 0.01)
    topics = mavros_topics(m, {}, dict.fromkeys((POSE, LOAD, VEL, "/mavros/setpoint_raw/attitude"),
                                               t))  # fmt: skip
    a = truth(t)
    q = a["attitude"][:, [3, 0, 1, 2]]
    v_body = frames.rotate(frames.quat_conjugate(q), a["v"])
    rows = []
    for i, (ns, pose_msg) in enumerate(topics.pop(POSE)[1]):
        pose = store.types["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose_msg.pose, covariance=np.zeros(36)
        )
        twist = store.types["geometry_msgs/msg/Twist"](
            linear=m.vec(v_body[i]), angular=m.vec((0, 0, 0))
        )
        twist = store.types["geometry_msgs/msg/TwistWithCovariance"](
            twist=twist, covariance=np.zeros(36)
        )
        rows.append(
            (
                ns,
                store.types["nav_msgs/msg/Odometry"](
                    header=pose_msg.header, child_frame_id="quad", pose=pose, twist=twist
                ),
            )
        )
    del topics[VEL]
    topics["/odom"] = ("nav_msgs/msg/Odometry", rows)  # fmt: skip
    bag = write_bag(tmp_path / "odom", topics, store, ros1=False)
    options = ImportOptions(hover_throttle=HOVER, split="train")
    import_logs([bag], tmp_path / "ds", params=PARAMS, mapping={"vehicle_pose": "/odom",
                "velocity": "/odom"}, options=options, progress=False)  # fmt: skip
    got = imported(tmp_path / "ds")["odom"]
    expected = truth(got["time"])
    assert np.abs(got["v"] - expected["v"]).max() < 1e-4


def test_missing_velocity_topic_says_how_to_use_finite_differences(tmp_path):
    log = ulog(tmp_path / "px4.ulg")
    with pytest.raises(LogError, match=r"no topic 'odometry' \(mapping key 'velocity'\).*"
                       r'velocity = "" takes the velocity from finite differences'):  # fmt: skip
        import_logs([log], tmp_path / "x", params=PARAMS, progress=False,
                    mapping={**LOAD_TOPIC, "velocity": "odometry"})  # fmt: skip


def test_a_ulog_cut_short_is_noted_a_disarmed_one_is_not(tmp_path):
    log = ulog(tmp_path / "px4.ulg", duration_us=4_000_000)

    def disarmed(name, data):  # the last 0.5 s on the ground: no thrust
        if name == "vehicle_thrust_setpoint":
            late = data["timestamp"] > 3_500_000
            data = {**data, "xyz[2]": np.where(late, 0.0, data["xyz[2]"])}
        return data

    def half(name, data):
        keep = data["timestamp"] < 2_000_000
        return {k: v[keep] for k, v in data.items()}

    kw = {"params": PARAMS, "mapping": LOAD_TOPIC, "progress": False,
          "options": ImportOptions(split="train")}  # fmt: skip
    whole = import_logs([rewrite(log, tmp_path / "whole.ulg", disarmed)], tmp_path / "a", **kw)
    assert not any("ends abruptly" in n for n in whole.notes)
    cut = import_logs([rewrite(log, tmp_path / "cut.ulg", half)], tmp_path / "b", **kw)
    assert any("cut.ulg: the log ends abruptly, with the vehicle in the air" in n
               for n in cut.notes), cut.notes  # fmt: skip


def test_hover_throttle_with_thrust_in_newtons_is_said_to_be_unused(tmp_path, capsys):
    log = write_csv(tmp_path / "f.csv", default_columns(truth(PARAMS.dt * np.arange(60))))
    code = main(["import", str(log), "--out", str(tmp_path / "ds"), "--hover-throttle", "0.5",
                 "--quiet"])  # fmt: skip
    out = capsys.readouterr().out
    assert code == 0 and "--hover-throttle 0.5 not used: its thrust (column T_ref)" in out, out
    argv = ["import", str(log), "--out", str(tmp_path / "e"), "--hover-throttle", "0.5"]
    with pytest.raises(SystemExit) as exit_:  # argparse: one of the two thrust maps
        main([*argv, "--newtons-per-throttle", "30"])
    assert exit_.value.code == 2 and "not allowed with" in capsys.readouterr().err


def test_a_dropout_split_note_names_the_stream_and_the_option(tmp_path):
    columns = default_columns(truth(PARAMS.dt * np.arange(200)))
    for a in "xyz":
        columns[f"p_load_{a}"][90:97] = np.nan
    log = write_csv(tmp_path / "f.csv", columns)
    result = import_logs([log], tmp_path / "ds", params=PARAMS, progress=False)
    assert any(
        "split at 1 gap(s) longer than --max-gap 0.1 s (columns p_load_x, p_load_y, "
        "p_load_z: 1 gap(s), the longest 0.240 s)" in n
        for n in result.notes
    ), result.notes


def test_output_folders_have_the_usual_permissions(tmp_path):
    umask = os.umask(0o022)
    try:
        log = write_csv(tmp_path / "f.csv", default_columns(truth(PARAMS.dt * np.arange(60))))
        import_logs([log], tmp_path / "ds", params=PARAMS, progress=False)
    finally:
        os.umask(umask)
    mode = {
        p.name: stat.S_IMODE(p.stat().st_mode)
        for p in [tmp_path / "ds", tmp_path / "ds" / "data", *(tmp_path / "ds").rglob("*.*")]
    }
    assert mode.pop("ds") == 0o755 and mode.pop("data") == 0o755, mode
    assert set(mode.values()) == {0o644}, mode
