"""Log formats one by one: frame conversions, PX4 ULog, CSV, the authors' release layout and
vehicle keys, the log-reader registry (bags: ``test_readers.py``). Logs are written by
``log_files.py``."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import numpy as np
import pytest
from log_files import (
    HOVER,
    PARAMS,
    THRUST_PER_THROTTLE,
    default_columns,
    imported,
    px4_topics,
    rotation_angle,
    truth,
    write_csv,
    write_ulog,
)

from slungload import frames
from slungload.cli import main
from slungload.config import VehicleParams
from slungload.data.dataset import load_dataset
from slungload.data.flight import DatasetError
from slungload.data.folder import read_splits
from slungload.data.importing import (
    ImportOptions,
    find_logs,
    import_logs,
    read_log,
)
from slungload.data.readers import LOG_READERS, read_flight
from slungload.data.readers.logs import LogError
from slungload.data.readers.ulog import ulog_streams
from slungload.data.summary import summarize
from slungload.fileio import write_json, write_npz, write_splits
from slungload.vehicle_file import load_vehicle, vehicle_from_dict


def _window():
    from slungload.config import WindowConfig

    return WindowConfig(history=10, horizon=5)


# --- frames -------------------------------------------------------------------------------------


def test_ned_and_frd_vectors():
    np.testing.assert_array_equal(frames.world_vectors([1.0, 2.0, -3.0], "ned"), [2.0, 1.0, 3.0])
    np.testing.assert_array_equal(frames.world_vectors([1.0, 2.0, 3.0], "enu"), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(frames.body_vectors([1.0, 2.0, 3.0], "frd"), [1.0, -2.0, -3.0])
    with pytest.raises(ValueError, match="unknown world frame 'nwu'"):
        frames.world_vectors([0, 0, 0], "nwu")


def _axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis])


def test_px4_attitudes_on_known_rotations():
    e = np.eye(3)
    # level, nose north: in ENU the nose points along +y (yaw +90 deg), up is up
    q = frames.attitudes(_axis_angle([0, 0, 1], 0.0), "ned", "frd")
    np.testing.assert_allclose(q, _axis_angle([0, 0, 1], np.pi / 2), atol=1e-12)
    # yaw 90 deg in NED (nose east): ENU identity
    q = frames.attitudes(_axis_angle([0, 0, 1], np.pi / 2), "ned", "frd")
    assert min(np.abs(q - [1, 0, 0, 0]).max(), np.abs(q + [1, 0, 0, 0]).max()) < 1e-12
    # pitch up 30 deg (about FRD's right axis), nose north: nose (0, cos, sin) in ENU
    th = np.radians(30)
    q = frames.attitudes(_axis_angle([0, 1, 0], th), "ned", "frd")
    np.testing.assert_allclose(frames.rotate(q, e[0]), [0, np.cos(th), np.sin(th)], atol=1e-12)
    # body up (FLU z) tilts back, away from the nose: (0, -sin, cos)
    np.testing.assert_allclose(frames.rotate(q, e[2]), [0, -np.sin(th), np.cos(th)], atol=1e-12)
    # roll right 20 deg about the nose: FLU's left wing (y) rises
    ph = np.radians(20)
    q = frames.attitudes(_axis_angle([1, 0, 0], ph), "ned", "frd")
    left = frames.rotate(q, e[1])
    np.testing.assert_allclose(left, [-np.cos(ph), 0, np.sin(ph)], atol=1e-12)


def test_attitude_and_rate_conversions_agree_with_the_attitude_update():
    """q+ = q (x) exp(h w / 2) in PX4's frames maps to the same update in ours with the rates
    converted by body_vectors: the attitude and rate conversions are consistent."""
    rng = np.random.default_rng(1)
    q0 = rng.normal(size=4)
    q0 /= np.linalg.norm(q0)
    w, h = rng.normal(size=3), 0.05
    step = _axis_angle(w, h * np.linalg.norm(w))
    q1 = frames.quat_multiply(q0, step)
    w_flu = frames.body_vectors(w, "frd")
    ours = frames.quat_multiply(
        frames.attitudes(q0, "ned", "frd"), _axis_angle(w_flu, h * np.linalg.norm(w_flu))
    )
    np.testing.assert_allclose(ours, frames.attitudes(q1, "ned", "frd"), atol=1e-12)
    # and against rotation matrices: R' = M R B with M: NED -> ENU, B: FLU <-> FRD
    m = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    b = np.diag([1.0, -1.0, -1.0])
    r = np.stack([frames.rotate(q0, col) for col in np.eye(3)], axis=1)
    q = frames.attitudes(q0, "ned", "frd")
    r_conv = np.stack([frames.rotate(q, col) for col in np.eye(3)], axis=1)
    np.testing.assert_allclose(r_conv, m @ r @ b, atol=1e-12)


def test_slerp():
    q0, q1 = _axis_angle([0, 0, 1], 0.0), _axis_angle([0, 0, 1], np.pi / 2)
    got = frames.slerp(np.array([0.0, 0.5, 1.0]), np.array([0.0, 1.0]), np.stack([q0, -q1]))
    half = _axis_angle([0, 0, 1], np.pi / 4)
    assert min(np.abs(got[1] - half).max(), np.abs(got[1] + half).max()) < 1e-12
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0)


# --- PX4 ULog -------------------------------------------------------------------------------


def test_ulog_round_trip(tmp_path):
    """A ULog written here (PX4's topics in NED / FRD, MPC_THR_HOVER as a parameter) and read
    by pyulog comes back as the flight within the interpolation error."""
    us = {k: np.arange(0, 3_000_000, r) + o for k, r, o in
          [("position", 10_000, 1000), ("attitude", 4_000, 0), ("rates", 20_000, 500),
           ("thrust", 20_000, 700), ("load", 8_333, 300)]}  # fmt: skip
    log = write_ulog(tmp_path / "px4.ulg", px4_topics(us), {"MPC_THR_HOVER": HOVER})
    with pytest.raises(LogError, match=r"px4.ulg: the log holds no load position.*"
                       r"\(not the vehicle's own, vehicle_local_position:0, nor set-points\): "
                       r"vehicle_mocap_odometry:1"):  # fmt: skip
        import_logs([log], tmp_path / "x", params=PARAMS, progress=False)
    result = import_logs(
        [log],
        tmp_path / "ds",
        params=PARAMS,
        mapping={"load": "vehicle_mocap_odometry:1"},
        options=ImportOptions(split="train"),
        progress=False,
    )
    assert any("MPC_THR_HOVER" in n for n in result.notes)
    got = imported(tmp_path / "ds")["px4"]
    start = max(v[0] for v in us.values()) * 1e-6
    expected = truth(start + got["time"])
    assert np.abs(got["p"] - expected["p"]).max() < 0.01**2 / 8 * 0.3 + 1e-6
    assert np.abs(got["v"] - expected["v"]).max() < 1e-5
    assert np.abs(got["p_load"] - expected["p_load"]).max() < 0.0084**2 / 8 * 2.2 + 1e-6
    assert rotation_angle(got["attitude"], expected["attitude"]).max() < 1e-5
    assert np.abs(got["w_ref"] - expected["w_ref"]).max() < 0.02 * 0.1 + 1e-6
    assert np.abs(got["T_ref"] - expected["T_ref"]).max() < 0.02 * 0.1 + 1e-4


def test_ulog_conversion_on_arrays_and_missing_topics(tmp_path):
    us = {
        k: np.arange(0, 2_000_000, 10_000)
        for k in ("position", "attitude", "rates", "thrust", "load")
    }
    topics = {f"{n}:{i}": f for (n, i), f in px4_topics(us).items()}
    raw = ulog_streams(topics, tmp_path / "a.ulg", {"load": "vehicle_mocap_odometry:1"})
    expected = truth(us["position"] * 1e-6)
    np.testing.assert_allclose(raw.streams["position"].values, expected["p"], atol=1e-12)
    np.testing.assert_allclose(raw.streams["rates"].values, expected["w_ref"], atol=1e-12)
    np.testing.assert_allclose(
        raw.streams["thrust"].values[:, 0] * THRUST_PER_THROTTLE,
        expected["T_ref"][:, 0],
        rtol=1e-12,
    )
    del topics["vehicle_rates_setpoint:0"]
    with pytest.raises(
        LogError, match=r"a.ulg: no topic 'vehicle_rates_setpoint' \(mapping key 'rates'\)"
    ):
        ulog_streams(topics, tmp_path / "a.ulg", {"load": "vehicle_mocap_odometry:1"})


# --- CSV ----------------------------------------------------------------------------------------


def test_csv_round_trip_with_the_default_columns(tmp_path):
    a = truth(PARAMS.dt * np.arange(80))
    columns = default_columns(a)
    log = write_csv(tmp_path / "flight.csv", columns)
    import_logs([log], tmp_path / "ds", params=PARAMS, progress=False)
    got = imported(tmp_path / "ds")["flight"]
    for key in ("time", "p", "v", "p_load", "w_ref", "T_ref"):
        np.testing.assert_allclose(got[key], a[key], atol=1e-12, err_msg=key)
    assert rotation_angle(got["attitude"], a["attitude"]).max() < 1e-7


def test_csv_with_a_column_map_ned_frd_ms_and_normalised_thrust(tmp_path):
    """Mocap at 100 Hz and commands at 50 Hz in rows of their own (blank cells elsewhere),
    NED / FRD, time in ms, throttle: the column map brings them back."""
    m = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    t_mocap, t_cmd = np.arange(0, 3, 0.01), np.arange(0.005, 3, 0.02)
    a, c = truth(t_mocap), truth(t_cmd)
    q = frames.quat_multiply(
        frames.quat_conjugate(frames.Q_ENU_FROM_NED),
        frames.quat_multiply(a["attitude"][:, [3, 0, 1, 2]], frames.Q_FLU_FROM_FRD),
    )
    names = ["t_ms", "N0", "N1", "N2", "Q0", "Q1", "Q2", "Q3", "L0", "L1", "L2"]
    names += ["wx", "wy", "wz", "throttle"]
    mocap = np.column_stack([t_mocap * 1000, a["p"] @ m, q, a["p_load"] @ m])
    w = c["w_ref"] * [1, -1, -1]
    cmd = np.column_stack([t_cmd * 1000, w, c["T_ref"][:, 0] / THRUST_PER_THROTTLE])
    rows = [(r[0], ",".join(map(repr, r.tolist())) + ",,,,") for r in mocap]
    rows += [
        (r[0], f"{float(r[0])!r}" + "," * 11 + ",".join(map(repr, r[1:].tolist()))) for r in cmd
    ]
    log = tmp_path / "mocap.csv"
    log.write_text(",".join(names) + "\n" + "".join(f"{r}\n" for _, r in sorted(rows)))
    mapping = {
        "time": "t_ms", "time_unit": "ms", "p": ["N0", "N1", "N2"], "v": "",
        "attitude": ["Q1", "Q2", "Q3", "Q0"], "p_load": ["L0", "L1", "L2"],
        "w_ref": ["wx", "wy", "wz"], "T_ref": "throttle", "thrust": "normalized",
        "world": "ned", "body": "frd", "rates": "frd",
    }  # fmt: skip
    (tmp_path / "map.json").write_text(json.dumps({"csv": mapping}))
    out = tmp_path / "ds"
    code = main(["import", str(log), "--out", str(out), "--map", str(tmp_path / "map.json"),
                 "--hover-throttle", str(HOVER), "--quiet"])  # fmt: skip
    assert code == 0
    got = imported(out)["mocap"]
    expected = truth(0.005 + got["time"])  # the commands start last, at 5 ms
    assert np.abs(got["p"] - expected["p"]).max() < 1e-4
    assert rotation_angle(got["attitude"], expected["attitude"]).max() < 1e-4
    assert np.abs(got["w_ref"] - expected["w_ref"]).max() < 0.02 * 0.1 + 1e-9
    assert np.abs(got["T_ref"] - expected["T_ref"]).max() < 0.02 * 0.1 + 1e-9
    assert np.abs(got["v"][2:] - expected["v"][2:]).max() < 1e-3


def test_csv_errors_name_the_column(tmp_path, capsys):
    log = tmp_path / "bad.csv"
    log.write_text("time,p_x\n0.0,1.0\n")
    code = main(["import", str(log), "--out", str(tmp_path / "ds"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and "bad.csv: no column 'p_y' (mapping key 'p')" in err
    log.write_text("time,p_x\n0.0,abc\n")
    with pytest.raises(LogError, match=r"bad.csv: row 2, column 'p_x': 'abc' is not a number"):
        import_logs([log], tmp_path / "ds", mapping={"p": ["p_x"] * 3}, progress=False)
    assert not (tmp_path / "ds").exists()


# --- the authors' release layout and vehicle keys -----------------------------------------------


def _release(folder: Path, names: list[str]) -> Path:
    for i, name in enumerate(names):
        write_npz(folder / "data" / f"{name}.npz", truth(PARAMS.dt * np.arange(40 + i)))
    (folder / "train.txt").write_text("".join(f"{n}.npz\n" for n in names[:-2]))
    (folder / "val.txt").write_text(f"{names[-2]}.npz\n")
    (folder / "test.txt").write_text(f"{names[-1]}.npz\n")
    return folder


def test_authors_release_layout_loads_and_inspects(tmp_path, capsys):
    folder = _release(tmp_path / "DATASET", ["xy_step", "xy_step_04", "baf_fast_01", "roll_35_00"])
    ds = load_dataset(folder, params=PARAMS, window=_window(), use_cache=False)
    assert sorted(ds.flights) == ["baf_fast_01", "roll_35_00", "xy_step", "xy_step_04"]
    assert ds.splits["val"].names == ("baf_fast_01",)
    assert ds.flights["xy_step"].path == folder / "data" / "xy_step.npz"
    summary = summarize(folder, params=PARAMS, window=_window())
    assert summary.splits["train"].flights == 2
    assert main(["inspect", str(folder), "--history", "10", "--horizon", "5"]) == 0
    assert "train" in capsys.readouterr().out
    write_npz(folder / "stray.npz", truth(PARAMS.dt * np.arange(40)))
    with pytest.raises(DatasetError, match="both at the top .* and under data/"):
        load_dataset(folder, params=PARAMS, window=_window(), use_cache=False)


def test_write_splits_names_files_with_npz_and_reads_both(tmp_path):
    for name in ("a", "b", "c"):
        write_npz(tmp_path / f"{name}.npz", truth(PARAMS.dt * np.arange(20)))
    write_splits(tmp_path, {"train": ["a", "b.npz"], "val": ["c"], "test": []})
    assert (tmp_path / "train.txt").read_text() == "a.npz\nb.npz\n"
    assert (tmp_path / "val.txt").read_text() == "c.npz\n"
    assert read_splits(tmp_path) == {"train": ["a", "b"], "val": ["c"], "test": []}
    (tmp_path / "train.txt").write_text("a\nb\n")  # our old lists, without the suffix
    assert read_splits(tmp_path)["train"] == ["a", "b"]


def test_vehicle_keys_aliases_and_unknown_keys(tmp_path):
    p = vehicle_from_dict({"mass_quadrotor": 1.5, "Load-Mass": 0.2, "L": 0.65, "h": 0.02, "g": 9.8})
    assert p == VehicleParams(mass_quad=1.5, mass_load=0.2, cable_length=0.65, dt=0.02, gravity=9.8)
    assert vehicle_from_dict({"quad_mass": 1.1, "cable_length": 0.5}).mass_quad == 1.1
    write_json(tmp_path / "vehicle.json", {"mass_quad": 1.2, "weight": 3})
    accepted = r"accepted keys: mass_quad \(or mass_quadrotor"
    with pytest.raises(ValueError, match=r"vehicle.json: .*unknown .* \['weight'\]; " + accepted):
        load_vehicle(tmp_path)
    write_json(tmp_path / "vehicle.json", {"mass_quad": 1.2, "mass_quadrotor": 1.3})
    with pytest.raises(ValueError, match="'mass_quad' and 'mass_quadrotor' both set mass_quad"):
        load_vehicle(tmp_path)
    write_json(tmp_path / "vehicle.json", {"vehicle": {"mass_quadrotor": 1.4}, "sim": {"x": 1}})
    assert load_vehicle(tmp_path).mass_quad == 1.4
    write_json(tmp_path / "vehicle.json", {"mass_quad": "heavy"})
    with pytest.raises(ValueError, match="'mass_quad' must be a number"):
        load_vehicle(tmp_path)


def test_imported_flight_reads_like_any_npz(tmp_path):
    """What import writes is a published-schema flight: read_flight takes it unchanged."""
    a = truth(PARAMS.dt * np.arange(50))
    columns = default_columns(a)
    import_logs(
        [write_csv(tmp_path / "f.csv", columns)], tmp_path / "ds", params=PARAMS, progress=False
    )
    flight = read_flight(tmp_path / "ds" / "data" / "f.npz", PARAMS)
    assert len(flight) == 50


def test_log_libraries_load_only_when_a_log_is_read():
    """``slungload --help`` and the import pipeline's module do not import rosbags / pyulog /
    mcap."""
    import subprocess
    import sys

    code = (
        "import sys, slungload.cli as c, slungload.data.importing; c.build_parser(); "
        "print(sorted({m.split('.')[0] for m in sys.modules} & {'rosbags', 'pyulog', 'mcap'}))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


# --- the log-reader registry ---------------------------------------------------------------------


def test_every_log_suffix_dispatches_to_its_reader(tmp_path, monkeypatch):
    """``find_logs`` names each suffix's format and ``read_log`` calls that format's reader with
    its section of a mapping file (and the preset only for bags), imported when called."""
    calls = []

    def fake(name):
        def read(path, mapping, *, progress=False, roles=None):
            calls.append((name, path.name, mapping, progress, roles))
            return name

        return read

    for reader in LOG_READERS.values():
        module, function = reader.function.split(":")
        target = importlib.import_module(f"slungload.data.readers.{module}")
        assert callable(getattr(target, function))
        monkeypatch.setattr(target, function, fake(reader.function))
    mapping = {"ros": {"stamps": "header"}, "ulog": {"load": "x:1"}, "csv": {"world": "enu"},
               "tlog": {"load_component": 197}}  # fmt: skip
    claimed = {}
    for kind, reader in LOG_READERS.items():
        for suffix in reader.suffixes:
            path = tmp_path / f"log{suffix}"
            path.write_bytes(b"")
            claimed[suffix] = kind
            assert find_logs([path]) == [(path, kind)]
            assert read_log(path, kind, mapping, preset="px4", progress=True) == reader.function
            settings = dict(mapping[reader.section])
            if reader.presets:
                settings["preset"] = "px4"
            assert calls[-1] == (reader.function, path.name, settings, True, None)
    assert claimed == {".bag": "ros1", ".mcap": "ros2", ".db3": "ros2", ".ulg": "ulog",
                       ".csv": "csv", ".tlog": "tlog"}  # fmt: skip
    bag2 = tmp_path / "bag2"
    bag2.mkdir()
    (bag2 / "metadata.yaml").write_text("")
    assert find_logs([bag2]) == [(bag2, "ros2")]
    assert [k for _, k in find_logs([tmp_path])] == [
        "ros2", "ros1", "csv", "ros2", "ros2", "tlog", "ulog"]  # fmt: skip


def test_unknown_log_suffix_names_the_file(tmp_path):
    log = tmp_path / "flight.txt"
    log.write_text("")
    with pytest.raises(LogError, match=r"flight.txt: unknown log format '.txt'; known: \.bag, "
                       r"\.mcap, \.db3, \.ulg, \.csv, \.tlog and rosbag2 folders"):  # fmt: skip
        find_logs([log])
    with pytest.raises(LogError, match=rf"{tmp_path.name}: holds no logs \(\*\.bag"):
        find_logs([tmp_path])


def test_numpy_rotations_match_the_torch_ones():
    """``frames``' rotation matrix and exponential map (the simulator's) equal ``state``'s
    torch versions (the models'), a batch of unnormalised quaternions included."""
    import torch

    from slungload.state import quat_from_rotvec as torch_rotvec
    from slungload.state import quat_to_rotmat

    rng = np.random.default_rng(4)
    q = rng.normal(size=(7, 4)) * 3.0
    want = quat_to_rotmat(torch.from_numpy(q)).numpy()
    np.testing.assert_allclose(frames.rotation_matrix(q), want, atol=1e-14)
    np.testing.assert_allclose(frames.rotation_matrix(q[2]), want[2], atol=1e-14)
    for r in (rng.normal(size=3), np.array([1e-13, -2e-13, 0.0]), np.zeros(3)):
        got = frames.quat_from_rotvec(r)
        np.testing.assert_allclose(got, torch_rotvec(torch.from_numpy(r)).numpy(), atol=1e-15)
        np.testing.assert_allclose(frames.rotate(got, np.eye(3)).T, frames.rotation_matrix(got),
                                   atol=1e-15)  # fmt: skip


def test_the_log_map_inverts_the_exponential_map():
    """``frames.rotvec_from_matrix`` (the PID's attitude error) returns the rotation vector a
    matrix was made from, for angles below pi and near zero."""
    rng = np.random.default_rng(5)
    vectors = [rng.normal(size=3) for _ in range(5)] + [np.array([2e-10, -1e-10, 3e-10])]
    for r in vectors:
        r = r * min(1.0, 3.0 / np.linalg.norm(r))  # below pi
        rot = frames.rotation_matrix(frames.quat_from_rotvec(r))
        np.testing.assert_allclose(frames.rotvec_from_matrix(rot), r, atol=1e-9)
