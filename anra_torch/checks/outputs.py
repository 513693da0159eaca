"""Where outputs go: never over an input, never half-written.

- :func:`check_output`: the one check of an output path every command and writer makes before it computes:
  not one of the inputs (the same file by any path), not an existing folder or device where a file goes
  (``-o /dev/null``), not an existing file where a folder goes (``--report FILE``);
- :func:`atomic_output`: a temporary file beside the target, renamed onto it when the writing succeeded and
  removed when it failed, so an interruption leaves the previous file or the new one, never a partial one
  (``anra batch``'s tables, ``anra convert``, ``save_npz``, the maps and the reports all write through it);
- :func:`write_text`: a text file written that way.
"""

from __future__ import annotations

import os
import secrets
import stat
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path

__all__ = ["atomic_output", "check_output", "write_text"]

_KINDS = {
    stat.S_ISDIR: "a folder",
    stat.S_ISCHR: "a character device",
    stat.S_ISBLK: "a block device",
    stat.S_ISFIFO: "a pipe",
    stat.S_ISSOCK: "a socket",
}


def _kind(mode: int) -> str:
    return next((name for test, name in _KINDS.items() if test(mode)), "not a regular file")


def _same(a: Path, b: Path) -> bool:
    """Whether ``a`` and ``b`` name one file (by path, or by inode where both exist: links, ``..``)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return a.resolve() == b.resolve()


def check_output(
    path: str | os.PathLike[str],
    inputs: Iterable[str | os.PathLike[str]] = (),
    *,
    name: str,
    folder: bool = False,
) -> Path:
    """``path`` as a :class:`~pathlib.Path` if an output may go there.

    Args:
        path: where the output goes (a file, or with ``folder`` a folder).
        inputs: the paths read (files or folders of frame files): the output must be none of them.
        name: the argument, for the message (``"-o"``, ``"--out"``, ``"--report"``).
        folder: the output is a folder (created if missing); else a file (replaced if it exists).

    Returns:
        The checked path.

    Shape:
        No tensors.

    Raises:
        ValueError: ``path`` is an input; a file output where a folder, a device or a pipe exists; a folder
            output where a file exists.
    """
    out = Path(path)
    for source in inputs:
        if _same(out, Path(source)):
            raise ValueError(
                f"{name} {out} is the input {source}: writing there would replace what was read; "
                "name another path"
            )
    try:
        mode = out.stat().st_mode
    except OSError:  # not there yet (or unreachable: the writing says why)
        return out
    if folder and not stat.S_ISDIR(mode):
        raise ValueError(f"{name} {out} must be a folder (DIR), got an existing file; name a folder")
    if not folder and not stat.S_ISREG(mode):
        raise ValueError(f"{name} {out} must be a file path, got {_kind(mode)}; name a file")
    return out


def _temporary(path: Path) -> Path:
    """A new, empty hidden file beside ``path`` that keeps its suffix (writers that choose a format by the
    suffix choose the same one), mode 0666 less the umask as ``open`` would make it
    (:func:`tempfile.mkstemp` makes 0600, which the rename would then keep)."""
    while True:
        temp = path.with_name(f".{path.stem}.{secrets.token_hex(6)}.tmp{path.suffix}")
        try:
            os.close(os.open(temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return temp
        except FileExistsError:  # pragma: no cover - 48 random bits
            continue


@contextmanager
def atomic_output(path: str | os.PathLike[str]) -> Iterator[Path]:
    """Write ``path`` atomically: the block writes the temporary path it is given (beside ``path``, same
    suffix); when the block ends without error the file is renamed onto ``path`` (:func:`os.replace`),
    otherwise it is removed and ``path`` is left as it was. The parent folders are created.

    Shape:
        No tensors.

    Raises:
        OSError: the folder cannot be written, or the rename fails (the temporary file is removed).

    Example:
        >>> import tempfile
        >>> target = Path(tempfile.mkdtemp()) / "notes.txt"
        >>> with atomic_output(target) as temp:
        ...     _ = temp.write_text("whole")
        >>> target.read_text(), sorted(p.name for p in target.parent.iterdir())
        ('whole', ['notes.txt'])
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    temp = _temporary(target)
    try:
        yield temp
        os.replace(temp, target)
    except BaseException:
        temp.unlink(missing_ok=True)
        raise


def write_text(path: str | os.PathLike[str], text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically (:func:`atomic_output`); returns the path.

    Shape:
        No tensors.

    Raises:
        OSError: the file cannot be written.
    """
    with atomic_output(path) as temp:
        temp.write_text(text, encoding="utf-8")
    return Path(path)
