"""Every command's --help fits a screen and leads with usage and two examples; every usage
error is one line with exit status 2 (docs/cli.md, README)."""
from __future__ import annotations

import re

import pytest
from click.testing import CliRunner

from pencilcal.cli.main import COMMANDS, cli

#: the most lines a --help may have, on an 80-column terminal
MAX_LINES = 60


def _all_commands():
    out = [()]
    for name in sorted(COMMANDS):
        out.append((name,))
        cmd = cli.get_command(None, name)
        out += [(name, sub) for sub in sorted(getattr(cmd, "commands", {}) or {})]
    return out


@pytest.mark.parametrize("path", _all_commands(), ids=lambda p: " ".join(p) or "pencilcal")
def test_help_fits_a_screen_and_leads_with_examples(path):
    # click wraps a terminal's width less 2: 78 is what an 80-column terminal shows
    r = CliRunner().invoke(cli, [*path, "--help"], terminal_width=78, prog_name="pencilcal")
    assert r.exit_code == 0, r.output
    lines = r.output.rstrip("\n").splitlines()
    assert len(lines) <= MAX_LINES, f"{' '.join(path)} --help: {len(lines)} lines"
    assert "None" not in r.output, "an open range or default shown as None (x<=None)"
    assert lines[0].startswith(f"Usage: pencilcal {' '.join(path)}".rstrip())
    # the one-line summary, then the examples, before any explanation
    text = [ln.strip() for ln in lines[1:] if ln.strip()]
    k = text.index("Examples:")
    assert k <= 3, f"{' '.join(path)}: the examples come after {k} lines of text"
    examples = text[k + 1:k + 3]
    assert len(examples) == 2 and all(e.startswith("pencilcal ") for e in examples), examples
    # an example fits the 80 columns it is shown in
    assert all(len(ln) <= 80 for ln in lines if ln.strip().startswith("pencilcal ")), path


@pytest.mark.parametrize("path", [p for p in _all_commands() if p], ids=" ".join)
def test_usage_error_is_one_line_with_status_2(path):
    r = CliRunner().invoke(cli, [*path, "--no-such-option"], prog_name="pencilcal")
    assert r.exit_code == 2, r.output
    assert r.stdout == ""
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pencilcal: usage error: No such option"), r.stderr
    assert f"'pencilcal {' '.join(path)} --help'" in err[0]


@pytest.mark.parametrize("args, message", [
    (["orient", "frames/"], "Missing option '--camera'"),
    (["report", "v.json"], "Missing option '-o'"),
    (["report", "v.json", "-o", "r.docx"], ".html or .pdf"),
    (["simulate", "out", "--scenario", "orbit", "--frames", "0"], "0 is not in the range 1<=x<=100000"),
    (["orient", "--camera", "c.json", "--pencil", "p.yaml", "-o", "o.json"], "give IMAGES, --source or --lines"),
    (["nonsense"], "No such command 'nonsense'"),
    (["experiment", "nonsense"], "No such command 'nonsense'"),
])
def test_missing_or_malformed_options_are_one_line(args, message, tmp_path):
    with CliRunner().isolated_filesystem(temp_dir=tmp_path):
        r = CliRunner().invoke(cli, args, prog_name="pencilcal")
    assert r.exit_code == 2, r.output
    err = r.stderr.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pencilcal: usage error: ") and message in err[0], r.stderr


def test_no_arguments_still_shows_the_help():
    r = CliRunner().invoke(cli, [], prog_name="pencilcal")
    assert "Usage: pencilcal" in r.output and "Commands:" in r.output


def test_ranges_say_their_bounds():
    # a bounded option says its bounds; an unbounded one says nothing (never "x<=None")
    r = CliRunner().invoke(cli, ["simulate", "--help"], terminal_width=200, prog_name="pencilcal")
    assert re.search(r"--noise FLOAT .*0<=x<=255", r.output)
    r = CliRunner().invoke(cli, ["sensitivity", "--help"], terminal_width=200, prog_name="pencilcal")
    assert re.search(r"--focal PX .*\[default: 800\.0\]", r.output) and "x<=" not in r.output
