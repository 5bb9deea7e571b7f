"""A package's public names loaded when first used (PEP 562), as scientific Python's ``lazy_loader``
does, so that importing a package imports none of its modules until a name is asked for."""

from __future__ import annotations

import importlib
import sys


def attach(package, exports, *, before=None):
    """``(__getattr__, __dir__, names)`` for the package named `package` (its ``__name__``).

    `exports` maps each public name to the module, relative to the package, that defines it; the
    module is imported when the name is first used and the name then kept in the package's
    namespace. `before`, if given, is called before each such import (the dependency check).

    Examples
    --------
    In a package's ``__init__.py``:

    >>> __getattr__, __dir__, __all__ = attach("json", {"JSONDecodeError": "decoder"})
    >>> __getattr__("JSONDecodeError").__name__
    'JSONDecodeError'
    """
    namespace = sys.modules[package].__dict__

    def __getattr__(name):
        module = exports.get(name)
        if module is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        if before is not None:
            before()
        value = getattr(importlib.import_module(f".{module}", package), name)
        namespace[name] = value
        return value

    def __dir__():
        return sorted(set(namespace) | set(exports))

    return __getattr__, __dir__, sorted(exports)
