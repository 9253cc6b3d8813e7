"""The affine certificate path: agrees with CCD, refuses what it cannot prove."""

import numpy as np
import pytest

from penfree.core.verify.affine import verify_affine_step
from penfree.core.verify.path import verify_step

from _geom import two_sheets


def _affine(V, A, b):
    return V @ np.asarray(A).T + b


@pytest.mark.parametrize("thickness", [0.0, 0.05], ids=["zero", "thick"])
def test_affine_fast_path_agrees_with_ccd(thickness):
    V, F = two_sheets(n=4, gap=0.5)
    c, s = np.cos(0.3), np.sin(0.3)
    A = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.diag([1.1, 0.9, 1.05])
    b = np.array([0.1, -0.2, 0.3])
    x_def = _affine(V, A, b)
    fast = verify_affine_step(V, x_def, A, b, faces=F, thickness=thickness)
    assert fast is not None and fast.ok and fast.method == "certificate"
    assert fast.min_separation >= thickness
    assert verify_step(V, x_def, faces=F, thickness=thickness).ok


def test_affine_fast_path_refuses_what_it_cannot_prove():
    V, F = two_sheets(n=4, gap=0.5)
    # 170 degree rotation with anisotropic stretch: det > 0, singular M(t) half-way
    c, s = np.cos(np.radians(170)), np.sin(np.radians(170))
    A = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]) @ np.diag([2.0, 0.5, 1.0])
    assert np.linalg.det(A) > 0
    x_def = _affine(V, A, np.zeros(3))
    assert verify_affine_step(V, x_def, A, np.zeros(3), faces=F) is None
    # and an x_def that is not A x + b (one vertex moved through the other sheet)
    A = np.eye(3)
    bad = V.copy()
    bad[5, 2] = 2.0
    assert verify_affine_step(V, bad, A, np.zeros(3), faces=F) is None
    assert not verify_step(V, bad, faces=F).ok
    # thickness larger than the gap: the start state violates, the fast path declines
    assert verify_affine_step(V, V, A, np.zeros(3), faces=F, thickness=0.6) is None


def _proven(scene, g):
    # The certificate path's start pass: edge-face test, vertex-face and edge-edge folds.
    from penfree.core.verify.affine import _start_pass
    from penfree.core.verify.path import _Collector

    col = _Collector()
    return _start_pass(col, scene, g) and not col.kinds


@pytest.mark.parametrize("seed", range(4))
def test_distance_pass_never_clears_a_pair_the_static_ccd_flags(seed):
    # `_proven_apart` (one pass over computed distances) may skip the static CCD only
    # when that CCD finds nothing within g. Two sheets at gaps straddling g, jittered.
    from penfree.core.verify.path import _bodies, _Collector, _pairs_self

    rng = np.random.default_rng(seed)
    g = 0.1
    for gap in (0.5 * g, g * (1 - 1e-7), g, g * (1 + 1e-7), 1.01 * g, 3 * g):
        V, F = two_sheets(n=5, gap=gap)
        V = V + rng.normal(scale=1e-9, size=V.shape) * (seed > 0)
        scene = _bodies(V, V, None, F, None)[0]
        col = _Collector()
        _pairs_self(col, scene, g, static=True)
        if _proven(scene, g):
            assert not col.kinds, gap
        if gap < g * (1 - 1e-6):
            assert not _proven(scene, g) and col.kinds
    V, F = two_sheets(n=5, gap=3 * g)
    assert _proven(_bodies(V, V, None, F, None)[0], g)


def test_affine_step_with_a_pair_inside_g_goes_to_the_ccd():
    # A start gap below g = thickness / m: the distance pass cannot clear it, the
    # static CCD flags it, and the certificate path declines (full CCD decides).
    V, F = two_sheets(n=4, gap=0.01)
    A = np.diag([1.01, 1.0, 1.0])
    assert verify_affine_step(V, _affine(V, A, np.zeros(3)), A, np.zeros(3), faces=F, thickness=0.02) is None


@pytest.mark.parametrize("A, b, match", [
    (np.eye(3), [0.0, np.nan, 0.0], "finite; b holds"),
    (np.diag([1.0, np.inf, 1.0]), [0.0, 0.0, 0.0], "finite; A holds"),
    (np.eye(2), [0.0, 0.0], r"A \(2, 2\)"),
])
def test_unusable_map_says_what_is_wrong(A, b, match):
    """The message names the part of the map at fault (it printed the expected shapes)."""
    from penfree.errors import InputError

    V, F = two_sheets(n=3, gap=1.0)
    with pytest.raises(InputError, match=match):
        verify_affine_step(V, V, A, b, faces=F)


def _shuffled_sheets(rng, n, gap, pierce=False):
    V, F = two_sheets(n=n, gap=gap)
    if pierce:  # a small triangle through the lower sheet: edge-face candidates
        V = np.r_[V, [[2.5, 2.6, -0.5], [2.9, 2.6, 0.5], [2.5, 3.1, 0.5]]]
        F = np.r_[F, [[V.shape[0] - 3, V.shape[0] - 2, V.shape[0] - 1]]]
    V = V + rng.normal(scale=1e-3, size=V.shape)
    perm = rng.permutation(V.shape[0])  # new vertex k is old vertex perm[k]
    inv = np.empty_like(perm)
    inv[perm] = np.arange(perm.size)
    return np.ascontiguousarray(V[perm]), np.ascontiguousarray(inv[F][rng.permutation(F.shape[0])])


@pytest.mark.parametrize("g", [0.0, 0.05, 0.3, 1.5])
def test_start_pass_of_a_relabelled_scene_gives_the_same_pairs_and_minimum(rng, g):
    # The start pass on the scene renumbered along a Morton curve: the same edge-face
    # candidates (taken back to the caller's edges and faces: a triangle pierces a sheet)
    # and the same minimum, bit for bit. At g = 1.5 the boxes reach across the gap.
    from penfree.core.contact.broad_phase import start_pass
    from penfree.core.contact.locality import Relabelling
    from penfree.core.verify.path import _bodies, _inflation

    V, F = _shuffled_sheets(rng, 7, 1.0, pierce=True)
    scene = _bodies(V, V, None, F, None)[0]
    r = Relabelling(V, scene.E, scene.F)
    infl = _inflation(g, V)
    for cap in (np.inf, 4.0 * g * g):
        want, d_want = start_pass(V, scene.E, scene.F, scene.V, infl, cap)
        got, d_got = start_pass(r.positions(V), r.E, r.F, r.inv[scene.V], infl, cap)
        np.testing.assert_array_equal(r.edge_face_to_caller(got), want)
        assert np.float64(d_got).view(np.uint64) == np.float64(d_want).view(np.uint64)
        assert len(want) >= 2


@pytest.mark.parametrize("gap", [0.01, 0.5])
def test_certificate_path_on_a_relabelled_scene_gives_the_same_verdict(rng, monkeypatch, gap):
    # Forced on a small scene: the certificate path with a result's neighbour list runs
    # its fresh start pass on the list's relabelling, and answers as without it.
    from penfree.core.contact import locality
    from penfree.core.verify.path import _bodies
    from penfree.core.verify.reuse import result_lists

    monkeypatch.setattr(locality, "GAP_MIN", -1)
    monkeypatch.setattr(locality, "GAP_SHARE", 0.0)
    V, F = _shuffled_sheets(rng, 6, gap)
    scene = _bodies(V, V, None, F, None)[0]
    A = np.diag([1.01, 1.0, 0.99])
    x_def = _affine(V, A, np.zeros(3))
    nl = result_lists(scene.E, scene.F)
    for thickness in (0.0, 0.005, 0.02):
        want = verify_affine_step(V, x_def, A, np.zeros(3), faces=F, thickness=thickness)
        got = verify_affine_step(V, x_def, A, np.zeros(3), faces=F, thickness=thickness, neighbours=nl)
        assert (got is None) == (want is None)
        if want is not None:
            assert got.to_dict() == want.to_dict()
    assert nl.relabelling(V) is not None and nl.info["fresh"] > 0
    assert (gap < 0.02) == (verify_affine_step(V, x_def, A, np.zeros(3), faces=F, thickness=0.02, neighbours=nl)
                            is None)
