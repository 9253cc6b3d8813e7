"""The ``penfree`` command line: thin layers over the library.

Every command parses, calls the library and prints. Errors map to exit codes:
0 success, 1 a check failed, 2 unusable input or arguments (one line on stderr).
"""

import importlib
import sys

import click

from .._version import __version__
from ..errors import InputError

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
            click.echo(f"penfree: error: {exc}", err=True)
            ctx.exit(2)
        except KeyboardInterrupt:
            click.echo("penfree: interrupted; no output written", err=True)
            ctx.exit(130)


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
