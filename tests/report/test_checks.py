"""CI checks: certificate summary, thresholds, regression against a baseline report, and the
re-check that every stored deformed state is the image of its certified map."""

import dataclasses

import numpy as np
import pytest
from _samples import SAMPLES

import penfree.report.checks as checks_mod
from penfree.report.checks import applied_maps, certificate_summary, recheck_certificates, run_checks
from penfree.sequence import Sequence


def test_certificate_summary():
    steps = {"frame": np.array([1, 2, 3]), "certificate_margin": np.array([0.3, np.nan, 0.05]),
             "margin_required": np.array([0.1, 0.1, 0.1]), "model": np.array(["affine"] * 3),
             "projection": np.array(["none", "sym", "sym"])}
    c = certificate_summary(steps)
    assert (c["all_certified"], c["n_uncertified"], c["uncertified_frames"]) == (False, 2, [2, 3])
    assert c["min_margin"] == 0.05 and c["projections"] == {"none": 1, "sym": 2}


def _rep(name="a.h5", speedup=1.2, gain=0.1, k=2.0, hit=0.8, n_uncert=0):
    return {"name": name, "summary": {"hit_rate_gain_next": gain,
                                      "deformed": {"k_1pct_next": k, "hit_rate_next": hit},
                                      "projected": {"k_1pct": {"speedup": speedup}}},
            "certificate": {"all_certified": n_uncert == 0, "n_uncertified": n_uncert,
                            "uncertified_frames": list(range(n_uncert))}}


@pytest.mark.parametrize(
    "kw, rep_kw, passed",
    [
        pytest.param({"min_speedup": 1.1}, {}, [True], id="speedup-pass"),
        pytest.param({"min_speedup": 1.3}, {}, [False], id="speedup-fail"),
        pytest.param({"min_speedup": 1.0}, {"speedup": float("nan")}, [False], id="speedup-missing"),
        pytest.param({"min_hit_rate_gain": 10.0}, {}, [True], id="gain-10-points-pass"),
        pytest.param({"min_hit_rate_gain": 10.5}, {}, [False], id="gain-fail"),
        pytest.param({"fail_if_uncertified": True}, {"n_uncert": 2}, [False], id="uncertified"),
        pytest.param({"fail_if_uncertified": True}, {}, [True], id="certified"),
    ],
)
def test_threshold_checks(kw, rep_kw, passed):
    checks = run_checks([_rep(**rep_kw)], **kw)
    assert [c["passed"] for c in checks] == passed


def test_regression_checks():
    base = {"files": [_rep(name="a.h5")]}
    same = run_checks([_rep()], baseline=base, max_regression=0.0)
    assert len(same) == 3 and all(c["passed"] for c in same)
    # K_1pct 2 -> 2.1 is a 5 % regression; speedup 1.2 -> 1.17 is 2.5 %
    worse = run_checks([_rep(k=2.1, speedup=1.17)], baseline=base, max_regression=3.0)
    by = {c["name"]: c["passed"] for c in worse}
    assert by == {"regression:deformed.k_1pct_next": False, "regression:projected.k_1pct.speedup": True,
                  "regression:deformed.hit_rate_next": True}
    better = run_checks([_rep(k=1.0, speedup=2.0, hit=0.99)], baseline=base, max_regression=0.0)
    assert all(c["passed"] for c in better)
    # a single file on each side is matched whatever its name; two are matched by name
    assert all(c["passed"] for c in run_checks([_rep(name="b.h5")], baseline=base, max_regression=0.0))
    two = run_checks([_rep(name="b.h5"), _rep(name="a.h5")], baseline=base, max_regression=0.0)
    assert [c["passed"] for c in two if c["file"] == "b.h5"] == [False]


# ---------------------------------------------------------------- the stored deformed state is the map's image

#: Offset of the far-from-origin variants (SPEC: coordinates well away from the origin are common).
FAR = 1.0e4
#: Frames of a sample deformed by these tests (steps 1..5): small and quick.
SAMPLE_FRAMES = 6


def _deformed_sample(tmp_path, name, model, variant):
    """A real deform output of the first frames of `samples/<name>.h5`, written and read back."""
    from penfree.core.pipeline.deform import deform_sequence, result_attrs
    from penfree.formats import read_sequence
    from penfree.formats.result import write_result
    from penfree.report.build import open_result

    seq0 = read_sequence(str(SAMPLES / f"{name}.h5"))
    pos = np.asarray(seq0.positions[:SAMPLE_FRAMES])
    if variant == "f64-far":
        pos = pos.astype(np.float64) + FAR
    elif variant == "f32-far":
        pos = (pos.astype(np.float64) + FAR).astype(np.float32)
    seq = dataclasses.replace(seq0, positions=pos).validate()
    out = deform_sequence(seq, model=model)
    path = tmp_path / f"{name}-{model}-{variant}.h5"
    write_result(path, seq, out.steps, result_attrs(str(path), out.options), groups=out.groups)
    return open_result(path)


GENUINE = [(name, model) for name, models in (
    ("rods", ("translation", "rigid", "similarity", "affine", "auto")),
    ("cloth", ("affine", "auto")),
    ("carried_stack", ("per-component", "auto")),
) for model in models]


@pytest.mark.parametrize("variant", ["f32", "f64-far", "f32-far"])
@pytest.mark.parametrize("name, model", GENUINE, ids=[f"{n}-{m}" for n, m in GENUINE])
def test_genuine_deform_outputs_are_certified_images(tmp_path, name, model, variant):
    res = _deformed_sample(tmp_path, name, model, variant)
    assert res.steps["deformed"].dtype == res.sequence.dtype
    assert applied_maps(res.steps, res.groups, res.sequence).all()
    assert recheck_certificates(res.steps, res.groups, res.sequence).all()
    if model == "per-component" and variant != "f32-far":  # the per-component path is exercised
        assert np.isnan(res.steps["A"]).all(axis=(1, 2)).any()


@pytest.mark.parametrize("dtype, offset", [(np.float32, 0.0), (np.float32, FAR), (np.float64, FAR)],
                         ids=["f32", "f32-far", "f64-far"])
def test_shortened_steps_are_images_of_their_maps(rng, dtype, offset):
    # deform's shortened steps scale an already rounded x_def (strategy.shortened)
    from penfree.constants import SHORTEN_LEVELS
    from penfree.core.fit.step import fit_step
    from penfree.core.pipeline.strategy import StepInput, from_step_result, shortened

    x_prev = (rng.normal(size=(300, 3)) + offset).astype(dtype)
    R = np.array([[0.998, -0.05, 0.0], [0.05, 0.998, 0.0], [0.0, 0.0, 1.01]])
    c = x_prev.astype(np.float64).mean(axis=0)
    x = ((x_prev.astype(np.float64) - c) @ R.T + c + 0.01).astype(dtype)
    r = fit_step(x_prev, x, model="affine")
    x64 = x.astype(np.float64)
    step = StepInput(1, x_prev, x, x64, 2 * x64 - x_prev, 0.0, 0.0, None)
    seq = Sequence(positions=np.stack([x_prev, x]), edges=np.array([[0, 1]])).validate()
    outs = [from_step_result(r)] + [shortened(from_step_result(r), step, a) for a in SHORTEN_LEVELS]
    steps = {"frame": np.ones(len(outs), dtype=np.int64), "A": np.stack([o.A for o in outs]),
             "b": np.stack([o.b for o in outs]), "deformed": np.stack([o.x_def for o in outs])}
    assert applied_maps(steps, None, seq).all()


@pytest.mark.parametrize("dtype, offset", [(np.float32, 0.0), (np.float64, FAR), (np.float32, 1e-30)],
                         ids=["f32", "f64-far", "f32-tiny"])
def test_apply_map_output_passes_and_more_than_rounding_fails(rng, dtype, offset):
    # x_def exactly as deform forms it (apply_map: x + D (x - c) + u, float64, cast), random
    # maps; one coordinate moved by 16 float32 ulps / 1024 float64 ulps (1e-13 relative:
    # the float64 bound is about 100 ulps far from the origin) is caught
    from penfree.core.fit.models import apply_map

    for _ in range(20):
        x = ((rng.normal(size=(200, 3)) + rng.normal(size=3) * 10) * (1e-30 if offset == 1e-30 else 1.0)
             + (0.0 if offset == 1e-30 else offset)).astype(dtype)
        D = 0.1 * rng.normal(size=(3, 3))
        u = 0.05 * rng.normal(size=3) * np.abs(x).max()
        c = x.astype(np.float64).mean(axis=0)
        x_def, _ = apply_map(x, D, u, c)
        A = np.eye(3) + D
        steps = {"frame": np.array([1]), "A": A[None], "b": (u - D @ c)[None], "deformed": x_def[None]}
        seq = Sequence(positions=np.stack([x, x])).validate()
        assert applied_maps(steps, None, seq).all()
        bad = x_def.copy()
        bad[7, 1] += (16 if dtype == np.float32 else 1024) * np.spacing(np.abs(bad[7, 1]))
        assert not applied_maps({**steps, "deformed": bad[None]}, None, seq).any()


def _step_with_spacing(res):
    """(k, spacing): a step that moves, and the smallest edge length of its start state."""
    seq = res.sequence
    k = int(np.flatnonzero(np.asarray(res.steps["model"]) != "none")[0])
    x = np.asarray(seq.positions[res.steps["frame"][k]], dtype=np.float64)
    E = seq.edges if seq.edges is not None else np.concatenate([seq.faces[:, [0, 1]], seq.faces[:, [1, 2]]])
    return k, float(np.linalg.norm(x[E[:, 0]] - x[E[:, 1]], axis=1).min())


@pytest.mark.parametrize("variant", ["f32", "f64-far"])
@pytest.mark.parametrize("name, model", [("rods", "affine"), ("cloth", "auto"), ("carried_stack", "per-component")],
                         ids=["rods-affine", "cloth-auto", "stack-per-component"])
def test_deformed_moved_below_the_spacing_is_not_certified(tmp_path, name, model, variant):
    res = _deformed_sample(tmp_path, name, model, variant)
    k, spacing = _step_with_spacing(res)
    d = res.steps["deformed"].copy()
    v = int(np.argmax(np.abs(d[k, :, 0])))
    eps = 1e-2 * spacing  # far below a vertex spacing ...
    assert eps > 64 * np.spacing(np.abs(d[k, v, 0]))  # ... far above the rounding
    d[k, v, 0] += eps
    ok = applied_maps({**res.steps, "deformed": d}, res.groups, res.sequence)
    assert not ok[k] and ok.sum() == ok.size - 1
    assert not recheck_certificates({**res.steps, "deformed": d}, res.groups, res.sequence)[k]


@pytest.mark.parametrize("variant", ["f32", "f64-far"])
def test_map_altered_by_two_percent_is_not_certified(tmp_path, variant):
    res = _deformed_sample(tmp_path, "rods", "affine", variant)
    k, _ = _step_with_spacing(res)
    A = res.steps["A"].copy()
    A[k] = A[k] @ np.diag([1.02, 0.98, 1.01])  # still a certified map, no longer the applied one
    from penfree.core.fit.certificate import certify_map

    assert certify_map(A[k], float(res.steps["margin_required"][k]))
    rc = recheck_certificates({**res.steps, "A": A}, res.groups, res.sequence)
    assert not rc[k] and rc.sum() == rc.size - 1


def test_mirrored_deformed_state_with_the_map_kept_is_not_certified(tmp_path):
    # the audit's reproducer: a penetrating deformed state under a certified map
    res = _deformed_sample(tmp_path, "rods", "affine", "f32")
    k, _ = _step_with_spacing(res)
    x = np.asarray(res.sequence.positions[res.steps["frame"][k]], dtype=np.float64)
    c = x.mean(axis=0)
    d = res.steps["deformed"].copy()
    d[k] = (c + (x - c) * [1.0, 1.0, -1.0]).astype(d.dtype)
    assert not recheck_certificates({**res.steps, "deformed": d}, res.groups, res.sequence)[k]


def _per_component_step(res):
    k = int(np.flatnonzero(np.isnan(res.steps["A"]).all(axis=(1, 2)))[0])
    comp = res.groups["component_maps"]
    labels = np.asarray(comp["labels"])
    return k, comp, labels


@pytest.mark.parametrize("forge", ["map-2pct", "b-shifted", "labels-swapped", "labels-missing", "maps-missing",
                                   "identity-maps"])
def test_forged_component_maps_are_not_certified(tmp_path, forge):
    res = _deformed_sample(tmp_path, "carried_stack", "per-component", "f32")
    k, comp, labels = _per_component_step(res)
    comp = {key: np.array(v, copy=True) for key, v in comp.items()}
    moved = [c for c in np.unique(labels) if not np.allclose(comp["A"][k, c], np.eye(3))
             or np.abs(comp["b"][k, c]).max() > 0]
    c = int(moved[0])
    if forge == "map-2pct":
        comp["A"][k, c] = comp["A"][k, c] @ np.diag([1.02, 0.98, 1.01])
    elif forge == "b-shifted":
        comp["b"][k, c] += 1e-4
    elif forge == "labels-swapped":  # every vertex judged by another component's map
        comp["labels"] = (labels + 1) % (labels.max() + 1)
    elif forge == "labels-missing":  # deform's own labels are used: still the image
        del comp["labels"]
    elif forge == "maps-missing":
        del comp["A"]
    else:  # certified identity maps claimed for a moved state (the audit's forgery)
        comp["A"][k] = np.eye(3)
        comp["b"][k] = 0.0
    groups = {**res.groups, "component_maps": comp}
    rc = recheck_certificates(res.steps, groups, res.sequence)
    assert rc[k] == (forge == "labels-missing")


def test_applied_check_runs_in_blocks(tmp_path, monkeypatch):
    # memory stays bounded for large scenes: the blockwise check gives the same verdicts
    res = _deformed_sample(tmp_path, "carried_stack", "per-component", "f32")
    d = res.steps["deformed"].copy()
    d[-1, 500, 2] += 1e-4
    steps = {**res.steps, "deformed": d}
    whole = applied_maps(steps, res.groups, res.sequence)
    monkeypatch.setattr(checks_mod, "APPLIED_BLOCK_ROWS", 7)
    assert np.array_equal(applied_maps(steps, res.groups, res.sequence), whole)
    assert whole[:-1].all() and not whole[-1]


# ---------------------------------------------------------------- forgeries the bound itself allowed (audit, 12-05)


def _flat_sheet_on_the_ground(tmp_path, thickness=0.0):
    """A flat 10 x 10 sheet (every z = 1e-3) turning and drifting above a ground half-space;
    its affine deform result, read back."""
    from _scenes import grid_faces, sheet

    from penfree.core.pipeline.deform import deform_sequence, result_attrs
    from penfree.formats.result import write_result
    from penfree.report.build import open_result
    from penfree.sequence import Obstacle

    u, v = sheet(10)
    frames = []
    for t in range(6):
        a = 0.02 * t + 0.002 * t * t
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        xy = (np.stack([u, v], axis=1) - 0.5) @ R.T + 0.5 + [0.004 * t, 0.001 * t]
        frames.append(np.column_stack([xy, np.full(u.size, 1e-3)]))
    ground = Obstacle("ground", normal=np.array([0.0, 0.0, 1.0]), offset=0.0)
    seq = Sequence(positions=np.array(frames), faces=grid_faces(10), obstacles=[ground],
                   thickness=thickness).validate()
    out = deform_sequence(seq, model="affine")
    path = tmp_path / "flat.h5"
    write_result(path, seq, out.steps, result_attrs(str(path), out.options), groups=out.groups)
    return open_result(path)


@pytest.mark.parametrize("dz, through", [(-2e-3, True), (3e-3, False)], ids=["through-the-ground", "up"])
def test_a_map_inflated_along_a_flat_scenes_normal_cannot_hide_an_edit(tmp_path, dz, through):
    """``A_zz += 1e15``, ``b_z -= 1e15 z`` is the same map on a flat sheet, and its terms
    made the rounding bound 1.4e-2: a vertex moved 2 mm through the ground passed. Such a
    step now also needs verify's path check: the penetration fails it, a harmless edit
    (2 mm up) passes it, and the genuine step with the inflated map still passes."""
    res = _flat_sheet_on_the_ground(tmp_path)
    k = 2
    z0 = float(res.sequence.positions[res.steps["frame"][k]][0, 2])
    A, b = res.steps["A"].copy(), res.steps["b"].copy()
    A[k, 2, 2] += 1e15
    b[k, 2] -= 1e15 * z0
    inflated = {**res.steps, "A": A, "b": b}
    assert applied_maps(inflated, res.groups, res.sequence).all()  # the same map on the data
    d = res.steps["deformed"].copy()
    d[k, 55, 2] += dz
    forged = {**inflated, "deformed": d}
    assert checks_mod._is_image(res.sequence.positions[res.steps["frame"][k]], d[k], A[k][None], b[k][None]) == (
        True, True)  # within the inflated bound: loose
    assert applied_maps(forged, res.groups, res.sequence)[k] == (not through)
    assert recheck_certificates(forged, res.groups, res.sequence)[k] == (not through)


def test_component_labels_must_be_the_scenes_components(tmp_path):
    """One "component" per vertex with a translation each makes any state an image: a
    sheet jittered by 1e-2 passed. The stored labels must be deform's own components."""
    res = _flat_sheet_on_the_ground(tmp_path)
    k, N, S = 2, res.sequence.n_vertices, res.n_steps
    x = np.asarray(res.sequence.positions[res.steps["frame"][k]], dtype=np.float64)
    d = res.steps["deformed"].copy()
    d[k] += 1e-2 * np.random.default_rng(1).standard_normal(d[k].shape)
    A, b = res.steps["A"].copy(), res.steps["b"].copy()
    A[k], b[k] = np.nan, np.nan
    cA, cb = np.full((S, N, 3, 3), np.nan), np.full((S, N, 3), np.nan)
    cA[k], cb[k] = np.eye(3), d[k] - x
    groups = {**res.groups, "component_maps": {"A": cA, "b": cb, "labels": np.arange(N)}}
    forged = {**res.steps, "A": A, "b": b, "deformed": d}
    assert not applied_maps(forged, groups, res.sequence)[k]
    # deform's own labels (one component) with that component's true map: still the image
    cA1, cb1 = np.full((S, 1, 3, 3), np.nan), np.full((S, 1, 3), np.nan)
    cA1[k], cb1[k] = res.steps["A"][k], res.steps["b"][k]
    honest = {**res.groups, "component_maps": {"A": cA1, "b": cb1, "labels": np.zeros(N, np.int64)}}
    assert applied_maps({**res.steps, "A": A, "b": b}, honest, res.sequence)[k]


def test_a_stored_margin_below_the_thickness_rule_is_not_trusted(tmp_path):
    """``margin_required`` forged to 0 on a thickness result let a map squeezing the sheet to
    2% pass (its certificate holds at margin 0, not at the thickness's 0.1)."""
    res = _flat_sheet_on_the_ground(tmp_path, thickness=1e-4)
    k = 2
    x = np.asarray(res.sequence.positions[res.steps["frame"][k]], dtype=np.float64)
    A, b, d = res.steps["A"].copy(), res.steps["b"].copy(), res.steps["deformed"].copy()
    A[k] = np.diag([0.02, 1.0, 1.0])
    b[k] = x.mean(axis=0) - A[k] @ x.mean(axis=0)
    d[k] = x @ A[k].T + b[k]
    forged = {**res.steps, "A": A, "b": b, "deformed": d, "margin_required": np.zeros(res.n_steps)}
    assert recheck_certificates(res.steps, res.groups, res.sequence).all()
    assert applied_maps(forged, res.groups, res.sequence)[k]
    assert not recheck_certificates(forged, res.groups, res.sequence)[k]
