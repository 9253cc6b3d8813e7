"""Scale-out on Dask: inputs expand as documented, frame ranges cover every step once,
and outputs of the several-inputs path equal a serial run dataset by dataset (the
oracle), for deform (with the selection table and stats), verify and report."""

import builtins
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from penfree import scaleout
from penfree.cli import main
from penfree.errors import InputError
from penfree.formats.partials import merge_partials
from penfree.scaleout import Task, expand_inputs, plan

SAMPLES = Path(__file__).resolve().parents[1] / "samples"
#: Wall times differ between any two runs; everything else must be equal.
NONDETERMINISTIC = {"steps/time_fit_s"}


def _datasets(path):
    out = {}
    with h5py.File(path, "r") as f:
        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                out[name] = obj[()]
        f.visititems(visit)
        attrs = {k: str(v) for k, v in f.attrs.items()}
    return out, attrs


def assert_same_result(a, b):
    da, aa = _datasets(a)
    db, ab = _datasets(b)
    assert set(da) == set(db)
    for k in sorted(set(da) - NONDETERMINISTIC):
        x, y = da[k], db[k]
        if getattr(x, "dtype", None) is not None and x.dtype.kind == "f":
            np.testing.assert_array_equal(x, y, err_msg=k)
        else:
            assert np.array_equal(x, y), k
    assert aa == ab


@pytest.fixture
def inputs(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    for name in ("rods.h5", "twisting_cloth.h5"):
        shutil.copy(SAMPLES / name, d / name)
    return d


def test_expand_inputs(inputs, tmp_path):
    files = sorted(str(p) for p in inputs.glob("*.h5"))
    assert expand_inputs([str(inputs)]) == files
    assert expand_inputs([str(inputs / "*.h5"), files[0]]) == files  # duplicates dropped
    (tmp_path / "frames").mkdir()
    assert expand_inputs([str(tmp_path / "frames")]) == [str(tmp_path / "frames")]  # a mesh-sequence directory
    with pytest.raises(InputError, match="no file matches"):
        expand_inputs([str(tmp_path / "nothing*.h5")])
    with pytest.raises(InputError, match="no such file"):
        expand_inputs([str(tmp_path / "missing.h5")])


@pytest.mark.parametrize("kind, frames", [("sequence", None), ("sequence", (5, 30)), ("path", None),
                                          ("sequence", (-20, None)), ("path", (5, 30)), ("path", (-20, None))])
def test_plan_covers_every_step_once(kind, frames):
    """Ranges cover the selected steps once; a raw sequence verified with a frame slice is
    cut in ranges too (its steps whose two frames are selected): it was one task, which
    read a long recording whole."""
    path = str(SAMPLES / "rods.h5")
    T = 48
    tasks = plan([path], 3, frames, kind)
    assert len(tasks) > 1
    steps = np.arange(1, T) if kind == "sequence" else np.arange(0, T - 1)
    if frames is not None:
        sel = np.arange(T)[slice(*frames)]
        steps = steps[np.isin(steps, sel) & (np.isin(steps + 1, sel) if kind == "path" else True)]
    covered = np.concatenate([np.arange(t.lo, t.hi) for t in tasks])
    np.testing.assert_array_equal(covered, steps)


def test_merge_selection_orders_columns_by_first_appearance(tmp_path):
    parts = []
    for k, (names, chosen) in enumerate([(["a", "b"], [1, 0]), (["c", "a"], [0, -1])]):
        p = tmp_path / f"part-{k}.npz"
        pred = np.arange(4.0).reshape(2, 2) + 10 * k
        np.savez(p, **{"steps/frame": np.array([2 * k + 1, 2 * k + 2]),
                       "groups/selection/candidates": np.array(names),
                       "groups/selection/chosen": np.array(chosen),
                       "groups/selection/predicted_k_any": pred})
        parts.append(p)
    steps, groups = merge_partials(parts)
    sel = groups["selection"]
    assert sel["candidates"].tolist() == ["a", "b", "c"]
    assert sel["chosen"].tolist() == [1, 0, 2, -1]
    np.testing.assert_array_equal(sel["predicted_k_any"],
                                  [[0, 1, np.nan], [2, 3, np.nan], [11, np.nan, 10], [13, np.nan, 12]])
    assert steps["frame"].tolist() == [1, 2, 3, 4]


def test_merge_streams_the_per_vertex_rows_one_range_at_a_time(tmp_path):
    """A streaming merge (`merge_task`'s) holds no ``--per-vertex`` dataset whole: each is a
    `PartialRows` of the ranges' rows in frame order (shape and dtype from the first
    range's header), equal to the plain merge's array NaN for NaN, and written as that
    array is (contiguous, the same values); the driver's summary rows carry none of them
    (`_light`)."""
    from penfree.formats.partials import PartialFrames, PartialRows
    from penfree.formats.result import _write_array
    from penfree.scaleout.deform import _light

    rng = np.random.default_rng(3)
    N, parts, counts = 5, [], (3, 1, 2)
    for k, S in enumerate(counts):
        p = tmp_path / f"part-{k}.npz"
        nxt = rng.random((S, N)).astype(np.float32)
        if k == len(counts) - 1:
            nxt[-1] = np.nan  # the last step has no next frame
        np.savez(p, **{"steps/frame": np.arange(S) + 1 + sum(counts[:k]),
                       "steps/deformed": rng.random((S, N, 3)),
                       "steps/residual_pred_per_vertex": rng.random((S, N)).astype(np.float32),
                       "steps/residual_next_per_vertex": nxt,
                       "steps/residual_pred_rms": rng.random(S)})
        parts.append(p)
    plain, _ = merge_partials(parts)
    steps, _ = merge_partials(parts, stream=True)
    assert isinstance(steps["deformed"], PartialFrames)
    np.testing.assert_array_equal(steps["residual_pred_rms"], plain["residual_pred_rms"])
    for key in ("residual_pred_per_vertex", "residual_next_per_vertex"):
        rows = steps[key]
        assert isinstance(rows, PartialRows) and rows.shape == (6, N) and rows.dtype == np.float32
        blocks = list(rows.blocks())
        assert [len(b) for b in blocks] == list(counts)
        np.testing.assert_array_equal(np.concatenate(blocks), plain[key])
        with h5py.File(tmp_path / f"{key}.h5", "w") as f:
            _write_array(f, key, rows)
            _write_array(f, "plain", plain[key])
            assert f[key].chunks is None and f[key].compression is None and f[key].dtype == np.float32
            np.testing.assert_array_equal(f[key][()], f["plain"][()])
    assert set(_light(steps)) == {"frame", "residual_pred_rms"}


@pytest.mark.parametrize("extra", [["--model", "auto", "--stats"], ["--model", "affine", "--frames", "3:40"]])
def test_deform_many_equals_serial(inputs, tmp_path, scheduler, extra):
    runner = CliRunner()
    out = tmp_path / "out"
    r = runner.invoke(main, ["deform", str(inputs), "-o", str(out), "--scheduler", scheduler, *extra])
    assert r.exit_code == 0, r.output
    for src in sorted(inputs.glob("*.h5")):
        serial = tmp_path / f"serial-{src.stem}.h5"
        r = runner.invoke(main, ["deform", str(src), "-o", str(serial), *extra])
        assert r.exit_code == 0, r.output
        assert_same_result(out / f"{src.stem}.h5", serial)
    assert sorted(p.name for p in out.iterdir()) == ["rods.h5", "twisting_cloth.h5"]  # no parts left behind


def test_whole_file_tasks_write_their_results(inputs, tmp_path, scheduler):
    # Four files on two workers: one task per file, each writing its own result (no
    # partials, no merge); the outputs still equal serial runs.
    for name in ("rods.h5", "twisting_cloth.h5"):
        shutil.copy(inputs / name, inputs / f"b_{name}")
    paths = sorted(str(p) for p in inputs.glob("*.h5"))
    assert [t.lo for t in plan(paths, 2)] == [None] * 4
    runner = CliRunner()
    out = tmp_path / "out"
    args = ["--model", "affine", "--frames", ":10"]
    r = runner.invoke(main, ["deform", str(inputs), "-o", str(out), "--scheduler", scheduler, "--json", *args])
    assert r.exit_code == 0, r.output
    for src in sorted(inputs.glob("*.h5")):
        serial = tmp_path / f"serial-{src.stem}.h5"
        assert runner.invoke(main, ["deform", str(src), "-o", str(serial), *args]).exit_code == 0
        assert_same_result(out / f"{src.stem}.h5", serial)
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in inputs.glob("*.h5"))


def test_deform_local_workers_and_no_silent_overwrite(inputs, tmp_path):
    pytest.importorskip("distributed")
    runner = CliRunner()
    out = tmp_path / "out" / "rods_def.h5"  # one input: -o names its result file, as in a serial run
    args = ["deform", str(inputs / "rods.h5"), "-o", str(out), "--workers", "2", "--model", "affine",
            "--frames", ":12"]
    r = runner.invoke(main, args)
    assert r.exit_code == 0, r.output
    before = out.stat().st_mtime_ns
    r = runner.invoke(main, args)
    assert r.exit_code == 2 and "exists" in r.output
    assert out.stat().st_mtime_ns == before
    assert sorted(p.name for p in out.parent.iterdir()) == ["rods_def.h5"]


@pytest.mark.parametrize("bad", ["exists", "frames", "baseline", "input"])
def test_report_ended_by_a_check_starts_no_worker_server(inputs, tmp_path, monkeypatch, bad):
    """`report --workers` checks its arguments before it starts the process the workers
    are forked from, so a command they end (exit 2) starts none. An unreadable input is
    found later, while the server prepares itself: the control that the stub is called."""
    from penfree.scaleout import cluster

    started = []
    monkeypatch.setattr(cluster, "start_worker_server", lambda: started.append(1) or True)
    out = tmp_path / "rep"
    extra = {"frames": ["--frames", "5:2:0"], "baseline": ["--max-regression", "0.1"]}.get(bad, [])
    if bad == "exists":
        out.mkdir()
        (out / "report.json").write_text("{}")
    if bad == "input":
        (inputs / "broken.h5").write_text("not HDF5")
    r = CliRunner().invoke(main, ["report", str(inputs), "-o", str(out), "--workers", "2", *extra])
    assert r.exit_code == 2, r.output
    assert started == ([1] if bad == "input" else []), r.output


def test_verify_and_report_many_equal_serial(inputs, tmp_path, scheduler):
    runner = CliRunner()
    out = tmp_path / "out"
    assert runner.invoke(main, ["deform", str(inputs), "-o", str(out), "--scheduler", scheduler,
                                "--frames", ":20"]).exit_code == 0
    files = sorted(str(p) for p in out.glob("*.h5")) + [str(inputs / "rods.h5")]
    r = runner.invoke(main, ["verify", *files, "--scheduler", scheduler, "--json", "--frames", ":20"])
    assert r.exit_code == 0, r.output
    import json

    many = json.loads(r.output)["files"]
    for f, rep in zip(files, many):
        r1 = runner.invoke(main, ["verify", f, "--json", "--frames", ":20"])
        assert json.loads(r1.output) == rep
    rd = tmp_path / "rep-many"
    r = runner.invoke(main, ["report", str(out / "*.h5"), "-o", str(rd), "--scheduler", scheduler, "--no-plots",
                             "--no-ladder", "--json"])
    assert r.exit_code == 0, r.output
    r1 = runner.invoke(main, ["report", *files[:2], "-o", str(tmp_path / "rep-serial"), "--no-plots",
                              "--no-ladder", "--json"])
    a, b = json.loads(r.output), json.loads(r1.output)
    assert a["files"] == b["files"]


def test_failed_task_names_file_and_frames(tmp_path, scheduler):
    distributed = pytest.importorskip("distributed")
    path = str(SAMPLES / "rods.h5")
    bad = {"model": "no-such-model", "projection": "auto", "margin": None, "thickness": None, "per_vertex": False,
           "frames": None}
    with distributed.Client(scheduler) as c:
        with pytest.raises(InputError, match=r"rods\.h5 frames 5:9"):
            scaleout.run_tasks(c, scaleout.deform_task, [Task(path, 5, 9)], (str(tmp_path), bad, False, 1))


_FAULTS_PER_BLOCK = """
import resource, numpy as np
import numba  # loaded by a worker before its first task; it changes how numpy's blocks come back
from penfree.scaleout.cluster import task_setup
def faults():  # minor page faults per 8 MiB block allocated, filled and freed
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(8):
        a = np.ones(1 << 20)
        del a
    return (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / 8
before = faults()
task_setup(None)
faults()
print(before, faults())
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc settings")
def test_worker_tasks_keep_freed_blocks_under_the_nannys_malloc_settings():
    # Dask's nanny starts each worker with its `pre-spawn-environ`, which tells glibc to
    # trim freed memory at once (MALLOC_TRIM_THRESHOLD_): every scratch block of every step
    # then came back as fresh pages, faulted in one at a time (a 64K x 50 recording's
    # task 1.2-1.3x slower than in the CLI's process). A task's set-up undoes it.
    dask = pytest.importorskip("dask")
    import distributed  # noqa: F401  (its defaults are dask's config)

    environ = {k: str(v) for k, v in dask.config.get("distributed.nanny.pre-spawn-environ", {}).items()}
    if "MALLOC_TRIM_THRESHOLD_" not in environ:
        pytest.skip("this Dask does not set glibc's trim threshold on its workers")
    out = subprocess.run([sys.executable, "-c", _FAULTS_PER_BLOCK], env={**os.environ, **environ},
                         capture_output=True, text=True, check=True).stdout.split()
    before, after = float(out[0]), float(out[1])
    assert before >= 128, f"precondition: the nanny's setting makes each block fault ({before} faults)"
    assert after <= 8, f"{after} faults per block after a task's set-up"


def test_without_dask_one_line_and_exit_2(inputs, tmp_path, monkeypatch):
    _no_dask(monkeypatch)
    r = CliRunner().invoke(main, ["deform", str(inputs), "-o", str(tmp_path / "out")])
    assert r.exit_code == 2
    assert "pip install 'penfree[dask]'" in r.output and len(r.output.strip().splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_single_input_output_directory_is_refused(inputs, tmp_path):
    out = tmp_path / "outdir"
    out.mkdir()
    r = CliRunner().invoke(main, ["deform", str(inputs / "rods.h5"), "-o", str(out), "--overwrite"])
    assert r.exit_code == 2 and "is a directory" in r.output
    assert not any(out.iterdir())


def test_range_task_reads_only_its_frames_and_equals_the_full_read(tmp_path, monkeypatch):
    # A frame range's task (run here in-process) reads frames lo-1 .. hi only, and its
    # partial result equals the same steps of a full read, frame numbers included.
    import penfree.formats as formats
    from penfree.core.pipeline.deform import deform_sequence

    path = str(SAMPLES / "rods.h5")
    seen = []
    real = formats.read_sequence

    def spy(*args, **kw):
        seen.append(kw.get("frame_window"))
        return real(*args, **kw)

    monkeypatch.setattr(formats, "read_sequence", spy)
    opts = {"model": "auto", "projection": "auto", "margin": None, "thickness": None, "per_vertex": True,
            "frames": None}
    part = scaleout.deform_task(Task(path, 5, 9), str(tmp_path), opts, True, 1)
    assert seen == [(4, 10)]
    steps, groups = merge_partials([part])
    ref = deform_sequence(real(path), model="auto", frames=(5, 9), per_vertex=True, check_start=True)
    assert steps["frame"].tolist() == [5, 6, 7, 8] and groups["stats"]["frame"].tolist() == [5, 6, 7, 8]
    for k, v in ref.steps.items():
        if k != "time_fit_s":
            assert np.array_equal(steps[k], v, equal_nan=v.dtype.kind == "f"), k


def test_stopped_local_run_leaves_no_temporary(inputs, tmp_path, monkeypatch):
    """A worker stopped mid-write (local cluster closed by a failure or Ctrl-C) leaves no .pf*.tmp."""
    from penfree.scaleout import deform as sdeform

    out = tmp_path / "out"
    out.mkdir()
    (out / ".pfkeepme01.tmp").write_text("someone else's, there before the run")

    def stopped(**kw):  # workers write inside the run's own folder
        (Path(kw["stage"]) / ".pfstopped01.tmp").write_text("half a result")
        (Path(kw["stage"]) / "rods.parts").mkdir()
        raise KeyboardInterrupt

    monkeypatch.setattr(sdeform, "_run", lambda **kw: stopped(**kw))
    with pytest.raises(KeyboardInterrupt):
        sdeform.deform_many([str(inputs)], str(out), options={"frames": None}, workers=1)
    assert sorted(p.name for p in out.iterdir()) == [".pfkeepme01.tmp"]


def _cloth_over_a_rising_plate(path, T=12, nan_frame=None):
    """A 4 x 4 cloth drifting up over a plate (a mesh obstacle stored per frame) rising below it."""
    from _scenes import grid_faces, sheet

    from penfree.formats import write_sequence
    from penfree.sequence import Obstacle, Sequence

    u, v = sheet(4)
    x = np.array([np.stack([u, v, 0.5 + 0.01 * t + 0.01 * t * u], axis=1) for t in range(T)])
    P = np.array([[-1, -1, 0], [2, -1, 0], [2, 2, 0], [-1, 2, 0.0]])
    plate = Obstacle("plate", positions=np.stack([P + [0, 0, 0.005 * t] for t in range(T)]),
                     faces=np.array([[0, 1, 2], [0, 2, 3]]))
    write_sequence(str(path), Sequence(positions=x, faces=grid_faces(4), obstacles=[plate], thickness=0.01))
    if nan_frame is not None:  # a damaged frame (penfree writes only valid sequences)
        with h5py.File(path, "r+") as f:
            f["positions"][nan_frame, 2, 1] = np.nan
    return str(path)


def test_merge_reads_the_input_one_frame_at_a_time(tmp_path, monkeypatch):
    """The merge of a split file streams its frames into the result (`formats.frames`):
    the input's positions and per-frame obstacle positions are read two frames at a time
    for the header, then frame by frame, never whole (it read the whole recording); the
    result equals a serial deform's arrays."""
    import penfree.formats.hdf5 as hdf5
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.formats import read_sequence
    from penfree.formats.frames import StoredFrames
    from penfree.formats.result import read_result

    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    opts = {"model": "affine", "projection": "auto", "margin": None, "thickness": None, "per_vertex": False,
            "frames": None}
    tasks = plan([path], 1)
    assert len(tasks) == 2 and all(t.lo is not None for t in tasks)
    parts = [scaleout.deform_task(t, str(tmp_path), opts, False, 1) for t in tasks]
    windows, reads = [], []
    real_positions, real_read = hdf5.read_positions, StoredFrames._read
    monkeypatch.setattr(hdf5, "read_positions",
                        lambda ds, where, name="positions", window=None:
                        windows.append((name, window)) or real_positions(ds, where, name, window))
    monkeypatch.setattr(StoredFrames, "_read", lambda self, t: reads.append((self.name, t)) or real_read(self, t))
    scaleout.merge_task(path, str(tmp_path / "out.h5"), parts, opts)
    assert windows == [("positions", (0, 2)), ("obstacles/plate/positions", (0, 2))]
    # the header's two frames, then every frame once
    assert sorted(reads) == sorted((name, t) for name in ("positions", "obstacles/plate/positions")
                                   for t in (0, 1, *range(12)))
    monkeypatch.undo()
    res, seq = read_result(str(tmp_path / "out.h5")), read_sequence(path)
    ref = deform_sequence(seq, model="affine", per_vertex=False)
    np.testing.assert_array_equal(res.sequence.positions, seq.positions)
    np.testing.assert_array_equal(res.sequence.obstacles[0].positions, seq.obstacles[0].positions)
    for k in ("frame", "A", "b", "deformed", "certificate_margin"):
        np.testing.assert_array_equal(res.steps[k], ref.steps[k], err_msg=k)


def test_split_file_with_a_moving_obstacle_equals_serial(tmp_path, scheduler):
    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    runner = CliRunner()
    for name, extra in [("split.h5", ["--scheduler", scheduler]), ("serial.h5", [])]:
        r = runner.invoke(main, ["deform", path, "-o", str(tmp_path / name), "--model", "auto", *extra])
        assert r.exit_code == 0, r.output
    assert_same_result(tmp_path / "split.h5", tmp_path / "serial.h5")


def test_split_file_with_nan_beyond_the_selected_frames_fails_like_serial(tmp_path, scheduler):
    """No range task reads frame 11 (the selection ends at 9); the merge does and names it."""
    path = _cloth_over_a_rising_plate(tmp_path / "in.h5", nan_frame=11)
    runner = CliRunner()
    for name, extra in [("split.h5", ["--scheduler", scheduler]), ("serial.h5", [])]:
        r = runner.invoke(main, ["deform", path, "-o", str(tmp_path / name), "--frames", "0:10", *extra])
        assert r.exit_code == 2, r.output
        assert "frame 11 holds NaN or Inf" in r.output and "in.h5:/positions" in r.output, r.output
        assert not (tmp_path / name).exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.h5"]


def test_large_files_go_in_ranges_of_bounded_size(tmp_path, scheduler, monkeypatch):
    """A file whose frames exceed `MAX_TASK_BYTES` is deformed in ranges however many files
    share the workers (a whole-file task reads every frame), a small selection of it in one
    range; the results equal serial runs."""
    import sys

    plan_module = sys.modules["penfree.scaleout.plan"]  # the package exports the function `plan`
    paths = [_cloth_over_a_rising_plate(tmp_path / f"in{k}.h5") for k in range(4)]
    assert [t.lo for t in plan(paths, 1)] == [None] * 4
    monkeypatch.setattr(plan_module, "MAX_TASK_BYTES", 2000)  # a frame: 16 x 3 float64 = 384 bytes
    tasks = plan(paths, 1)
    assert [(t.lo, t.hi) for t in tasks if t.path == paths[0]] == [(1, 6), (6, 12)]
    assert [(t.lo, t.hi) for t in plan(paths[:1], 1, frames=(9, 11))] == [(9, 11)]
    runner = CliRunner()
    for extra in ([], ["--frames", "9:11"]):
        out = tmp_path / f"out{len(extra)}"
        r = runner.invoke(main, ["deform", *paths[:2], "-o", str(out), "--scheduler", scheduler, *extra])
        assert r.exit_code == 0, r.output
        for p in paths[:2]:
            serial = tmp_path / f"serial{len(extra)}-{Path(p).name}"
            assert runner.invoke(main, ["deform", p, "-o", str(serial), *extra]).exit_code == 0
            assert_same_result(out / Path(p).name, serial)


@pytest.mark.parametrize("chunks", [None, (1, 16, 3), (5, 16, 3), (12, 8, 3)], ids=str)
def test_stored_frames_read_any_layout_frame_by_frame(tmp_path, chunks):
    """A foreign input's layout (contiguous, chunked over several frames or vertex blocks)
    streams the same frames; a non-finite one is named."""
    from penfree.formats.frames import StoredFrames

    x = np.random.default_rng(0).normal(size=(12, 16, 3)).astype(np.float32)
    x[9, 3, 1] = np.nan
    with h5py.File(tmp_path / "f.h5", "w") as f:
        f.create_dataset("positions", data=x, chunks=chunks)
    with h5py.File(tmp_path / "f.h5", "r") as f:
        frames = StoredFrames(f["positions"], "f.h5")
        for t in (*range(9), 10, 11, 0):
            np.testing.assert_array_equal(frames.frame(t), x[t])
        with pytest.raises(InputError, match=r"frame 9 holds NaN or Inf in f.h5:/positions"):
            frames.frame(9)


def _no_dask(monkeypatch):
    real_import = builtins.__import__

    def no_dask(name, *args, **kw):
        if name == "distributed" or name.startswith("dask"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kw)

    monkeypatch.setattr(builtins, "__import__", no_dask)


def _spy_windows(monkeypatch):
    """Every frame window the HDF5 positions reader is asked for (None: the whole file)."""
    import penfree.formats.hdf5 as hdf5

    windows, real = [], hdf5.read_positions
    monkeypatch.setattr(hdf5, "read_positions", lambda ds, where, name="positions", window=None:
                        windows.append((name, window)) or real(ds, where, name, window))
    return windows


@pytest.mark.parametrize("extra", [[], ["--frames", "3:11", "--stats"], ["--per-vertex"]],
                         ids=["all", "frames-stats", "per-vertex"])
def test_serial_deform_of_a_long_file_goes_in_ranges_without_dask(tmp_path, monkeypatch, extra):
    """A serial ``deform`` of a file whose frames exceed `MAX_TASK_BYTES` runs its frame
    ranges one after another in this process (`cluster.InProcess`, no Dask), each reading
    only its frames (it read the whole recording, however long); the result equals a run
    that reads the file whole, the summary likewise."""
    import json
    import sys

    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    runner = CliRunner()
    whole = runner.invoke(main, ["deform", path, "-o", str(tmp_path / "whole.h5"), "--json", *extra])
    assert whole.exit_code == 0, whole.output
    monkeypatch.setattr(sys.modules["penfree.scaleout.plan"], "MAX_TASK_BYTES", 2000)  # 12 frames x 384 bytes
    _no_dask(monkeypatch)
    windows = _spy_windows(monkeypatch)
    r = runner.invoke(main, ["deform", path, "-o", str(tmp_path / "ranges.h5"), "--json", *extra])
    assert r.exit_code == 0, r.output
    assert windows and all(w is not None and min(w[1], 12) - w[0] <= 7 for _, w in windows), windows
    assert_same_result(tmp_path / "ranges.h5", tmp_path / "whole.h5")
    a, b = json.loads(r.output), json.loads(whole.output)
    for k in ("wall_time_s", "frames_per_s", "mean_time_fit_ms", "output"):
        a.pop(k), b.pop(k)
    assert a == b
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.h5", "ranges.h5", "whole.h5"]


@pytest.mark.parametrize("what", ["result", "sequence", "violating result"])
def test_serial_verify_of_a_long_file_goes_in_ranges_without_dask(tmp_path, monkeypatch, what):
    """A serial ``verify`` of a long result or raw sequence reads it a frame range at a time
    (`result.read_result` / `read_sequence` with a window) and prints the report of a
    whole read, frame numbers and exit code included (a violation in the second range)."""
    import json
    import sys

    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    runner = CliRunner()
    target = path
    if what != "sequence":
        target = str(tmp_path / "out.h5")
        assert runner.invoke(main, ["deform", path, "-o", target]).exit_code == 0
        if what == "violating result":  # step of frame 9: a vertex pushed through the plate
            with h5py.File(target, "r+") as f:
                k = int(np.flatnonzero(f["steps/frame"][()] == 9)[0])
                d = f["steps/deformed"][k]
                d[5, 2] = -1.0
                f["steps/deformed"][k] = d
    whole = runner.invoke(main, ["verify", target, "--json"])
    monkeypatch.setattr(sys.modules["penfree.scaleout.plan"], "MAX_TASK_BYTES", 2000)
    _no_dask(monkeypatch)
    windows = _spy_windows(monkeypatch)
    r = runner.invoke(main, ["verify", target, "--json"])
    assert (r.exit_code, whole.exit_code) == ((1, 1) if what == "violating result" else (0, 0)), r.output
    assert windows and all(w is not None and min(w[1], 12) - w[0] <= 7 for _, w in windows), windows
    a, b = json.loads(r.output), json.loads(whole.output)
    assert a == b
    if what == "violating result":
        assert [s["frame"] for s in a["steps"] if not s["ok"]] == [9]


def test_result_read_in_a_window_equals_the_same_rows_of_a_whole_read(tmp_path):
    """`read_result(window=...)`: the window's frames and the steps among them, with their rows of
    the per-step groups, frame numbers shifted to the window's; a NaN outside the window is not
    read, one inside is named by the file's step and frame."""
    from penfree.formats.result import read_result

    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    out = str(tmp_path / "out.h5")
    assert CliRunner().invoke(main, ["deform", path, "-o", out, "--stats", "--model", "auto"]).exit_code == 0
    full, part = read_result(out), read_result(out, window=(4, 9))
    rows = np.flatnonzero((full.steps["frame"] >= 4) & (full.steps["frame"] < 9))
    np.testing.assert_array_equal(part.sequence.positions, full.sequence.positions[4:9])
    assert part.steps["frame"].tolist() == (full.steps["frame"][rows] - 4).tolist()
    for k, v in full.steps.items():
        if k != "frame":
            np.testing.assert_array_equal(part.steps[k], np.asarray(v)[rows], err_msg=k)
    assert part.groups["stats"]["frame"].tolist() == (full.groups["stats"]["frame"][rows] - 4).tolist()
    if "selection" in full.groups:
        np.testing.assert_array_equal(part.groups["selection"]["candidates"], full.groups["selection"]["candidates"])
        np.testing.assert_array_equal(part.groups["selection"]["chosen"], full.groups["selection"]["chosen"][rows])
    with h5py.File(out, "r+") as f:
        k_in, k_out = int(rows[1]), int(np.flatnonzero(full.steps["frame"] == 10)[0])
        for k in (k_in, k_out):
            d = f["steps/deformed"][k]
            d[0, 0] = np.nan
            f["steps/deformed"][k] = d
    read_result(out, window=(1, 4))  # neither NaN is read
    from penfree.errors import FormatError

    with pytest.raises(FormatError, match=rf"step {k_in} \(frame {int(full.steps['frame'][k_in])}\) holds NaN"):
        read_result(out, window=(4, 9))


def test_window_reads_only_its_rows_of_per_vertex_datasets(tmp_path, monkeypatch):
    """`read_result(window=...)` read every per-step dataset whole, the ``--per-vertex``
    residuals (S, N) too: a long verify range task read them all. Now only the window's
    rows of those, equal to the whole read's."""
    from penfree.formats.result import read_result

    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    out = str(tmp_path / "out.h5")
    assert CliRunner().invoke(main, ["deform", path, "-o", out, "--per-vertex"]).exit_code == 0
    full = read_result(out)
    names = [k for k in full.steps if k.endswith("per_vertex")]
    assert names
    reads, real = [], h5py.Dataset.__getitem__

    def spy(ds, sel):
        reads.append((ds.name, sel))
        return real(ds, sel)

    monkeypatch.setattr(h5py.Dataset, "__getitem__", spy)
    part = read_result(out, window=(4, 9))
    rows = np.flatnonzero((full.steps["frame"] >= 4) & (full.steps["frame"] < 9))
    for k in names:
        np.testing.assert_array_equal(part.steps[k], full.steps[k][rows])
        got = [sel for name, sel in reads if name == f"/steps/{k}"]
        assert len(got) == 1 and isinstance(got[0], np.ndarray), (k, got)
    assert part.rows.tolist() == rows.tolist()


def test_window_reads_name_the_files_steps_and_frame_counts(tmp_path):
    """Messages of a frame window's read name the file's step and frame count: a per-component
    step without finite maps (it named the window's row), a per-frame obstacle with the wrong
    number of frames (it named the window's count)."""
    from penfree.core.pipeline.verification import verify_file
    from penfree.formats import read_sequence

    out = str(tmp_path / "pc.h5")
    assert CliRunner().invoke(main, ["deform", str(SAMPLES / "carried_stack.h5"), "-o", out, "--model",
                                     "per-component", "--frames", "0:14"]).exit_code == 0
    with h5py.File(out, "r+") as f:
        k = int(np.flatnonzero(f["steps/frame"][()] == 10)[0])
        A = f["component_maps/A"][k]
        A[0] = np.nan
        f["component_maps/A"][k] = A
    for window in (None, (8, 13)):
        with pytest.raises(InputError, match=rf"steps/A of step {k} is not finite"):
            verify_file(out, window=window)
    path = _cloth_over_a_rising_plate(tmp_path / "in.h5")
    with h5py.File(path, "r+") as f:
        P = f["obstacles/plate/positions"][()]
        del f["obstacles/plate/positions"]
        f["obstacles/plate/positions"] = P[:-1]
    for window in (None, (0, 2), (4, 9)):
        with pytest.raises(InputError, match=r"obstacle positions must be \(12, M, 3\) or \(M, 3\); got \(11, 4, 3\)"):
            read_sequence(path, frame_window=window)


def _plate_result(tmp_path, *extra, T=16):
    """A deform result of `_cloth_over_a_rising_plate` (16 vertices, a mesh obstacle per frame)."""
    path = _cloth_over_a_rising_plate(tmp_path / "in.h5", T=T)
    out = str(tmp_path / "out.h5")
    r = CliRunner().invoke(main, ["deform", path, "-o", out, *extra])
    assert r.exit_code == 0, r.output
    return out


def _long(monkeypatch, max_bytes=2000):
    """Every result beyond `max_bytes` of frames is long; Dask cannot be imported; returns the
    positions windows read (`_spy_windows`)."""
    import sys

    monkeypatch.setattr(sys.modules["penfree.scaleout.plan"], "MAX_TASK_BYTES", max_bytes)
    _no_dask(monkeypatch)
    return _spy_windows(monkeypatch)


def _without_fit_times(doc):
    """`doc` (report.json) without the ladder's fit wall times, which differ between any two runs."""
    import copy

    doc = copy.deepcopy(doc)
    for entry in doc["files"]:
        for row in (entry.get("ladder") or {}).get("rows", []):
            row.pop("fit_ms_mean"), row.pop("fit_ms_median")
    return doc


@pytest.mark.parametrize("extra", [
    ["--no-ladder"],
    ["--no-ladder", "--replay", "--fail-if-uncertified"],
    ["--no-ladder", "--frames", "4:13", "--min-speedup", "0.5"],
    ["--replay"],
], ids=["no-ladder", "replay-fail-if-uncertified", "frames-slice", "ladder-replay"])
def test_serial_report_of_a_long_file_goes_in_ranges_without_dask(tmp_path, monkeypatch, extra):
    """A serial ``report`` of a result whose frames exceed `MAX_TASK_BYTES` read it whole (its
    positions and every deformed state). It now reads the file's per-step tables (frames 0
    and 1 of the positions), then one frame range after another in this process
    (`cluster.InProcess`, no Dask), each only the frames its steps use, s - 1 .. s + 1;
    report.json and report.md equal those of a whole read byte for byte (the ladder's fit
    wall times aside), obstacles, --replay, checks and a --frames slice included."""
    import json

    out = _plate_result(tmp_path)
    runner = CliRunner()
    args = ["--no-plots", "--json", *extra]
    whole = runner.invoke(main, ["report", out, "-o", str(tmp_path / "whole"), *args])
    assert whole.exit_code == 0, whole.output
    windows = _long(monkeypatch)
    r = runner.invoke(main, ["report", out, "-o", str(tmp_path / "ranges"), *args])
    assert r.exit_code == 0, r.output
    read = [w for name, w in windows if name == "positions"]
    assert (0, 2) in read and all(w is not None and min(w[1], 16) - w[0] <= 7 for w in read), read
    assert len({w for w in read if w != (0, 2)}) >= 2, read  # several ranges
    a, b = (json.loads((tmp_path / d / "report.json").read_text()) for d in ("ranges", "whole"))
    if "--no-ladder" in extra:
        for name in ("report.json", "report.md"):
            assert (tmp_path / "ranges" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes(), name
    else:
        assert a["files"][0]["ladder"]["n_steps"] == 15
        assert _without_fit_times(a) == _without_fit_times(b)
    entry = a["files"][0]
    assert entry["scene"]["n_frames"] == 16 and entry["certificate"]["n_uncertified"] == 0
    if "--frames" in extra:
        assert entry["steps"]["frame"] == list(range(4, 13))


@pytest.mark.parametrize("tamper", ["stored", "differs", "unusable"])
def test_long_report_takes_the_stats_group_as_a_whole_read_does(tmp_path, monkeypatch, tamper):
    """Whether a stored ``stats/`` group serves is decided over every step, once: a group
    edited in one range differs from the computed statistics (a CI check notes the key),
    a ``stats/frame`` wrong in one range makes the group unusable for all, as in a whole
    read; an untouched group is read, range by range."""
    import json

    out = _plate_result(tmp_path, "--stats")
    with h5py.File(out, "r+") as f:
        k = int(np.flatnonzero(f["stats/frame"][()] == 12)[0])
        if tamper == "differs":
            f["stats/k_1pct_next_deformed"][k] = 7.0
        elif tamper == "unusable":
            f["stats/frame"][k] = 11
    extra = ["--fail-if-uncertified"] if tamper == "differs" else []
    runner = CliRunner()
    args = ["--no-plots", "--no-ladder", *extra]
    whole = runner.invoke(main, ["report", out, "-o", str(tmp_path / "whole"), *args])
    assert whole.exit_code == 0, whole.output
    _long(monkeypatch)
    r = runner.invoke(main, ["report", out, "-o", str(tmp_path / "ranges"), *args])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "ranges" / "report.json").read_bytes() == (tmp_path / "whole" / "report.json").read_bytes()
    entry = json.loads((tmp_path / "ranges" / "report.json").read_text())["files"][0]
    assert entry["stats_source"] == ("file" if tamper == "stored" else "computed")
    note = {"stored": None, "differs": "k_1pct_next_deformed", "unusable": "stats/frame differs from steps/frame"}
    assert (entry.get("stats_note") is None) if note[tamper] is None else note[tamper] in entry["stats_note"]


def _carried_stack_result(tmp_path, forge=False):
    out = str(tmp_path / "pc.h5")
    r = CliRunner().invoke(main, ["deform", str(SAMPLES / "carried_stack.h5"), "-o", out, "--model",
                                  "per-component", "--frames", "0:14"])
    assert r.exit_code == 0, r.output
    if forge:  # a per-component step in the second range without finite maps
        with h5py.File(out, "r+") as f:
            k = int(np.flatnonzero(f["steps/frame"][()] == 10)[0])
            A = f["component_maps/A"][k]
            A[0] = np.nan
            f["component_maps/A"][k] = A
    return out


@pytest.mark.parametrize("what", ["own-client", "per-component", "per-component-unverifiable", "frames-slice"])
def test_report_in_process_ranges_equal_the_whole_report(tmp_path, monkeypatch, what):
    """`report_many` in this process, a file in frame ranges (each read windowed), gives the
    entry `make_file_report` gives for the whole read: the own client's replay (every 2nd
    step with a next frame), per-component maps checked through verify's path check, and
    verify's message when it cannot check them (maps of a step in the second range made NaN)."""
    from penfree.formats._json import json_safe
    from penfree.report.build import make_file_report, open_result, select_steps
    from penfree.scaleout import report_many

    frames, client = None, None
    if what == "own-client":
        out = _plate_result(tmp_path)
        client = {"client": "own", "truncation": "both", "radius": "both", "dhat": None, "every": 2}
    elif what == "frames-slice":
        out, frames = _plate_result(tmp_path), (-13, -1)
    else:
        out = _carried_stack_result(tmp_path, forge=what == "per-component-unverifiable")
    options = dict(frames=frames, cd_share=0.4, frame_ms=20.0, replay=False, ladder=False, use_stored_stats=False,
                   verify_paths=True, client=client)
    common = {k: options[k] for k in ("cd_share", "frame_ms", "replay", "ladder", "use_stored_stats", "verify_paths")}
    want = make_file_report(out, select_steps(open_result(out), frames), client=client, **common)
    windows = _long(monkeypatch, max_bytes=1)
    seen = []
    inputs, [got] = report_many([out], options=options, in_process=True, step_progress=lambda: seen.append(1))
    assert inputs == [out] and seen
    read = [w for name, w in windows if name == "positions"]
    assert read and None not in read and len(read) >= 3, read
    assert json_safe(got) == json_safe(want)
    if what == "own-client":  # the rising plate is in the client's mesh, at each range's own frames
        assert got["client"]["steps"]["frame"] == list(range(1, 15, 2))
        assert got["client"]["options"]["obstacles"] == ["plate"]
    if what == "per-component-unverifiable":
        assert "is not finite" in got["certificate"]["path_check_error"]
        assert got["certificate"]["n_path_failed"] == got["scene"]["n_steps"]
    elif what != "frames-slice":
        assert got["certificate"]["n_path_failed"] == 0


def test_long_report_of_a_damaged_range_exits_2_in_one_line(tmp_path, monkeypatch):
    """A NaN in a deformed state of a long result is found by the range that reads it: exit 2,
    one line naming the file, its frame range and the step; nothing written."""
    out = _plate_result(tmp_path)
    with h5py.File(out, "r+") as f:
        k = int(np.flatnonzero(f["steps/frame"][()] == 12)[0])
        d = f["steps/deformed"][k]
        d[3, 1] = np.nan
        f["steps/deformed"][k] = d
    _long(monkeypatch)
    r = CliRunner().invoke(main, ["report", out, "-o", str(tmp_path / "rep"), "--no-ladder"])
    assert r.exit_code == 2, r.output
    assert len(r.output.strip().splitlines()) == 1
    assert "frames" in r.output and f"step {k} (frame 12) holds NaN or Inf" in r.output, r.output
    assert not (tmp_path / "rep").exists()


def test_long_report_frames_selecting_no_step_exits_2_before_reading_frames(tmp_path, monkeypatch):
    """A --frames slice selecting no step of a long result is the one-line exit 2 of a whole read,
    decided on the per-step tables: no frame beyond the tables' first two is read."""
    out = _plate_result(tmp_path)
    whole = CliRunner().invoke(main, ["report", out, "-o", str(tmp_path / "w"), "--frames", "0:1"])
    windows = _long(monkeypatch)
    r = CliRunner().invoke(main, ["report", out, "-o", str(tmp_path / "rep"), "--frames", "0:1"])
    assert (r.exit_code, whole.exit_code) == (2, 2) and r.output == whole.output, r.output
    assert "selects none of the 15 steps" in r.output and len(r.output.strip().splitlines()) == 1
    assert [w for name, w in windows if name == "positions"] == [(0, 2)]


def test_report_on_dask_splits_a_file_in_ranges_and_equals_serial(tmp_path, scheduler, monkeypatch):
    """``report --scheduler`` ran one task per file; a file is now cut in frame ranges as verify
    cuts it (a long one always), the ranges' parts joined in step order on the driver: the
    entry of a serial run (ladder fit times aside), checks and replay included."""
    import json

    out = _plate_result(tmp_path)
    runner = CliRunner()
    args = ["--no-plots", "--json", "--replay", "--fail-if-uncertified"]
    serial = runner.invoke(main, ["report", out, "-o", str(tmp_path / "serial"), *args])
    assert serial.exit_code == 0, serial.output
    spy = []
    import penfree.scaleout.verify_report as vr

    real = vr.run_tasks
    monkeypatch.setattr(vr, "run_tasks", lambda c, fn, tasks, *a, **kw: spy.extend(tasks) or real(c, fn, tasks, *a,
                                                                                                   **kw))
    r = runner.invoke(main, ["report", out, "-o", str(tmp_path / "dask"), *args, "--scheduler", scheduler])
    assert r.exit_code == 0, r.output
    assert len(spy) >= 2 and all(t.lo is not None for t in spy), spy
    a, b = (json.loads((tmp_path / d / "report.json").read_text()) for d in ("dask", "serial"))
    assert _without_fit_times(a) == _without_fit_times(b)


def test_report_client_on_dask_equals_serial(tmp_path, scheduler):
    """``report --client ipctk --scheduler`` was refused; the ranges now replay their steps
    through the real client on the workers (every 2nd step of the file, as a serial run
    picks them), and the client section equals the serial report's."""
    import json

    pytest.importorskip("ipctk")
    out = _plate_result(tmp_path)
    runner = CliRunner()
    args = ["--no-plots", "--no-ladder", "--client", "ipctk", "--every", "2"]
    serial = runner.invoke(main, ["report", out, "-o", str(tmp_path / "serial"), *args])
    assert serial.exit_code == 0, serial.output
    r = runner.invoke(main, ["report", out, "-o", str(tmp_path / "dask"), *args, "--scheduler", scheduler])
    assert r.exit_code == 0, r.output
    a, b = (json.loads((tmp_path / d / "report.json").read_text()) for d in ("dask", "serial"))
    assert a["files"][0]["client"] == b["files"][0]["client"] and b["files"][0]["client"]["steps"]["frame"]
    assert _without_fit_times(a) == _without_fit_times(b)


def test_own_local_cluster_workers_are_set_up_for_it_a_schedulers_not(scheduler):
    """The workers of the cluster a command starts end with it, and it waits for them
    (`memory.skip_exit_collection`); they run without Dask's profiler and frequent
    monitors (`LOCAL_CLUSTER_CONFIG`). The workers of a cluster given by --scheduler are
    not the command's to change."""
    import dask

    from penfree.scaleout.cluster import LOCAL_CLUSTER_CONFIG, client

    def state():
        import dask

        from penfree.core import memory

        return memory._exit_collection_skipped, {k: dask.config.get(k) for k in LOCAL_CLUSTER_CONFIG}

    mine = (True, LOCAL_CLUSTER_CONFIG)
    before = {k: dask.config.get(k) for k in LOCAL_CLUSTER_CONFIG}
    assert before != LOCAL_CLUSTER_CONFIG  # Dask's defaults
    with client(workers=1) as c:
        assert list(c.run(state).values()) == [mine]
        assert {k: dask.config.get(k) for k in LOCAL_CLUSTER_CONFIG} == before  # the caller's, restored
    with client(scheduler=scheduler) as c:
        assert list(c.run(state).values()) == [(False, before)] * 2


_SERVER_PROBE = """
import gc, os
import numba
import penfree.scaleout.preload as preload
try:
    numba.threading_layer()
    launched = True
except ValueError:  # not started in this process
    launched = False
print(len(os.listdir("/proc/self/task")), launched, gc.get_freeze_count() > 0, preload.prepare_numba())
"""


_TASKS_AFTER_PRELOAD = """
import importlib.util, os, sys, tempfile
import penfree.scaleout.preload  # noqa: F401
before = set(sys.modules)
sys.modules["penfree.scaleout.plan"].MAX_TASK_BYTES = 4000  # frame ranges: partial results, their merge
from penfree.scaleout import deform_many, report_many, verify_many
d = tempfile.mkdtemp()
outs = [os.path.join(d, name) for name in ("cloth_drape_box.h5", "rods.h5")]
for out in outs:
    deform_many([os.path.join(sys.argv[1], os.path.basename(out))], out, options=dict(
        model="auto", projection="auto", margin=0.0, thickness=None, frames=(0, 6), per_vertex=False),
        with_stats=True, in_process=True)
verify_many(outs, in_process=True)
client = dict(client="ipctk", truncation="both", radius="both", dhat=None, every=5)
report_many(outs, options=dict(frames=None, cd_share=0.5, frame_ms=32.0, replay=True, ladder=True,
                               use_stored_stats=False, verify_paths=True,
                               client=client if importlib.util.find_spec("ipctk") else None), in_process=True)
print(sorted(m for m in set(sys.modules) - before if m.startswith("penfree")))
"""


def test_worker_server_preload_covers_what_the_tasks_import():
    """A forked worker finds every penfree module its tasks import already imported by the
    server (`preload`): deform with `auto`, frame ranges and their merge, a scene with an
    analytic collider, verify, report with its statistics and the real client. A module
    missed there would be imported by each worker, on every run (10-20 ms each here)."""
    out = subprocess.run([sys.executable, "-c", _TASKS_AFTER_PRELOAD, str(SAMPLES)], capture_output=True, text=True,
                         check=True).stdout
    assert out.strip().splitlines()[-1] == "[]", out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only")
def test_worker_server_preload_starts_no_thread():
    """The process a local cluster's workers are forked from must hold one thread when it
    forks: a thread's locks would be held for ever in the child, and GNU OpenMP, once
    Numba's threading layer has started it, ends a forked child at its first parallel
    region. Its preload imports NumPy under `SERVER_ENVIRON` (one OpenBLAS thread)."""
    from penfree.scaleout.cluster import SERVER_ENVIRON

    def probe(env):
        out = subprocess.run([sys.executable, "-c", _SERVER_PROBE], env=env, capture_output=True, text=True,
                             check=True).stdout.split()
        return int(out[0]), out[1:]

    threads, flags = probe({**os.environ, **SERVER_ENVIRON})
    assert threads == 1 and flags == ["False", "True", "True"]  # no thread, no threading layer; frozen; Numba ready
    if os.cpu_count() > 1 and "openblas" in _numpy_blas():  # the control: without it, OpenBLAS starts threads
        env = {k: v for k, v in os.environ.items() if k not in SERVER_ENVIRON}
        assert probe(env)[0] > 1


def _numpy_blas() -> str:
    try:
        return np.__config__.CONFIG["Build Dependencies"]["blas"]["name"].lower()
    except (AttributeError, KeyError, TypeError):  # an older NumPy: no control
        return ""


def _worker_state():
    import gc
    import os
    import sys

    return (os.getppid(), "penfree.core.pipeline.deform" in sys.modules, gc.get_freeze_count() > 0,
            os.environ.get("OPENBLAS_NUM_THREADS"))


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="workers are forked on Linux only")
def test_local_cluster_workers_are_forked_from_the_prepared_server(inputs, tmp_path):
    """Before any task, each worker of a local cluster has penfree's task modules imported
    and their objects frozen (`preload`); its parent is the fork server, not this process,
    and the next cluster reuses that server. Tasks whose parallel kernels run on two
    threads there give the serial run's results (the threading layer starts in the worker)."""
    from penfree.scaleout.cluster import client

    with client(workers=2) as c:
        first = list(c.run(_worker_state).values())
    with client(workers=1) as c:
        second = list(c.run(_worker_state).values())
    parents = {s[0] for s in first + second}
    assert len(parents) == 1 and os.getpid() not in parents
    assert all(s[1:] == (True, True, "1") for s in first + second), first + second
    r = CliRunner().invoke(main, ["deform", str(inputs), "-o", str(tmp_path / "dask"), "--workers", "2",
                                  "--threads", "2", "--model", "auto"])
    assert r.exit_code == 0, r.output
    for name in ("rods.h5", "twisting_cloth.h5"):
        serial = tmp_path / f"serial-{name}"
        r = CliRunner().invoke(main, ["deform", str(inputs / name), "-o", str(serial), "--model", "auto"])
        assert r.exit_code == 0, r.output
        assert_same_result(tmp_path / "dask" / name, serial)


def test_local_cluster_workers_are_spawned_without_the_server(monkeypatch):
    """Where workers are not forked (`FORK_WORKERS`: other systems), they are spawned by
    this process's nannies and prepare themselves, as Dask does by default."""
    from penfree.scaleout import cluster

    monkeypatch.setattr(cluster, "FORK_WORKERS", False)
    assert not cluster.start_worker_server()
    with cluster.client(workers=1) as c:
        [state] = c.run(_worker_state).values()
    assert state[:2] == (os.getpid(), False)


def test_importing_scaleout_loads_neither_dask_nor_numba():
    """The CLI starts the worker server as soon as it knows a command takes this path
    (`cli.scaleout.start_workers`): the decision and the start must not wait for
    Numba's or Dask's import (0.2-0.4 s), which the server does in the meantime."""
    probe = ("import sys, penfree.cli, penfree.scaleout, penfree.scaleout.cluster; "
             "print(sorted(m for m in ('numba', 'distributed', 'dask', 'h5py') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_worker_server_leaves_this_process_environment(monkeypatch):
    """The server is started under `SERVER_ENVIRON` (its workers see it: the test above);
    this process gets its own values back, a variable it did not have included."""
    from penfree.scaleout import cluster

    monkeypatch.setenv("OMP_NUM_THREADS", "7")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert cluster.start_worker_server() == cluster.FORK_WORKERS
    assert os.environ["OMP_NUM_THREADS"] == "7" and "OPENBLAS_NUM_THREADS" not in os.environ


@pytest.mark.parametrize("threads, workers, scheduler, in_process, cores, expected", [
    (3, 1, None, False, 4, 3),           # given: as given
    (None, None, None, True, 4, None),   # in this process: its own
    (None, 1, None, False, 4, 4),        # one local worker: every core
    (None, 3, None, False, 4, 1),        # the cores shared, rounded down
    (None, None, None, False, 4, 1),     # one worker per core (`client`'s default)
    (None, 8, None, False, 2, 1),        # more workers than cores: never 0
    (None, None, "tcp://h:8786", False, 64, 1),  # a scheduler's workers: their cores are unknown here
])
def test_task_threads_share_the_local_cores(monkeypatch, threads, workers, scheduler, in_process, cores, expected):
    from penfree.scaleout import cluster

    monkeypatch.setattr(cluster.os, "cpu_count", lambda: cores)
    assert cluster.task_threads(threads, workers, scheduler, in_process) == expected
    if expected is not None and scheduler is None:
        assert expected * (workers or cores) <= max(cores, workers or cores)  # never more threads than cores
