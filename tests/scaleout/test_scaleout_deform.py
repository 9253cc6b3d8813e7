"""`penfree.scaleout.deform_many` removes only what its run created: a failure during the
computation (not detectable up front) names the file and frame range and leaves no
output, partial result, temporary or directory; another run's temporaries stay."""

import os

import h5py
import numpy as np
import pytest
from _scenes import grid_faces, sheet

from penfree.errors import InputError
from penfree.scaleout import deform as sdeform

OPTIONS = {"model": "auto", "projection": "auto", "margin": None, "thickness": None, "per_vertex": False,
           "frames": None}


def cloth(path, T=10):
    """A 4 x 4 cloth drifting up and bending; 10 frames split into ranges on one worker."""
    u, v = sheet(4)
    with h5py.File(path, "w") as f:
        f["positions"] = np.array([np.stack([u, v, 0.01 * t + 0.01 * t * u], axis=1) for t in range(T)])
        f["faces"] = grid_faces(4)
    return str(path)


def test_failure_during_compute_leaves_nothing(tmp_path):
    pytest.importorskip("distributed")
    a = cloth(tmp_path / "a.h5")
    assert [t.lo for t in sdeform.plan([a], 1)] == [1, 5]  # two frame ranges and a merge
    out = tmp_path / "new" / "a_def.h5"
    with pytest.raises(InputError, match=r"a\.h5 frames \d+:\d+: .*no-such-model") as exc:
        sdeform.deform_many([a], str(out), options=dict(OPTIONS, model="no-such-model"), workers=1)
    assert "\n" not in str(exc.value)
    assert sorted(os.listdir(tmp_path)) == ["a.h5"]  # no output, parts, temporary or directory


def test_failed_run_keeps_another_runs_temporaries(tmp_path, monkeypatch):
    a = cloth(tmp_path / "a.h5", 6)
    out = tmp_path / "out"
    out.mkdir()
    (out / ".pfkeepme01.tmp").write_text("someone else's, there before the run")
    seen = {}

    def stopped(**kw):
        # Meanwhile a concurrent run starts writing its own result here.
        (out / ".pfconcur01.tmp").write_text("another run's half-written result")
        seen["stage"] = kw["stage"]
        with open(os.path.join(kw["stage"], "a.h5"), "w") as fh:
            fh.write("this run's half-written result")
        raise KeyboardInterrupt

    monkeypatch.setattr(sdeform, "_run", stopped)
    with pytest.raises(KeyboardInterrupt):
        sdeform.deform_many([a, a.replace("a.h5", "*.h5")], str(out), options=OPTIONS, workers=1)
    assert os.path.dirname(seen["stage"]) == str(out) and os.path.basename(seen["stage"]).startswith(".pf")
    assert sorted(p.name for p in out.iterdir()) == [".pfconcur01.tmp", ".pfkeepme01.tmp"]
