"""The `pencilcal` command group."""
from __future__ import annotations

import importlib

import click

from .common import CONTEXT_SETTINGS, Group, Stopped, install_signal_handlers, release_signal_handlers, stopped_status

# command name -> its module in this package: a command's module (and what it imports:
# OpenCV, scipy, pycolmap, matplotlib) is loaded only when that command runs, so a live
# `pencilcal orient` does not pay for the others' imports at start-up
COMMANDS = {
    "bench": "bench", "calibrate": "calibrate", "convert": "convert", "demo": "demo", "experiment": "experiment",
    "fulcrum": "fulcrum", "lines": "lines", "orient": "orient", "pnp": "pnp", "report": "report",
    "score": "score", "sensitivity": "sensitivity", "sfm": "sfm", "simulate": "simulate", "target": "target", "validate": "validate",
}


class LazyGroup(Group):
    """A click group whose commands are imported when first asked for (`COMMANDS`)."""

    def list_commands(self, ctx):
        return sorted(set(COMMANDS) | set(self.commands))

    def get_command(self, ctx, name):
        if name not in self.commands and name in COMMANDS:
            module = importlib.import_module(f"{__package__}.{COMMANDS[name]}")
            self.add_command(getattr(module, name.replace("-", "_")), name)
        return self.commands.get(name)


def _print_version(ctx, _param, value):
    """--version: the installed version ("0+unknown" from a source tree without installing),
    looked up only when asked for: importing importlib.metadata cost every command ~15 ms
    of start-up."""
    if not value or ctx.resilient_parsing:
        return
    from importlib.metadata import PackageNotFoundError, version

    try:
        v = version("pencilcal")
    except PackageNotFoundError:
        v = "0+unknown"
    click.echo(f"pencilcal, version {v}")
    ctx.exit()


@click.group(cls=LazyGroup, context_settings=CONTEXT_SETTINGS)
@click.option("--version", is_flag=True, expose_value=False, is_eager=True, callback=_print_version,
              help="Show the version and exit.")
@click.option("--debug", is_flag=True, help="Show the traceback of an internal error instead of one line.")
def cli(debug):
    """pencilcal: orientation of a pencil of lines from its image angles.

    \b
    Examples:
      pencilcal demo
      pencilcal orient frames/ --camera cam.yaml --pencil pencil.yaml -o o.json

    A camera sees a pencil (straight lines through one point: a printed fan of spokes, an
    instrument pivoting about its port). From the image angles alone pencilcal recovers the
    plane's orientation, the vertex and its viewing ray, and how far to trust them.

    Conventions: OpenCV camera frame (x right, y down, z forward); transforms named
    a_from_b; angles in degrees in files and options. Exit status: 0 done; 1 an input
    that cannot be used or a failure (one line); 2 a usage error (one line); 130, 143 stopped
    by Ctrl-C or SIGTERM (earlier outputs kept: docs/faults.md).
    """


def main():
    """The command line, with pencilcal's stop signals (`common.install_signal_handlers`):
    a signal outside a command's body (while click parses, while a command's module is
    imported) ends it with the same line and status as inside; once the outcome is settled
    a late signal is ignored."""
    install_signal_handlers()
    try:
        cli(prog_name="pencilcal")
    except Stopped as e:
        raise SystemExit(stopped_status(e.signum)) from None
    finally:
        release_signal_handlers()


if __name__ == "__main__":
    main()
