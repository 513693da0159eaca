"""Resuming a batch run: which inputs are done, keyed by the input's stamp and the result-changing options."""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from anra_torch.batch.options import BatchOptions
from anra_torch.batch.table import row_key

__all__ = ["plan"]


def _done(row: dict[str, Any], options: BatchOptions) -> bool:
    """Whether an ``ok`` row holds everything this run asks for (the diagnosis when ``diagnose``)."""
    if row.get("status") != "ok":
        return False
    return not options.diagnose or row.get("top_effect") not in (None, "")


def _stamp(path: str) -> str:
    """The ``input_stamp`` cell: size and modification time of the input (of each file of a folder video);
    "" when it cannot be read."""
    target = Path(path)
    try:
        if target.is_dir():
            files = sorted(f for f in target.iterdir() if f.is_file())
            digest = hashlib.sha256()
            for f in files:
                info = f.stat()
                digest.update(f"{f.name}\0{info.st_size}\0{info.st_mtime_ns}\n".encode())
            return f"{len(files)} files {digest.hexdigest()[:16]}"
        info = target.stat()
        return f"{info.st_size} bytes mtime_ns {info.st_mtime_ns}"
    except OSError:
        return ""


def _differences(row: dict[str, Any], parameters: dict[str, Any]) -> list[str] | None:
    """How the parameters of an ``ok`` row differ from ``parameters`` (``[]``: the same result), or None
    when the row has no readable key (an older table: recompute it).

    ``dt`` and ``dx`` compare the values used: an override equal to the file's value the row was made with
    is the same result.
    """
    try:
        before = json.loads(row.get("parameters") or "")
    except ValueError:
        return None
    if not isinstance(before, dict):
        return None
    found = []
    for key, now in parameters.items():
        old = before.get(key)
        if key in ("dt", "dx"):
            used = row.get(key)
            if now is None and old is not None:
                found.append(f"{key} {old:g} -> the file's")
            elif now is not None and (used is None or not math.isclose(used, now, rel_tol=1e-9)):
                found.append(f"{key} {'?' if used is None else format(used, 'g')} -> {now:g}")
        elif old != now:
            found.append(f"{key} {json.dumps(old)} -> {json.dumps(now)}")
    return found


def plan(
    paths: Sequence[str], table: dict[str, dict[str, Any]], options: BatchOptions, *, rerun: bool, out: Path
) -> tuple[list[str], dict[str, str], set[str]]:
    """Which inputs to process now, each one's ``input_stamp``, and which were done but have changed since.

    Args:
        paths: the inputs of this run.
        table: the rows of earlier runs by :func:`~anra_torch.batch.table.row_key`.
        options: this run's options.
        rerun: recompute ``ok`` rows made with other parameters instead of stopping.
        out: the table's path, for the message.

    Shape:
        No tensors.

    Raises:
        ValueError: an ``ok`` row made with other parameters, unless ``rerun``.
    """
    parameters = options.parameters()
    todo, stamps, changed, conflicts = [], {}, set(), {}
    for path in paths:
        stamps[path] = _stamp(path)
        row = table.get(row_key(path), {})
        differences = _differences(row, parameters) if row.get("status") == "ok" else None
        if differences and not rerun:
            conflicts[path] = differences
        elif differences is None or differences or not _done(row, options):
            todo.append(path)
        elif row.get("input_stamp") != stamps[path]:
            todo.append(path)
            changed.add(path)
    if conflicts:
        first, what = next(iter(conflicts.items()))
        more = f" and {len(conflicts) - 1} more" if len(conflicts) > 1 else ""
        raise ValueError(
            f"{out} holds results made with other parameters for {len(conflicts)} of the inputs "
            f"({first}{more}: {', '.join(what)}); recompute and replace them with --rerun (rerun=True), "
            "or write to another --out"
        )
    return todo, stamps, changed
