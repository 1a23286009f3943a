"""docs/cli.md from the commands' own --help: the reference of the command line.

``python -m pencilcal.cli.helpdoc > docs/cli.md`` writes it; a test keeps the file equal to
what this prints, so the page never drifts from the code. A command's --help fits a screen
(usage, two examples, a few lines, one line per option); what it has to say at length is
written in its docstring after a form feed (``\\f``: click shows nothing after it) and
printed here under "In detail", with the options several commands share
(`common.SHARED_DETAILS`) at the end.
"""
from __future__ import annotations


__all__ = ["cli_reference"]

_HEAD = """# Command line reference

Every command's `--help`, as `pencilcal COMMAND --help` prints it, and what the command
does in detail. Generated from the code (`python -m pencilcal.cli.helpdoc > docs/cli.md`);
a test keeps this page current.

Exit status: 0 on success; 1 with one line on stderr (`pencilcal: error: ...`) when the
input cannot be used or processing fails; 2 with one line (`pencilcal: usage error: ...`)
for a missing or malformed option or argument; 130, 143 or 129 when Ctrl-C, SIGTERM or a
closed terminal stopped it, its outputs then not written and the earlier ones kept byte for
byte (docs/faults.md: what is guaranteed on an interrupt, a full disk, bad input, and the
limits on what a user can make large).
"""


def _context(cmd, name, parent=None):
    # make_context applies the command's context_settings (-h) the same way on every click
    # version; a bare click.Context does so on some versions only
    return cmd.make_context(name, [], parent=parent, resilient_parsing=True,
                            max_content_width=100, terminal_width=100)


def _help(cmd, name, parent=None):
    return cmd.get_help(_context(cmd, name, parent))


def _details(cmd):
    """A command's text after the form feed of its docstring, as Markdown ("" when none)."""
    import inspect

    rest = inspect.cleandoc(cmd.help or "").partition("\f")[2].strip("\n")
    return inspect.cleandoc(rest) + "\n" if rest.strip() else ""


def _command_parts(cmd, title, help_text):
    parts = [title, "```text\n" + help_text + "\n```\n"]
    more = _details(cmd)
    if more:
        parts.append("In detail:\n\n" + more)
    return parts


def _shared():
    """The options several commands share, in detail."""
    from .common import SHARED_DETAILS

    rows = "".join(f"- `{k}`: {v}\n" for k, v in SHARED_DETAILS.items())
    return "## Options several commands share\n\n" + rows


def cli_reference() -> str:
    """The Markdown of docs/cli.md."""
    from .main import cli

    root = _context(cli, "pencilcal")
    parts = [_HEAD, "## pencilcal\n", "```text\n" + cli.get_help(root) + "\n```\n"]
    for name in cli.list_commands(root):
        cmd = cli.get_command(root, name)
        parts += _command_parts(cmd, f"## pencilcal {name}\n", _help(cmd, name, root))
        for sub in sorted(getattr(cmd, "commands", {}) or {}):
            sub_ctx = _context(cmd, name, root)
            parts += _command_parts(cmd.commands[sub], f"### pencilcal {name} {sub}\n",
                                    _help(cmd.commands[sub], sub, sub_ctx))
    parts.append(_shared())
    return "\n".join(parts)


if __name__ == "__main__":  # pragma: no cover - the generator's entry point
    print(cli_reference(), end="")
