"""The code's structural rules, checked on the source (docs/codemap.md says why they hold).

- no module imports another module's private names (``from x import _y``);
- no import cycles between pencilcal's modules (imports inside functions count too);
- dependencies go one way: cli -> validation -> toolkit (and the API, pencilcal/__init__,
  on validation and toolkit), and inside toolkit along LAYERS;
- no source file over 1,000 lines, no function over 120 (docstring excluded).
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TOP = {"toolkit": "pencilcal.toolkit", "validation": "pencilcal.validation", "cli": "pencilcal.cli",
       "pencilcal": "pencilcal"}
MAX_FILE_LINES = 1000
MAX_FUNCTION_LINES = 120

# What each part of pencilcal may import (besides itself). Subpackages of toolkit are named
# by their first component; a module directly in toolkit/ (errors, lazy) by its own name.
# the base every part may import: the error types and the lazy exports of the packages
BASE = {"toolkit.errors", "toolkit.lazy"}
LAYERS = {
    "toolkit.errors": set(),
    "toolkit.lazy": set(),
    "toolkit.geometry": BASE,
    "toolkit.io": BASE | {"toolkit.geometry"},
    "toolkit.camera": BASE | {"toolkit.geometry", "toolkit.io"},
    "toolkit.board": BASE | {"toolkit.geometry", "toolkit.io", "toolkit.camera"},
    "toolkit.pencil": BASE | {"toolkit.geometry", "toolkit.io", "toolkit.camera"},
    "toolkit.detect": BASE | {"toolkit.geometry", "toolkit.io", "toolkit.camera", "toolkit.pencil"},
    "toolkit.draw": BASE | {"toolkit.geometry", "toolkit.io", "toolkit.camera", "toolkit.pencil"},
    "toolkit.synth": BASE | {"toolkit.geometry", "toolkit.io", "toolkit.camera", "toolkit.board", "toolkit.pencil"},
}

def _modules():
    """{dotted name: path} of every source module of the three packages."""
    out = {}
    for folder, dotted in TOP.items():
        paths = [REPO / folder / "__init__.py"] if folder == "pencilcal" else sorted((REPO / folder).rglob("*.py"))
        for path in paths:
            rel = path.relative_to(REPO / folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            out[".".join([dotted, *parts])] = path
    return out


MODULES = _modules()


def _resolve(name: str, level: int, here: str, is_pkg: bool) -> str:
    if level == 0:
        return name
    base = here.split(".")
    base = base if is_pkg else base[:-1]
    base = base[: len(base) - (level - 1)]
    return ".".join(base + ([name] if name else []))


def _imports(mod: str, path: Path):
    """(imported module, names taken from it, line) for every import in the file."""
    tree = ast.parse(path.read_text())
    is_pkg = path.name == "__init__.py"
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                yield a.name, [], node.lineno
        elif isinstance(node, ast.ImportFrom):
            target = _resolve(node.module or "", node.level, mod, is_pkg)
            names = [a.name for a in node.names]
            # "from pkg import module" imports the module
            subs = [n for n in names if f"{target}.{n}" in MODULES]
            for n in subs:
                yield f"{target}.{n}", [], node.lineno
            rest = [n for n in names if n not in subs]
            if rest:
                yield target, rest, node.lineno


def _owner(mod: str):
    """The module an import lands in (the longest known prefix), or None if not ours."""
    while mod and mod not in MODULES:
        mod = mod.rpartition(".")[0]
    return mod or None


def _graph():
    g = {}
    for mod, path in MODULES.items():
        g[mod] = {}
        for target, names, line in _imports(mod, path):
            owner = _owner(target)
            if owner and owner != mod:
                g[mod].setdefault(owner, (names, line))
    return g


def _layer(mod: str) -> str:
    parts = mod.split(".")[1:]          # drop "pencilcal"
    return ".".join(parts[:2])


def test_no_private_names_across_modules():
    bad = []
    for mod, path in MODULES.items():
        for target, names, line in _imports(mod, path):
            owner = _owner(target)
            if not owner or owner == mod:
                continue
            private = [n for n in names if n.startswith("_")]
            if private or target.rpartition(".")[2].startswith("_"):
                bad.append(f"{path.relative_to(REPO)}:{line} takes {private or target} from {owner}")
    assert not bad, "\n".join(bad)


def test_no_import_cycles():
    g = _graph()
    state, stack, cycles = {}, [], []

    def visit(m):
        state[m] = 1
        stack.append(m)
        for n in g.get(m, {}):
            if state.get(n) == 1:
                cycles.append(" -> ".join(stack[stack.index(n):] + [n]))
            elif n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(g):
        if m not in state:
            visit(m)
    assert not cycles, "\n".join(cycles)


def test_dependencies_go_one_way():
    # the public API (pencilcal/__init__) sits on the library, beside the command line
    order = {"pencilcal.toolkit": 0, "pencilcal.validation": 1, "pencilcal": 2, "pencilcal.cli": 2}
    bad = []
    for mod, deps in _graph().items():
        top = ".".join(mod.split(".")[:2])
        for dep, (_, line) in deps.items():
            dtop = ".".join(dep.split(".")[:2])
            if top == "pencilcal" and dtop == "pencilcal.cli" or top == "pencilcal.cli" and dtop == "pencilcal":
                bad.append(f"{MODULES[mod].relative_to(REPO)}:{line} imports {dep} (the API and the CLI are apart)")
                continue
            where = f"{MODULES[mod].relative_to(REPO)}:{line} imports {dep}"
            if order[dtop] > order[top]:
                bad.append(where)
            elif top == dtop == "pencilcal.toolkit":
                here, there = _layer(mod), _layer(dep)
                if here != there and here in LAYERS and there not in LAYERS[here]:
                    bad.append(where + f" ({here} may import only {sorted(LAYERS[here])})")
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("mod", sorted(MODULES))
def test_sizes(mod):
    path = MODULES[mod]
    text = path.read_text()
    n = text.count("\n")
    assert n <= MAX_FILE_LINES, f"{path.relative_to(REPO)} has {n} lines (at most {MAX_FILE_LINES})"
    long = []
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(getattr(body[0], "value", None), ast.Constant) \
                    and isinstance(body[0].value.value, str):
                body = body[1:]
            if not body:
                continue
            length = body[-1].end_lineno - body[0].lineno + 1
            if length > MAX_FUNCTION_LINES:
                long.append(f"{node.name} ({length} lines)")
    assert not long, f"{path.relative_to(REPO)}: functions over {MAX_FUNCTION_LINES} lines: {', '.join(long)}"
