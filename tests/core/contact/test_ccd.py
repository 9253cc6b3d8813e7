"""Conservative CCD kernels: named cases with hand-computed toi, exact-rational
oracles at sampled times, the float kernel against the exact decision, and
invariance of the verdicts under exact rigid motions and relabelling."""

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from penfree.constants import CCD_ERR_REL, CCD_TOI_TOL, CCD_TOL_REL
from penfree.core.contact.ccd import BUDGET, CLOSE, SEPARATED, ccd_details, ccd_edge_edge, ccd_indexed, ccd_vertex_face
from penfree.core.contact.ccd_exact import exact_edge_edge, exact_vertex_face
from penfree.errors import InputError

from oracles import exact_dist_sq  # exact Fraction distance at a rational time

def run(kind, x_t0, x_t1, thickness=0.0, exact=True):
    f = ccd_edge_edge if kind == "ee" else ccd_vertex_face
    hit, toi = f(np.asarray(x_t0, float)[None], np.asarray(x_t1, float)[None], thickness, exact=exact)
    return bool(hit[0]), float(toi[0])


# --- named hard cases with hand-computed toi -----------------------------------------

EE_X = [[-1, 0, 1], [1, 0, 1], [0, -1, -1], [0, 1, -1]]  # crossing edges 2 apart in z
NAMED = [
    # id, kind, x_t0, x_t1, thickness, expected hit, true toi (None: no hit)
    ("crossing-edges", "ee", EE_X, [[-1, 0, -2], [1, 0, -2], [0, -1, -1], [0, 1, -1]], 0.0, True, 2 / 3),
    ("parallel-edges", "ee", [[0, 0, 1], [1, 0, 1], [0, 0, 0], [1, 0, 0]],
     [[0, 0, -1], [1, 0, -1], [0, 0, 0], [1, 0, 0]], 0.0, True, 0.5),
    ("parallel-edges-miss", "ee", [[0, 0, 1], [1, 0, 1], [2, 0, 0], [3, 0, 0]],
     [[0, 0, -1], [1, 0, -1], [2, 0, 0], [3, 0, 0]], 0.0, False, None),
    ("touching-at-t0", "ee", [[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0]],
     [[-1, 0, 1], [1, 0, 1], [0, -1, 0], [0, 1, 0]], 0.0, True, 0.0),
    ("touching-at-t1", "vf", [[0.25, 0.25, 1], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[0.25, 0.25, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.0, True, 1.0),
    ("degenerate-edge", "ee", [[0, 0, 1], [0, 0, 1], [-1, 0, 0], [1, 0, 0]],
     [[0, 0, -1], [0, 0, -1], [-1, 0, 0], [1, 0, 0]], 0.0, True, 0.5),
    ("degenerate-edge-miss", "ee", [[2, 0, 1], [2, 0, 1], [-1, 0, 0], [1, 0, 0]],
     [[2, 0, -1], [2, 0, -1], [-1, 0, 0], [1, 0, 0]], 0.0, False, None),
    ("point-on-edge-line", "vf", [[2, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[1.5, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.0, False, None),
    ("point-reaches-edge", "vf", [[2, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[0, 0, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.0, True, 0.5),
    ("coplanar-sliding", "vf", [[-1, 0.25, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[1, 0.25, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.0, True, 0.5),
    ("coplanar-sliding-miss", "vf", [[-1, 1.25, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[1, 1.25, 0], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.0, False, None),
    ("thickness-only-contact", "vf", [[0.25, 0.25, 1], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[0.25, 0.25, 0.05], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.1, True, 0.9 / 0.95),
    ("thickness-miss", "vf", [[0.25, 0.25, 1], [0, 0, 0], [1, 0, 0], [0, 1, 0]],
     [[0.25, 0.25, 0.2], [0, 0, 0], [1, 0, 0], [0, 1, 0]], 0.1, False, None),
    ("thickness-edges", "ee", EE_X, [[-1, 0, -1], [1, 0, -1], [0, -1, -1], [0, 1, -1]], 0.5, True, 0.75),
    ("far-from-origin", "ee", (np.array(EE_X) + 1e6).tolist(),
     (np.array([[-1, 0, -2], [1, 0, -2], [0, -1, -1], [0, 1, -1]]) + 1e6).tolist(), 0.0, True, 2 / 3),
]
#: toi tolerance of these unit-speed scenes: the terminal box spans at most
#: CCD_TOI_TOL in time and is within ~1e-10 in distance of contact.
TOI_ATOL = 2 * CCD_TOI_TOL


@pytest.mark.parametrize("exact", [True, False], ids=["exact", "kernel"])
@pytest.mark.parametrize("name,kind,x_t0,x_t1,thickness,expected,true_toi", NAMED, ids=[c[0] for c in NAMED])
def test_named(name, kind, x_t0, x_t1, thickness, expected, true_toi, exact):
    hit, toi = run(kind, x_t0, x_t1, thickness, exact)
    assert hit == expected
    if expected:
        assert toi <= true_toi
        assert true_toi - toi <= TOI_ATOL
    else:
        assert toi == np.inf


def test_batch_and_validation():
    x0 = np.array([n[2] for n in NAMED if n[1] == "ee" and n[4] == 0.0], float)
    x1 = np.array([n[3] for n in NAMED if n[1] == "ee" and n[4] == 0.0], float)
    hit, toi = ccd_edge_edge(x0, x1)
    single = [run("ee", a, b)[0] for a, b in zip(x0, x1)]
    assert hit.tolist() == single
    assert ccd_vertex_face(np.zeros((0, 4, 3)), np.zeros((0, 4, 3)))[0].shape == (0,)
    with pytest.raises(InputError, match=r"\(Q, 4, 3\)"):
        ccd_edge_edge(np.zeros((2, 3, 3)), np.zeros((2, 3, 3)))
    with pytest.raises(InputError, match="finite"):
        ccd_edge_edge(np.full((1, 4, 3), np.nan), np.zeros((1, 4, 3)))
    with pytest.raises(InputError, match="thickness"):
        ccd_edge_edge(x0, x1, -1.0)
    with pytest.raises(InputError, match="same shape"):
        ccd_edge_edge(x0, x1[:1])


def test_huge_coordinates_are_never_declared_safe():
    """Beyond 1e150 the float kernel could overflow: it must flag, and the exact path decides."""
    x0 = np.array(EE_X, float)[None] * 1e200
    x1 = x0 + [0, 0, 1e210]  # far apart all the time
    status = ccd_details(x0, x1, "ee", exact=False)[0]
    assert status[0] == BUDGET
    assert not ccd_edge_edge(x0, x1)[0][0]


@pytest.mark.parametrize("kind", ["ee", "vf"])
def test_indexed_matches_gathered(kind):
    rng = np.random.default_rng(21)
    V0 = rng.integers(-2, 3, size=(40, 3)).astype(float)
    V1 = rng.integers(-2, 3, size=(40, 3)).astype(float)
    idx = np.array([rng.choice(40, 4, replace=False) for _ in range(700)])  # > 512: parallel path
    for exact in (False, True):
        a = ccd_indexed(V0, V1, idx, kind, exact=exact)
        b = ccd_details(V0[idx], V1[idx], kind, exact=exact)
        for u, v in zip(a, b):
            np.testing.assert_array_equal(u, v)


# --- oracles at sampled exact times ---------------------------------------------------

SAMPLES = [Fraction(k, 16) for k in range(17)]


def _int_queries(rng, n, lo=-2, hi=2):
    """Small-integer scenes: exact in float, full of touching and degenerate cases."""
    return rng.integers(lo, hi + 1, size=(n, 4, 3)).astype(float), rng.integers(lo, hi + 1, size=(n, 4, 3)).astype(float)


@pytest.mark.parametrize("kind", ["ee", "vf"])
def test_integer_scenes_against_exact_and_sampling(kind):
    """Kernel hit=False => exact False => no sampled contact; exact True => kernel True."""
    rng = np.random.default_rng(7 if kind == "ee" else 8)
    x_t0, x_t1 = _int_queries(rng, 200)
    status, toi, _, _ = ccd_details(x_t0, x_t1, kind, exact=False)
    decide = exact_edge_edge if kind == "ee" else exact_vertex_face
    n_hits = 0
    verdicts = []
    for i in range(len(x_t0)):
        ex = decide(x_t0[i], x_t1[i])
        verdicts.append(ex)
        sampled = [t for t in SAMPLES[::2] if exact_dist_sq(kind, x_t0[i], x_t1[i], t) == 0]
        n_hits += ex
        if sampled:
            assert ex, (i, sampled)
            assert Fraction(float(toi[i])) <= sampled[0]
        if ex:
            assert status[i] != SEPARATED, i
    assert 20 < n_hits < 180  # the scenes exercise contacts and misses
    got = ccd_details(x_t0, x_t1, kind)[0] != SEPARATED
    assert got.tolist() == verdicts


@pytest.mark.parametrize("kind", ["ee", "vf"])
def test_thickness_against_sampled_exact_distance(kind):
    """Random float scenes with thickness: a sampled distance <= thickness must be a hit,
    toi must precede it, and a CLOSE hit must really be close at toi (the stated bound)."""
    rng = np.random.default_rng(11 if kind == "ee" else 12)
    n = 150
    x_t0 = rng.normal(size=(n, 4, 3))
    x_t1 = x_t0 + rng.normal(scale=1.5, size=(n, 4, 3))
    thickness = 0.05
    status, toi, sep, witness = ccd_details(x_t0, x_t1, kind, thickness)
    th2 = Fraction(thickness) ** 2
    close = 0
    for i in range(n):
        d2 = [exact_dist_sq(kind, x_t0[i], x_t1[i], t) for t in SAMPLES[::2]]
        first = next((t for t, d in zip(SAMPLES[::2], d2) if d <= th2), None)
        if first is not None:
            assert status[i] != SEPARATED, i
            assert Fraction(float(toi[i])) <= first
        if status[i] == SEPARATED:
            assert sep[i] >= thickness and all(Fraction(float(sep[i])) ** 2 <= d for d in d2)
        if status[i] == CLOSE:
            close += 1
            assert toi[i] <= witness[i]
            m = max(abs(x_t0[i]).max(), abs(x_t1[i]).max())
            ext = max((np.maximum(x_t0[i], x_t1[i]).max(0) - np.minimum(x_t0[i], x_t1[i]).min(0)).max(), 0)
            err = CCD_ERR_REL * m
            bound = np.sqrt(3) * (thickness + max(CCD_TOL_REL * ext, 4 * err) + 2 * err)
            assert exact_dist_sq(kind, x_t0[i], x_t1[i], Fraction(float(witness[i]))) <= Fraction(bound) ** 2 * (1 + 1e-12)
    assert close > 5


# --- invariance (hypothesis) -----------------------------------------------------------

# signed axis permutations: exact in floating point, so verdicts must not move at all
_PERMS = [(0, 1, 2), (1, 2, 0), (2, 0, 1), (1, 0, 2), (0, 2, 1), (2, 1, 0)]
coords = st.integers(-3, 3)
query = st.lists(st.lists(coords, min_size=3, max_size=3), min_size=4, max_size=4)


@settings(max_examples=40, deadline=None)
@given(
    kind=st.sampled_from(["ee", "vf"]), x0=query, x1=query,
    perm=st.sampled_from(_PERMS), signs=st.tuples(*[st.sampled_from([-1, 1])] * 3),
    shift=st.tuples(*[st.integers(-50, 50)] * 3), scale=st.sampled_from([0.125, 1.0, 1024.0]),
    swap=st.booleans(), flip=st.booleans(),
)
def test_invariance_rigid_and_relabel(kind, x0, x1, perm, signs, shift, scale, swap, flip):
    x0, x1 = np.array(x0, float), np.array(x1, float)
    ref_hit = run(kind, x0, x1)[0]
    assert ref_hit == (exact_edge_edge if kind == "ee" else exact_vertex_face)(x0, x1)

    def rigid(x):  # rotation by a signed permutation + translation, all exact
        return (x[:, list(perm)] * np.array(signs) + np.array(shift)) * scale

    y0, y1 = rigid(x0), rigid(x1)
    if kind == "ee":
        order = [0, 1, 2, 3]
        if swap:
            order = [2, 3, 0, 1]
        if flip:
            order = [order[1], order[0], order[3], order[2]]
    else:
        order = [0, 2, 3, 1] if swap else [0, 1, 2, 3]
        if flip:
            order = [order[0], order[2], order[1], order[3]]
    for exact in (True, False):
        hit, _ = run(kind, y0[order], y1[order], exact=exact)
        if exact:
            assert hit == ref_hit
        else:
            assert hit or not ref_hit  # the float kernel may add near-misses, never drop contacts


def test_exact_decisions_are_capped_conservatively(monkeypatch):
    import penfree.core.contact.ccd as ccd_module

    # crossing edges passing 2^-50 apart: below the kernel's error bound, exactly separated
    x_t0 = np.array([[[-1, 0, 1], [1, 0, 1], [0, -1, -1], [0, 1, -1]]] * 3, float)
    x_t1 = x_t0.copy()
    x_t1[:, :2, 2] = -1 + 2.0**-50
    assert (ccd_details(x_t0, x_t1, "ee", exact=False)[0] != SEPARATED).all()
    assert (ccd_details(x_t0, x_t1, "ee")[0] == SEPARATED).all()
    monkeypatch.setattr(ccd_module, "CCD_MAX_EXACT", 2)
    capped = ccd_details(x_t0, x_t1, "ee")[0] != SEPARATED
    assert capped.tolist() == [False, False, True]  # the third stays flagged: conservative
