"""The format table that every format module registers itself into (as in meshio)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional


@dataclass(frozen=True)
class FormatSpec:
    """One registered format.

    Attributes
    ----------
    name : str
    extensions : tuple of str
        Lower-case, with the dot (``".h5"``).
    reader : callable ``(path: str) -> Sequence``
        Returns an unvalidated or validated sequence; the dispatcher validates.
    writer : callable ``(path: str, seq: Sequence, overwrite: bool) -> None``
        Writes atomically (formats.atomic) and refuses an existing output
        without `overwrite`.
    sniff : callable ``(path: str, writing: bool) -> bool`` or None
        Recognises paths that the extension alone does not (patterns, directories,
        magic bytes of an existing input).
    outputs : callable ``(path: str) -> list of str`` or None
        Every path the writer creates (XDMF writes a heavy-data file beside the XML).
    options : tuple of str
        Keyword options the reader accepts besides the path (USD: ``prims``, ``obstacles``).
    input_files : callable ``(path: str) -> list of str`` or None
        Every file the reader reads (a mesh sequence: its frame files); None: ``[path]``.
    output_files : callable ``(path: str, n_frames: int) -> list of str`` or None
        Every file writing `n_frames` frames creates, replaces or removes; None: `outputs`.
    """

    name: str
    extensions: tuple
    reader: Callable
    writer: Callable
    sniff: Optional[Callable] = None
    outputs: Optional[Callable] = None
    options: tuple = ()
    input_files: Optional[Callable] = None
    output_files: Optional[Callable] = None


FORMATS: dict = {}


def register(name, extensions, reader, writer, sniff=None, outputs=None, options=(), input_files=None,
             output_files=None) -> None:
    """Register a format under `name` for `extensions` (later registrations replace)."""
    exts = tuple(e.lower() if e.startswith(".") else "." + e.lower() for e in extensions)
    FORMATS[name] = FormatSpec(name, exts, reader, writer, sniff, outputs, tuple(options), input_files, output_files)
