"""The numpy facade: parity with the eager network, file quaternion convention, shapes."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import torch
from flights import SMALL, WXYZ_TO_XYZW, file_rows, predict_args

from slungload.deploy.predictor import Predictor
from slungload.models.checkpoints import load_checkpoint
from slungload.state import QUAT, STATE_DIM, with_unit_quaternion

torch.set_num_threads(1)

M, N = SMALL.history, SMALL.horizon


def test_predict_matches_the_eager_model(tiny_run) -> None:
    val = tiny_run.dataset.splits["val"]
    predictor = Predictor.from_checkpoint(tiny_run.out)
    model = load_checkpoint(tiny_run.out / "best.ckpt").model
    for i in (0, len(val) - 1):
        states, inputs = val.states[i], val.inputs[i]
        got = predictor.predict(file_rows(states[:M], inputs[:M]), inputs[M:].numpy())
        with torch.no_grad():
            pred = model(states[None, :M], inputs[None, :M], inputs[None, M:]).states[0]
        want = with_unit_quaternion(pred).double().numpy()
        want[:, QUAT] = want[:, QUAT][:, WXYZ_TO_XYZW]
        assert got.shape == (N, STATE_DIM) and got.dtype == np.float64
        np.testing.assert_allclose(got, want, atol=1e-5)
        np.testing.assert_allclose(np.linalg.norm(got[:, QUAT], axis=-1), 1.0, atol=1e-6)


def test_batch_and_single_inputs_agree(tiny_run) -> None:
    val = tiny_run.dataset.splits["val"]
    predictor = Predictor.from_checkpoint(tiny_run.out / "best.ckpt")
    history, future = predict_args(val[:5])  # (5, M, 17), (5, N, 4)
    batch = predictor.predict(history, future)
    assert batch.shape == (5, N, STATE_DIM)
    for b in range(5):
        np.testing.assert_allclose(batch[b], predictor.predict(history[b], future[b]), atol=1e-5)


def test_other_horizons_and_quaternion_sign_flips(tiny_run) -> None:
    val = tiny_run.dataset.splits["val"]
    predictor = Predictor.from_checkpoint(tiny_run.out)
    history = file_rows(val.states[0, :M], val.inputs[0, :M])
    longer = np.repeat(val.inputs[0, M:].numpy(), 2, axis=0)  # 2N steps of inputs
    out = predictor.predict(history, longer)
    assert out.shape == (2 * N, STATE_DIM)
    # q and -q are one rotation: a sign jump inside the history must not change the answer.
    flipped = history.copy()
    flipped[M // 2 :, QUAT] *= -1
    np.testing.assert_allclose(predictor.predict(flipped, longer), out, atol=1e-6)


@pytest.mark.parametrize(
    ("history_shape", "future_shape"),
    [
        ((M, 13), (N, 4)),  # states without inputs
        ((M, 17), (N, 3)),  # missing a rate
        ((M, 17), (2, N, 4)),  # single history with batched inputs
        ((2, M, 17), (3, N, 4)),  # batch sizes differ
        ((17,), (4,)),  # one row is not a history
        ((0, 17), (N, 4)),  # empty history
        ((M, 17), (0, 4)),  # no future
    ],
)
def test_bad_shapes_name_expected_and_actual(
    tiny_run, history_shape: tuple, future_shape: tuple
) -> None:
    predictor = Predictor.from_checkpoint(tiny_run.out)
    with pytest.raises(ValueError, match=r"expected history .*got history") as info:
        predictor.predict(np.zeros(history_shape), np.zeros(future_shape))
    assert str(history_shape) in str(info.value) and str(future_shape) in str(info.value)


def test_non_finite_values_and_bad_checkpoints_are_refused(tiny_run, tmp_path) -> None:
    predictor = Predictor.from_checkpoint(tiny_run.out)
    history = np.zeros((M, 17))
    history[:, 9] = 1.0  # identity quaternion, x-y-z-w
    history[2, 0] = np.nan
    with pytest.raises(ValueError, match="history holds NaN"):
        predictor.predict(history, np.zeros((N, 4)))
    bad = tmp_path / "bad.ckpt"
    bad.write_text("hello")
    with pytest.raises(ValueError, match="bad.ckpt"):
        Predictor.from_checkpoint(bad)


def test_predict_runs_on_one_torch_thread_by_default(tiny_run) -> None:
    seen: list[int] = []
    history, future = predict_args(tiny_run.dataset.splits["val"][:1])
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for threads, expected in ((1, 1), (3, 3), (None, 2)):
            kwargs = {} if threads == 1 else {"threads": threads}  # 1 is the default
            predictor = Predictor.from_checkpoint(tiny_run.out, **kwargs)
            assert predictor.threads == threads
            hook = predictor.network.register_forward_pre_hook(
                lambda module, args: seen.append(torch.get_num_threads())
            )
            predictor.predict(history[0], future[0])
            hook.remove()
            assert seen[-1] == expected, (threads, seen)
            assert torch.get_num_threads() == 2  # restored after the call
    finally:
        torch.set_num_threads(before)
    with pytest.raises(ValueError, match="threads must be >= 1"):
        Predictor.from_checkpoint(tiny_run.out, threads=0)


def test_flight_window_cuts_predict_arguments_from_a_flight(tiny_run, physics_flight) -> None:
    from slungload.data.readers import read_flight
    from slungload.deploy.predictor import flight_window

    flight = read_flight(tiny_run.data / "test_4.npz")  # package layout, q w-x-y-z
    predictor = Predictor.from_checkpoint(tiny_run.out)
    start = 7
    w = flight_window(flight, start, history=M, horizon=N)
    assert (w.history.shape, w.future_inputs.shape, w.truth.shape) == ((M, 17), (N, 4), (N, 13))
    rows = file_rows(torch.from_numpy(flight.states), torch.from_numpy(flight.inputs))
    np.testing.assert_array_equal(w.history, rows[start : start + M])
    np.testing.assert_array_equal(w.future_inputs, flight.inputs[start + M : start + M + N])
    np.testing.assert_array_equal(w.truth, rows[start + M : start + M + N, :13])  # x-y-z-w
    # The same window as the data module's: the same prediction.
    windows = tiny_run.dataset.splits["test"]
    index = next(
        i
        for i in range(len(windows))
        if np.allclose(windows.states[i, 0].numpy(), flight.states[start])
    )
    history, future = predict_args(windows[index : index + 1])
    np.testing.assert_allclose(
        predictor.predict(w.history, w.future_inputs), predictor.predict(history[0], future[0]),
        atol=1e-6,
    )  # fmt: skip
    # Plain arrays work too (a Flight-like object), and windows that do not fit are refused.
    tail = len(flight.states) - M - N
    assert flight_window(physics_flight("p", 1, 30), 0, history=M, horizon=N).truth.shape == (N, 13)
    with pytest.raises(ValueError, match=rf"do not fit in test_4 .*start must be 0 \.\.\. {tail}"):
        flight_window(flight, tail + 1, history=M, horizon=N)
    with pytest.raises(ValueError, match="history and horizon must be >= 1"):
        flight_window(flight, 0, history=0, horizon=N)


def readme_controller_snippet() -> str:
    """The python block under README's "Use a trained model in a controller" heading."""
    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    section = readme.split("## Use a trained model in a controller", 1)[1].split("\n## ", 1)[0]
    match = re.search(r"```python\n(.*?)```", section, re.DOTALL)
    assert match, "README: no python block under 'Use a trained model in a controller'"
    return match.group(1)


def test_readme_controller_snippet_runs(
    tiny_run, physics_flight, tmp_path, monkeypatch, capsys
) -> None:
    """The README's snippet, as written, against a tiny run and a flight at the paths it names
    (``reproduce --out out`` writes them there)."""
    from flights import file_arrays

    from slungload.fileio import write_npz

    code = readme_controller_snippet()
    run = re.search(r'from_checkpoint\("([^"]+)"\)', code).group(1)
    flight = re.search(r'read_flight\("([^"]+)"\)', code).group(1)
    (tmp_path / run).parent.mkdir(parents=True)
    (tmp_path / run).symlink_to(tiny_run.out, target_is_directory=True)
    write_npz(tmp_path / flight, file_arrays(physics_flight("long", 3, 200)))
    monkeypatch.chdir(tmp_path)
    namespace: dict = {}
    exec(compile(code, "README.md", "exec"), namespace)
    assert namespace["states"].shape == namespace["truth"].shape == (25, 13)
    assert namespace["model"].threads == 1
    assert "position 0.75 s ahead:" in capsys.readouterr().out
