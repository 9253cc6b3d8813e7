"""Readers and writers: one module per format, one dispatcher (as in meshio).

Every reader produces the same validated :class:`penfree.Sequence`.

=========  ===========================  =========================================
name       recognised by                notes
=========  ===========================  =========================================
hdf5       ``.h5`` ``.hdf5``, magic     layout v1 (SPEC section 2), the primary format
npz        ``.npz``                     ``positions``/``vertices_seq`` + topology
meshseq    pattern, glob, directory,    numbered mesh files through meshio;
           numbered ``.ply``/``.obj``   OBJ (with ``l`` polylines) read natively
xdmf       ``.xdmf`` ``.xmf``           temporal collection, geometry per step
usd        ``.usd`` ``.usda`` ``.usdc``  needs the ``usd`` extra (usd-core); meshes and
                                        linear curves, colliders as obstacles, metres
=========  ===========================  =========================================

>>> import penfree
>>> seq = penfree.read_sequence("samples/rods.h5")           # doctest: +SKIP
>>> penfree.write_sequence("rods.xdmf", seq, overwrite=True)  # doctest: +SKIP
"""

from __future__ import annotations

import os

from ..errors import InputError
from ..sequence import Sequence
from ._registry import FORMATS, register
from . import hdf5, npz, meshseq, xdmf, usd  # noqa: E402,F401  (each registers itself)

__all__ = ["read_sequence", "write_sequence", "detect_format", "output_paths", "input_files", "output_files",
           "check_outputs", "register", "FORMATS"]


def _by_name(format: str):
    if format not in FORMATS:
        raise InputError(f"unknown format {format!r}; expected one of {', '.join(sorted(FORMATS))}")
    return FORMATS[format]


def detect_format(path, *, writing: bool = False) -> str:
    """The format name for `path`: sniffers first (patterns, directories, magic bytes), then the extension.

    Raises
    ------
    InputError
        Nothing recognises `path`; the message names the file and the formats.
    """
    path = os.fspath(path)
    for spec in FORMATS.values():
        if spec.sniff is not None and spec.sniff(path, writing=writing):
            return spec.name
    ext = os.path.splitext(path)[1].lower()
    for spec in FORMATS.values():
        if ext in spec.extensions:
            return spec.name
    known = "; ".join(f"{s.name} ({' '.join(s.extensions)})" for s in FORMATS.values())
    raise InputError(f"cannot tell the format of {path} from its name or content; expected one of: {known}, or pass --format")


def read_sequence(path, format: str | None = None, **options) -> Sequence:
    """Read and validate a sequence.

    Parameters
    ----------
    path : str or os.PathLike
        A file, or for ``meshseq`` a printf pattern (``out/A%08d.ply``), a glob
        (``frames/frame_*.obj``), a directory or one numbered file.
    format : {"hdf5", "npz", "meshseq", "xdmf", "usd"} or None
        None: detected from the name and content.
    **options
        Reader options, e.g. ``prims=["/World/Cloth"]``, ``obstacles=[...]`` for USD.
        Empty values (None, ``()``) are ignored, so callers may always pass them.

    Returns
    -------
    Sequence
        Validated (``Sequence.validate``), ``origin`` set to `path`.

    Raises
    ------
    InputError, FormatError
        One line naming the file, the dataset and what was expected.
    """
    from .hdf5 import check_readable

    path = os.fspath(path)
    if os.path.isfile(path):
        check_readable(path)  # "permission denied", not a wrong diagnosis of the content
    spec = _by_name(format) if format else FORMATS[detect_format(path)]
    options = {k: v for k, v in options.items() if v}
    for key in options:
        if key not in spec.options:
            raise InputError(f"option {key} does not apply to {path} ({spec.name}); "
                             f"{spec.name} reads {', '.join(spec.options) or 'no options'}")
    seq = spec.reader(path, **options)
    seq.origin = path
    return seq.validate()


def write_sequence(path, seq: Sequence, format: str | None = None, overwrite: bool = False) -> None:
    """Write `seq` atomically; an existing output is replaced only with `overwrite`.

    Raises
    ------
    OutputExistsError
        An output exists and `overwrite` is False.
    """
    path = os.fspath(path)
    spec = _by_name(format) if format else FORMATS[detect_format(path, writing=True)]
    seq.validate()
    spec.writer(path, seq, overwrite)


def output_paths(path, format: str | None = None) -> list:
    """Every path that ``write_sequence(path, ..., format)`` would create."""
    path = os.fspath(path)
    spec = _by_name(format) if format else FORMATS[detect_format(path, writing=True)]
    return list(spec.outputs(path)) if spec.outputs is not None else [path]


def input_files(path, format: str | None = None) -> list:
    """Every file that ``read_sequence(path, format)`` reads (mesh sequences: each frame file)."""
    path = os.fspath(path)
    spec = _by_name(format) if format else FORMATS[detect_format(path)]
    return list(spec.input_files(path)) if spec.input_files is not None else [path]


def output_files(path, format: str | None = None, n_frames: int = 0) -> list:
    """Every file that writing `n_frames` frames to `path` creates, replaces or removes."""
    path = os.fspath(path)
    spec = _by_name(format) if format else FORMATS[detect_format(path, writing=True)]
    if spec.output_files is not None:
        return list(spec.output_files(path, n_frames))
    return output_paths(path, format)


def check_outputs(outputs, inputs, overwrite: bool = False) -> None:
    """Refuse when any output file is any input file (under any spelling, hard links too) or exists.

    An input that is a directory (a mesh sequence named by its directory) is read
    whole: no output may be that directory or lie inside it, since a file added
    there would change what the directory reads as (12 frames instead of 6).

    Parameters
    ----------
    outputs : list of str
        `output_files` of the output.
    inputs : list of str
        `input_files` of every input, plus any input directory.
    overwrite : bool

    Raises
    ------
    InputError, OutputExistsError
    """
    from .atomic import check_output, inside

    inputs = [os.fspath(i) for i in inputs if i is not None]
    dirs = [d for d in inputs if os.path.isdir(d)]
    files = [i for i in inputs if i not in dirs]
    for p in outputs:
        check_output(p, True, inputs=files)  # "is also an input" first: the most specific refusal
        _check_pattern_names_no_input(os.fspath(p), files)
        for d in dirs:
            if inside(os.fspath(p), d):
                raise InputError(f"output {p} is inside the input directory {d}; choose an output outside it "
                                 f"(inputs are never modified)")
        check_output(p, overwrite)


def _check_pattern_names_no_input(pattern: str, files: list) -> None:
    """A printf output (``seq/frame_%04d.ply``) whose numbered files would include an input file is an input."""
    from fnmatch import fnmatchcase

    from .atomic import PRINTF_DIRECTIVE, printf_to_glob

    head, base = os.path.split(pattern)
    if not PRINTF_DIRECTIVE.search(base):
        return
    names = os.path.basename(printf_to_glob(pattern))
    where = os.path.realpath(head or ".")
    for f in files:
        if fnmatchcase(os.path.basename(f), names) and os.path.realpath(os.path.dirname(f) or ".") == where:
            raise InputError(f"output {pattern} is also an input (its frames include {f}); choose another output "
                             f"name (inputs are never modified)")
