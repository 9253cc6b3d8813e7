"""describe / describe_result against hand-computed values."""

import numpy as np
import pytest

from penfree.core.describe import describe, describe_result, frame_motion
from penfree.formats.result import DeformResult
from penfree.sequence import Obstacle, Sequence


def test_triangle_scene_values():
    # unit right triangle translated by (0, 0, s) per frame, 3 frames
    x0 = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    pos = np.stack([x0 + [0, 0, s * s] for s in range(3)]).astype(np.float32)
    seq = Sequence(positions=pos, faces=np.array([[0, 1, 2]]), thickness=0.1, dt=0.5,
                   obstacles=[Obstacle("floor", np.zeros((3, 3)), faces=np.array([[0, 1, 2]]))]).validate()
    d = describe(seq)
    assert (d["frames"], d["vertices"], d["kind"], d["n_faces"], d["n_edges"], d["dtype"]) == (3, 3, "triangles", 1, 0, "float32")
    assert d["bbox"] == {"min": [0, 0, 0], "max": [1, 1, 4], "extent": [1, 1, 4]}
    # edges of the face: 1, 1, sqrt(2) -> median 1
    assert d["edge_length_median"] == pytest.approx(1.0, abs=0)
    # step motions: 1 then 3 for every vertex
    assert d["motion"]["per_step_max"] == [1.0, 3.0] and d["motion"]["per_step_rms"] == [1.0, 3.0]
    assert d["motion"]["max"] == {"min": 1.0, "median": 2.0, "max": 3.0}
    assert (d["thickness"], d["dt"]) == (pytest.approx(0.1), 0.5)
    assert d["obstacles"] == [{"name": "floor", "half_space": False, "vertices": 3, "faces": 1, "edges": 0,
                               "static": True, "solid": None}]


def test_motion_against_brute_force():
    rng = np.random.default_rng(2)
    pos = rng.standard_normal((6, 50, 3)) + 1e6  # far from the origin: differences in float64
    mx, rms = frame_motion(pos)
    d = np.linalg.norm(np.diff(pos, axis=0), axis=2)
    np.testing.assert_allclose(mx, d.max(axis=1), rtol=0, atol=1e-12)
    np.testing.assert_allclose(rms, np.sqrt((d ** 2).mean(axis=1)), rtol=1e-14, atol=0)


def test_segments_and_points():
    pos = np.zeros((2, 4, 3))
    pos[:, :, 0] = [0, 1, 3, 6]
    seg = describe(Sequence(positions=pos, edges=np.array([[0, 1], [1, 2], [2, 3]])).validate())
    assert seg["edge_length_median"] == 2.0 and seg["kind"] == "segments"
    pts = describe(Sequence(positions=pos).validate())
    assert pts["edge_length_median"] is None and pts["motion"]["max"]["max"] == 0.0


def test_describe_result():
    seq = Sequence(positions=np.zeros((4, 3, 3)), faces=np.array([[0, 1, 2]])).validate()
    steps = {"frame": np.array([1, 2, 3]), "model": np.array(["affine", "rigid", "affine"]),
             "projection": np.array(["none", "none", "sym"]), "certificate_margin": np.array([0.5, 0.25, 0.75])}
    r = describe_result(DeformResult(seq, steps, attrs={"input": "x.h5"}, groups={"stats": {}}))["result"]
    assert r["steps"] == 3 and r["frames"] == [1, 3]
    assert r["models"] == {"affine": 2, "rigid": 1} and r["projections"] == {"none": 2, "sym": 1}
    assert r["min_certificate_margin"] == 0.25 and r["groups"] == ["stats"]
    steps["certificate_margin"] = np.array([0.5, np.nan, 0.75])
    assert np.isnan(describe_result(DeformResult(seq, steps))["result"]["min_certificate_margin"])
