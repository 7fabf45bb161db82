"""Flight logs into datasets (``slungload import``), the authors' release layout, vehicle keys.

The logs are written by ``log_files.py`` (rosbags' own writers, a ULog writer, CSV by hand);
each is imported back and compared with what was written.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from log_files import (
    CMD,
    HOVER,
    LOAD,
    PARAMS,
    POSE,
    THRUST_PER_THROTTLE,
    VEL,
    Msgs,
    import_to_train,
    imported,
    mavros_topics,
    rotation_angle,
    truth,
    typestore,
    write_bag,
)
from rosbags.typesys import get_types_from_msg

from slungload.cli import main
from slungload.config import VehicleParams
from slungload.data.dataset import load_dataset
from slungload.data.folder import read_splits
from slungload.data.importing import (
    ImportOptions,
    backward_velocity,
    import_logs,
)
from slungload.data.readers.logs import LogError
from slungload.data.readers.rosbag import MSG_DEFINITIONS
from slungload.vehicle_file import load_vehicle


def simulated_flight() -> dict[str, np.ndarray]:
    """A short MuJoCo flight (noisy mocap, the PID's commands) in the published schema."""
    from slungload.sim import simulate_flight

    return simulate_flight("fast_ellipses_xy", seed=3, steps=70).arrays


def sim_params() -> VehicleParams:
    from slungload.sim import SimConfig, vehicle_params

    return vehicle_params(SimConfig())


# --- round trips through bags ------------------------------------------------------------------


@pytest.mark.parametrize("ros1", [False, True], ids=["ros2-mcap", "ros1-bag"])
def test_simulated_flight_round_trip_through_a_bag(tmp_path, ros1):
    """Every topic at the flight's own instants and dt = the flight's step: the grid falls on
    the samples, so the interpolation error is zero and the import returns the flight (thrust
    to float32, the AttitudeTarget's type)."""
    arrays, params = simulated_flight(), sim_params()
    store = typestore(ros1)
    bag = write_bag(
        tmp_path / ("flight.bag" if ros1 else "flight"),
        mavros_topics(Msgs(store, ros1), arrays),
        store,
        ros1=ros1,
    )
    result = import_to_train(bag, tmp_path / "ds", params)
    assert result.flights == {"flight": 70}
    got = imported(tmp_path / "ds")["flight"]
    np.testing.assert_allclose(got["time"], arrays["time"], atol=1e-12)
    for key in ("p", "v", "p_load", "w_ref"):
        np.testing.assert_allclose(got[key], arrays[key], atol=1e-6, err_msg=key)
    assert rotation_angle(got["attitude"], arrays["attitude"]).max() < 1e-6
    np.testing.assert_allclose(got["T_ref"], arrays["T_ref"], rtol=1e-6)
    ds = load_dataset(tmp_path / "ds", use_cache=False, window=_window())
    assert ds.params == params and list(ds.flights) == ["flight"]


def _window():
    from slungload.config import WindowConfig

    return WindowConfig(history=10, horizon=5)


@pytest.mark.parametrize(
    ("ros1", "storage"), [(False, "sqlite3"), (True, "bag")], ids=["ros2-sqlite3", "ros1-bag"]
)
def test_multi_rate_bag_matches_the_flight_within_the_interpolation_error(tmp_path, ros1, storage):
    """Mocap at 120 Hz with jitter, velocity at 50 Hz, commands at 40 Hz, none on the 30 ms
    grid: positions and attitude within the linear / slerp bound h^2/8 max|f''|, commands
    within the hold bound h max|f'|."""
    rng = np.random.default_rng(0)
    span = 4.0

    def stamps(rate: float, offset: float) -> np.ndarray:
        t = offset + np.arange(0, span, 1 / rate)
        return t + rng.uniform(-0.1, 0.1, len(t)) / rate

    times = {POSE: stamps(120, 0.003), LOAD: stamps(120, 0.001), VEL: stamps(50, 0.0)}
    times[CMD] = stamps(40, 0.01)
    store = typestore(ros1)
    name = "multi.bag" if ros1 else "multi"
    bag = write_bag(
        tmp_path / name,
        mavros_topics(Msgs(store, ros1), {}, times),
        store,
        ros1=ros1,
        storage=storage,
    )
    import_to_train(bag, tmp_path / "ds")
    got = imported(tmp_path / "ds")["multi"]
    start = max(t[0] for t in times.values())
    expected = truth(start + got["time"])
    h_mocap, h_vel, h_cmd = 1.1 / 120, 1.1 / 50, 1.1 / 40
    # |p''| <= 0.25, |pL''| <= 0.25 + 9 * 0.7 * sin 0.3; |v''| <= 0.125; |w'|, |T'| <= 0.1
    assert np.abs(got["p"] - expected["p"]).max() < h_mocap**2 / 8 * 0.3 + 1e-6
    assert np.abs(got["p_load"] - expected["p_load"]).max() < h_mocap**2 / 8 * 2.2 + 1e-6
    assert np.abs(got["v"] - expected["v"]).max() < h_vel**2 / 8 * 0.15 + 1e-6
    assert rotation_angle(got["attitude"], expected["attitude"]).max() < h_mocap**2 / 8 * 0.5
    assert np.abs(got["w_ref"] - expected["w_ref"]).max() < h_cmd * 0.1 + 1e-6
    assert np.abs(got["T_ref"] - expected["T_ref"]).max() < h_cmd * 0.1 + 1e-4
    end = min(t[-1] for t in times.values())
    assert len(got["time"]) == int((end - start) / PARAMS.dt) + 1


def test_velocity_from_finite_differences_when_the_bag_has_none(tmp_path):
    t = np.arange(0, 3, 0.01)
    store = typestore(False)
    topics = mavros_topics(Msgs(store, False), {}, {POSE: t, LOAD: t, VEL: t, CMD: t})
    del topics[VEL]
    bag = write_bag(tmp_path / "novel", topics, store, ros1=False)
    result = import_logs(
        [bag],
        tmp_path / "ds",
        mapping={"velocity": ""},
        options=ImportOptions(hover_throttle=HOVER),
        progress=False,
    )
    assert any("finite difference" in n for n in result.notes)
    assert any("paper's are used" in n for n in result.notes)
    got = imported(tmp_path / "ds")["novel"]
    expected = truth(got["time"])
    # BDF2: error h^2/3 |p'''| (|p'''| <= 0.125) from step 2; steps 0, 1 first order h/2 |p''|
    assert np.abs(got["v"][2:] - expected["v"][2:]).max() < PARAMS.dt**2 / 3 * 0.13 + 1e-5
    assert np.abs(got["v"][:2] - expected["v"][:2]).max() < PARAMS.dt / 2 * 0.26


def test_px4_ros2_preset_with_vehicle_rates_setpoint(tmp_path):
    """PX4 over ROS 2: px4_msgs/VehicleRatesSetpoint (FRD rates, thrust_body[2] negative up)
    registered from MSG_DEFINITIONS, mocap from vrpn_mocap, no velocity topic."""
    from slungload.data.readers.rosbag import RATES_SETPOINT

    store = typestore(False)
    store.register(get_types_from_msg(MSG_DEFINITIONS[RATES_SETPOINT], RATES_SETPOINT))
    m = Msgs(store, False)
    t = np.arange(0, 3, 0.01)
    topics = mavros_topics(m, {}, dict.fromkeys((POSE, LOAD, VEL, CMD), t))
    a = truth(t)
    setpoints = [
        store.types[RATES_SETPOINT](
            timestamp=0,
            roll=float(a["w_ref"][i, 0]),
            pitch=float(-a["w_ref"][i, 1]),
            yaw=float(-a["w_ref"][i, 2]),
            thrust_body=np.array([0, 0, -a["T_ref"][i, 0] / THRUST_PER_THROTTLE], np.float32),
            reset_integral=False,
        )
        for i in range(len(t))
    ]
    px4 = {
        "/vrpn_mocap/quad/pose": topics[POSE],
        "/vrpn_mocap/load/pose": topics[LOAD],
        "/fmu/in/vehicle_rates_setpoint": (
            RATES_SETPOINT,
            [(ns, s) for (ns, _), s in zip(topics[CMD][1], setpoints, strict=True)],
        ),
    }
    bag = write_bag(tmp_path / "px4bag", px4, store, ros1=False)
    result = import_logs(
        [bag],
        tmp_path / "ds",
        params=PARAMS,
        preset="px4",
        options=ImportOptions(hover_throttle=HOVER),
        progress=False,
    )
    assert any("finite difference" in n for n in result.notes)
    got = imported(tmp_path / "ds")["px4bag"]
    expected = truth(got["time"])
    np.testing.assert_allclose(got["w_ref"], expected["w_ref"], atol=1e-6)
    np.testing.assert_allclose(got["T_ref"], expected["T_ref"], rtol=1e-6)


def test_backward_velocity_is_causal_and_exact_for_a_quadratic():
    t = 0.03 * np.arange(20)
    p = np.stack([t**2, 3 * t, 0 * t], axis=1)
    v = backward_velocity(p, 0.03)
    np.testing.assert_allclose(v[2:], np.stack([2 * t, 3 + 0 * t, 0 * t], axis=1)[2:], atol=1e-12)
    changed = p.copy()
    changed[10:] += 1.0  # the future does not move the past
    np.testing.assert_array_equal(backward_velocity(changed, 0.03)[:10], v[:10])


def test_gap_splits_the_flight_and_short_pieces_are_dropped(tmp_path):
    t = np.arange(0, 5, 0.01)
    store = typestore(False)
    keep = (t < 2.0) | (t > 2.5)
    topics = mavros_topics(
        Msgs(store, False), {}, {POSE: t[keep], LOAD: t, VEL: t, CMD: np.arange(0, 5, 0.02)}
    )
    bag = write_bag(tmp_path / "gappy", topics, store, ros1=False)
    result = import_to_train(bag, tmp_path / "ds")
    assert sorted(result.flights) == ["gappy_00", "gappy_01"]
    flights = imported(tmp_path / "ds")
    assert abs(len(flights["gappy_00"]["time"]) * PARAMS.dt - 2.0) < 2 * PARAMS.dt
    result = import_logs(
        [bag],
        tmp_path / "ds2",
        params=PARAMS,
        options=ImportOptions(hover_throttle=HOVER, min_duration=2.2),
        progress=False,
    )
    assert list(result.flights) == ["gappy"] and any("dropped" in n for n in result.notes)


def test_a_clean_10_hz_stream_has_no_gap_at_the_default_max_gap(tmp_path):
    # 0.1 s steps from nanosecond stamps round to a hair over 0.1 s: not a gap at --max-gap 0.1
    t = np.arange(0, 5, 0.01)
    store = typestore(False)
    topics = mavros_topics(Msgs(store, False), {},
                           {POSE: np.arange(0, 5, 0.1), LOAD: t, VEL: t, CMD: t[::2]})  # fmt: skip
    bag = write_bag(tmp_path / "slow", topics, store, ros1=False)
    result = import_to_train(bag, tmp_path / "ds")
    assert list(result.flights) == ["slow"] and not any("gap" in n for n in result.notes)


# --- bad logs: one clear line, exit status 2, nothing written ------------------------------------


def _bad_bag(tmp_path: Path, spoil) -> Path:
    t = np.arange(0, 3, 0.01)
    store = typestore(False)
    msgs = Msgs(store, False)
    topics = mavros_topics(msgs, {}, {POSE: t, LOAD: t, VEL: t, CMD: t})
    spoil(topics, msgs)
    return write_bag(tmp_path / "bad", topics, store, ros1=False)


def _drop(topic):
    def spoil(topics, msgs):
        del topics[topic]

    return spoil


def _wrong_type(topics, msgs):
    topics[LOAD] = (
        "geometry_msgs/msg/TwistStamped",
        [(ns, msgs.twist(ns, (0, 0, 0))) for ns, _ in topics[LOAD][1]],
    )


def _gap(topics, msgs):
    kind, rows = topics[POSE]
    topics[POSE] = (kind, rows[:100] + rows[150:])


def _out_of_order(topics, msgs):
    """Messages 40 and 41 swapped, bag times kept: the header stamps go back at 41."""
    kind, rows = topics[LOAD]
    swapped = [m for _, m in rows]
    swapped[40], swapped[41] = swapped[41], swapped[40]
    topics[LOAD] = (kind, [(ns, m) for (ns, _), m in zip(rows, swapped, strict=True)])


def _never_seen(topics, msgs):
    kind, rows = topics[LOAD]
    topics[LOAD] = (kind, [(ns, msgs.pose(ns, (np.nan, np.nan, np.nan))) for ns, _ in rows])


def _no_load_messages(topics, msgs):
    kind, _ = topics[LOAD]
    topics[LOAD] = (kind, [])


def _ignored_rates(topics, msgs):
    kind, rows = topics[CMD]
    topics[CMD] = (kind, [(ns, msgs.command(ns, (0, 0, 0), 14.0, mask=7)) for ns, _ in rows])


BAD_BAGS = {
    "missing topic": (_drop(LOAD), [LOAD, "no topic", "the bag has"], []),
    "wrong message type": (_wrong_type, [LOAD, "TwistStamped", "PoseStamped"], []),
    "gap longer than the limit": (
        _gap,
        [POSE, "no sample for 0.5", "--max-gap 0.1"],
        ["--on-gap", "error"],
    ),
    "stamps out of order": (_out_of_order, [LOAD, "out of order at message 41"], []),
    "load never seen": (_never_seen, [LOAD, "load is never seen", "300 messages but none"], []),
    "load topic empty": (_no_load_messages, [LOAD, "load is never seen", "no message"], []),
    "rates ignored": (_ignored_rates, [CMD, "type_mask 7", "body rates"], []),
}


@pytest.mark.parametrize("case", list(BAD_BAGS))
def test_bad_bag_is_one_clear_error_and_writes_nothing(tmp_path, capsys, case):
    spoil, words, extra = BAD_BAGS[case]
    bag = _bad_bag(tmp_path, spoil)
    before = sorted(p.name for p in tmp_path.iterdir())
    out = tmp_path / "ds"
    code = main(
        ["import", str(bag), "--out", str(out), "--hover-throttle", "0.4", "--quiet", *extra]
    )
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("slungload import: error: "), err
    for word in [str(bag), *words]:
        assert word in lines[0], (word, lines[0])
    assert sorted(p.name for p in tmp_path.iterdir()) == before  # no ds, no temporary folder


def test_one_bad_log_among_good_ones_leaves_the_old_folder_untouched(tmp_path):
    """Logs are all read and checked before anything is written; --overwrite replaces the
    folder only once the new one is complete."""
    t = np.arange(0, 2, 0.01)
    store = typestore(False)
    logs = tmp_path / "logs"
    logs.mkdir()
    good = mavros_topics(Msgs(store, False), {}, dict.fromkeys((POSE, LOAD, VEL, CMD), t))
    write_bag(logs / "a_good", good, store, ros1=False)
    write_bag(logs / "b_bad", {k: v for k, v in good.items() if k != LOAD}, store, ros1=False)
    out = tmp_path / "ds"
    out.mkdir()
    (out / "old.txt").write_text("previous dataset")
    options = ImportOptions(hover_throttle=HOVER)
    with pytest.raises(LogError, match=f"b_bad: no topic '{LOAD}'"):
        import_logs([logs], out, params=PARAMS, options=options, overwrite=True, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds", "logs"]
    assert [p.name for p in out.iterdir()] == ["old.txt"]
    import_logs([logs / "a_good"], out, options=options, overwrite=True, progress=False)
    assert sorted(p.name for p in out.iterdir()) == [
        "data",
        "test.txt",
        "train.txt",
        "val.txt",
        "vehicle.json",
    ]


def plain_ros2_bag(path):
    """A 2 s ROS 2 bag of the default MAVROS topics, every one at 100 Hz."""
    t = np.arange(0, 2, 0.01)
    store = typestore(False)
    topics = mavros_topics(Msgs(store, False), {}, dict.fromkeys((POSE, LOAD, VEL, CMD), t))
    return write_bag(path, topics, store, ros1=False)


def test_normalised_thrust_needs_a_hover_throttle(tmp_path):
    bag = plain_ros2_bag(tmp_path / "b")
    with pytest.raises(LogError, match=f"{CMD} is a normalised throttle.*--hover-throttle"):
        import_logs([bag], tmp_path / "ds", params=PARAMS, progress=False)
    assert not (tmp_path / "ds").exists()


def test_existing_folder_is_refused_unless_overwrite(tmp_path):
    out = tmp_path / "ds"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="not empty"):
        import_logs([tmp_path / "none.bag"], out, progress=False)
    assert (out / "keep.txt").read_text() == "mine"


def test_unknown_mapping_key_lists_the_known_ones(tmp_path):
    bag = plain_ros2_bag(tmp_path / "b")
    with pytest.raises(LogError, match=r"unknown mapping keys \['lod_pose'\].*load_pose"):
        import_logs([bag], tmp_path / "ds", mapping={"lod_pose": "/x"}, progress=False)


def test_mapping_file_and_cli_import_then_inspect(tmp_path, capsys):
    t = np.arange(0, 4, 0.01)
    store = typestore(False)
    topics = mavros_topics(Msgs(store, False), {}, dict.fromkeys((POSE, LOAD, VEL, CMD), t))
    renamed = {"/optitrack/drone": topics[POSE], "/optitrack/box": topics[LOAD], CMD: topics[CMD]}
    bags = tmp_path / "bags"
    bags.mkdir()
    for i in range(3):
        write_bag(bags / f"run_{i}", renamed, store, ros1=False)
    mapping = tmp_path / "topics.toml"
    mapping.write_text(
        '[ros]\nvehicle_pose = "/optitrack/drone"\nload_pose = "/optitrack/box"\nvelocity = ""\n'
    )
    vehicle = tmp_path / "my_vehicle.json"
    vehicle.write_text(json.dumps({"mass_quadrotor": 1.5, "load_mass": 0.2, "rope_length": 0.65}))
    out = tmp_path / "ds"
    code = main(
        ["import", str(bags), "--out", str(out), "--map", str(mapping), "--vehicle", str(vehicle),
         "--hover-throttle", "0.45", "--quiet"]
    )  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "imported 3 flight(s)" in captured.out and "finite difference" in captured.out
    assert sorted(p.name for p in out.iterdir()) == [
        "data",
        "test.txt",
        "train.txt",
        "val.txt",
        "vehicle.json",
    ]
    splits = read_splits(out)  # a seeded draw by flight: one each for three equal flights
    assert sorted(n for v in splits.values() for n in v) == ["run_0", "run_1", "run_2"]
    assert all(len(v) == 1 for v in splits.values())
    assert all(
        line.endswith(".npz")
        for s in ("train", "val", "test")
        for line in (out / f"{s}.txt").read_text().split()
    )
    params = load_vehicle(out)
    assert (params.mass_quad, params.mass_load, params.cable_length) == (1.5, 0.2, 0.65)
    meta = json.loads((out / "vehicle.json").read_text())["import"]
    assert meta["interpolation"]["attitude"] == "slerp" and len(meta["flights"]) == 3
    assert main(["inspect", str(out), "--history", "10", "--horizon", "5"]) == 0
    assert "run_0" not in capsys.readouterr().err
