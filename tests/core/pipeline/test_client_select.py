"""`auto` by the client's predicted CD passes, and `penfree.predeform`."""

from __future__ import annotations

import numpy as np
import pytest

import penfree
from penfree import Obstacle
from penfree.core.trust.client import replay_step
from penfree import constants as K
from penfree.core.pipeline.client_select import (
    ClientModel, _better, _replay_order, choose_by_client, corotated_target, held_target,
)
from penfree.errors import InputError

#: Two parallel unit segments 20 apart, moving by V per step (nothing near: the
#: radius cap 0.45 R alone limits every vertex).
X = np.array([[0.0, 0, 0], [1, 0, 0], [0, 20, 0], [1, 20, 0]])
EDGES = np.array([[0, 1], [2, 3]])
V = np.array([5.0, 0, 0])


def _select(x_prev, x, truncation="isotropic", dhat=1.0):
    """`auto` with a client model on one step (`predeform` runs deform's step)."""
    r = penfree.predeform(x_prev, x, edges=EDGES, contact_radius=dhat, truncation=truncation)
    return r, r.table


@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
def test_static_scene_does_nothing(truncation):
    res, table = _select(X, X, truncation)
    assert res.model == "none"
    np.testing.assert_array_equal(res.x_def, X)
    assert table[0]["name"] == "none" and table[0]["chosen"]


def test_fast_coherent_translation_is_taken():
    """Baseline: 3 passes to x_pred (test_client's hand count); translating to x_pred: 1."""
    res, table = _select(X - V, X)
    assert res.model != "none"
    np.testing.assert_allclose(res.x_def, X + V, atol=1e-12)
    assert penfree.certify(res.A)
    rows = {r["name"]: r for r in table}
    assert rows["none"]["client_passes"] == 3
    assert min(r["client_passes"] for r in table if r.get("client_passes") is not None) == 1
    # the prediction is the real count of the own client toward x_pred
    assert replay_step(res.x_def, X, X + V, X + V, edges=EDGES, dhat=1.0, client="own")["passes"] == 1


def test_planar_tie_goes_to_doing_nothing():
    """Planar with nothing near: one pass either way (radius ball 5 >= |V|), so none."""
    res, table = _select(X - V, X, "planar")
    assert res.model == "none"
    assert {r["client_passes"] for r in table if r.get("client_passes") is not None} == {1}


def test_held_target():
    x = np.zeros((3, 3))
    x_pred = np.ones((3, 3))
    y = held_target(x, x_pred, np.array([0.1, 0.5, 0.1]), dhat=0.1, r_q=0.1)
    # vertex 0: 0.1 <= 1.5 dhat but at the cap r_q (nothing within the query): free
    np.testing.assert_array_equal(y, x_pred)
    y = held_target(x, x_pred, np.array([0.05, 0.5, 0.09]), dhat=0.1, r_q=1.0)
    np.testing.assert_array_equal(y, [[0, 0, 0], [1, 1, 1], [0, 0, 0]])


def test_held_target_only_at_rest():
    """With the last step given, a contact vertex is held only if that step moved it at
    most CONTACT_REST_STEP contact radii (0.45 dhat): one that moved with what it
    touches is not held."""
    x = np.zeros((3, 3))
    x_pred = np.ones((3, 3))
    d = np.array([0.05, 0.05, 0.5])  # vertices 0 and 1 in contact (dhat 0.1), 2 free
    x_prev = np.array([[0.0, 0, 0.04], [0.0, 0, 0.05], [0.0, 0, 0.3]])  # moved 0.04 and 0.05
    y = held_target(x, x_pred, d, dhat=0.1, r_q=1.0, x_prev=x_prev)
    assert K.CONTACT_REST_STEP * 0.1 == pytest.approx(0.045)
    np.testing.assert_array_equal(y, [[0, 0, 0], [1, 1, 1], [1, 1, 1]])
    # without the last step every contact vertex is held (the rule before the rest gate)
    np.testing.assert_array_equal(held_target(x, x_pred, d, dhat=0.1, r_q=1.0), [[0, 0, 0], [0, 0, 0], [1, 1, 1]])


@pytest.mark.parametrize("p, q, deadlock, expected", [
    ((3, 9), (4, 1), False, True),      # fewer toward y_hat wins, whatever the half-way count
    ((4, 2), (4, 3), False, True),      # as many, fewer half-way
    ((4, 3), (4, 3), False, False),     # a tie goes to the earlier candidate
    ((5, 1), (4, 9), False, False),
    ((40, 1), (33, 2), False, True),    # beyond the cap (32) every count is a deadlock, alike
    ((33, 2), (40, 2), False, False),
    ((20, 3), (34, 4), True, True),     # doing nothing deadlocks: the half-way point alone
    ((1, 4), (34, 4), True, False),
    ((None, 3), (None, 4), True, True),
], ids=["fewer", "tie-half", "tie", "more", "both-capped", "capped-tie", "deadlock-half", "deadlock-tie",
        "deadlock-none"])
def test_better(p, q, deadlock, expected):
    assert _better(p, q, deadlock, K.DEFAULT_CLIENT_MAX_ITER) is expected


@pytest.mark.parametrize("s", [3, 9, 20])
def test_cut_replays_choose_as_full_replays(s):
    """The replays cut short where a count can no longer win choose the candidate that
    full replays of every candidate, compared by `_better`, choose (swinging coil)."""
    from penfree.core.fit.auto import ranked_candidates
    from penfree.core.fit import models as fit_models
    from penfree.core.pipeline.strategy import start_separations, step_target
    from penfree.core.trust.bounds import scene_arrays
    from tests._samples import SAMPLES

    seq = penfree.read_sequence(SAMPLES / "swinging_coil.h5")
    _, E, F = scene_arrays(seq.positions[0], seq.edges, seq.faces)
    x_prev, x = seq.positions[s - 1], seq.positions[s]
    x64, x_pred, r_q = step_target(x_prev, x, seq.contact_radius, seq.thickness)
    d = start_separations(x64, E, F, r_q)
    model = ClientModel(truncation="isotropic", dhat=seq.contact_radius, edges=seq.edges)
    _, xp, m, cands = ranked_candidates(x_prev, x, d, r_q=r_q, thickness=seq.thickness, margin=0.1, repeat=True)
    chosen = choose_by_client(cands, xp, x, m.c, d, model, seq.thickness, r_q)

    rot = next(c for c in cands if c.name == "rigid-repeat")
    y_hat = held_target(x64, corotated_target(xp, x64, rot.A, rot.u, m.c), d, model.dhat, r_q, x_prev=xp)
    cap = K.DEFAULT_CLIENT_MAX_ITER

    def full(cand):
        x_def = np.asarray(fit_models.apply_map(x, cand.D, cand.u, m.c)[0], dtype=np.float64)
        return tuple(replay_step(x_def, x64, x_pred, y, edges=seq.edges, dhat=model.dhat, thickness=seq.thickness,
                                 client="own", max_iter=cap)["passes"] for y in (y_hat, 0.5 * (x64 + y_hat)))

    best, best_p = 0, full(cands[0])
    deadlock = best_p[0] > cap
    seen = set()
    for i in _replay_order(cands, model.shortlist):
        key = (cands[i].A.tobytes(), cands[i].u.tobytes())
        if key in seen:
            continue
        seen.add(key)
        p = full(cands[i])
        if _better(p, best_p, deadlock, cap):
            best, best_p = i, p
    assert chosen == best
    assert cands[chosen].predicted["client_passes"] == best_p[0]
    assert model.query(x64).info["memo_hits"] > 0  # each start replayed toward both targets


def test_shared_client_queries_change_no_output(monkeypatch):
    """`deform --client-model` with the model's one `ClientQuery` writes what replays
    that each query afresh write, bit for bit (swinging coil, 5 steps)."""
    from penfree.core.pipeline.deform import deform_sequence
    from tests._samples import SAMPLES

    seq = penfree.read_sequence(SAMPLES / "swinging_coil.h5")

    def run():
        model = ClientModel(truncation="isotropic", dhat=seq.contact_radius, edges=seq.edges)
        return deform_sequence(seq, model="auto", frames=(0, 6), client_model=model).steps, model

    shared, model = run()
    assert model._query is not None and model._query.info["memo_hits"] > 0
    monkeypatch.setattr(ClientModel, "query", lambda self, x: None)
    fresh, model = run()
    assert model._query is None
    for key in ("deformed", "A", "b", "model", "certificate_margin"):
        np.testing.assert_array_equal(np.asarray(shared[key]), np.asarray(fresh[key]), err_msg=key)


def test_client_model_validation():
    with pytest.raises(InputError, match="truncation"):
        ClientModel(truncation="cubic", dhat=1.0)
    with pytest.raises(InputError, match="dhat"):
        ClientModel(truncation="planar", dhat=0.0)


class TestPredeform:
    @pytest.mark.parametrize("dtypes", [(np.int64, np.int64), (np.float64, np.int32), (np.float64, np.float32)],
                             ids=["integers", "int-x", "float32-x"])
    def test_any_real_dtype_is_computed_in_float64(self, dtypes):
        """x_prev was cast to x's dtype: an integer x truncated x_prev's motion (0.9 -> 1.0, x_def moved 0.083)."""
        X0 = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [0, 0, 4]])
        step = np.array([0.0, 0.0, 1.0 if dtypes[0] == np.int64 else 0.9])
        x_prev, x = (X0 - step).astype(dtypes[0]), X0.astype(dtypes[1])
        r = penfree.predeform(x_prev, x, faces=[[0, 1, 2]], contact_radius=0.1)
        ref = penfree.predeform(x_prev.astype(np.float64), x.astype(np.float64), faces=[[0, 1, 2]],
                                contact_radius=0.1)
        assert r.x_def.dtype == np.float64 and np.array_equal(r.x_def, ref.x_def) and r.model == ref.model
        assert r.query_radius == pytest.approx(step[2], abs=1e-12)  # max(2 dhat, max |x_pred - x|)
        both32 = penfree.predeform(x_prev.astype(np.float32), x.astype(np.float32), faces=[[0, 1, 2]],
                                   contact_radius=0.1)
        assert both32.x_def.dtype == np.float32

    def test_positions_must_be_real_and_alike(self):
        with pytest.raises(InputError, match="x must be real numbers"):
            penfree.predeform(X - V, X.astype(complex), edges=EDGES, contact_radius=1.0)
        with pytest.raises(InputError, match="same .N, 3. shape"):
            penfree.predeform((X - V)[:-1], X, edges=EDGES, contact_radius=1.0)

    def test_moves_and_returns_the_radius_to_keep(self):
        r = penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0)
        np.testing.assert_allclose(r.x_def, X + V, atol=1e-12)
        assert r.query_radius == 5.0  # max(2 dhat, max |x_pred - x|), at x
        assert penfree.certify(r.A)
        np.testing.assert_allclose(X @ r.A.T + r.b, r.x_def, atol=1e-12)

    @pytest.mark.parametrize("rule", ["own", "step"])
    def test_radius_rule_is_predicted_and_its_radius_returned(self, rule, monkeypatch):
        """Every replay runs under the rule asked for, and the radius returned is the one
        to keep at x (rule step: max |x_pred - x| = 5) or the one ipctk's warm start
        computes from x_def (rule own: 2 dhat, x_def being x_pred)."""
        from penfree.core.pipeline import client_select

        rules = []

        def spy(*args, **kw):
            rules.append(kw["radius"])
            return replay_step(*args, **kw)

        monkeypatch.setattr(client_select, "replay_step", spy)
        r = penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0, radius_rule=rule)
        np.testing.assert_allclose(r.x_def, X + V, atol=1e-12)
        assert r.query_radius == {"own": 2.0, "step": 5.0}[rule]
        assert rules and set(rules) == {rule}

    def test_radius_rule_is_validated(self):
        with pytest.raises(InputError, match="radius rule must be one of"):
            penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0, radius_rule="mine")

    @pytest.mark.parametrize("bounds", [np.array(["a", "b", "c", "d"]), np.ones(4) * (1 + 1j), np.ones(4, bool),
                                        np.full(4, np.nan), -np.ones(4), np.ones(3)],
                             ids=["str", "complex", "bool", "nan", "negative", "short"])
    def test_bad_bounds_are_input_errors(self, bounds):
        """(Strings raised ValueError; complex bounds passed with a warning.)"""
        with pytest.raises(InputError, match=r"bounds must be \(4,\) real, finite and >= 0"):
            penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0, bounds=bounds)

    def test_needs_a_contact_offset(self):
        """The library call names its own arguments (it said "give --dhat", a CLI flag)."""
        with pytest.raises(InputError, match="contact_radius > 0") as e:
            penfree.predeform(X - V, X, edges=EDGES)
        assert "--dhat" not in str(e.value)

    def test_static_does_nothing(self):
        r = penfree.predeform(X, X, edges=EDGES, contact_radius=1.0)
        assert r.model == "none" and r.query_radius == 2.0
        np.testing.assert_array_equal(r.x_def, X)

    @pytest.mark.parametrize("wall_x, moved", [(3.0, False), (100.0, True)], ids=["wall-ahead", "wall-far"])
    def test_mesh_obstacle(self, wall_x, moved):
        """A triangle wall in the plane x = wall_x across both segments' way (+5 in x from x <= 1):
        the applied path never reaches it (checked by verify's CCD), the full move only when far."""
        P = np.array([[wall_x, -10.0, -10.0], [wall_x, 60.0, -10.0], [wall_x, -10.0, 40.0]])
        F = np.array([[0, 1, 2]])
        r = penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0,
                              obstacles=[Obstacle("wall", positions=P, faces=F)])
        assert penfree.verify_step(X, r.x_def, edges=EDGES, obstacles=[(P, P, F, None)]).ok
        assert np.allclose(r.x_def, X + V, atol=1e-12) == moved

    @pytest.mark.parametrize("offset, moved", [(-3.0, False), (-100.0, True)], ids=["wall-ahead", "wall-far"])
    def test_half_space(self, offset, moved):
        """Normal -e_x: the free side is x < -offset; the segments move +5 in x from x <= 1."""
        ob = Obstacle("wall", normal=np.array([-1.0, 0, 0]), offset=offset)
        r = penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0, obstacles=[ob])
        assert np.allclose(r.x_def, X + V, atol=1e-12) == moved
        assert np.all(r.x_def @ ob.normal > ob.offset)

    def test_bounds_replace_the_query(self):
        """The simulator's own bounds (nothing near: the cap) give the same choice."""
        r_q = 1.0 + 5.0
        b = np.full(len(X), 0.45 * r_q)
        r = penfree.predeform(X - V, X, edges=EDGES, contact_radius=1.0, bounds=b)
        np.testing.assert_allclose(r.x_def, X + V, atol=1e-12)

    def test_needs_topology_and_offset(self):
        with pytest.raises(InputError, match="edges or faces"):
            penfree.predeform(X, X)
        with pytest.raises(InputError, match="contact_radius"):
            penfree.predeform(X, X, edges=EDGES)


def test_predictor_validation():
    with pytest.raises(InputError, match="predictor"):
        ClientModel(truncation="planar", dhat=1.0, predictor="magic")


@pytest.mark.parametrize("truncation", ["isotropic", "planar"])
def test_ipctk_predictor_agrees_on_the_hand_count(truncation):
    """``predictor="ipctk"`` replays through ipctk itself: on the translating pair the
    same choice and counts as the own client (3 passes for doing nothing isotropic)."""
    pytest.importorskip("ipctk", reason="the ipctk predictor needs ipctk (penfree[ogc]); make test installs it")
    from penfree.core.pipeline.deform import deform_sequence

    seq = penfree.Sequence(positions=np.stack([X - V, X]), edges=EDGES, contact_radius=1.0).validate()
    models = {}
    for predictor in ("own", "ipctk"):
        cm = ClientModel(truncation=truncation, dhat=1.0, edges=EDGES, predictor=predictor)
        out = deform_sequence(seq, model="auto", client_model=cm)
        models[predictor] = (str(out.steps["model"][0]), out.steps["deformed"][0].tolist())
    assert models["own"] == models["ipctk"]


def test_repeat_switch():
    """``repeat=False``: no rigid-repeat candidate in a spinning step's table."""
    t = np.linspace(0.0, 2 * np.pi, 9)[:-1]
    ring = np.column_stack([np.cos(t), np.sin(t), np.zeros(8)])
    edges = np.column_stack([np.arange(8), (np.arange(8) + 1) % 8])
    c, s_ = np.cos(0.2), np.sin(0.2)
    Rz = np.array([[c, -s_, 0], [s_, c, 0], [0, 0, 1]])
    seq = penfree.Sequence(positions=np.stack([ring, ring @ Rz.T]), edges=edges, contact_radius=0.01).validate()
    from penfree.core.pipeline.deform import deform_sequence

    names = {}
    for repeat in (True, False):
        cm = ClientModel(truncation="isotropic", dhat=0.01, edges=edges, repeat=repeat)
        out = deform_sequence(seq, model="auto", client_model=cm)
        names[repeat] = set(out.groups["selection"]["candidates"].tolist())
    assert "rigid-repeat" in names[True] and "rigid-repeat" not in names[False]
