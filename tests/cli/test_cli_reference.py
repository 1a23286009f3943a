"""docs/cli.md is every command's --help as the code prints it now."""
from __future__ import annotations

from pathlib import Path

from pencilcal.cli.helpdoc import cli_reference

DOC = Path(__file__).resolve().parents[2] / "docs" / "cli.md"


def test_docs_cli_md_is_current():
    assert DOC.read_text() == cli_reference(), \
        "docs/cli.md is stale: regenerate it with `python -m pencilcal.cli.helpdoc > docs/cli.md`"
