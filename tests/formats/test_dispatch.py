"""The format dispatcher: detection by pattern, directory, content and extension; unknown names."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from penfree.errors import InputError
from penfree.formats import FORMATS, detect_format, read_sequence, register, write_sequence
from penfree.sequence import SCALE_MAX, SCALE_MIN, Sequence


@pytest.mark.parametrize("path,writing,name", [
    ("a.h5", False, "hdf5"), ("a.HDF5", True, "hdf5"), ("a.npz", False, "npz"),
    ("a.xdmf", True, "xdmf"), ("a.xmf", False, "xdmf"),
    ("out/A%08d.ply", False, "meshseq"), ("out/A%08d.ply", True, "meshseq"),
    ("frames/frame_*.obj", False, "meshseq"), ("frame_0001.ply", False, "meshseq"),
    ("out/", True, "meshseq"),
], ids=["h5", "HDF5-upper", "npz", "xdmf", "xmf", "pattern-read", "pattern-write", "glob", "numbered-file", "dir-slash"])
def test_detect_by_name(path, writing, name):
    assert detect_format(path, writing=writing) == name


def test_detect_by_content_and_directory(tmp_path):
    seq = Sequence(positions=np.zeros((2, 3, 3)), faces=np.array([[0, 1, 2]])).validate()
    write_sequence(tmp_path / "x.h5", seq)
    (tmp_path / "x.h5").rename(tmp_path / "x.sim")
    assert detect_format(str(tmp_path / "x.sim")) == "hdf5"
    assert detect_format(str(tmp_path)) == "meshseq"


@pytest.mark.parametrize("name,fmt", [("d.h5", "hdf5"), ("d.npz", "npz"), ("d.xdmf", "xdmf"), ("d.usda", "usd"),
                                      ("d.ply", "meshseq"), ("d", "meshseq")])
def test_existing_directory_output_keeps_its_extension_format(tmp_path, name, fmt):
    # an explicit file extension wins over "an existing directory is a mesh sequence"
    (tmp_path / name).mkdir()
    assert detect_format(str(tmp_path / name), writing=True) == fmt


def test_unknown_extension_names_file_and_formats(tmp_path):
    with pytest.raises(InputError) as err:
        read_sequence(tmp_path / "frames.csv")
    msg = str(err.value)
    assert "frames.csv" in msg and all(n in msg for n in ("hdf5", "npz", "meshseq", "xdmf"))
    with pytest.raises(InputError, match="unknown format 'csv'"):
        read_sequence(tmp_path / "frames.h5", format="csv")


def test_register_a_format(tmp_path):
    seen = {}

    def reader(path):
        return Sequence(positions=np.ones((2, 2, 3)), edges=np.array([[0, 1]]))

    def writer(path, seq, overwrite):
        seen["written"] = (path, seq.n_frames, overwrite)

    register("toy", (".toy",), reader, writer)
    try:
        seq = read_sequence(tmp_path / "a.toy")
        assert seq.origin == str(tmp_path / "a.toy") and seq.kind == "segments"
        write_sequence(tmp_path / "b.toy", seq, overwrite=True)
        assert seen["written"] == (str(tmp_path / "b.toy"), 2, True)
    finally:
        FORMATS.pop("toy")



@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    dtype=st.sampled_from([np.float32, np.float64]),
    shape=st.tuples(st.integers(2, 4), st.integers(3, 6)),
    target=st.sampled_from(["s.h5", "s.npz", "s.xdmf", "m/f_%03d.obj", "m/f_%03d.ply"]),
    data=st.data(),
)
def test_any_finite_values_round_trip_bit_exactly(tmp_path_factory, dtype, shape, target, data):
    """Subnormals, huge values, -0.0: every format gives back the very same bits.

    Within the supported range (largest |coordinate| in [SCALE_MIN, SCALE_MAX]);
    scenes outside it are refused (test_sequence.py).
    """
    T, N = shape
    bound = SCALE_MAX if dtype == np.float64 else None  # float32 never exceeds it
    pos = data.draw(hnp.arrays(dtype, (T, N, 3), elements=st.floats(
        min_value=None if bound is None else -bound, max_value=bound, allow_nan=False, allow_infinity=False,
        width=32 if dtype == np.float32 else 64)))
    if np.abs(pos).max() < SCALE_MIN:
        pos[0, 0, 0] = 1.0  # subnormals stay, the scene gets a supported scale
    seq = Sequence(positions=pos, faces=np.array([[0, 1, 2]])).validate()
    d = tmp_path_factory.mktemp("rt")
    write_sequence(str(d / target), seq)
    back = read_sequence(str(d / target))
    assert back.positions.dtype == dtype
    assert back.positions.tobytes() == pos.tobytes()
