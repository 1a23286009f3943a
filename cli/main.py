"""The `pencilcal` command group."""
from __future__ import annotations

from importlib.metadata import PackageNotFoundError, version

import click

from .bench import bench
from .calibrate import calibrate
from .convert import convert
from .common import CONTEXT_SETTINGS, install_signal_handlers
from .demo import demo
from .experiment import experiment
from .fulcrum import fulcrum
from .lines import lines
from .orient import orient
from .pnp import pnp
from .report import report
from .sensitivity import sensitivity
from .sfm import sfm
from .simulate import simulate
from .target import target
from .validate import validate

try:
    __version__ = version("pencilcal")
except PackageNotFoundError:  # running from a source tree without installing
    __version__ = "0+unknown"


@click.group(context_settings=CONTEXT_SETTINGS)
@click.version_option(__version__, prog_name="pencilcal")
@click.option("--debug", is_flag=True, help="Show the traceback of an internal error instead of one line.")
def cli(debug):
    """pencilcal: orientation of a pencil of lines from its image angles.

    A camera sees a pencil (straight lines through one point: a printed fan of spokes, an
    instrument pivoting about its port). From the image angles alone pencilcal recovers the
    plane's orientation, the vertex and its viewing ray, and how far to trust them.

    Conventions: OpenCV camera frame (x right, y down, z forward); transforms named
    a_from_b; angles in degrees in files and options.
    """


cli.add_command(bench)
cli.add_command(calibrate)
cli.add_command(demo)
cli.add_command(convert)
cli.add_command(experiment)
cli.add_command(orient)
cli.add_command(fulcrum)
cli.add_command(lines)
cli.add_command(pnp)
cli.add_command(report)
cli.add_command(sensitivity)
cli.add_command(sfm)
cli.add_command(simulate)
cli.add_command(target)
cli.add_command(validate)


def main():
    install_signal_handlers()
    cli(prog_name="pencilcal")


if __name__ == "__main__":
    main()
