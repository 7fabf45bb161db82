"""State layout and quaternion helpers."""

from __future__ import annotations

import math
import subprocess
import sys

import torch

from slungload import layout, state
from slungload.state import (
    GROUPS,
    STATE_DIM,
    body_z,
    join_state,
    quat_conj,
    quat_continuous,
    quat_error,
    quat_from_rotvec,
    quat_mul,
    quat_to_rotmat,
    quat_wxyz_to_xyzw,
    quat_xyzw_to_wxyz,
    split_state,
)


def test_groups_tile_the_state():
    covered = sorted(i for s in GROUPS.values() for i in range(STATE_DIM)[s])
    assert covered == list(range(STATE_DIM))


def test_layout_imports_without_torch():
    # An onboard controller runs on numpy alone: the layout module must not pull in torch.
    code = (
        "import sys, slungload.layout as l\n"
        "bad = sorted(m for m in ('torch', 'roma') if m in sys.modules)\n"
        "assert not bad, bad\n"
        "print(l.STATE_DIM)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "13"


def test_layout_slices_partition_the_columns():
    for names, dim in (
        (("POS", "VEL", "QUAT", "LOAD_POS"), layout.STATE_DIM),
        (("THRUST", "RATES"), layout.INPUT_DIM),
        (("LOAD_VEL", "LOAD_RATE"), layout.AUX_DIM),
    ):
        covered = [i for name in names for i in range(dim)[getattr(layout, name)]]
        assert covered == list(range(dim)), names  # in order, no gap, no overlap
    assert (layout.STATE_DIM, layout.INPUT_DIM, layout.AUX_DIM) == (13, 4, 6)
    assert len(layout.STATE_NAMES) == len(layout.STATE_COLUMNS) == layout.STATE_DIM
    assert len(layout.HISTORY_COLUMNS) == layout.HISTORY_DIM == 17
    assert layout.STATE_COLUMNS[layout.QUAT] == ("qx", "qy", "qz", "qw")  # the file order
    assert [layout.WXYZ_TO_XYZW[i] for i in layout.XYZW_TO_WXYZ] == [0, 1, 2, 3]


def test_state_re_exports_the_layout():
    for name in ("POS", "QUAT", "GROUPS", "STATE_NAMES", "STATE_COLUMNS", "AUX_DIM"):
        assert getattr(state, name) is getattr(layout, name)


def test_body_z_is_the_rotation_matrix_last_column_to_the_bit():
    gen = torch.Generator().manual_seed(0)
    for dtype in (torch.float32, torch.float64):
        q = torch.randn(500, 4, generator=gen, dtype=dtype) * 2.0  # off unit norm too
        q.requires_grad_(True)
        want = quat_to_rotmat(q)[..., :, 2]
        (gw,) = torch.autograd.grad(want.sum(), q)
        got = body_z(q)
        (gg,) = torch.autograd.grad(got.sum(), q)
        assert torch.equal(got, want) and torch.equal(gg, gw)  # the same arithmetic, gradients
    up = body_z(torch.tensor([[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]))
    torch.testing.assert_close(up, torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]))


def test_split_join_round_trip():
    x = torch.randn(5, 7, STATE_DIM)
    assert torch.equal(join_state(*split_state(x)), x)


def test_layout_conversion_round_trip():
    q = torch.randn(10, 4)
    assert torch.equal(quat_xyzw_to_wxyz(quat_wxyz_to_xyzw(q)), q)
    assert torch.equal(
        quat_wxyz_to_xyzw(torch.tensor([1.0, 2, 3, 4])), torch.tensor([2.0, 3, 4, 1])
    )


def test_product_matches_rotation_composition():
    a = quat_from_rotvec(torch.randn(6, 3, dtype=torch.float64))
    b = quat_from_rotvec(torch.randn(6, 3, dtype=torch.float64))
    r = quat_to_rotmat(quat_mul(a, b))
    assert torch.allclose(r, quat_to_rotmat(a) @ quat_to_rotmat(b), atol=1e-12)


def test_error_is_zero_for_equal_and_small_for_near():
    q = quat_from_rotvec(torch.randn(6, 3, dtype=torch.float64))
    assert torch.allclose(quat_error(q, q), torch.zeros(6, 4, dtype=torch.float64), atol=1e-12)
    dq = quat_from_rotvec(torch.tensor([0.01, 0.0, 0.0], dtype=torch.float64))
    err = quat_error(quat_mul(dq, q), q)
    # For a small rotation by angle a, the error is about (0, a/2 * axis).
    assert torch.allclose(err[:, 1], torch.full((6,), 0.005, dtype=torch.float64), atol=1e-6)
    assert torch.allclose(quat_mul(q, quat_conj(q))[:, 0], torch.ones(6, dtype=torch.float64))


def test_continuity_removes_sign_flips():
    angles = torch.linspace(0, 2 * math.pi, 50, dtype=torch.float64)
    q = quat_from_rotvec(torch.stack([angles * 0, angles * 0, angles], -1))
    flipped = q.clone()
    flipped[10:20] *= -1
    flipped[30] *= -1
    fixed = quat_continuous(flipped)
    assert torch.allclose(fixed, q * torch.sign(q[0, 0]))
    assert torch.all((fixed[1:] * fixed[:-1]).sum(-1) > 0)


def test_the_heading_frame_turns_a_scene_to_heading_zero_and_back():
    from slungload.state import (
        POS,
        QUAT,
        from_heading_frame,
        heading_turn,
        heading_twist,
        quat_normalize,
        rotate_about_z,
        to_heading_frame,
    )

    g = torch.Generator().manual_seed(4)
    x = torch.randn(5, 7, 13, generator=g, dtype=torch.float64)
    x[..., QUAT] = quat_normalize(x[..., QUAT])
    twist = heading_twist(x[:, -1, QUAT])  # (5, 4)
    torch.testing.assert_close(twist.norm(dim=-1), torch.ones(5, dtype=torch.float64))
    turn = heading_turn(twist)  # (5, 13, 13), orthogonal
    eye = torch.eye(13, dtype=torch.float64).expand(5, 13, 13)
    torch.testing.assert_close(turn @ turn.transpose(-1, -2), eye, atol=1e-12, rtol=0)
    # the matrix is the turn written out (rotate_about_z by the twist's angle): vectors
    # rotated, the attitude left-multiplied
    yaw = 2 * torch.atan2(twist[:, 3], twist[:, 0])[:, None]  # (5, 1)
    want = rotate_about_z(x, torch.zeros(5, 7, 6, dtype=torch.float64), yaw)[0]
    torch.testing.assert_close(from_heading_frame(x, turn), want, atol=1e-12, rtol=0)
    local = to_heading_frame(x, turn)
    # the last attitude now has no turn about z: its twist is the identity (up to sign)
    heading = heading_twist(local[:, -1, QUAT])
    torch.testing.assert_close(heading[:, 0].abs(), torch.ones(5, dtype=torch.float64))
    torch.testing.assert_close(from_heading_frame(local, turn), x, atol=1e-12, rtol=0)
    # the twist turns with the world, so a turned scene has the same local frame
    yaw = torch.tensor(-1.9, dtype=torch.float64)
    turned = rotate_about_z(x, torch.zeros(5, 7, 6, dtype=torch.float64), yaw)[0]
    again = to_heading_frame(turned, heading_turn(heading_twist(turned[:, -1, QUAT])))
    torch.testing.assert_close(again, local, atol=1e-12, rtol=0)
    # heights and distances are untouched
    torch.testing.assert_close(local[..., 2], x[..., 2])
    torch.testing.assert_close(local[..., POS].norm(dim=-1), x[..., POS].norm(dim=-1))
