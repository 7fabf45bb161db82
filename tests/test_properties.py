"""Property-based checks (hypothesis): the physics step over the flight envelope, and the
flight reader over random valid flights and random corruptions of them.

Example counts stay modest (``max_examples`` 50, no deadline) so the module runs in seconds.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from slungload.config import VehicleParams
from slungload.data.flight import DataWarning, FlightFormatError
from slungload.data.readers import read_flight
from slungload.fileio import FLIGHT_KEYS, write_npz
from slungload.physics import step
from slungload.state import LOAD_POS, POS, QUAT, VEL, join_state

PARAMS = VehicleParams()
SETTINGS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def floats(lo: float, hi: float) -> st.SearchStrategy[float]:
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


def vectors(lo: float, hi: float, n: int = 3) -> st.SearchStrategy[list[float]]:
    return st.lists(floats(lo, hi), min_size=n, max_size=n)


@st.composite
def unit_vectors(draw: st.DrawFn, n: int = 3) -> torch.Tensor:
    """A direction drawn from n normal deviates (nearly zero draws are rejected)."""
    v = torch.tensor(draw(vectors(-1.0, 1.0, n)), dtype=torch.float64)
    assume(float(v.norm()) > 0.1)
    return v / v.norm()


@st.composite
def envelope(draw: st.DrawFn) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """(x, u, aux) in the flight envelope: thrust 0-40 N, body and load rates within
    +-10 rad/s, speeds below 10 m/s, cable within 5 % of its length, any attitude."""
    p = torch.tensor(draw(vectors(-50.0, 50.0)), dtype=torch.float64)
    v = draw(unit_vectors()) * draw(floats(0.0, 9.99))
    q = draw(unit_vectors(4))
    xi = draw(unit_vectors())
    p_load = p + PARAMS.cable_length * draw(floats(0.95, 1.05)) * xi
    u = torch.tensor([draw(floats(0.0, 40.0)), *draw(vectors(-10.0, 10.0))], dtype=torch.float64)
    v_load = draw(unit_vectors()) * draw(floats(0.0, 9.99))
    load_rate = torch.tensor(draw(vectors(-10.0, 10.0)), dtype=torch.float64)
    return join_state(p, v, q, p_load), u, torch.cat([v_load, load_rate])


# --- physics.step ---------------------------------------------------------------------------


@SETTINGS
@given(envelope())
def test_step_keeps_unit_quaternions_and_finite_values(sample):
    x, u, aux = sample
    x_next, aux_next = step(x, u, aux, PARAMS)
    assert torch.isfinite(x_next).all() and torch.isfinite(aux_next).all()
    assert float(x_next[QUAT].norm()) == pytest.approx(1.0, abs=1e-12)
    # One step of 30 ms cannot move anything far: accelerations stay bounded in the envelope.
    assert float((x_next[POS] - x[POS]).norm()) < 1.0
    assert float((x_next[LOAD_POS] - x[LOAD_POS]).norm()) < 1.0


@SETTINGS
@given(envelope(), vectors(-100.0, 100.0))
def test_step_is_translation_invariant(sample, shift):
    x, u, aux = sample
    c = torch.tensor(shift, dtype=torch.float64)
    moved = x.clone()
    moved[POS] += c
    moved[LOAD_POS] += c
    a, a_aux = step(x, u, aux, PARAMS)
    b, b_aux = step(moved, u, aux, PARAMS)
    torch.testing.assert_close(b[POS] - c, a[POS], atol=1e-9, rtol=0)
    torch.testing.assert_close(b[LOAD_POS] - c, a[LOAD_POS], atol=1e-9, rtol=0)
    torch.testing.assert_close(b[VEL], a[VEL], atol=1e-9, rtol=0)
    torch.testing.assert_close(b_aux, a_aux, atol=1e-9, rtol=0)


@SETTINGS
@given(envelope())
def test_step_without_body_rates_keeps_the_attitude(sample):
    x, u, aux = sample
    u = u.clone()
    u[1:] = 0.0
    x_next, _ = step(x, u, aux, PARAMS)
    torch.testing.assert_close(x_next[QUAT], x[QUAT], atol=1e-12, rtol=0)


# --- the flight reader ----------------------------------------------------------------------


@st.composite
def flights(draw: st.DrawFn) -> dict[str, np.ndarray]:
    """A valid flight in the published schema: 2-60 samples at dt with 5 % jitter."""
    n = draw(st.integers(2, 60))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    dt = PARAMS.dt
    time = draw(floats(-10.0, 1000.0)) + dt * np.arange(n) + rng.uniform(-0.05, 0.05, n) * dt
    attitude = rng.normal(size=(n, 4))
    attitude /= np.linalg.norm(attitude, axis=1, keepdims=True)
    scale = draw(floats(0.0, 100.0))
    return {
        "time": time,
        "p": scale * rng.normal(size=(n, 3)),
        "v": rng.uniform(-10, 10, (n, 3)),
        "attitude": attitude * rng.uniform(0.95, 1.05, (n, 1)),  # x-y-z-w, nearly unit
        "p_load": scale * rng.normal(size=(n, 3)),
        "w_ref": rng.uniform(-10, 10, (n, 3)),
        "T_ref": rng.uniform(0, 40, (n, 1)),
    }


def _write(folder: Path, arrays: dict[str, np.ndarray]) -> Path:
    path = folder / "flight.npz"
    write_npz(path, arrays)
    return path


def _read(path: Path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DataWarning)
        return read_flight(path, PARAMS)


@SETTINGS
@given(flights())
def test_valid_flights_round_trip(arrays):
    with tempfile.TemporaryDirectory() as tmp:
        flight = _read(_write(Path(tmp), arrays))
    np.testing.assert_array_equal(flight.time, arrays["time"])
    np.testing.assert_array_equal(flight.states[:, POS], arrays["p"])
    np.testing.assert_array_equal(flight.states[:, VEL], arrays["v"])
    np.testing.assert_array_equal(flight.states[:, LOAD_POS], arrays["p_load"])
    np.testing.assert_array_equal(flight.inputs[:, 0], arrays["T_ref"][:, 0])
    np.testing.assert_array_equal(flight.inputs[:, 1:], arrays["w_ref"])
    q = flight.states[:, QUAT]  # w-x-y-z, unit, the same rotation as the file's (up to sign)
    unit = arrays["attitude"] / np.linalg.norm(arrays["attitude"], axis=1, keepdims=True)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.abs((q * unit[:, [3, 0, 1, 2]]).sum(1)), 1.0, atol=1e-12)
    assert np.all((q[1:] * q[:-1]).sum(1) >= 0)  # no sign flips between steps
    assert np.isfinite(flight.aux).all()


@st.composite
def broken_flights(draw: st.DrawFn) -> tuple[dict[str, np.ndarray], str]:
    """A flight with one fault that must be refused: (arrays, what the message names)."""
    arrays = draw(flights())
    n = len(arrays["time"])
    fault = draw(st.sampled_from(["drop", "nan", "inf", "shuffle", "length", "norm"]))
    key = draw(st.sampled_from(sorted(FLIGHT_KEYS)))
    if fault == "drop":
        del arrays[key]
        return arrays, key
    if fault in ("nan", "inf"):
        flat = arrays[key].reshape(-1).copy()
        flat[draw(st.integers(0, flat.size - 1))] = np.nan if fault == "nan" else -np.inf
        arrays[key] = flat.reshape(arrays[key].shape)
        return arrays, key
    if fault == "shuffle":
        order = np.array(draw(st.permutations(range(n))))
        assume(np.any(order != np.arange(n)))
        arrays["time"] = arrays["time"][order]
        return arrays, "time"
    if fault == "length":
        arrays[key] = arrays[key][: draw(st.integers(0, n - 1))] if key != "time" else arrays[key]
        assume(key != "time")
        return arrays, key
    arrays["attitude"] = arrays["attitude"] * draw(st.sampled_from([0.0, 0.5, 2.0]))
    return arrays, "attitude"


@SETTINGS
@given(broken_flights())
def test_broken_flights_are_refused_naming_the_file_and_key(case):
    arrays, key = case
    with tempfile.TemporaryDirectory() as tmp:
        path = _write(Path(tmp), arrays)
        with pytest.raises(FlightFormatError) as info:
            _read(path)
    assert str(path) in str(info.value) and key in str(info.value)


@SETTINGS
@given(flights(), st.data())
def test_damaged_bytes_are_refused_or_read_intact(arrays, data):
    """Truncated files are always refused; flipped bytes either are refused or (when they hit
    bytes no reader checks, like a zip timestamp) leave a flight that still reads intact."""
    with tempfile.TemporaryDirectory() as tmp:
        path = _write(Path(tmp), arrays)
        raw = bytearray(path.read_bytes())
        if data.draw(st.booleans(), label="truncate"):
            path.write_bytes(raw[: data.draw(st.integers(0, len(raw) - 1), label="length")])
            with pytest.raises(FlightFormatError, match="flight.npz"):
                _read(path)
            return
        for _ in range(data.draw(st.integers(1, 4), label="flips")):
            i = data.draw(st.integers(0, len(raw) - 1), label="index")
            raw[i] ^= data.draw(st.integers(1, 255), label="mask")
        path.write_bytes(bytes(raw))
        try:
            flight = _read(path)
        except FlightFormatError as exc:
            assert str(path) in str(exc)
            return
    assert np.isfinite(flight.states).all() and np.isfinite(flight.inputs).all()
    assert np.all(np.diff(flight.time) > 0)
