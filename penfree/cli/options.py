"""Options shared by several commands, defined once."""

import json
import sys

import click

from ..errors import InputError


def parse_frames(text):
    """``START:STOP`` (Python slice of frame indices, either end optional) -> (start, stop)."""
    if text is None:
        return None
    try:
        a, _, b = text.partition(":")
        start = int(a) if a.strip() else None
        stop = int(b) if b.strip() else None
    except ValueError:
        raise InputError(f"--frames must be START:STOP with integers; got {text!r}") from None
    if not _ == ":":
        raise InputError(f"--frames must be START:STOP with integers; got {text!r}")
    return start, stop


frames_option = click.option(
    "--frames", "frames", default=None, metavar="START:STOP",
    help="Only these frames (Python slice, e.g. 10:50 or :20).",
)
threads_option = click.option(
    "--threads", type=click.IntRange(min=1), default=None,
    help="Numba threads (default: all cores). Results do not depend on it.",
)
json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout.")
overwrite_option = click.option("--overwrite", is_flag=True, help="Replace an existing output.")
thickness_option = click.option(
    "--thickness", type=click.FloatRange(min=0.0), default=None,
    help="Contact distance (default: the file's thickness attribute, else 0).",
)


def set_threads(threads):
    if threads is None:
        return
    import numba

    numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def echo_json(obj):
    """Strict JSON on stdout (NaN and inf as null, as in report.json)."""
    from ..formats._json import json_safe

    click.echo(json.dumps(json_safe(obj), indent=2))


class Progress:
    """A progress bar on stderr when it is a terminal; silent otherwise (CI, pipes)."""

    def __init__(self, total, label, enabled=None):
        self.enabled = sys.stderr.isatty() if enabled is None else enabled
        self._bar = None
        if self.enabled and total > 1:
            self._bar = click.progressbar(length=total, label=label, file=sys.stderr)
            self._bar.__enter__()

    def __call__(self, n=1):
        if self._bar is not None:
            self._bar.update(n)

    def close(self):
        if self._bar is not None:
            self._bar.__exit__(None, None, None)
            self._bar = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def scaleout_options(f):
    """``--workers N`` and ``--scheduler ADDRESS`` (several inputs run on Dask)."""
    f = click.option("--scheduler", default=None, metavar="ADDRESS",
                     help="Run on an existing Dask cluster (e.g. tcp://host:8786). Needs penfree[dask].")(f)
    f = click.option("--workers", type=click.IntRange(min=1), default=None,
                     help="Run on a local Dask cluster of N worker processes (several inputs: default all "
                          "cores). Needs penfree[dask]; outputs equal a serial run.")(f)
    return f
