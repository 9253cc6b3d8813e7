"""Atomic outputs: nothing half-written, nothing replaced without overwrite, inputs refused."""

import os

import pytest

from penfree.errors import InputError, OutputExistsError
from penfree.formats.atomic import atomic_dir, atomic_file, check_output, output_exists


def _listing(d):
    return sorted(os.listdir(d))


def test_atomic_file_renames_on_success(tmp_path):
    target = tmp_path / "out.bin"
    with atomic_file(target) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path)
        assert os.path.basename(tmp).startswith(".pf") and len(os.path.basename(tmp)) <= 16  # short: any output name fits
        with open(tmp, "w") as fh:
            fh.write("new")
        assert not target.exists()  # nothing visible before the end
    assert target.read_text() == "new"
    assert _listing(tmp_path) == ["out.bin"]
    umask = os.umask(0)
    os.umask(umask)
    assert os.stat(target).st_mode & 0o777 == 0o666 & ~umask  # the usual mode, not mkstemp's 0600


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt], ids=["error", "ctrl-c"])
def test_atomic_file_cleans_up_and_keeps_old(tmp_path, exc):
    target = tmp_path / "out.bin"
    target.write_text("old")
    with pytest.raises(exc):
        with atomic_file(target, overwrite=True) as tmp:
            with open(tmp, "w") as fh:
                fh.write("half")
            raise exc()
    assert target.read_text() == "old"
    assert _listing(tmp_path) == ["out.bin"]


def test_atomic_file_refuses_existing_without_overwrite(tmp_path):
    target = tmp_path / "out.bin"
    target.write_text("old")
    with pytest.raises(OutputExistsError, match="out.bin exists"):
        with atomic_file(target):
            pass  # pragma: no cover
    assert target.read_text() == "old"
    assert _listing(tmp_path) == ["out.bin"]


def test_atomic_file_creates_parent_dirs(tmp_path):
    target = tmp_path / "a" / "b" / "out.txt"
    with atomic_file(target) as tmp:
        open(tmp, "w").write("x")
    assert target.read_text() == "x"


def test_atomic_dir_swaps_and_cleans(tmp_path):
    out = tmp_path / "rep"
    with atomic_dir(out) as tmp:
        (open(os.path.join(tmp, "a.md"), "w")).write("1")
    assert _listing(out) == ["a.md"]
    with pytest.raises(OutputExistsError):
        with atomic_dir(out):
            pass  # pragma: no cover
    with pytest.raises(KeyboardInterrupt):
        with atomic_dir(out, overwrite=True) as tmp:
            open(os.path.join(tmp, "b.md"), "w").write("2")
            raise KeyboardInterrupt
    assert _listing(out) == ["a.md"] and _listing(tmp_path) == ["rep"]
    with atomic_dir(out, overwrite=True) as tmp:
        open(os.path.join(tmp, "b.md"), "w").write("2")
    assert _listing(out) == ["b.md"] and _listing(tmp_path) == ["rep"]


def test_check_output(tmp_path):
    inp = tmp_path / "in.h5"
    inp.write_text("x")
    with pytest.raises(InputError, match="is also an input"):
        check_output(inp, overwrite=True, inputs=[str(inp)])
    # the same file under another spelling
    with pytest.raises(InputError, match="is also an input"):
        check_output(str(tmp_path / "." / "in.h5"), overwrite=True, inputs=[str(inp)])
    with pytest.raises(OutputExistsError):
        check_output(inp, overwrite=False)
    check_output(inp, overwrite=True)
    check_output(tmp_path / "new.h5", overwrite=False, inputs=[str(inp)])


def test_output_exists_understands_printf_patterns(tmp_path):
    pattern = str(tmp_path / "A%04d.ply")
    assert not output_exists(pattern)
    (tmp_path / "A0003.ply").write_text("")
    assert output_exists(pattern)
    with pytest.raises(OutputExistsError):
        check_output(pattern)


@pytest.mark.parametrize("ctx", [atomic_file, atomic_dir], ids=["file", "dir"])
def test_uncreatable_output_is_an_input_error(tmp_path, ctx):
    (tmp_path / "plain").write_text("a file, not a directory")
    with pytest.raises(InputError, match="cannot create output"):
        with ctx(tmp_path / "plain" / "out"):
            pass  # pragma: no cover


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_signal_while_writing_leaves_nothing(tmp_path, sig):
    import signal

    from penfree.errors import Interrupted

    signum = getattr(signal, sig)
    before = signal.getsignal(signum)
    with pytest.raises(Interrupted) as info:
        with atomic_file(tmp_path / "new" / "out.bin") as tmp:
            os.kill(os.getpid(), signum)  # deferred: the writer finishes, nothing is renamed
            open(tmp, "w").write("complete but interrupted")
    assert info.value.signum == signum
    assert _listing(tmp_path) == []  # no output, no temporary, no created parent
    assert signal.getsignal(signum) is before  # handlers restored


def test_new_directory_output_is_exclusive(tmp_path):
    out = tmp_path / "rep"
    with pytest.raises(OutputExistsError):
        with atomic_dir(out) as tmp:
            open(os.path.join(tmp, "mine.md"), "w").write("slower")
            out.mkdir()  # another writer created it meanwhile
            (out / "theirs.md").write_text("faster")
    assert _listing(out) == ["theirs.md"] and _listing(tmp_path) == ["rep"]


def test_writers_in_threads_do_not_share_a_write_phase(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    def write(k):
        with atomic_file(tmp_path / f"out{k}.txt") as tmp:
            open(tmp, "w").write(str(k))

    with ThreadPoolExecutor(4) as pool:
        list(pool.map(write, range(16)))
    assert _listing(tmp_path) == sorted(f"out{k}.txt" for k in range(16))
    assert all((tmp_path / f"out{k}.txt").read_text() == str(k) for k in range(16))


# ---------------------------------------------------------------- failed renames, symlinked outputs


def _failing(monkeypatch, name, fails):
    """Make ``os.<name>`` raise EBUSY (as on a mount point) for the call where ``fails(src, dst)``."""
    import errno

    real = getattr(os, name)

    def fake(src, dst, *a, **k):
        if fails(os.fspath(src), os.fspath(dst)):
            raise OSError(errno.EBUSY, "Device or resource busy", os.fspath(src))
        return real(src, dst, *a, **k)

    monkeypatch.setattr(os, name, fake)


@pytest.mark.parametrize("which", ["old-aside", "new-in", "new-in-new-dir"])
def test_atomic_dir_failed_rename_is_an_input_error_and_keeps_old(tmp_path, monkeypatch, which):
    out = tmp_path / "rep"
    if which != "new-in-new-dir":
        out.mkdir()
        (out / "a.md").write_text("old")
    if which == "old-aside":  # the existing directory cannot be moved (a mount point)
        _failing(monkeypatch, "rename", lambda src, dst: src == str(out))
    else:  # the new tree cannot be moved in
        _failing(monkeypatch, "rename", lambda src, dst: dst == str(out) and os.path.basename(src).endswith(".tmp"))
    busy = r"cannot (replace output directory|write output) .*rep: Device or resource busy"
    with pytest.raises(InputError, match=busy):
        with atomic_dir(out, overwrite=True) as tmp:
            open(os.path.join(tmp, "b.md"), "w").write("new")
    if which == "new-in-new-dir":
        assert _listing(tmp_path) == []  # nothing written: no claim, no temporary
    else:
        assert _listing(out) == ["a.md"] and (out / "a.md").read_text() == "old"
        assert _listing(tmp_path) == ["rep"]  # no .pf*.tmp, no .pf*.old


def test_atomic_file_failed_replace_is_an_input_error_and_keeps_old(tmp_path, monkeypatch):
    target = tmp_path / "out.bin"
    target.write_text("old")
    _failing(monkeypatch, "replace", lambda src, dst: dst == str(target))
    with pytest.raises(InputError, match=r"cannot write output .*out.bin: Device or resource busy; the existing"):
        with atomic_file(target, overwrite=True) as tmp:
            open(tmp, "w").write("new")
    assert target.read_text() == "old" and _listing(tmp_path) == ["out.bin"]


def test_atomic_dir_old_tree_left_behind_is_reported(tmp_path, monkeypatch):
    import penfree.formats.atomic as atomic

    out = tmp_path / "rep"
    out.mkdir()
    (out / "a.md").write_text("old")
    real = atomic.shutil.rmtree

    def stuck(path, *a, onerror=None, **k):
        if os.fspath(path).endswith(".old") and onerror is not None:
            return onerror(os.unlink, os.fspath(path), (PermissionError, PermissionError(13, "denied"), None))
        return real(path, *a, onerror=onerror, **k)

    monkeypatch.setattr(atomic.shutil, "rmtree", stuck)
    with pytest.raises(InputError, match=r"wrote .*rep, but cannot remove its previous version, left at .*\.old"):
        with atomic_dir(out, overwrite=True) as tmp:
            open(os.path.join(tmp, "b.md"), "w").write("new")
    assert _listing(out) == ["b.md"]
    left = [n for n in _listing(tmp_path) if n != "rep"]
    assert len(left) == 1 and left[0].endswith(".old")  # named in the message, not silently left


@pytest.mark.parametrize("spelling", ["", "/", "//"], ids=["link", "link-slash", "link-slashes"])
def test_symlinked_output_dir_is_refused(tmp_path, spelling):
    from penfree.formats.atomic import check_output_dir

    real = tmp_path / "real"
    real.mkdir()
    (real / "a.md").write_text("old")
    os.symlink("real", tmp_path / "link")
    target = str(tmp_path / "link") + spelling  # (pathlib would drop a trailing separator)
    with pytest.raises(InputError, match="exists and is not a directory"):
        check_output_dir(target, overwrite=True, owned=lambda n: True)
    with pytest.raises(InputError, match="exists and is not a directory"):
        with atomic_dir(target, overwrite=True) as tmp:
            open(os.path.join(tmp, "b.md"), "w").write("new")  # pragma: no cover
    assert os.path.islink(tmp_path / "link") and os.readlink(tmp_path / "link") == "real"
    assert _listing(real) == ["a.md"] and _listing(tmp_path) == ["link", "real"]


def test_trailing_separator_on_a_real_dir_still_works(tmp_path):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "a.md").write_text("old")
    with atomic_dir(str(out) + os.sep, overwrite=True) as tmp:
        open(os.path.join(tmp, "b.md"), "w").write("new")
    assert _listing(out) == ["b.md"] and _listing(tmp_path) == ["rep"]


# --- a full disk while writing (found by an adversarial sweep) ------------------------------

def _sample_result(tmp_path):
    """A small deform result, written once: (sequence, steps, its size in bytes)."""
    from penfree.core.pipeline.deform import deform_sequence
    from penfree.formats import read_sequence
    from penfree.formats.result import write_result

    seq = read_sequence(os.path.join(os.path.dirname(__file__), "..", "..", "samples", "twisting_cloth.h5"))
    steps = deform_sequence(seq, frames=(0, 6)).steps
    full = tmp_path / "full.h5"
    write_result(full, seq, steps, {"input": "twisting_cloth.h5"})
    return seq, steps, full


@pytest.mark.parametrize("writer", ["result", "sequence", "xdmf"])
def test_a_full_disk_while_writing_leaves_nothing_and_names_the_output(tmp_path, monkeypatch, writer):
    """HDF5 writes fail after `budget` bytes (ENOSPC). Before, h5py ignored a failure at a
    close and renamed a truncated file into place, and HDF5 crashed (SIGSEGV) closing a
    file after a failed write. Every budget short of the whole file is now one InputError
    naming the output, and no file, temporary or directory is left; the whole budget
    writes a file that reads back whole."""
    import errno

    from penfree.formats import read_sequence, write_sequence
    from penfree.formats.result import read_result, write_result

    seq, steps, full = _sample_result(tmp_path)
    write = {"result": lambda p: write_result(p, seq, steps, {"input": "twisting_cloth.h5"}), "sequence": lambda p: write_sequence(p, seq),
             "xdmf": lambda p: write_sequence(p, seq)}[writer]
    name = "out.xdmf" if writer == "xdmf" else "out.h5"
    real_pwrite, used = os.pwrite, [0]

    def pwrite(fd, data, offset):
        if used[0] + len(data) > budget:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        used[0] += len(data)
        return real_pwrite(fd, data, offset)

    monkeypatch.setattr(os, "pwrite", pwrite)
    size = full.stat().st_size
    for budget in [0, 100, 2000] + [size * k // 8 for k in range(1, 8)]:
        used[0] = 0
        out = tmp_path / f"b{budget}" / name
        with pytest.raises(InputError) as err:
            write(out)
        named = f"{out}.h5" if writer == "xdmf" else out  # XDMF: the HDF5 file holding its arrays
        assert str(err.value) == f"cannot write output {named}: No space left on device; nothing was written"
        assert not out.parent.exists(), os.listdir(out.parent)  # the directory the write created, gone too
    budget, used[0] = 10 * size, 0
    out = tmp_path / "whole" / name
    write(out)
    if writer == "result":
        back = read_result(str(out))
        assert back.n_steps == len(steps["frame"])
    else:
        back = read_sequence(str(out))
    assert (back.sequence if writer == "result" else back).positions.shape == seq.positions.shape


def test_deform_and_report_under_a_file_size_limit_fail_in_one_line(tmp_path):
    """The CLI, with the process's file-size limit below its output (SIGXFSZ ignored, so
    a write fails with EFBIG as on a full disk): exit 2, one line, nothing written."""
    import resource
    import signal
    import subprocess
    import sys

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    src = os.path.join(os.path.dirname(__file__), "..", "..", "samples", "twisting_cloth.h5")
    out = tmp_path / "out" / "def.h5"
    cli = [sys.executable, "-m", "penfree"]
    r = subprocess.run([*cli, "deform", src, "-o", str(out), "--frames", "0:6"], capture_output=True, text=True,
                       preexec_fn=limit)
    assert (r.returncode, r.stderr.count("\n")) == (2, 1), r.stderr
    assert f"cannot write output {out}: File too large; nothing was written" in r.stderr
    assert not out.parent.exists()
    r = subprocess.run([*cli, "deform", src, "-o", str(out), "--frames", "0:6"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    rep = tmp_path / "rep"
    r = subprocess.run([*cli, "report", str(out), "-o", str(rep), "--no-ladder"], capture_output=True, text=True,
                       preexec_fn=limit)
    assert (r.returncode, r.stderr.count("\n")) == (2, 1), r.stderr
    assert "File too large; nothing was written" in r.stderr
    assert sorted(os.listdir(tmp_path)) == ["out"]
