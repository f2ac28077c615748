"""Paths as they may be written into anything that gets committed: result JSONs, plot legends, lineage records.

An absolute path names one machine's layout (``/work/...``, ``/home/<user>/...``, a ``/tmp`` scratch folder) and
means nothing anywhere else, so the scripts of ``benchmarks/``, ``agents/`` and ``training/`` record

* :func:`portable_path`: a path, repository-relative when it lies under the repository root, else its last
  components (``parent/name``), never absolute;
* :func:`portable_text`: a command line, spec or note (``ppo:/abs/step.zip``, ``--out /abs/x``, a plain name)
  with every absolute path in it made portable and everything else kept as given.

``tests/test_no_absolute_paths.py`` scans the committed results and docs for absolute paths. Standard library only.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parent.parent


def portable_path(path: str | os.PathLike, parts: int = 2) -> str:
    """``path`` relative to the repository root when it lies under it (a relative path counts from the current
    directory), else its last ``parts`` components joined by ``/``; never absolute (the root itself is ``.``)."""
    if parts < 1:
        raise ValueError(f"parts must be >= 1, got {parts}")
    given = Path(os.path.expanduser(os.fspath(path)))
    for candidate in (Path(os.path.abspath(given)), given.resolve()):
        for root in (REPO_ROOT, Path(os.path.abspath(REPO_ROOT))):
            try:
                return candidate.relative_to(root).as_posix() or "."
            except ValueError:
                continue
    absolute = Path(os.path.abspath(given))
    tail = absolute.parts[1:] if absolute.anchor else absolute.parts  # without the leading "/"
    return "/".join(tail[-parts:]) or "."


# an absolute path: at the start, after white space, ':', '=' or an opening bracket/quote; not a '//' URL part
_ABSOLUTE = re.compile(r"""(^|[\s:=(\[{,'"`])(/(?![/\s])[^\s:=,;'"`)\]}]+)""")


def portable_text(text: str, parts: int = 2) -> str:
    """A command line, spec or note with each absolute path in it (at its start or after white space, ``:``,
    ``=``, a bracket or a quote) replaced by :func:`portable_path`: ``ppo:/x/runs/a/step.zip`` ->
    ``ppo:a/step.zip``; ``default``, ``runs/x``, ``8 / 16`` and ``http://host/`` are returned unchanged."""
    return _ABSOLUTE.sub(lambda m: m.group(1) + portable_path(m.group(2), parts), str(text))
