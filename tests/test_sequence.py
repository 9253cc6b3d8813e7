"""Sequence.validate: what it accepts, normalises and refuses (with a one-line message)."""

import warnings

import numpy as np
import pytest

from penfree.errors import InputError
from penfree.sequence import Obstacle, Sequence, first_nonfinite_frame


RNG_SEED = 20261121  # seed of the shared `rng` fixture (tests/conftest.py)


def _seq(rng, **kw):
    base = dict(positions=rng.random((3, 4, 3)), faces=np.array([[0, 1, 2], [1, 2, 3]]), origin="s.h5")
    base.update(kw)
    return Sequence(**base)


def test_valid_sequence_keeps_dtype_and_normalises_topology(rng):
    for dtype in (np.float32, np.float64):
        seq = _seq(rng, positions=rng.random((3, 4, 3)).astype(dtype),
                   faces=np.array([[0, 1, 2]], dtype=np.int32), edges=np.array([[0, 3.0]])).validate()
        assert seq.positions.dtype == dtype
        assert seq.faces.dtype == np.int64 and seq.edges.dtype == np.int64
        assert seq.edges.tolist() == [[0, 3]]
        assert (seq.n_frames, seq.n_vertices, seq.kind) == (3, 4, "triangles")


def test_big_endian_float32_stays_float32(rng):
    pos = rng.random((2, 3, 3)).astype(">f4")
    seq = _seq(rng, positions=pos, faces=np.array([[0, 1, 2]])).validate()
    assert seq.positions.dtype == np.float32 and seq.positions.dtype.isnative
    np.testing.assert_array_equal(seq.positions, pos.astype(np.float32))


def test_integer_positions_become_float64(rng):
    seq = _seq(rng, positions=np.arange(24).reshape(2, 4, 3)).validate()
    assert seq.positions.dtype == np.float64


@pytest.mark.parametrize("faces,edges,kind", [
    (np.array([[0, 1, 2]]), None, "triangles"),
    (None, np.array([[0, 1]]), "segments"),
    (np.zeros((0, 3), int), None, "points"),
    (None, None, "points"),
], ids=["triangles", "segments", "empty-faces", "no-topology"])
def test_kind(rng, faces, edges, kind):
    assert _seq(rng, faces=faces, edges=edges).validate().kind == kind


@pytest.mark.parametrize("change,expect", [
    (dict(positions=np.zeros((3, 4))), "positions must be (T, N, 3); got (3, 4) in s.h5:/positions"),
    (dict(positions=np.zeros((1, 4, 3))), "at least 2 frames; got 1 in s.h5:/positions"),
    (dict(positions=np.zeros((2, 0, 3))), "at least 1 vertex"),
    (dict(positions=np.array([[["a"] * 3] * 4] * 2)), "float32 or float64"),
    (dict(faces=np.array([[0, 1, 4]])), "faces indices must be in [0, 3] for 4 vertices; found 4 in s.h5:/faces"),
    (dict(faces=np.array([[0, -1, 2]])), "found -1 in s.h5:/faces"),
    (dict(faces=np.array([[0, 1]])), "faces must be (M, 3); got (1, 2) in s.h5:/faces"),
    (dict(faces=np.array([[0, 1, 1]])), "row 0 is [0, 1, 1] in s.h5:/faces"),
    (dict(faces=np.array([[0, 1, 2.5]])), "faces must be integer indices; got float64"),
    (dict(edges=np.array([[0, 9]])), "edges indices must be in [0, 3]"),
    # a whole float beyond int64 (it was cast first, with a RuntimeWarning, and reported wrapped)
    (dict(edges=np.array([[0.0, 1e308]])), "edges indices must be in [0, 3] for 4 vertices; found 1e+308 in s.h5:/edges"),
    (dict(weights=np.ones(3)), "weights must be (4,) to match positions; got (3,) in s.h5:/weights"),
    (dict(weights=np.array([1.0, -1, 1, 1])), "weights must be finite and >= 0; got min -1 in s.h5:/weights"),
    (dict(weights=np.array([1.0, np.nan, 1, 1])), "found NaN or Inf in s.h5:/weights"),
    (dict(weights=np.zeros(4)), "weights must not all be zero"),
    (dict(components=np.ones(4) * 0.5), "components must be (4,) integer"),
    (dict(thickness=-1.0), "thickness must be finite and >= 0; got -1.0 in s.h5:@thickness"),
    (dict(thickness="thick"), "thickness must be finite and >= 0; got 'thick'"),
    (dict(obstacles=[Obstacle("wall", np.zeros((5, 4, 3)), faces=np.array([[0, 1, 2]]))]),
     "obstacle positions must be (3, M, 3) or (M, 3); got (5, 4, 3) in s.h5:/obstacles/wall/positions"),
    (dict(obstacles=[Obstacle("wall", np.zeros((4, 3)))]), "obstacle needs faces or edges in s.h5:/obstacles/wall"),
    (dict(obstacles=[Obstacle("wall", np.full((4, 3), np.inf), edges=np.array([[0, 1]]))]), "must be finite"),
], ids=["not-3d", "one-frame", "no-vertex", "strings", "index-too-big", "negative-index", "faces-2-columns",
        "repeated-vertex", "fractional-index", "edge-index", "huge-float-index", "weights-length", "negative-weight", "nan-weight",
        "zero-weights", "float-components", "negative-thickness", "text-thickness", "obstacle-frames",
        "obstacle-no-topology", "obstacle-inf"])
def test_refused_with_named_dataset(rng, change, expect):
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a refusal prints nothing but its message
        with pytest.raises(InputError) as err:
            _seq(rng, **change).validate()
    assert expect in str(err.value)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("frame", [0, 2])
def test_non_finite_frame_is_named(rng, frame):
    pos = rng.random((3, 4, 3))
    pos[frame, 1, 2] = np.nan
    with pytest.raises(InputError, match=f"frame {frame} holds NaN or Inf in s.h5:/positions"):
        _seq(rng, positions=pos).validate()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
@pytest.mark.parametrize("bad", [[], [0], [4], [1, 3], [0, 1, 2, 3, 4]])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_first_nonfinite_frame_matches_whole_array_mask(rng, dtype, bad, value):
    pos = rng.random((5, 7, 3)).astype(dtype)
    for s in bad:
        pos[s, rng.integers(7), rng.integers(3)] = value
    oracle = np.flatnonzero(~np.isfinite(pos).all(axis=(1, 2)))
    assert first_nonfinite_frame(pos) == (int(oracle[0]) if oracle.size else None)


def test_obstacle_frame_static_and_moving(rng):
    static = Obstacle("floor", rng.random((4, 3)), faces=np.array([[0, 1, 2]]))
    moving = Obstacle("ball", rng.random((3, 4, 3)), edges=np.array([[0, 1]]))
    _seq(rng, obstacles=[static, moving]).validate()
    np.testing.assert_array_equal(static.frame(2), static.positions)
    np.testing.assert_array_equal(moving.frame(2), moving.positions[2])


@pytest.mark.parametrize("values, ok", [
    ([0.0, -0.0], True),                      # all zero passes
    ([1.0, -1e100], True),                    # the largest magnitude is negative, at SCALE_MAX
    ([1.0, -1.0000001e100], False),
    ([1e-100, -1e-100], True),
    ([3e-101, -1e-101], False),               # below SCALE_MIN
    ([1.0, np.nan], False),
    ([np.nan, 1.0], False),
    ([-np.inf, 1.0], False),
], ids=["zeros", "negative-at-max", "negative-above-max", "at-min", "below-min", "nan-last", "nan-first", "inf"])
def test_check_scale_decides_on_the_largest_magnitude(values, ok):
    # Without an |a| temporary: the verdict is the one of max |a| formed explicitly.
    from penfree.sequence import SCALE_MAX, SCALE_MIN, check_scale

    a = np.asarray(values, dtype=np.float64)
    big = float(np.max(np.abs(a)))
    assert ok == (big == 0.0 or SCALE_MIN <= big <= SCALE_MAX)
    for b in (a, a[::-1].copy(), np.tile(a, (3, 2))):
        if ok:
            check_scale(b, "f.h5", "positions")
        else:
            with pytest.raises(InputError, match="positions must have its largest magnitude"):
                check_scale(b, "f.h5", "positions")


def test_check_scale_of_float32_and_integers():
    from penfree.sequence import check_scale

    check_scale(np.array([1.0, -3e38], dtype=np.float32), "f.h5", "positions")
    with pytest.raises(InputError, match="largest magnitude"):
        check_scale(np.array([1.0, np.nan], dtype=np.float32), "f.h5", "positions")
    check_scale(np.array([-128, 3], dtype=np.int8), "f.h5", "faces")  # no overflow in |-128|
