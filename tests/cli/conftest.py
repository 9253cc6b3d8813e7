"""The CLI contract, asserted around every command a CLI test runs.

`cli` runs ``penfree ARGS...`` in-process (click's CliRunner) with a snapshot
(content hash of every file, hidden ones included) of a folder taken before and
after, and asserts what every command promises whatever its outcome:

- no traceback, and an exit code in {0, 1, 2, 130, 143};
- exit 2 (unusable input or option): exactly one line on stderr, nothing written;
- no new, changed or missing file other than the named output (``-o``, convert's
  OUT with its XDMF heavy-data file, a pattern's numbered files, a directory's
  contents), inputs included.

>>> def test_x(cli, tmp_path):                                       # doctest: +SKIP
...     r = cli("deform", tmp_path / "in.h5", "-o", tmp_path / "out.h5", expect=0)
...     r.changed        # {"out.h5": "new"}
"""

from __future__ import annotations

import fnmatch
import hashlib
import os
import warnings
from dataclasses import dataclass

import pytest
from click.testing import CliRunner

from penfree.cli import main
from penfree.formats.atomic import printf_to_glob
from penfree.formats.meshseq import MESH_EXTENSIONS, output_pattern

EXIT_CODES = (0, 1, 2, 130, 143)


def snapshot(folder) -> dict:
    """``relative path -> digest`` of everything under `folder` (files hashed, links by target)."""
    out = {}
    folder = os.fspath(folder)
    for root, dirs, files in os.walk(folder):
        for name in dirs + files:
            full = os.path.join(root, name)
            rel = os.path.relpath(full, folder)
            if os.path.islink(full):
                out[rel] = "link:" + os.readlink(full)
            elif os.path.isdir(full):
                out[rel] = "dir"
            else:
                try:
                    with open(full, "rb") as fh:
                        out[rel] = hashlib.sha256(fh.read()).hexdigest()
                except OSError:  # unreadable on purpose (permission tests)
                    st = os.stat(full)
                    out[rel] = f"unreadable:{st.st_size}:{st.st_mtime_ns}"
    return out


def diff(before: dict, after: dict) -> dict:
    """``path -> "new" | "changed" | "missing"``."""
    out = {p: "new" for p in after.keys() - before.keys()}
    out.update({p: "missing" for p in before.keys() - after.keys()})
    out.update({p: "changed" for p in before.keys() & after.keys() if before[p] != after[p]})
    return out


def inferred_outputs(args) -> list:
    """The named outputs of a command line: ``-o``/``--output``, and convert's OUT."""
    args = [str(a) for a in args]
    outs = []
    for k, a in enumerate(args[:-1]):
        if a in ("-o", "--output"):
            outs.append(args[k + 1])
    if args and args[0] == "convert":
        pos = [a for k, a in enumerate(args[1:], 1) if not a.startswith("-")
               and args[k - 1] not in ("--format", "--from-format")]
        if len(pos) >= 2:
            outs.append(pos[1])
    return outs


def _allowed(rel: str, folder: str, outputs) -> bool:
    full = os.path.join(folder, rel)
    for out in outputs:
        out = os.path.abspath(os.fspath(out))
        if out.lower().endswith(MESH_EXTENSIONS):
            out = output_pattern(out)  # frame_0001.ply names the series frame_%04d.ply
        globbed = printf_to_glob(out)
        if full == out or full.startswith(out.rstrip(os.sep) + os.sep):
            return True  # the output itself, or inside an output directory
        if full == out + ".h5" and out.lower().endswith((".xdmf", ".xmf")):
            return True  # XDMF heavy data
        if globbed != out and fnmatch.fnmatch(full, globbed):
            return True  # numbered files of a pattern output
        if os.path.dirname(full) == out.rstrip(os.sep) or full == os.path.dirname(globbed):
            return True  # a mesh sequence written into a directory
    return False


@dataclass
class CliRun:
    """What one command did: exit code, stdout, stderr and the folder's changes."""

    exit_code: int
    stdout: str
    stderr: str
    output: str
    changed: dict
    exception: BaseException | None


def check_contract(where, exit_code, stdout, stderr, changed, after, folder, outputs, expect, concurrent=False):
    """The assertions shared by in-process (`cli`) and subprocess (`cli_process`) runs."""
    output = stdout + stderr
    assert "Traceback" not in output and "Exception ignored" not in output, f"{where}:\n{output}"
    assert exit_code in EXIT_CODES, f"{where}: exit {exit_code}\n{output}"
    if exit_code in (2, 130, 143):
        lines = stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith("penfree: "), f"{where}: stderr must be one line:\n{stderr}"
        # (with a concurrent writer the named output may be that writer's)
        assert not changed or concurrent, f"{where}: exit {exit_code} but files changed: {changed}"
    stray = {p: c for p, c in changed.items() if not _allowed(p, folder, outputs)}
    assert not stray, f"{where}: changed files other than the named output {outputs}: {stray}"
    assert not [p for p in after if os.path.basename(p).startswith(".pf")], f"{where}: temporary left: {after}"
    if expect is not None:
        assert exit_code == expect, f"{where}: exit {exit_code}, expected {expect}\n{output}"


def run_checked(folder, args, *, outputs=None, expect=None, input=None) -> CliRun:
    """Run ``penfree args`` in-process and assert the contract of the module docstring (see `cli`)."""
    folder = os.path.abspath(os.fspath(folder))
    args = [str(a) for a in args]
    outputs = inferred_outputs(args) if outputs is None else [os.fspath(o) for o in outputs]
    before = snapshot(folder)
    with warnings.catch_warnings(record=True) as caught:  # a real run prints them on stderr
        warnings.simplefilter("always")
        r = CliRunner().invoke(main, args, input=input)
    after = snapshot(folder)
    ours = [w for w in caught if not issubclass(w.category, (DeprecationWarning, PendingDeprecationWarning))]
    assert not ours, f"penfree {' '.join(args)} printed warnings: " + "; ".join(
        f"{w.category.__name__}: {w.message} ({w.filename}:{w.lineno})" for w in ours)
    changed = diff(before, after)
    exc = r.exception if not isinstance(r.exception, SystemExit) else None
    where = f"penfree {' '.join(args)}"
    if exc is not None:
        import traceback

        tb = "".join(traceback.format_exception(*r.exc_info))
        raise AssertionError(f"{where} raised {type(exc).__name__}: {exc}\n{r.output}\n{tb}")
    check_contract(where, r.exit_code, r.stdout, r.stderr, changed, after, folder, outputs, expect)
    return CliRun(r.exit_code, r.stdout, r.stderr, r.output, changed, r.exception)


@pytest.fixture
def cli(tmp_path):
    """``cli(*args, outputs=None, expect=None, folder=tmp_path)``: run penfree, assert the file contract.

    `outputs` defaults to the outputs named on the command line (``-o``, convert's OUT);
    `folder` is the folder snapshotted (default: the test's tmp_path).
    """
    def run(*args, outputs=None, expect=None, folder=None, input=None):
        return run_checked(folder or tmp_path, args, outputs=outputs, expect=expect, input=input)

    return run


#: ``python -c`` program: penfree's main with test hooks (Python source) run when the write
#: phase begins (signal deferral just installed) or when the command first reads its input.
HOOKED_MAIN = """
import json, sys
import penfree.formats as formats
import penfree.formats.atomic as atomic
import penfree.formats.result as result
spec = json.loads(sys.argv[1])
install = atomic._install
def hooked_install():
    install()
    exec(spec["during_write"] or "", {})
atomic._install = hooked_install
def before(read):
    def hooked(*a, **k):
        exec(spec["before_read"] or "", {})
        return read(*a, **k)
    return hooked
formats.read_sequence = before(formats.read_sequence)
result.read_result = before(result.read_result)
from penfree.cli import main
sys.argv = ["penfree"] + spec["args"]
main()
"""


def _default_sigint():
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.fixture
def cli_process(tmp_path):
    """``cli_process(*args, during_write=None, before_read=None, expect=None)``: penfree in a subprocess.

    For what needs a real process (signals, concurrent writers); the hooks are Python
    source run inside penfree, e.g. ``"import os, signal; os.kill(os.getpid(), signal.SIGTERM)"``.
    The file contract is asserted as in `cli`.
    """
    import json
    import subprocess
    import sys

    def run(*args, during_write=None, before_read=None, outputs=None, expect=None, folder=None, concurrent=False):
        folder_ = os.path.abspath(os.fspath(folder or tmp_path))
        args = [str(a) for a in args]
        outs = inferred_outputs(args) if outputs is None else [os.fspath(o) for o in outputs]
        spec = json.dumps({"args": args, "during_write": during_write, "before_read": before_read})
        before = snapshot(folder_)
        # The child starts with SIGINT at its default, as under a terminal: pytest run as a
        # background job of a non-interactive shell ignores SIGINT, the child would inherit
        # that and no SIGINT test could see penfree's own handling.
        p = subprocess.run([sys.executable, "-c", HOOKED_MAIN, spec], capture_output=True, text=True,
                           cwd=folder_, timeout=600, preexec_fn=_default_sigint)
        after = snapshot(folder_)
        changed = diff(before, after)
        check_contract(f"penfree {' '.join(args)} (subprocess)", p.returncode, p.stdout, p.stderr, changed, after,
                       folder_, outs, expect, concurrent)
        return CliRun(p.returncode, p.stdout, p.stderr, p.stdout + p.stderr, changed, None)

    return run
