"""README's Python snippet prints what README says it prints, and what it prints is right."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

README = Path(__file__).resolve().parents[1] / "README.md"


def _snippet_and_output():
    text = README.read_text()
    m = re.search(r"```python\n(.*?)```\s*\nprints\s*\n\s*```text\n(.*?)```", text, re.S)
    assert m, "README: a ```python block followed by 'prints' and its ```text output"
    return m.group(1), m.group(2)


def test_readme_snippet_prints_its_shown_output(tmp_path):
    code, shown = _snippet_and_output()
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert r.stdout == shown


def test_readme_snippet_is_right():
    """The truth it prints beside the estimate is the truth: the tilt within 2 sigma of it,
    the estimate ambiguous, one twin within a degree and the prior choosing that one."""
    _, shown = _snippet_and_output()
    tilt, sigma, truth = map(float, re.search(r"tilt ([\d.]+) \+- ([\d.]+) deg, truth ([\d.]+)", shown).groups())
    assert abs(tilt - truth) < 2 * sigma
    normal, twin = map(float, re.search(r"normal ([\d.]+) deg from the truth, normal_twin ([\d.]+) deg", shown).groups())
    assert "ambiguous True" in shown and min(normal, twin) < 1.0 < max(normal, twin)
    chosen = float(re.search(r"with the prior: ([\d.]+) deg", shown).group(1))
    assert chosen == min(normal, twin)
