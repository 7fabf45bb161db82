"""Reading flights, estimating the load state, windows, splits, the cache and the writer.

The flights are analytic (``flights.flight_arrays``): a vehicle on a smooth curve with a load
swinging on a cone around it, in the published schema (quaternions x-y-z-w).
"""

from __future__ import annotations

import json
import os
import stat
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import flight_arrays

from slungload._version import __version__
from slungload.config import VehicleParams, WindowConfig, to_dict
from slungload.data.dataset import load_dataset
from slungload.data.flight import DataWarning, FlightFormatError
from slungload.data.folder import read_splits
from slungload.data.readers import read_flight
from slungload.data.summary import summarize
from slungload.data.writer import DatasetWriter
from slungload.fileio import write_npz, write_splits
from slungload.load_state import estimate_load_state
from slungload.state import LOAD_RATE, LOAD_VEL, QUAT

PARAMS = VehicleParams()
SMALL = WindowConfig(history=10, horizon=5, stride=1)


def write_flight(path: Path, **changes) -> Path:
    arrays = flight_arrays()
    arrays.update(changes)
    write_npz(path, {k: v for k, v in arrays.items() if v is not None})
    return path


# --- one flight -----------------------------------------------------------------------------


@pytest.mark.parametrize("thrust_shape", [(60,), (60, 1)])
@pytest.mark.parametrize("time_shape", [(60,), (60, 1), (1, 60)])
def test_round_trip(tmp_path, thrust_shape, time_shape):
    arrays = flight_arrays()
    path = write_flight(
        tmp_path / "f.npz",
        T_ref=arrays["T_ref"].reshape(thrust_shape),
        time=arrays["time"].reshape(time_shape),
    )
    flight = read_flight(path)
    assert flight.name == "f" and flight.path == path
    assert flight.states.shape == (60, 13) and flight.states.dtype == np.float64
    np.testing.assert_array_equal(flight.time, arrays["time"])
    np.testing.assert_allclose(flight.states[:, 0:3], arrays["p"])
    np.testing.assert_allclose(flight.states[:, 3:6], arrays["v"])
    np.testing.assert_allclose(flight.states[:, QUAT], arrays["attitude"][:, [3, 0, 1, 2]])
    np.testing.assert_allclose(flight.states[:, 10:13], arrays["p_load"])
    np.testing.assert_allclose(flight.inputs[:, 0], arrays["T_ref"][:, 0])
    np.testing.assert_allclose(flight.inputs[:, 1:4], arrays["w_ref"])
    assert flight.aux.shape == (60, 6)


def test_matlab_keys_and_t_sampling_are_ignored_silently(tmp_path):
    path = write_flight(
        tmp_path / "m.npz",
        __header__=np.array("MATLAB 5.0 MAT-file"),
        __version__=np.array("1.0"),
        __globals__=np.zeros(0),
        t_sampling=np.array(0.03),
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_flight(path)


def test_unknown_keys_are_ignored_with_a_warning(tmp_path):
    path = write_flight(tmp_path / "u.npz", battery=np.ones(60))
    with pytest.warns(DataWarning, match="battery"):
        flight = read_flight(path)
    assert flight.states.shape == (60, 13)


def _bad_time(steps=60):
    t = 0.03 * np.arange(steps)
    t[20] = t[19]
    return t


def _gap_time(steps=60):
    t = 0.03 * np.arange(steps)
    t[30:] += 0.03
    return t


def _with(key, index, value):
    arr = flight_arrays()[key].copy()
    arr[index] = value
    return arr


BAD_FLIGHTS = {
    "missing key": ({"p_load": None}, "missing keys.*p_load"),
    "shape": ({"p": np.zeros((60, 2))}, r"p has shape \(60, 2\)"),
    "length": ({"v": np.zeros((59, 3))}, "v has 59 steps but time has 60"),
    "nan": ({"p": _with("p", (7, 1), np.nan)}, "p holds nan at step 7"),
    "inf": ({"w_ref": _with("w_ref", (9, 0), np.inf)}, "w_ref holds inf at step 9"),
    "not increasing": ({"time": _bad_time()}, "not strictly increasing at index 20"),
    "step far from dt": ({"time": _gap_time()}, "time step from index 29 to 30 is 0.06"),
    "quaternion": ({"attitude": _with("attitude", 12, [0, 0, 0, 1.5])}, "attitude at step 12"),
    "strings": ({"T_ref": np.array(["a"] * 60)}, "T_ref has dtype"),
}


@pytest.mark.parametrize("case", BAD_FLIGHTS)
def test_bad_flights_are_refused_naming_the_file(tmp_path, case):
    changes, problem = BAD_FLIGHTS[case]
    path = write_flight(tmp_path / f"bad_{case.replace(' ', '_')}.npz", **changes)
    with pytest.raises(FlightFormatError, match=problem) as info:
        read_flight(path)
    assert str(path) in str(info.value)


def test_unreadable_files_are_refused(tmp_path):
    junk = tmp_path / "junk.npz"
    junk.write_bytes(np.random.default_rng(0).bytes(500))
    truncated = write_flight(tmp_path / "cut.npz")
    truncated.write_bytes(truncated.read_bytes()[:700])
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, **flight_arrays(), extra=np.array([{"a": 1}], dtype=object))
    for path, problem in [
        (junk, "cannot be read"),
        (truncated, "cannot be read"),
        (pickled, "pickle"),
    ]:
        with pytest.raises(FlightFormatError, match=problem) as info:
            read_flight(path)
        assert str(path) in str(info.value)


def test_timing_jitter_is_tolerated(tmp_path):
    t = 0.03 * np.arange(60) + np.random.default_rng(1).uniform(-0.002, 0.002, 60)
    assert len(read_flight(write_flight(tmp_path / "j.npz", time=t))) == 60


def test_quaternion_sign_flips_are_made_continuous_and_renormalised(tmp_path):
    q = flight_arrays()["attitude"]
    flipped = q * np.where(np.arange(60) % 3 == 1, -1.0, 1.0)[:, None] * 1.05
    flight = read_flight(write_flight(tmp_path / "q.npz", attitude=flipped))
    got = flight.states[:, QUAT]
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), 1.0)
    assert np.all((got[1:] * got[:-1]).sum(1) > 0)
    np.testing.assert_allclose(got, q[:, [3, 0, 1, 2]], atol=1e-12)  # first sign was +


# --- the load-state estimate ----------------------------------------------------------------


def _states(p: np.ndarray, p_load: np.ndarray) -> np.ndarray:
    x = np.zeros((len(p), 13))
    x[:, 0:3], x[:, 10:13], x[:, 6] = p, p_load, 1.0
    return x


def _conical(dt: float, steps: int, theta: float = 0.5, rate: float = 3.0, lag: float = 0.0):
    """Vehicle accelerating, load on a cone of half-angle theta around it at ``rate`` rad/s.

    Returns states and the true Omega_L = xi x xi_dot (the part normal to the cable) at the
    sample times minus ``lag`` seconds.
    """
    t = dt * np.arange(steps)
    p = np.stack([0.8 * t**2, -0.3 * t, 1 + 0 * t], axis=1)
    s, c = np.sin(theta), np.cos(theta)

    def xi_and_rate(t):
        xi = np.stack([s * np.cos(rate * t), s * np.sin(rate * t), -c + 0 * t], axis=1)
        xi_dot = np.stack([-s * rate * np.sin(rate * t), s * rate * np.cos(rate * t), 0 * t], 1)
        return xi, np.cross(xi, xi_dot)

    xi, _ = xi_and_rate(t)
    return _states(p, p + PARAMS.cable_length * xi), xi_and_rate(t - lag)[1]


def test_load_rate_on_a_vertical_circle_around_a_moving_vehicle():
    # Load whirling in the x-z plane at 3 rad/s; true Omega_L = -3 e_y at every step.
    dt, rate = 0.03, 3.0
    t = dt * np.arange(100)
    p = np.stack([0.5 * t, 0.2 * t, 1 + 0 * t], axis=1)  # uniform motion
    xi = np.stack([np.sin(rate * t), 0 * t, -np.cos(rate * t)], axis=1)
    aux = estimate_load_state(_states(p, p + PARAMS.cable_length * xi), VehicleParams(dt=dt))
    np.testing.assert_allclose(aux[:, LOAD_RATE], [[0, -rate, 0]] * 100, atol=rate * 2e-3)


def test_load_rate_converges_with_dt_on_a_conical_pendulum():
    # |Omega_L| = rate sin(theta) = 1.44 rad/s and Omega_L turns with the load at 3 rad/s.
    now, half_step_back = [], []
    for dt in (0.03, 0.015, 0.0075):
        steps = round(3.0 / dt)
        states, true_now = _conical(dt, steps)
        _, true_back = _conical(dt, steps, lag=dt / 2)
        aux = estimate_load_state(states, VehicleParams(dt=dt))
        now.append(np.abs(aux[1:, LOAD_RATE] - true_now[1:]).max())
        half_step_back.append(np.abs(aux[1:, LOAD_RATE] - true_back[1:]).max())
    # A causal difference lags half a step: first order in dt against the present value
    # (4 % of |Omega_L| at dt = 30 ms), second order against the value half a step back.
    assert now[0] < 0.06
    assert 1.8 < now[0] / now[1] < 2.2 and 1.8 < now[1] / now[2] < 2.2
    assert half_step_back[0] < 0.005
    assert 3.5 < half_step_back[0] / half_step_back[1] < 4.5


def test_load_velocity_is_the_backward_difference():
    states, _ = _conical(0.03, 50)
    aux = estimate_load_state(states, PARAMS)
    p_load = states[:, 10:13]
    np.testing.assert_allclose(aux[1:, LOAD_VEL], (p_load[1:] - p_load[:-1]) / 0.03)
    np.testing.assert_allclose(aux[0, LOAD_VEL], aux[1, LOAD_VEL])


def test_estimate_is_causal_and_works_on_torch_batches():
    states, _ = _conical(0.03, 40)
    aux = estimate_load_state(states, PARAMS)
    changed = states.copy()
    changed[21:] += np.random.default_rng(0).normal(size=changed[21:].shape)
    np.testing.assert_array_equal(estimate_load_state(changed, PARAMS)[:21], aux[:21])
    batch = torch.from_numpy(np.stack([states, changed])).float()
    got = estimate_load_state(batch, PARAMS)
    assert isinstance(got, torch.Tensor) and got.shape == (2, 40, 6) and got.dtype == torch.float32
    np.testing.assert_allclose(got[0].numpy(), aux, rtol=1e-3, atol=1e-3)


# --- datasets, windows, splits ---------------------------------------------------------------


def test_windows_per_flight_never_cross_flights(tmp_path, write_dataset):
    lengths = {"a": 40, "b": 23, "c": 60}
    folder = write_dataset(tmp_path / "ds", lengths, {"train": ["a", "b"], "val": ["c"]})
    for stride in (1, 4):
        window = WindowConfig(history=10, horizon=5, stride=stride)
        ds = load_dataset(folder, window=window, params=PARAMS, use_cache=False)
        train = ds.splits["train"]
        assert train.names == ("a", "b") and ds.splits["val"].names == ("c",)
        for i, name in enumerate(train.names):
            count = (lengths[name] - 15) // stride + 1
            assert int((train.flight == i).sum()) == count
        assert len(ds.splits["test"]) == 0 and ds.splits["test"].states.shape == (0, 15, 13)
        for w in (train, ds.splits["val"]):
            for k in range(len(w)):
                f = ds.flights[w.names[w.flight[k]]]
                s = int(w.start[k])
                assert s % stride == 0 and s + 15 <= len(f)
                for key in ("states", "inputs", "aux"):
                    want = torch.from_numpy(getattr(f, key)[s : s + 15]).float()
                    assert torch.equal(getattr(w, key)[k], want)


def test_window_views_and_subsets(tmp_path, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"a": 40}, {"train": ["a"]})
    w = load_dataset(folder, window=SMALL, params=PARAMS, use_cache=False).splits["train"]
    assert w.history.states.shape == (26, 10, 13) and w.future.inputs.shape == (26, 5, 4)
    assert torch.equal(torch.cat([w.history.aux, w.future.aux], 1), w.aux)
    sub = w[torch.tensor([3, 0])]
    assert (
        len(sub) == 2 and torch.equal(sub.states[1], w.states[0]) and sub.start.tolist() == [3, 0]
    )
    assert len(w[w.start >= 20]) == 6 and len(w[2:5]) == 3 and len(w[7]) == 1


def test_short_flights_are_skipped_and_none_left_is_an_error(tmp_path, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"long": 30, "short": 12}, {"train": ["long", "short"]})
    with pytest.warns(DataWarning, match="short.npz: skipped, 12 steps"):
        ds = load_dataset(folder, window=SMALL, params=PARAMS, use_cache=False)
    assert list(ds.flights) == ["long"]
    with pytest.raises(ValueError, match="no flight left.*longest has 30"):
        load_dataset(folder, window=WindowConfig(40, 5), params=PARAMS, use_cache=False)


def test_split_lists(tmp_path, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"a": 20, "b": 20, "c": 20, "d": 20})
    (folder / "train.txt").write_text("a.npz\n\n# comment\nb\n")
    (folder / "val.txt").write_text("c\n")
    (folder / "test.txt").write_text("")
    with pytest.warns(DataWarning, match=r"no split list are ignored: \['d'\]"):
        assert read_splits(folder) == {"train": ["a", "b"], "val": ["c"], "test": []}
    for text, problem in [
        ("a\nzz\n", r"train.txt: flights not found .*\['zz'\]"),
        ("a\nb\na\n", "'a' is listed twice"),
        ("a\nc\n", "val.txt: flight 'a' is also listed in train.txt"),
    ]:
        (folder / ("val.txt" if "c" in text else "train.txt")).write_text(text)
        with pytest.raises(ValueError, match=problem):
            read_splits(folder)
        write_splits(folder, {"train": ["a", "b"], "val": ["c"], "test": ["d"]})
    for split in ("train", "val", "test"):
        (folder / f"{split}.txt").unlink()
    with pytest.raises(ValueError, match="no split files.*write_splits"):
        load_dataset(folder, params=PARAMS)


def test_missing_or_empty_folder(tmp_path):
    with pytest.raises(FileNotFoundError, match="nowhere"):
        load_dataset(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match="empty holds no flight files"):
        load_dataset(tmp_path / "empty")


def test_vehicle_constants_source(tmp_path, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"a": 20}, {"train": ["a"]}, vehicle=False)
    with pytest.warns(DataWarning, match="no vehicle.json"):
        ds = load_dataset(folder, window=SMALL, use_cache=False)
    assert ds.params == VehicleParams() and ds.params_source == "paper defaults"
    custom = {"mass_quad": 2.0, "mass_load": 0.2, "cable_length": 1.0, "load_damping": 0.0,
              "dt": 0.03, "gravity": 9.81}  # fmt: skip
    (folder / "vehicle.json").write_text(json.dumps({"vehicle": custom, "seed": 3}))
    ds = load_dataset(folder, window=SMALL, use_cache=False)
    assert ds.params == VehicleParams(**custom) and ds.params_source == "vehicle.json"
    other = VehicleParams(cable_length=0.5)
    ds = load_dataset(folder, window=SMALL, params=other, use_cache=False)
    assert ds.params == other and ds.params_source == "override"


def test_cache_hit_invalidation_and_corruption(tmp_path, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"a": 30, "b": 25}, {"train": ["a"], "test": ["b"]})
    cache = tmp_path / "cache"
    first = load_dataset(folder, window=SMALL, params=PARAMS, cache_dir=cache)
    assert not first.from_cache and first.cache_path.is_file()
    second = load_dataset(folder, window=SMALL, params=PARAMS, cache_dir=cache)
    assert second.from_cache and second.cache_path == first.cache_path
    for split in ("train", "val", "test"):
        a, b = first.splits[split], second.splits[split]
        for key in ("states", "inputs", "aux", "flight", "start"):
            assert torch.equal(getattr(a, key), getattr(b, key))
        assert a.names == b.names and a.window == b.window
    np.testing.assert_array_equal(second.flights["b"].aux, first.flights["b"].aux)
    assert second.flights["a"].path == folder / "a.npz"
    # The file holds the flights and the split lists, not the (much larger) windows.
    stored = torch.load(first.cache_path, weights_only=True)["payload"]
    assert stored["splits"] == {"train": ["a"], "val": [], "test": ["b"]}

    # Another window config or other constants: another cache file.
    other = load_dataset(folder, window=WindowConfig(10, 6), params=PARAMS, cache_dir=cache)
    assert not other.from_cache and other.cache_path != first.cache_path

    # A changed flight file invalidates the cache.
    arrays = flight_arrays(30)
    arrays["p"] = arrays["p"] + 1.0
    write_npz(folder / "a.npz", arrays)
    changed = load_dataset(folder, window=SMALL, params=PARAMS, cache_dir=cache)
    assert not changed.from_cache
    assert torch.allclose(
        changed.splits["train"].states[:, :, 0], first.splits["train"].states[:, :, 0] + 1
    )

    # A corrupt cache file is ignored and rebuilt.
    changed.cache_path.write_bytes(b"not a torch file")
    with pytest.warns(DataWarning, match="bad cache"):
        rebuilt = load_dataset(folder, window=SMALL, params=PARAMS, cache_dir=cache)
    assert not rebuilt.from_cache
    assert load_dataset(folder, window=SMALL, params=PARAMS, cache_dir=cache).from_cache


def test_cache_dir_from_environment(tmp_path, monkeypatch, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"a": 20}, {"train": ["a"]})
    monkeypatch.setenv("SLUNGLOAD_CACHE", str(tmp_path / "env_cache"))
    ds = load_dataset(folder, window=SMALL, params=PARAMS)
    assert ds.cache_path.parent == tmp_path / "env_cache" and ds.cache_path.is_file()


def test_notes_are_repeated_on_a_cache_hit(tmp_path, write_dataset):
    folder = write_dataset(tmp_path / "ds", {"a": 20, "b": 10}, {"train": ["a", "b"]})
    for _ in range(2):
        with pytest.warns(DataWarning, match="b.npz: skipped"):
            load_dataset(folder, window=SMALL, params=PARAMS, cache_dir=tmp_path / "c")


def test_summary(tmp_path, write_dataset):
    folder = write_dataset(
        tmp_path / "ds", {"a": 40, "b": 30, "c": 12}, {"train": ["a", "c"], "test": ["b"]}
    )
    summary = summarize(folder, window=SMALL, params=PARAMS)
    assert summary.splits["train"].flights == 2 and summary.splits["train"].windows == 26
    assert summary.splits["test"].windows == 16 and summary.skipped == ("c",)
    assert summary.splits["test"].steps == 30
    lo, mid, hi = summary.ranges["swing angle (deg)"]
    assert lo == pytest.approx(np.degrees(0.3)) and hi == pytest.approx(np.degrees(0.3))
    lo, _, hi = summary.ranges["cable length |pL - p| (m)"]
    assert lo == pytest.approx(0.7) and hi == pytest.approx(0.7)
    table = summary.to_table()
    assert "override" in table and "61.9 %" in table and "swing angle" in table


def test_summary_names_maneuvers_missing_from_training(tmp_path, write_dataset):
    names = ["xy_step", "xy_step_04", "roll_35_00", "roll_35_01", "baf_fast_01"]
    folder = write_dataset(tmp_path / "ds", dict.fromkeys(names, 40))
    splits = {"train": ["xy_step", "baf_fast_01"], "val": ["xy_step_04"], "test": ["roll_35_00"]}
    write_splits(folder, {**splits, "test": ["roll_35_00", "roll_35_01"]})
    summary = summarize(folder, window=SMALL, params=PARAMS)
    assert summary.unseen == {"val": (), "test": ("roll_35",)}
    assert "maneuvers not in train: test: roll_35" in summary.to_table()
    write_splits(folder, {**splits, "train": [*splits["train"], "roll_35_01"]})
    table = summarize(folder, window=SMALL, params=PARAMS).to_table()
    assert "every maneuver of val and test also has flights in train" in table


# --- the dataset writer --------------------------------------------------------------------------


@pytest.mark.parametrize("subfolder", ["", "data"], ids=["simulator-layout", "release-layout"])
def test_writer_writes_either_layout_and_the_readers_load_it(tmp_path, subfolder):
    out = tmp_path / "ds"
    splits = {"train": ["a", "b"], "val": ["c"], "test": ["d"]}
    with DatasetWriter(out, subfolder=subfolder) as writer:
        assert writer.folder.parent == tmp_path and not out.exists()  # beside the target
        for name in "abcd":
            writer.write_flight(name, flight_arrays(steps=30, seed=ord(name)))
        assert writer.flight_path("a") == writer.folder / subfolder / "a.npz"
        writer.finish(splits, PARAMS, {"made_by": "a test", "version": __version__})
    files = sorted(p.name for p in (out / subfolder).glob("*.npz"))
    assert files == ["a.npz", "b.npz", "c.npz", "d.npz"]
    assert (out / "train.txt").read_text() == "a.npz\nb.npz\n"
    meta = json.loads((out / "vehicle.json").read_text())
    assert meta == {"vehicle": to_dict(PARAMS), "made_by": "a test", "version": __version__}
    assert read_splits(out) == splits  # the readers find the flights in either layout
    ds = load_dataset(out, window=SMALL, use_cache=False)
    assert sorted(ds.flights) == ["a", "b", "c", "d"] and ds.params == PARAMS
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporary left


def test_writer_folder_has_the_permissions_of_mkdir(tmp_path):
    # tempfile.mkdtemp made dataset folders private (0o700); the writer's follow the umask.
    umask = os.umask(0o022)
    try:
        with DatasetWriter(tmp_path / "ds") as writer:
            writer.write_flight("a", flight_arrays(steps=10))
            writer.finish({"train": ["a"]}, PARAMS, {})
    finally:
        os.umask(umask)
    assert stat.S_IMODE((tmp_path / "ds").stat().st_mode) == 0o755
    assert stat.S_IMODE((tmp_path / "ds" / "a.npz").stat().st_mode) == 0o644


def test_writer_failure_leaves_nothing_and_the_old_folder_untouched(tmp_path):
    with pytest.raises(RuntimeError, match="boom"):
        with DatasetWriter(tmp_path / "new") as writer:
            writer.write_flight("a", flight_arrays(steps=10))
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    old = tmp_path / "old"
    old.mkdir()
    (old / "keep.npz").write_bytes(b"x")
    with pytest.raises(RuntimeError, match="boom"):
        with DatasetWriter(old, overwrite=True) as writer:
            writer.write_flight("a", flight_arrays(steps=10))
            raise RuntimeError("boom")
    assert [p.name for p in tmp_path.iterdir()] == ["old"]
    assert [p.name for p in old.iterdir()] == ["keep.npz"]
    with DatasetWriter(old, overwrite=True) as writer:  # (left without finish: nothing written)
        writer.write_flight("a", flight_arrays(steps=10))
    assert [p.name for p in tmp_path.iterdir()] == ["old"]


def test_writer_refuses_a_non_empty_target_unless_overwrite(tmp_path):
    (tmp_path / "ds").mkdir()
    with DatasetWriter(tmp_path / "ds") as writer:  # an empty folder is taken
        writer.finish({"train": []}, PARAMS, {})
    with pytest.raises(FileExistsError, match=r"ds: exists and is not empty \(--overwrite"):
        DatasetWriter(tmp_path / "ds")
    (tmp_path / "file").write_text("x")
    with pytest.raises(FileExistsError, match="not empty"):
        DatasetWriter(tmp_path / "file")
    with DatasetWriter(tmp_path / "ds", overwrite=True) as writer:
        writer.write_flight("b", flight_arrays(steps=10))
        writer.finish({"train": ["b"]}, PARAMS, {})
    assert sorted(p.name for p in (tmp_path / "ds").iterdir()) == [
        "b.npz", "test.txt", "train.txt", "val.txt", "vehicle.json"]  # fmt: skip
    with pytest.raises(RuntimeError, match="with block"):
        _ = DatasetWriter(tmp_path / "x").folder
