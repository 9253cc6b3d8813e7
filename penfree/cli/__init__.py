"""The ``penfree`` command line: thin layers over the library.

Every command parses, calls the library and prints. Errors map to exit codes:
0 success, 1 a check failed, 2 unusable input or arguments (one line on stderr,
option errors included), 130 / 143 interrupted by Ctrl-C / SIGTERM (one line;
no output and no temporary file left, see `penfree.formats.atomic`).
"""

import importlib
import signal
import sys
import threading

import click

from .._version import __version__
from ..errors import InputError, Interrupted

#: command name -> module under penfree.cli, imported only when invoked.
COMMANDS = {
    "deform": "deform",
    "verify": "verify",
    "report": "report",
    "info": "info",
    "convert": "convert",
}


class PenfreeGroup(click.Group):
    """Loads commands lazily and turns `InputError` into exit 2 with one line."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        if name not in COMMANDS:
            return None
        try:
            mod = importlib.import_module(f"penfree.cli.{COMMANDS[name]}")
        except ModuleNotFoundError:  # command not built yet
            return None
        return getattr(mod, "command")

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except InputError as exc:
            _error_line(str(exc))
            ctx.exit(2)
        except KeyboardInterrupt as exc:
            ctx.exit(_interrupted(exc))

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        """Click's main with one-line option errors and SIGTERM handled like Ctrl-C."""
        from ..formats.atomic import reset_committed

        from ..core.memory import retain_freed_memory, skip_exit_collection
        from ..core.parallel import limit_spin_wait

        reset_committed()
        retain_freed_memory()  # large scratch arrays reused, not re-faulted per call
        limit_spin_wait()  # before any parallel kernel: OpenMP's idle threads yield a busy machine's cores
        previous = _catch_sigterm()
        try:
            rv = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
            code = rv if isinstance(rv, int) else 0
        except _NO_ARGS as exc:  # bare `penfree` / `penfree deform`: the help, as click prints it
            click.echo(exc.ctx.get_help() if exc.ctx is not None else exc.format_message(), err=True)
            code = 2
        except click.ClickException as exc:  # usage and option errors: one line, exit 2
            _error_line(exc.format_message())
            code = 2
        except click.Abort as exc:  # Ctrl-C while click parsed the options
            code = _interrupted(exc.__cause__ or KeyboardInterrupt())
        except KeyboardInterrupt as exc:
            code = _interrupted(exc)
        finally:
            _restore_sigterm(previous)
        if standalone_mode:  # the process ends here
            skip_exit_collection()
            sys.exit(code)
        return code


#: click >= 8.2 raises this for a command given without arguments (it prints the help).
_NO_ARGS = getattr(click.exceptions, "NoArgsIsHelpError", ())


def _error_line(message):
    click.echo(f"penfree: error: {' '.join(str(message).split())}", err=True)


def _interrupted(exc) -> int:
    """One line for Ctrl-C / SIGTERM, true about what was written; returns 128 + signal number."""
    from ..formats.atomic import committed_outputs

    signum = exc.signum if isinstance(exc, Interrupted) else signal.SIGINT
    done = committed_outputs()
    what = "no output written" if not done else f"only {', '.join(map(str, done))} was written completely"
    name = "terminated (SIGTERM)" if signum == signal.SIGTERM else "interrupted"
    click.echo(f"penfree: {name}; {what}", err=True)
    return 128 + int(signum)


def _raise_terminated(signum, frame):
    raise Interrupted(signum)


def _catch_sigterm():
    if threading.current_thread() is not threading.main_thread():
        return None
    try:
        return signal.signal(signal.SIGTERM, _raise_terminated)
    except (ValueError, OSError):
        return None


def _restore_sigterm(previous):
    if previous is not None:
        try:
            signal.signal(signal.SIGTERM, previous)
        except (ValueError, OSError, TypeError):
            pass


@click.group(cls=PenfreeGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, prog_name="penfree")
def main():
    """Certified penetration-free affine pre-deformation of simulation frames.

    \b
      penfree deform frames.h5 -o deformed.h5
      penfree verify deformed.h5
      penfree report deformed.h5 -o report/
    """


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
