"""Real-client replay: hand-built cases with known pass counts, own client against ipctk."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from penfree import constants as K
from penfree.core.trust.bounds import per_vertex_separation, scene_arrays
from penfree.core.trust.client import ClientQuery, inflation_radius, replay_step
from penfree.core.trust.client_stats import client_counts, resolve_dhat, summarize_counts
from penfree.errors import InputError

HAVE_IPCTK = importlib.util.find_spec("ipctk") is not None
CLIENTS = ["own", pytest.param("ipctk", marks=pytest.mark.skipif(
    not HAVE_IPCTK, reason="ipctk (penfree[ogc]) not installed; make test installs it"))]

#: Two parallel unit segments 20 apart (nothing within any radius used below).
X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 20, 0], [1, 20, 0]])
EDGES = [[0, 1], [2, 3]]
V = np.array([5.0, 0, 0])


@pytest.mark.parametrize("client", CLIENTS)
def test_known_counts_isotropic_step(client):
    """x_pred = x_next = x + 5: radius R = 5, radii 0.45 R = 2.25 (nothing near).

    Warm start: 5 > 2.25, every vertex truncated -> pass 2 at x + 2.25; iteration 1:
    2.75 > 2.25 truncated -> pass 3 at x + 4.5; iteration 2: 0.5 arrives, no update.
    """
    r = replay_step(X, X, X + V, X + V, edges=EDGES, dhat=1.0, truncation="isotropic", radius="step",
                    client=client)
    assert (r["passes"], r["iterations"], r["converged"]) == (3, 2, True)


@pytest.mark.parametrize("client", CLIENTS)
def test_known_counts_planar_no_candidates(client):
    """Planar with no candidate pair: only the inflation-radius ball (R = 5) caps, so
    the warm start reaches x_pred in one pass."""
    r = replay_step(X, X, X + V, X + V, edges=EDGES, dhat=1.0, truncation="planar", radius="step",
                    client=client)
    assert (r["passes"], r["iterations"], r["converged"]) == (1, 0, True)


@pytest.mark.parametrize("client", CLIENTS)
def test_radius_rules_from_a_deformed_start(client):
    """From x_def = x + 4: rule step keeps R = 5 (radii 2.25): one pass. Rule own
    recomputes R = max(2 dhat, 1) = 2 (radii 0.9): the warm start truncates every
    vertex (pass 2), then the last 0.1 arrives."""
    x_def = X + np.array([4.0, 0, 0])
    step = replay_step(x_def, X, X + V, X + V, edges=EDGES, dhat=1.0, radius="step", client=client)
    own = replay_step(x_def, X, X + V, X + V, edges=EDGES, dhat=1.0, radius="own", client=client)
    assert (step["passes"], step["iterations"]) == (1, 0)
    assert (own["passes"], own["iterations"], own["converged"]) == (2, 1, True)


def test_inflation_radius_floor():
    assert inflation_radius(X, X + 0.1, 1.0) == 2.0
    assert inflation_radius(X, X + V, 1.0) == 5.0


@pytest.mark.skipif(not HAVE_IPCTK, reason="ipctk (penfree[ogc]) not installed; make test installs it")
@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
def test_own_client_matches_ipctk_on_a_sample(truncation, sample_sequence):
    """penfree's own client counts the same passes and iterations as ipctk."""
    seq = sample_sequence
    P = seq.positions
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    for s in (3, 9):
        x = P[s].astype(float)
        x_pred = 2 * x - P[s - 1]
        kw = dict(edges=seq.edges, faces=seq.faces, dhat=dhat, thickness=seq.thickness, truncation=truncation)
        for start in (x, 0.5 * (x + x_pred)):
            for rule in ("step", "own"):
                a = replay_step(start, x, x_pred, P[s + 1], radius=rule, client="own", **kw)
                b = replay_step(start, x, x_pred, P[s + 1], radius=rule, client="ipctk", **kw)
                assert (a["passes"], a["iterations"]) == (b["passes"], b["iterations"])


@pytest.fixture(scope="module")
def sample_sequence():
    from pathlib import Path

    from penfree import read_sequence

    seq = read_sequence(Path(__file__).resolve().parents[3] / "samples" / "twisted_cables.h5")
    seq.positions = np.asarray(seq.positions[:12], dtype=np.float64)
    return seq


@pytest.mark.parametrize("client", CLIENTS)
def test_client_counts_identity_replays_each_rule(sample_sequence, client):
    """x_def = x: each column is the replay of its rule from x. Rule step is the baseline
    itself; rule own is ipctk's warm start, whose move is isotropic within the radii, so
    it equals the baseline under isotropic truncation only (under planar the baseline's
    warm-start move is the planar filter). The own column was the baseline's copy under
    both truncations (898 passes where ipctk's own rule needs 883, audit 12-05); each
    rule is now compared with its own baseline, so doing nothing is a 0% change."""
    seq = sample_sequence
    frames = np.arange(1, 6)
    counts = client_counts(seq.positions, seq.positions[frames], frames, edges=seq.edges, dhat=seq.thickness,
                           thickness=seq.thickness, client=client, every=2)
    np.testing.assert_array_equal(counts["frame"], [1, 3, 5])
    for tr in ("isotropic", "planar"):
        np.testing.assert_array_equal(counts[f"passes_{tr}_step_deformed"], counts[f"passes_{tr}_baseline"])
        own = [replay_step(seq.positions[s], seq.positions[s], 2 * seq.positions[s] - seq.positions[s - 1],
                           seq.positions[s + 1], edges=seq.edges, dhat=seq.thickness, thickness=seq.thickness,
                           truncation=tr, radius="own", client=client)["passes"] for s in (1, 3, 5)]
        np.testing.assert_array_equal(counts[f"passes_{tr}_own_deformed"], own)
        np.testing.assert_array_equal(counts[f"passes_{tr}_own_baseline"], own)  # rule own's own baseline
        if tr == "isotropic":
            np.testing.assert_array_equal(own, counts[f"passes_{tr}_baseline"])
    sm = summarize_counts(counts)
    assert sm["n_steps"] == 3
    for tr in ("isotropic", "planar"):  # doing nothing changes nothing, under either rule
        assert sm[tr]["step_change"] == 0.0 and sm[tr]["own_change"] == 0.0, sm[tr]


@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
def test_a_shared_query_counts_as_fresh_replays(truncation, sample_sequence):
    """One `ClientQuery` for every replay of a scene (its reach and cells carried over,
    the start states memoised) gives the counts of replays that each query afresh."""
    seq = sample_sequence
    P = seq.positions
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    q = ClientQuery(P[0], seq.edges, seq.faces)
    kw = dict(edges=seq.edges, faces=seq.faces, dhat=dhat, thickness=seq.thickness, truncation=truncation,
              client="own")
    n = 0
    for s in (3, 9):
        x = P[s]
        x_pred = 2 * x - P[s - 1]
        for start in (x, 0.5 * (x + x_pred), x):  # the repeated start is answered from the memo
            for rule in ("step", "own"):
                for y in (P[s + 1], x_pred):
                    a = replay_step(start, x, x_pred, y, radius=rule, query=q, **kw)
                    b = replay_step(start, x, x_pred, y, radius=rule, **kw)
                    assert a == b
                    n += 1
    assert q.info["memo_hits"] >= n // 2  # every second replay repeats its start, at least
    assert q.info["queries"] > 0


def test_client_query_memo_matches_bits():
    """The memo answers a start state only bit for bit at the same radius, keeps the
    last `CLIENT_QUERY_MEMO` start states, and its values are a fresh query's."""
    rng = np.random.default_rng(5)
    x = rng.random((40, 3))
    E = np.array([[i, i + 1] for i in range(0, 40, 2)])
    q = ClientQuery(x, E, None)
    _, E_, F_ = scene_arrays(x, E, None)
    d = q.separations(x, 0.3, start=True)
    np.testing.assert_array_equal(d, per_vertex_separation(x, E_, F_, 0.3))
    assert q.separations(x.copy(), 0.3) is d and q.info == {"queries": 1, "memo_hits": 1, "lists": 0, "listed": 0}
    y = x.copy()
    y[7, 1] = np.nextafter(y[7, 1], 2.0)  # one ulp away: another state
    np.testing.assert_array_equal(q.separations(y, 0.3), per_vertex_separation(y, E_, F_, 0.3))
    np.testing.assert_array_equal(q.separations(x, 0.5), per_vertex_separation(x, E_, F_, 0.5))
    assert q.info == {"queries": 3, "memo_hits": 1, "lists": 0, "listed": 0}
    q.separations(y, 0.3)  # not a start state: not kept
    assert q.info["queries"] == 4
    for k in range(K.CLIENT_QUERY_MEMO):
        q.separations(x + (k + 1), 0.3, start=True)
    q.separations(x, 0.3)  # pushed out by the newer start states
    assert q.info["queries"] == 5 + K.CLIENT_QUERY_MEMO


def test_replay_refuses_a_query_of_another_scene():
    q = ClientQuery(X, EDGES, None)
    with pytest.raises(InputError, match="another scene"):
        replay_step(X, X, X, X, edges=[[0, 1], [2, 3]], dhat=1.0, client="own", query=q)
    with pytest.raises(InputError, match="another scene"):
        replay_step(X[:2], X[:2], X[:2], X[:2], edges=EDGES, dhat=1.0, client="own", query=q)
    r = replay_step(X, X, X + V, X + V, edges=EDGES, dhat=1.0, client="own", query=q)
    assert (r["passes"], r["iterations"]) == (3, 2)


def test_bad_arguments():
    with pytest.raises(InputError, match="dhat"):
        replay_step(X, X, X, X, edges=EDGES, dhat=0.0, client="own")
    with pytest.raises(InputError, match="truncation"):
        replay_step(X, X, X, X, edges=EDGES, dhat=1.0, truncation="cubic", client="own")
    with pytest.raises(InputError, match="radius rule"):
        replay_step(X, X, X, X, edges=EDGES, dhat=1.0, radius="mine", client="own")
    with pytest.raises(InputError, match="dhat"):
        resolve_dhat(None, 0.0, 0.0)


@pytest.mark.skipif(not HAVE_IPCTK, reason="ipctk (penfree[ogc]) not installed; make test installs it")
def test_ipctk_client_warm_start_is_ipctks(sample_sequence):
    """Where no radius is negative the replay's ipctk warm start is the native
    ``warm_start_time_step``: its positions, passes and trust-region centres, bit for
    bit (the step-by-step path, for clamped radii, rounds differently in the last bit,
    and the planar filter's counts can follow such bits)."""
    import ipctk

    from penfree.core.trust.client import make_client

    seq = sample_sequence
    P = seq.positions
    dhat = resolve_dhat(None, seq.contact_radius, seq.thickness)
    _, E, F = scene_arrays(P[0], seq.edges, seq.faces)
    n_second = 0
    for s in (2, 5, 9):
        x, x_pred = P[s], 2 * P[s] - P[s - 1]
        cl = make_client("ipctk", x, E, F, dhat, seq.thickness, "isotropic")
        got, passes = cl.warm_start(x, x_pred)
        tr = ipctk.ogc.TrustRegion(dhat)
        xs = np.array(x, dtype=np.float64, order="F")
        tr.warm_start_time_step(cl.mesh, xs, np.asfortranarray(x_pred), ipctk.NormalCollisions(), dhat,
                                seq.thickness)
        assert (np.asarray(tr.trust_region_radii) >= 0).all()
        np.testing.assert_array_equal(got, xs)
        np.testing.assert_array_equal(np.asarray(cl.tr.trust_region_centers), np.asarray(tr.trust_region_centers))
        assert passes == 1 + int(not np.array_equal(np.asarray(tr.trust_region_centers), x))
        n_second += passes == 2
    assert n_second > 0  # the conditional second pass is exercised


@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
@pytest.mark.parametrize("client", CLIENTS)
def test_a_crossing_start_replays_with_finite_positions(client, truncation):
    """Two segments crossing at the start (radius 0 at their four vertices) among eight
    free ones: the warm move lets the crossing vertices go (ipctk: 0 / 0, no truncation)
    down by 0.01; the iteration's move along x is then perpendicular to their offset
    from the centres, and ipctk's discriminant is negative (no truncation again). The
    own client clamped it to 0 and divided by 0: -inf, positions of NaN, and a broad
    phase that crashed the process on them. Both clients now count the same."""
    x = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, -0.5, 0], [0.5, 0.5, 0]]
                 + [[3.0 * k, 5, 0] for k in range(8) for _ in range(2)])
    x[4::2, 0] += 1.0
    edges = np.arange(x.shape[0]).reshape(-1, 2)
    x_pred = x + [0, 0, -0.01]
    x_next = x_pred + [0.01, 0, 0]
    r = replay_step(x, x, x_pred, x_next, edges=edges, dhat=0.05, truncation=truncation, radius="step",
                    client=client)
    assert r["converged"] and r["passes"] == 1, r


def test_non_finite_positions_are_refused_by_the_broad_phase():
    """A NaN or infinite coordinate reaches a grid's cell index as garbage (a crash):
    every grid is sized from its boxes' corners, which now refuse them."""
    from penfree.core.contact.proximity import per_vertex_separation

    E = np.array([[0, 1], [2, 3]])
    for bad in (np.nan, np.inf, -np.inf):
        x = X.copy()
        x[3, 1] = bad
        with pytest.raises(InputError, match="NaN or infinite"):
            per_vertex_separation(x, E, np.zeros((0, 3), np.int64), 1.0)
