"""Atomic outputs: a crash or Ctrl-C leaves no half-written file and never touches an input.

Every writer writes into a short temporary name beside the target
(``.pfXXXXXXXX.tmp``: same directory, hence same file system, and short enough
that any valid output name works) and renames it onto the target only when
everything succeeded. A new output (no ``overwrite``) is created exclusively:
of two concurrent writers the second gets OutputExistsError. SIGINT and SIGTERM
are deferred while outputs are written (`write_phase`): a signal there removes
every temporary and is re-raised as `Interrupted`, so no output appears.

>>> from penfree.formats.atomic import atomic_file
>>> with atomic_file("out.txt", overwrite=True) as tmp:     # doctest: +SKIP
...     open(tmp, "w").write("done")
"""

from __future__ import annotations

import errno
import glob
import os
import re
import shutil
import signal
import tempfile
import threading
from contextlib import contextmanager, suppress

from ..errors import InputError, Interrupted, OutputExistsError

#: Temporary names: ``.pf`` + 8 random characters + suffix (15 bytes, whatever the output name).
TMP_PREFIX, TMP_SUFFIX, OLD_SUFFIX = ".pf", ".tmp", ".old"

#: A printf integer directive in a file-name pattern (``A%08d.ply``).
PRINTF_DIRECTIVE = re.compile(r"%(0?)(\d*)d")


def printf_to_glob(path: str) -> str:
    """``out/A%08d.ply`` -> ``out/A*.ply`` (for existence checks of numbered outputs)."""
    head, tail = os.path.split(path)
    return os.path.join(head, PRINTF_DIRECTIVE.sub("*", glob.escape(tail)))


def output_exists(path) -> bool:
    """True if `path` exists; for a printf pattern, if any file matches it."""
    path = os.fspath(path)
    if PRINTF_DIRECTIVE.search(os.path.basename(path)):
        return bool(glob.glob(printf_to_glob(path)))
    return os.path.lexists(path)


def _same_path(a: str, b: str) -> bool:
    try:
        if os.path.exists(a) and os.path.exists(b):
            return os.path.samefile(a, b)
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


def check_output(path, overwrite: bool = False, inputs=()) -> None:
    """Refuse an output that is an input, or that exists without `overwrite`.

    Commands call this *before* doing any work, so a refused output costs nothing.

    Parameters
    ----------
    path : str or os.PathLike
        The output (a file, a directory, or a printf pattern such as ``out/A%04d.ply``).
    overwrite : bool
        Allow replacing an existing output.
    inputs : iterable of str
        The inputs of the command; the output must be none of them.

    Raises
    ------
    InputError
        `path` is one of `inputs`.
    OutputExistsError
        `path` exists and `overwrite` is False.
    """
    path = os.fspath(path)
    for inp in inputs:
        if inp is not None and _same_path(path, os.fspath(inp)):
            raise InputError(f"output {path} is also an input; choose another output name (inputs are never modified)")
    if not overwrite and output_exists(path):
        raise OutputExistsError(f"output {path} exists; pass --overwrite (overwrite=True) to replace it")


def check_file_name(path) -> None:
    """InputError unless `path` can name a file: not a directory, no trailing separator."""
    path = os.fspath(path)
    if path.endswith(os.sep) or (os.altsep and path.endswith(os.altsep)) or os.path.isdir(path):
        raise InputError(f"output {path} is a directory name; expected a file name")


def _umask_mode(mode: int) -> int:
    # mkstemp/mkdtemp create 0600/0700; the output should get the usual umask mode.
    umask = os.umask(0)
    os.umask(umask)
    return mode & ~umask


# --- the write phase: signals deferred, outputs committed together --------------------------

class _PhaseState(threading.local):
    """State of the re-entrant write phase, per thread (signals reach the main thread's)."""

    def __init__(self):
        self.depth = 0
        self.pending = None  # first signal number received while deferred
        self.saved = {}
        self.actions = []  # [commit, rollback] pairs registered by atomic_file / atomic_dir / on_commit
        self.committed = []  # outputs made visible since the last `reset_committed`


_Phase = _PhaseState()


def _defer(signum, frame):
    if _Phase.pending is None:
        _Phase.pending = signum


def _install():
    _Phase.pending, _Phase.saved = None, {}
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers can only be set in the main thread
    for sig in (signal.SIGINT, signal.SIGTERM):
        with suppress(ValueError, OSError):
            _Phase.saved[sig] = signal.signal(sig, _defer)


def _restore():
    for sig, handler in _Phase.saved.items():
        with suppress(ValueError, OSError, TypeError):
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)
    _Phase.saved = {}


def on_commit(commit, rollback) -> None:
    """Register a multi-file writer's rename step (`commit`) and its cleanup (`rollback`).

    Call inside `write_phase`; `commit` runs when the outermost phase succeeds and
    returns the name of what it made visible; `rollback` runs on any failure.
    """
    def wrapped():
        _Phase.committed.append(commit())

    _Phase.actions.append((wrapped, rollback))


def committed_outputs() -> list:
    """Outputs made visible since the last `reset_committed` (the CLI's interrupt message)."""
    return list(_Phase.committed)


def reset_committed() -> None:
    _Phase.committed = []


@contextmanager
def write_phase():
    """Defer SIGINT / SIGTERM while outputs are written; commit them all at the outermost exit.

    Writers (`atomic_file`, `atomic_dir`) register their temporary and its rename;
    nested writers (XDMF: XML + heavy data) are made visible together, heavy data
    first, only when the outermost phase ends without error and without a signal.
    A signal received inside the phase removes every temporary and raises
    `Interrupted` (a KeyboardInterrupt) at the end: no output, no temporary file.
    """
    outer = _Phase.depth == 0
    if outer:
        _Phase.actions = []
        _install()
    _Phase.depth += 1
    failed = True
    try:
        yield
        if outer:
            if _Phase.pending is not None:
                raise Interrupted(_Phase.pending)
            done = []
            try:
                for commit, _ in reversed(_Phase.actions):  # innermost first
                    done.append(commit())
            except BaseException:
                for undo in done:
                    if undo is not None:
                        undo()
                raise
        failed = False
    except BaseException:
        if outer:
            for _, rollback in reversed(_Phase.actions):  # innermost first: shared new parents go last
                rollback()
        raise
    finally:
        _Phase.depth -= 1
        if outer:
            _Phase.actions = []
            pending = _Phase.pending
            _restore()
            _Phase.pending = None
            if pending is not None and not failed:
                raise Interrupted(pending)  # arrived while the outputs were renamed: they are complete


def _exists_error(path):
    return OutputExistsError(f"output {path} exists; pass --overwrite (overwrite=True) to replace it")


def _link_new(tmp: str, path: str) -> None:
    """Make `tmp` visible as `path`, which must not exist (exclusive, also between processes)."""
    try:
        os.link(tmp, path)
    except FileExistsError:
        raise _exists_error(path) from None
    except OSError as exc:
        if exc.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK, errno.EXDEV):
            raise
        # no hard links on this file system: claim the name, then rename over the claim
        try:
            os.close(os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
        except FileExistsError:
            raise _exists_error(path) from None
        try:
            os.replace(tmp, path)
        except OSError:
            _unlink(path)  # our own empty claim
            raise
    else:
        os.unlink(tmp)


@contextmanager
def atomic_file(path, overwrite: bool = False):
    """Yield a temporary path beside `path`; rename it onto `path` on success.

    On any exception (including KeyboardInterrupt) the temporary file is removed
    and `path` is left as it was. SIGINT / SIGTERM are deferred while the body
    runs (`write_phase`).

    Parameters
    ----------
    path : str or os.PathLike
        The final file. Missing parent directories are created.
    overwrite : bool
        Replace an existing `path`; otherwise raise OutputExistsError up front,
        and again at the end if another process created `path` meanwhile.

    Yields
    ------
    tmp : str
        A file name in the same directory (``.pfXXXXXXXX.tmp``); it already exists
        (empty), writers may truncate it.
    """
    path = os.fspath(path)
    check_file_name(path)
    if not overwrite and os.path.lexists(path):
        raise _exists_error(path)
    parent = os.path.dirname(os.path.abspath(path))
    with write_phase():
        created = []
        try:
            created = make_parents(parent)
            fd, tmp = tempfile.mkstemp(prefix=TMP_PREFIX, suffix=TMP_SUFFIX, dir=parent)
        except OSError as exc:
            remove_dirs(created)
            raise InputError(f"cannot create output {path}: {exc.strerror or exc}") from None
        os.close(fd)

        def commit():
            try:
                if overwrite:
                    os.replace(tmp, path)
                else:
                    _link_new(tmp, path)
            except OSError as exc:
                keep = "the existing file is unchanged" if os.path.lexists(path) else "nothing was written"
                raise InputError(f"cannot write output {path}: {_reason(exc)}; {keep}") from None
            _Phase.committed.append(path)
            return None if overwrite else (lambda: (_unlink(path), _Phase.committed.remove(path)))

        _Phase.actions.append((commit, lambda: (_unlink(tmp), remove_dirs(created))))
        os.chmod(tmp, _umask_mode(0o666))
        with _write_failures(path):
            yield tmp


#: Errors of a write that the output's place causes (its file system), not the command.
_WRITE_ERRNOS = (errno.ENOSPC, errno.EFBIG, errno.EDQUOT, errno.EIO, errno.EROFS)


@contextmanager
def _write_failures(path):
    """A write into the temporary of `path` that fails for want of room (a full disk, a
    quota, a file-size limit) or on a read-only or failing file system: one line naming
    `path`, after `write_phase` removed the temporary."""
    try:
        yield
    except OSError as exc:
        if exc.errno not in _WRITE_ERRNOS:
            raise
        raise write_error(path, exc) from None


def write_error(path, exc: OSError) -> InputError:
    """The one line of an output `path` that could not be written: nothing of it is left."""
    return InputError(f"cannot write output {path}: {_reason(exc)}; nothing was written")


def _unlink(p):
    with suppress(OSError):
        os.unlink(p)


def _reason(exc: OSError) -> str:
    return exc.strerror or str(exc)


def _strip_sep(path: str) -> str:
    """`path` without trailing separators (``link/`` names the symlink ``link``, not its target)."""
    seps = os.sep + (os.altsep or "")
    return path.rstrip(seps) or path[:1]


def make_parents(parent: str) -> list:
    """Create `parent` and its missing ancestors; returns those created, deepest first.
    OSError when one cannot be created (those made before it removed again)."""
    missing, p = [], parent
    while not os.path.isdir(p) and os.path.dirname(p) != p:
        missing.append(p)
        p = os.path.dirname(p)
    try:
        os.makedirs(parent, exist_ok=True)
    except OSError:
        remove_dirs(missing)
        raise
    return missing


def remove_dirs(created: list) -> None:
    """Remove directories `make_parents` created (if still empty): a failed write leaves nothing."""
    for d in created:
        with suppress(OSError):
            os.rmdir(d)


@contextmanager
def atomic_dir(path, overwrite: bool = False):
    """Yield a temporary directory beside `path`; swap it in for `path` on success.

    An existing directory is replaced (removed after the swap) only with
    `overwrite`; callers that own only some names in it check it first
    (`check_output_dir`). On any exception the temporary directory is removed.

    Yields
    ------
    tmp : str
        An empty directory (``.pfXXXXXXXX.tmp``) in the parent of `path`.
    """
    path = os.path.abspath(_strip_sep(os.fspath(path)))
    if os.path.islink(path) or (os.path.lexists(path) and not os.path.isdir(path)):
        raise InputError(f"output {path} exists and is not a directory")
    if not overwrite and os.path.lexists(path):
        raise _exists_error(path)
    parent = os.path.dirname(path)
    with write_phase():
        created = []
        try:
            created = make_parents(parent)
            tmp = tempfile.mkdtemp(prefix=TMP_PREFIX, suffix=TMP_SUFFIX, dir=parent)
        except OSError as exc:
            remove_dirs(created)
            raise InputError(f"cannot create output {path}: {exc.strerror or exc}") from None

        def commit():
            if os.path.lexists(path) and overwrite:
                _swap_dir(tmp, path, parent)
                undo = None
            else:
                try:
                    os.mkdir(path)  # exclusive claim; rename then replaces this empty directory
                except FileExistsError:
                    raise _exists_error(path) from None
                except OSError as exc:
                    raise InputError(f"cannot create output {path}: {_reason(exc)}; nothing was written") from None
                try:
                    os.rename(tmp, path)
                except OSError as exc:
                    with suppress(OSError):
                        os.rmdir(path)  # our own empty claim
                    raise write_error(path, exc) from None
                undo = (lambda: (shutil.rmtree(path, ignore_errors=True), _Phase.committed.remove(path)))
            _Phase.committed.append(path)
            return undo

        _Phase.actions.append((commit, lambda: (shutil.rmtree(tmp, ignore_errors=True), remove_dirs(created))))
        os.chmod(tmp, _umask_mode(0o777))
        with _write_failures(path):
            yield tmp


def _swap_dir(tmp: str, path: str, parent: str) -> None:
    """Replace the directory `path` by `tmp`: two renames, never a moment without either tree.

    A failed rename leaves the old `path` in place (InputError); the old tree is removed
    only once the new one is in place, and a failure to remove it is reported, not ignored.
    """
    if os.path.islink(path) or not os.path.isdir(path):  # replaced meanwhile: never delete what we did not write
        raise InputError(f"output {path} exists and is not a directory; nothing was written")
    try:
        old = tempfile.mkdtemp(prefix=TMP_PREFIX, suffix=OLD_SUFFIX, dir=parent)
        os.rmdir(old)
        os.rename(path, old)
    except OSError as exc:
        raise InputError(f"cannot replace output directory {path}: {_reason(exc)}; "
                         f"the existing {path} is unchanged") from None
    try:
        os.rename(tmp, path)
    except OSError as exc:
        try:
            os.rename(old, path)
        except OSError as back:
            raise InputError(f"cannot replace output directory {path}: {_reason(exc)}; and cannot put the "
                             f"previous one back ({_reason(back)}): it is at {old}") from None
        raise InputError(f"cannot replace output directory {path}: {_reason(exc)}; "
                         f"the existing {path} is unchanged") from None
    errors = []
    shutil.rmtree(old, onerror=lambda fn, p, info: errors.append(f"{p}: {info[1]}"))
    if errors:
        raise InputError(f"wrote {path}, but cannot remove its previous version, left at {old} "
                         f"({errors[0]}); remove it by hand")


def inside(child: str, parent: str) -> bool:
    """`child` is `parent` or lies below it (links resolved; `child` need not exist)."""
    child, parent = os.path.realpath(child), os.path.realpath(parent)
    return child == parent or child.startswith(parent.rstrip(os.sep) + os.sep)


def check_output_dir(path, overwrite: bool = False, inputs=(), owned=None) -> None:
    """Refuse an output directory that holds an input, the working directory, or foreign files.

    ``--overwrite`` may replace the named output only: an existing directory is
    replaced only when every entry in it is one that the writer itself writes.

    Parameters
    ----------
    path : str or os.PathLike
    overwrite : bool
    inputs : iterable of str
        Files the command reads; none may lie inside `path`.
    owned : callable ``(name: str) -> bool`` or None
        True for an entry name the writer writes (e.g. ``report.md``); None: none.

    Raises
    ------
    InputError, OutputExistsError
    """
    path = _strip_sep(os.fspath(path))
    for inp in inputs:
        if inp is not None and inside(os.fspath(inp), path):
            raise InputError(f"output directory {path} contains the input {inp}; choose another output directory "
                             f"(inputs are never modified)")
    if inside(os.getcwd(), path):
        raise InputError(f"output directory {path} is the current directory or holds it; choose a new directory")
    if not os.path.lexists(path):
        return
    if not os.path.isdir(path) or os.path.islink(path):
        raise InputError(f"output {path} exists and is not a directory")
    if not overwrite:
        raise _exists_error(path)
    try:
        names = os.listdir(path)
    except OSError as exc:
        raise InputError(f"cannot read output directory {path}: {exc.strerror or exc}") from None
    foreign = sorted(n for n in names if owned is None or not owned(n)
                     or not os.path.isfile(os.path.join(path, n)) or os.path.islink(os.path.join(path, n)))
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise InputError(f"output directory {path} holds {foreign[0]!r}{more}, which penfree did not write; "
                         f"--overwrite replaces only a directory penfree wrote; choose another output directory")
