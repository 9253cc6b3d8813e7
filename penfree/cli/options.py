"""Options shared by several commands, defined once."""

import json
import math
import sys

import click

from ..errors import InputError
from ..sequence import SCALE_MAX


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


def no_step_error(path, frames, kind) -> InputError:
    """The error for a verify that would check nothing ("all steps safe" about nothing is a false claim)."""
    if frames is None:
        return InputError(f"{path} holds no step to verify")
    span = ":".join("" if v is None else str(v) for v in frames)
    return InputError(f"--frames {span} selects no step of {path} ({kind}); nothing to verify")


frames_option = click.option(
    "--frames", "frames", default=None, metavar="START:STOP",
    help="Only these frames (Python slice, e.g. 10:50 or :20).",
)
threads_option = click.option(
    "--threads", type=click.IntRange(min=1), default=None,
    help="Numba threads (default: all cores; on Dask, a local cluster's cores shared among its workers, "
         "1 on a --scheduler's). Results do not depend on it.",
)
json_option = click.option("--json", "as_json", is_flag=True, help="Machine-readable JSON on stdout.")
#: What penfree promises about your files; the README section of that name says the same.
FILE_PROMISES = (
    "Replace an existing output. penfree never modifies an input, and refuses an output that is an input "
    "under any name (other spelling, pattern, hard link). --overwrite replaces the named output only: a report "
    "directory that holds files penfree did not write, or an input, is refused. Outputs appear complete or "
    "not at all: an error, Ctrl-C or SIGTERM leaves no output and no temporary file. Without --overwrite, a new "
    "output is created exclusively: of two runs writing it at once, the second fails with 'output exists'."
)
overwrite_option = click.option("--overwrite", is_flag=True, help=FILE_PROMISES)


class FiniteFloat(click.FloatRange):
    """A float option in an optional range; NaN and infinities are never valid (click's range lets NaN through)."""

    def convert(self, value, param, ctx):
        v = super().convert(value, param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value} is not a finite number", param, ctx)
        return v

    def _describe_range(self):
        # Without bounds click's help would read "x<=None": any finite number is all it asks.
        return "" if self.min is None and self.max is None else super()._describe_range()


#: A distance option: in the range a file's distance attributes are held to (`penfree.sequence.SCALE_MAX`).
DISTANCE = FiniteFloat(min=0.0, max=SCALE_MAX)

thickness_option = click.option(
    "--thickness", type=DISTANCE, default=None,
    help="Hard minimum separation guaranteed / checked (default: the file's thickness attribute, else 0).",
)
contact_radius_option = click.option(
    "--contact-radius", "contact_radius", type=DISTANCE, default=None,
    help="The simulator's contact distance; sizes the trust-region query radius only, never a separation "
         "(default: the file's contact_radius attribute, else 0).",
)


def usd_options(f):
    """``--prim PATH`` and ``--obstacle PATH`` (repeatable), passed to the USD reader as ``prims``/``obstacles``."""
    f = click.option("--obstacle", "usd_obstacles", multiple=True, metavar="PATH",
                     help="USD input: also read this prim as an obstacle (repeatable).")(f)
    return click.option("--prim", "usd_prims", multiple=True, metavar="PATH",
                        help="USD input: read these prims as the scene (repeatable; default: every "
                             "time-sampled Mesh and linear BasisCurves).")(f)


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
