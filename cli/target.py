"""`pencilcal target`: the printable sheet (ChArUco board and a fan of spokes, or a Siemens star) at true
scale."""
from __future__ import annotations

from pathlib import Path

import click

from .common import (command, check_output, done, FiniteFloat, force_option, output_option, quiet_option, run)


def _parse_squares(text):
    try:
        nx, ny = (int(v) for v in text.lower().replace(",", "x").split("x"))
    except ValueError:
        raise click.BadParameter(f"expected NxM such as 7x5, got {text!r}", param_hint="--board-squares") from None
    return nx, ny


@command()
@output_option
@click.option("--paper", type=click.Choice(["a4", "a3", "letter"]), default="a4", show_default=True, help="Paper size.")
@click.option("--orientation", type=click.Choice(["landscape", "portrait"]), default="landscape", show_default=True)
@click.option("--dpi", type=FiniteFloat(min=10, max=2400), default=300.0, show_default=True,
              help="PNG resolution [dots per inch].")
@click.option("--board-squares", default="7x5", show_default=True, help="ChArUco squares along x and y, NxM.")
@click.option("--square", type=FiniteFloat(min=0, min_open=True), default=25.0, show_default=True,
              help="Square side [mm].")
@click.option("--marker", type=FiniteFloat(min=0, min_open=True), default=18.0, show_default=True,
              help="Marker side [mm].")
@click.option("--dictionary", default="DICT_5X5_100", show_default=True, help="cv2.aruco predefined dictionary.")
@click.option("--legacy", is_flag=True, help="ChArUco layout of OpenCV < 4.6.")
@click.option("--spokes", type=click.IntRange(min=3), default=8, show_default=True, help="Number of spokes.")
@click.option("--step-deg", type=FiniteFloat(), default=20.0, show_default=True, help="Angle between spokes [deg].")
@click.option("--start-deg", type=FiniteFloat(), default=None,
              help="Angle of the first spoke [deg]; default: away from the board.")
@click.option("--radius", type=(FiniteFloat(), FiniteFloat()), default=(15.0, 80.0), show_default=True,
              help="Inner and outer end of the spokes [mm].")
@click.option("--width", type=FiniteFloat(min=0, min_open=True), default=1.0, show_default=True,
              help="Width of the printed spokes (dark bars) [mm].")
@click.option("--side", type=click.Choice(["right", "below"]), default="right", show_default=True,
              help="Where the fan (or the star) goes relative to the board.")
@click.option("--star", type=click.IntRange(min=4, max=180), default=None, metavar="N",
              help="A Siemens star of N dark wedges instead of the fan (its wedges and gaps equal, its outline a "
                   "circle): a focus target that doubles as the orientation target.")
@click.option("--star-radius", type=FiniteFloat(min=0, min_open=True), default=None,
              help="With --star: the star's radius [mm]; default the largest whole millimetre that fits beside "
                   "the board.")
@click.option("--margin", type=FiniteFloat(min=0), default=10.0, show_default=True,
              help="Blank border kept on the paper [mm].")
@force_option
@quiet_option
@run
def target(output, paper, orientation, dpi, board_squares, square, marker, dictionary, legacy, spokes, step_deg,
           start_deg, radius, width, side, star, star_radius, margin, force, quiet):
    """Write a printable target: a ChArUco board with a fan of spokes (or a Siemens star) beside it.

    \b
    Examples:
      pencilcal target -o target.pdf
      pencilcal target -o target.png --dpi 600 --paper letter --spokes 10

    A PDF or PNG at true scale (print at 100 %), with board.yaml and pencil.yaml beside it.
    Measure a square after printing: it must be --square mm. In detail: docs/cli.md.
    \f
    The output is a PDF (vector, the page exactly the paper size) or a PNG (at --dpi, with
    the dpi in its metadata); either prints at true scale when printed at 100 % ("actual
    size", no "fit to page"). board.yaml and pencil.yaml are written beside it and state
    exactly what is printed: the board, and the spokes' angles, vertex, radius and width in
    the board frame (x right, y down, origin at the board's outer corner, mm). The fan goes
    to the right of the board or below it (--side); the first spoke's angle defaults to
    the fan opening away from the board. --margin is the blank border kept on the paper
    (printers cannot print to the edge). Measure a square after printing; it must be
    --square millimetres.

    With --star N the fan is a Siemens star of N dark wedges, each as wide as the gap beside
    it, from the vertex out to --star-radius, their outer ends arcs of one circle: the pencil
    file says shape wedge, and circles [radius], whose image resolves the twin and gives the
    plane a second time (`pencilcal orient`). The fan's options (--spokes, --step-deg,
    --start-deg, --radius, --width) do not apply.

    More examples:

        pencilcal target -o star.pdf --paper a3 --star 64
    """
    from pencilcal.toolkit.board.spec import board_from_dict, write_board
    from pencilcal.toolkit.pencil.spec import write_pencil
    from pencilcal.toolkit.synth.sheet import layout_sheet, write_sheet_pdf, write_sheet_png

    out = Path(output)
    suffix = out.suffix.lower()
    if suffix not in (".pdf", ".png"):
        raise click.BadParameter(f"the target must be a .pdf or .png file, got {out.name!r}", param_hint="-o/--output")
    if star is None and star_radius is not None:
        raise click.BadParameter("only with --star", param_hint="--star-radius")
    if star is not None:
        ctx = click.get_current_context()
        given = [f"--{n.replace('_', '-')}" for n in ("spokes", "step_deg", "start_deg", "radius", "width")
                 if ctx.get_parameter_source(n) != click.core.ParameterSource.DEFAULT]
        if given:
            raise click.UsageError(f"{', '.join(given)}: options of the fan, not of --star")
    nx, ny = _parse_squares(board_squares)
    board = board_from_dict({"type": "charuco", "squares": [nx, ny], "square": square, "marker": marker,
                             "dictionary": dictionary, "legacy": legacy}, source="board options")
    sheet = layout_sheet(board, paper=paper, orientation=orientation, margin=margin, spokes=spokes,
                         step_deg=step_deg, start_deg=start_deg, radius=radius, width=width, side=side, star=star,
                         star_radius=star_radius)
    board_path = out.parent / "board.yaml"
    pencil_path = out.parent / "pencil.yaml"
    for p in (out, board_path, pencil_path):
        check_output(p, force)
    if suffix == ".pdf":
        write_sheet_pdf(out, sheet, force=force)
    else:
        write_sheet_png(out, sheet, dpi=dpi, force=force)
    write_board(board_path, board, force=force)
    write_pencil(pencil_path, sheet.pencil, force=force)
    if not quiet:
        v, p = sheet.pencil.vertex, sheet.pencil
        what = f"a star of {p.count} wedges, radius {p.radius[1]:g} mm," if star else f"{spokes} spokes"
        done(f"{sheet.paper}: board {nx}x{ny} x {square:g} mm, {what} at vertex ({v[0]:g}, {v[1]:g}) mm",
             out, board_path, pencil_path)
