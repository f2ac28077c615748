"""Reading the JSON configs of ``training/configs/``, where one file may extend another.

A config with ``"extends": "<name>"`` starts from ``<name>.json`` in the same directory (itself possibly
extending another) and overrides it: a key whose value is an object in both files merges key by key, any
other value replaces the base's. So a preset that trains like ``tiny`` needs only its differences
(docs/training.md, "Stage configs").
"""

from __future__ import annotations

import json
from pathlib import Path


def merge(base: dict, override: dict) -> dict:
    """``base`` with ``override`` on top; objects present in both merge recursively."""
    out = dict(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = merge(out[key], value)
        else:
            out[key] = value
    return out


def read_json_config(path: str | Path) -> dict:
    """The JSON object at ``path`` with its ``extends`` chain resolved (the key itself removed)."""
    path = Path(path)
    chain: list[Path] = []
    while True:
        if path in chain:
            raise ValueError(f"config 'extends' cycle: {' -> '.join(p.name for p in chain + [path])}")
        if not path.is_file():
            where = f" (extended by {chain[-1]})" if chain else ""
            raise FileNotFoundError(f"no config file {path}{where}")
        chain.append(path)
        data = json.loads(path.read_text())
        if not isinstance(data, dict):
            raise ValueError(f"{path}: a config must be a JSON object, got {type(data).__name__}")  # noqa: TRY004
        base = data.get("extends")
        if base is None:
            break
        if not isinstance(base, str) or not base or "/" in base or base.endswith(".json"):
            raise ValueError(f"{path}: extends must be the name of a config in the same directory "
                             f"(e.g. \"tiny\"), got {base!r}")
        path = path.parent / f"{base}.json"
    out: dict = {}
    for p in reversed(chain):
        data = json.loads(p.read_text())
        data.pop("extends", None)
        out = merge(out, data)
    return out
