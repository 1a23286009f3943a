"""Lazy exports of a package's `__init__` (PEP 562): a name is imported when first used.

A subpackage's `__init__` names what it offers (``from pencilcal.toolkit.pencil import
orient_segments``) without importing every module behind those names: importing one module
of the package (``pencilcal.toolkit.pencil.orient``) then does not import the others and
their dependencies (scipy.stats, pycolmap, matplotlib), which is what a command's start-up
pays for.

Example
-------
>>> __getattr__, __dir__ = lazy_exports("pencilcal.toolkit.geometry", {"angles": ["wrap_angle"]})
>>> float(__getattr__("wrap_angle")(7.0)) < 3.15
True
"""
from __future__ import annotations

import importlib
import sys

__all__ = ["lazy_exports"]


def lazy_exports(package, modules):
    """(__getattr__, __dir__) for the package named `package` whose names, `modules`
    (module within the package -> the names it defines), are imported on first use and then
    kept in its namespace."""
    exports = {name: module for module, names in modules.items() for name in names}

    def __getattr__(name):
        if name not in exports:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{exports[name]}"), name)
        setattr(sys.modules[package], name, value)
        return value

    def __dir__():
        return sorted(set(vars(sys.modules[package])) | set(exports))

    return __getattr__, __dir__
