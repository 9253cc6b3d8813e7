"""NPZ archives: both position keys, round trips, refused inputs."""

import os

import numpy as np
import pytest

from penfree.errors import FormatError, InputError
from penfree.formats import read_sequence, write_sequence
from penfree.sequence import Obstacle, Sequence


RNG_SEED = 11  # seed of the shared `rng` fixture (tests/conftest.py)


@pytest.mark.parametrize("dtype", [np.float32, np.float64], ids=["float32", "float64"])
def test_round_trip(tmp_path, rng, dtype):
    seq = Sequence(positions=rng.random((3, 4, 3)).astype(dtype), edges=np.array([[0, 1], [2, 3]]),
                   faces=np.array([[0, 1, 2]]), weights=np.ones(4), components=np.array([0, 0, 1, 1]),
                   thickness=0.5, dt=0.01, source="npz", attrs={"k": {"a": 1}},
                   obstacles=[Obstacle("floor", rng.random((3, 3)), faces=np.array([[0, 1, 2]]))]).validate()
    p = tmp_path / "s.npz"
    write_sequence(p, seq)
    assert os.listdir(tmp_path) == ["s.npz"]  # no ".npz.npz", no temp left
    back = read_sequence(p)
    assert back.positions.dtype == dtype
    np.testing.assert_array_equal(back.positions, seq.positions)
    np.testing.assert_array_equal(back.edges, seq.edges)
    np.testing.assert_array_equal(back.faces, seq.faces)
    np.testing.assert_array_equal(back.components, seq.components)
    assert (back.thickness, back.dt, back.source, back.attrs) == (0.5, 0.01, "npz", {"k": {"a": 1}})
    assert back.obstacles[0].name == "floor"
    np.testing.assert_array_equal(back.obstacles[0].faces, [[0, 1, 2]])


def test_vertices_seq_key(tmp_path, rng):
    p = tmp_path / "drop.npz"
    pos = rng.random((2, 3, 3))
    np.savez(p, vertices_seq=pos, faces=np.array([[0, 1, 2]], dtype=np.int32), contact_radius=np.float64(0.1))
    seq = read_sequence(p)
    np.testing.assert_array_equal(seq.positions, pos)
    assert seq.kind == "triangles" and seq.thickness == 0.0 and seq.contact_radius == 0.1


@pytest.mark.parametrize("build,exc,expect", [
    (lambda p: open(p, "wb").write(b"PK\x03\x04garbage"), FormatError, "is not a readable .npz archive"),
    (lambda p: np.savez(p, faces=[[0, 1, 2]]), FormatError, "missing array positions (or vertices_seq)"),
    (lambda p: np.savez(p, positions=np.zeros((2, 3))), InputError, "positions must be (T, N, 3); got (2, 3)"),
    (lambda p: np.savez(p, positions=np.stack([np.zeros((3, 3)), np.full((3, 3), np.nan)])), InputError,
     "frame 1 holds NaN or Inf in {p}:/positions"),
    (lambda p: np.savez(p, positions=np.zeros((2, 3, 3)), faces=[[0, 1, 3]]), InputError, "found 3 in {p}:/faces"),
    (lambda p: np.savez(p, positions=np.zeros((2, 3, 3)), thickness=[1.0, 2.0]), InputError, "thickness must be one finite number"),
], ids=["not-zip", "no-positions", "wrong-shape", "nan-frame", "index-out-of-range", "thickness-array"])
def test_bad_inputs(tmp_path, build, exc, expect):
    p = str(tmp_path / "bad.npz")
    build(p)  # the name ends in .npz, so savez writes exactly there
    with pytest.raises(exc) as err:
        read_sequence(p)
    assert expect.format(p=p) in str(err.value)


def _npy_bytes(a) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def _zip(p, members, compression=None):
    import zipfile

    with zipfile.ZipFile(p, "w", compression=compression or zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(name, data)


def _flip_member_bytes(p):
    """Compress positions.npy, then damage its deflate stream in place (CRC and zlib errors)."""
    import zipfile

    _zip(p, {"positions.npy": _npy_bytes(np.arange(6 * 16 * 3, dtype=np.float64).reshape(6, 16, 3))},
         zipfile.ZIP_DEFLATED)
    with zipfile.ZipFile(p) as z:
        info = z.getinfo("positions.npy")
    data = bytearray(open(p, "rb").read())
    start = info.header_offset + 30 + len(info.filename) + len(info.extra)
    for k in range(start + 5, start + 40):
        data[k] ^= 0xA5
    open(p, "wb").write(bytes(data))


POS = np.zeros((6, 16, 3))


@pytest.mark.parametrize("build,member", [
    (lambda p: _zip(p, {"positions.npy": _npy_bytes(POS)[: len(_npy_bytes(POS)) // 2]}), "positions"),
    (lambda p: _zip(p, {"positions.npy": b"\x93NUMPY\x01\x00\x10\x00{'descr': <bad>}\n" + bytes(64)}), "positions"),
    (lambda p: _zip(p, {"positions.npy": b"definitely not an npy member"}), "positions"),
    (_flip_member_bytes, "positions"),
    (lambda p: _zip(p, {"positions.npy": _npy_bytes(POS), "faces.npy": _npy_bytes(np.zeros((2, 3), np.int64))[:90]}),
     "faces"),
], ids=["truncated-member", "bad-header", "not-npy", "damaged-deflate", "truncated-second-member"])
def test_damaged_member_is_named(tmp_path, build, member):
    # np.load reads members lazily: the damage shows only when the array is read
    p = str(tmp_path / "trunc_member.npz")
    build(p)
    with pytest.raises(FormatError) as err:
        read_sequence(p)
    msg = str(err.value)
    assert f"{p}:/{member}" in msg and "\n" not in msg, msg
