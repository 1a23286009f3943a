"""docs/cli.md from the commands' own --help: the reference of the command line.

``python -m pencilcal.cli.helpdoc > docs/cli.md`` writes it; a test keeps the file equal to
what this prints, so the page never drifts from the code.
"""
from __future__ import annotations


__all__ = ["cli_reference"]

_HEAD = """# Command line reference

Every command's `--help`, as `pencilcal COMMAND --help` prints it. Generated from the code
(`python -m pencilcal.cli.helpdoc > docs/cli.md`); a test keeps this page current.
"""


def _context(cmd, name, parent=None):
    # make_context applies the command's context_settings (-h) the same way on every click
    # version; a bare click.Context does so on some versions only
    return cmd.make_context(name, [], parent=parent, resilient_parsing=True,
                            max_content_width=100, terminal_width=100)


def _help(cmd, name, parent=None):
    return cmd.get_help(_context(cmd, name, parent))


def cli_reference() -> str:
    """The Markdown of docs/cli.md."""
    from .main import cli

    root = _context(cli, "pencilcal")
    parts = [_HEAD, "## pencilcal\n", "```text\n" + cli.get_help(root) + "\n```\n"]
    for name in cli.list_commands(root):
        cmd = cli.get_command(root, name)
        parts.append(f"## pencilcal {name}\n")
        parts.append("```text\n" + _help(cmd, name, root) + "\n```\n")
        for sub in sorted(getattr(cmd, "commands", {}) or {}):
            sub_ctx = _context(cmd, name, root)
            parts.append(f"### pencilcal {name} {sub}\n")
            parts.append("```text\n" + _help(cmd.commands[sub], sub, sub_ctx) + "\n```\n")
    return "\n".join(parts)


if __name__ == "__main__":  # pragma: no cover - the generator's entry point
    print(cli_reference(), end="")
