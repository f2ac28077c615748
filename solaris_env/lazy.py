"""Module attributes imported on first use (PEP 562), so importing a package stays cheap."""

import importlib


def lazy_getattr(package: str, table: dict[str, str]):
    """A module ``__getattr__`` that returns ``table[name]``'s attribute ``name`` (importing that module then)."""

    def __getattr__(name: str):
        if name in table:
            return getattr(importlib.import_module(table[name]), name)
        raise AttributeError(f"module {package!r} has no attribute {name!r}")

    return __getattr__
