"""The interval tracked in flight: its update rule (known solutions), its long-run coverage
on a plant whose errors the calibration under-states, the surprise flag, the causal replay
over a split's flights, and bad inputs."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from slungload.evaluation.uncertainty import tracked_multipliers
from slungload.layout import GROUPS, QUAT, STATE_DIM
from slungload.online_interval import (
    OnlineInterval,
    OnlineIntervalConfig,
    group_of_component,
    normalized_errors,
)

LEVEL = 0.9


def test_each_resolution_moves_the_log_multiplier_by_the_rule():
    rate = 0.05
    tracker = OnlineInterval(3, LEVEL, OnlineIntervalConfig(rate=rate))
    inside = np.full((3, STATE_DIM), 0.5)
    for _ in range(4):
        tracker.update(inside)
    np.testing.assert_allclose(tracker.log_scale, -4 * rate * (1 - LEVEL))
    outside = np.full((2, STATE_DIM), 10.0)  # a prediction resolved on its first 2 steps only
    tracker.update(outside)
    expected = np.full((3, len(GROUPS)), -4 * rate * (1 - LEVEL))
    expected[:2] += rate * LEVEL
    np.testing.assert_allclose(tracker.log_scale, expected)
    assert tracker.resolved == 5
    # half a group outside moves it by half a miss
    half = OnlineInterval(1, LEVEL, OnlineIntervalConfig(rate=rate))
    ratio = np.full((1, STATE_DIM), 0.5)
    ratio[0, GROUPS["position"].start] = 10.0  # 1 of position's 3 components
    half.update(ratio)
    g = list(GROUPS).index("position")
    assert half.log_scale[0, g] == pytest.approx(rate * (1 / 3 - (1 - LEVEL)))


def _stream(rng: np.random.Generator, n: int, steps: int, wide: float) -> np.ndarray:
    """(n, steps, 13) |error| / calibrated half width of Gaussian errors ``wide`` times those
    the calibration was fitted on (wide = 1: exactly 10 % outside)."""
    z = 1.6448536269514722
    return np.abs(wide * rng.standard_normal((n, steps, STATE_DIM))) / z


def test_tracking_reaches_the_level_where_the_calibration_under_states_the_errors():
    rng = np.random.default_rng(0)
    steps = 4
    ratios = _stream(rng, 6000, steps, wide=3.0)
    tracker = OnlineInterval(steps, LEVEL)
    misses = []
    for r in ratios:
        misses.append((r > tracker.component_multiplier()).mean())
        tracker.update(r)
    late = np.mean(misses[1000:])
    assert (ratios > 1).mean() > 0.5  # as calibrated: most errors outside
    assert late == pytest.approx(1 - LEVEL, abs=0.02)
    np.testing.assert_allclose(tracker.multiplier, 3.0, rtol=0.25)
    assert tracker.surprised


def test_not_surprised_on_errors_like_the_calibrations():
    rng = np.random.default_rng(1)
    tracker = OnlineInterval(4, LEVEL)
    flagged = 0
    for r in _stream(rng, 3000, 4, wide=1.0):
        tracker.update(r)
        flagged += tracker.surprised
    assert flagged == 0
    np.testing.assert_allclose(tracker.multiplier, 1.0, atol=0.3)


def test_normalized_errors_ignore_the_quaternion_sign():
    mean = np.zeros((2, STATE_DIM))
    mean[:, QUAT.start] = 1.0
    truth = mean.copy()
    truth[:, 0] = 0.3
    flipped = truth.copy()
    flipped[:, QUAT] *= -1
    half = np.full_like(mean, 0.1)
    np.testing.assert_allclose(
        normalized_errors(mean, half, flipped), normalized_errors(mean, half, truth)
    )
    assert normalized_errors(mean, half, truth)[0, 0] == pytest.approx(3.0)
    assert group_of_component()[QUAT].tolist() == [list(GROUPS).index("quaternion")] * 4


def two_flights(seed: int, n: int = 3, w: int = 12):
    """ratio (2w, n, 13) uniform in [0, 3), flight and start (2w,): two flights of w windows."""
    rng = np.random.default_rng(seed)
    ratio = torch.as_tensor(rng.uniform(0, 3, (2 * w, n, STATE_DIM)))
    return ratio, torch.tensor([0] * w + [1] * w), torch.cat([torch.arange(w), torch.arange(w)])


def test_the_replay_is_causal_and_restarts_with_each_flight():
    n, w = 3, 12
    ratio, flight, start = two_flights(2, n, w)
    order = torch.randperm(2 * w, generator=torch.Generator().manual_seed(0))
    mult, _ = tracked_multipliers(ratio[order], flight[order], start[order], LEVEL)
    back = np.empty_like(mult)
    back[order.numpy()] = mult  # the replay follows time, not the rows' order
    first, _ = tracked_multipliers(ratio, flight, start, LEVEL)
    np.testing.assert_allclose(back, first)
    # the first N windows of each flight: nothing resolved yet; then it moves
    assert np.all(first[:n] == 1.0) and np.all(first[w : w + n] == 1.0)
    assert np.any(first[n] != 1.0)
    # window s sees windows up to s - N only: change window 7 and nothing before 10 moves
    changed = ratio.clone()
    changed[7] = 100.0
    after, _ = tracked_multipliers(changed, flight, start, LEVEL)
    np.testing.assert_allclose(after[: 7 + n], first[: 7 + n])
    assert np.all(after[7 + n] >= first[7 + n]) and np.any(after[7 + n] > first[7 + n])
    np.testing.assert_allclose(after[w:], first[w:])  # the next flight starts afresh
    # every other window (stride 2): each still takes what has resolved, N steps late
    every = torch.arange(0, w, 2)
    sparse, _ = tracked_multipliers(ratio[every], flight[every], start[every], LEVEL)
    assert np.all(sparse[:2] == 1.0) and np.any(sparse[2] != 1.0)  # start 4 takes start 0


def test_carried_the_next_flight_starts_where_the_last_left_off():
    n, w = 3, 12
    ratio, flight, start = two_flights(3, n, w)
    fresh, _ = tracked_multipliers(ratio, flight, start, LEVEL)
    carried, surprised = tracked_multipliers(ratio, flight, start, LEVEL, carry=True)
    np.testing.assert_allclose(carried[:w], fresh[:w])  # the first flight: as before
    tracker = OnlineInterval(n, LEVEL)  # one vehicle: every window of flight 0 resolved ...
    for row in range(w):
        tracker.update(ratio[row].numpy())
    for row in range(w, w + n):  # ... before flight 1 issues its first N windows
        np.testing.assert_allclose(carried[row], tracker.multiplier)
    assert not np.allclose(carried[w], 1.0)
    for row in range(w + n, 2 * w):  # then flight 1's own windows, N steps late
        tracker.update(ratio[row - n].numpy())
        np.testing.assert_allclose(carried[row], tracker.multiplier)
        assert surprised[row] == tracker.surprised


def test_bad_inputs_are_refused():
    with pytest.raises(ValueError, match="horizon"):
        OnlineInterval(0, LEVEL)
    with pytest.raises(ValueError, match="level"):
        OnlineInterval(3, 1.0)
    with pytest.raises(ValueError, match="rate"):
        OnlineIntervalConfig(rate=0.0)
    with pytest.raises(ValueError, match="surprise"):
        OnlineIntervalConfig(surprise=1.0)
    tracker = OnlineInterval(3, LEVEL)
    with pytest.raises(ValueError, match="expected"):
        tracker.update(np.ones((3, 4)))
    bad = np.ones((3, STATE_DIM))
    bad[1, 2] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        tracker.update(bad)
