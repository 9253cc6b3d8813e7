"""Atomic outputs: a crash or Ctrl-C leaves no half-written file and never touches an input.

Every writer writes into a temporary name beside the target (``.name.tmp-XXXX``,
same directory, hence same file system) and renames it onto the target only
when everything succeeded.

>>> from penfree.formats.atomic import atomic_file
>>> with atomic_file("out.txt", overwrite=True) as tmp:     # doctest: +SKIP
...     open(tmp, "w").write("done")
"""

from __future__ import annotations

import glob
import os
import re
import shutil
import tempfile
from contextlib import contextmanager, suppress

from ..errors import InputError, OutputExistsError

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


def _umask_mode(mode: int) -> int:
    # mkstemp/mkdtemp create 0600/0700; the output should get the usual umask mode.
    umask = os.umask(0)
    os.umask(umask)
    return mode & ~umask


@contextmanager
def atomic_file(path, overwrite: bool = False):
    """Yield a temporary path beside `path`; rename it onto `path` on success.

    On any exception (including KeyboardInterrupt) the temporary file is removed
    and `path` is left as it was.

    Parameters
    ----------
    path : str or os.PathLike
        The final file. Missing parent directories are created.
    overwrite : bool
        Replace an existing `path`; otherwise raise OutputExistsError up front.

    Yields
    ------
    tmp : str
        A file name in the same directory (``.name.tmp-XXXX``); it already exists
        (empty), writers may truncate it.
    """
    path = os.fspath(path)
    if os.path.isdir(path):
        raise InputError(f"output {path} is a directory; expected a file name")
    if not overwrite and os.path.lexists(path):
        raise OutputExistsError(f"output {path} exists; pass --overwrite (overwrite=True) to replace it")
    parent = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(parent, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{os.path.basename(path)}.tmp-", dir=parent)
    except OSError as exc:
        raise InputError(f"cannot create output {path}: {exc.strerror or exc}") from None
    os.close(fd)
    try:
        os.chmod(tmp, _umask_mode(0o666))
        yield tmp
        os.replace(tmp, path)
    except BaseException:
        with suppress(OSError):
            os.unlink(tmp)
        raise


@contextmanager
def atomic_dir(path, overwrite: bool = False):
    """Yield a temporary directory beside `path`; swap it in for `path` on success.

    An existing directory is replaced (removed after the swap) only with
    `overwrite`. On any exception the temporary directory is removed.

    Yields
    ------
    tmp : str
        An empty directory (``.name.tmp-XXXX``) in the parent of `path`.
    """
    path = os.fspath(path).rstrip(os.sep) or os.sep
    if os.path.lexists(path) and not os.path.isdir(path):
        raise InputError(f"output {path} exists and is not a directory")
    if not overwrite and os.path.lexists(path):
        raise OutputExistsError(f"output {path} exists; pass --overwrite (overwrite=True) to replace it")
    parent = os.path.dirname(os.path.abspath(path))
    name = os.path.basename(os.path.abspath(path))
    try:
        os.makedirs(parent, exist_ok=True)
        tmp = tempfile.mkdtemp(prefix=f".{name}.tmp-", dir=parent)
    except OSError as exc:
        raise InputError(f"cannot create output {path}: {exc.strerror or exc}") from None
    try:
        os.chmod(tmp, _umask_mode(0o777))
        yield tmp
        if os.path.lexists(path):
            # Two renames, never a moment without either the old or the new tree.
            old = tempfile.mkdtemp(prefix=f".{name}.old-", dir=parent)
            os.rmdir(old)
            os.rename(path, old)
            os.rename(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.rename(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
