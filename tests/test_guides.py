"""Every guide's code blocks run as pasted: the Python (a ``literalinclude`` as the page shows it) and every
``anra`` command of its shell blocks, in order, in an empty folder holding the files the guide names.

The files a guide names but does not make are small stand-ins made here (a camera's ``.npy``, a plate, a
FLIR ``.seq`` / ``.csq``, a burn, a thermocouple trace, folders of videos, a calibration table); ``VIDEO``
is the page's placeholder for the reader's recording. ``../shared/data`` is resolved to the measured data
beside the repository, and a page that needs it is left out when it is absent.
"""

from __future__ import annotations

import re
import shlex
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import torch
from commands import run
from depth_scenes import burn_video
from fff_writer import Camera, counts_for, simple_frame
from shared_data import DATA

from anra_torch.simulation import FlashPlate, blobs_video, flash_plate_video
from anra_torch.video import save_npz

ROOT = Path(__file__).resolve().parents[1]
GUIDES = sorted((ROOT / "docs" / "guides").glob("*.md")) + [ROOT / "docs" / "getting-started.md"]
PLACEHOLDERS = {"VIDEO": "burn.npz"}
"""A page's placeholder for the reader's file -> the stand-in made here."""
FENCE = re.compile(r"^```(\w+|\{literalinclude\} (\S+))\n(.*?)^```", re.M | re.S)


def blocks(page: Path) -> list[tuple[str, str]]:
    """The page's code blocks as ``(language, text)``; a ``literalinclude`` as the page shows it (from its
    ``:start-at:`` line)."""
    found = []
    for head, include, body in FENCE.findall(page.read_text()):
        if not include:
            found.append((head, body))
            continue
        options = dict(re.findall(r"^:([\w-]+):\s*(.*)$", body, re.M))
        text = (page.parent / include).read_text()
        start = text.index(options["start-at"]) if "start-at" in options else 0
        found.append((options.get("language", "text"), text[start:]))
    return found


def commands(page: Path) -> list[list[str]]:
    """The ``anra`` commands of the page's shell blocks (the install block's ``make``, ``git`` and ``pip``
    lines are the reader's set-up, not commands of the package)."""
    lines = [line for kind, text in blocks(page) if kind == "bash" for line in text.splitlines()]
    argvs = [shlex.split(line, comments=True) for line in lines]
    return [argv for argv in argvs if argv and argv[0] == "anra"]


# ------------------------------------------------------------------------------------------ stand-ins
def spot(t: int, h: int, w: int, seed: int = 0) -> np.ndarray:
    """A spreading Gaussian spot on 30 C with 0.02 K noise, float32."""
    y, x = np.mgrid[:h, :w]
    s2 = 9.0 + 0.5 * np.arange(t)[:, None, None]
    clean = 30 + 200 * np.exp(-((x - w / 2) ** 2 + (y - h / 2) ** 2)[None] / (2 * s2)) / s2
    return (clean + 0.02 * np.random.default_rng(seed).standard_normal(clean.shape)).astype(np.float32)


def flir_sequence(path: Path, encoding: str) -> None:
    """30 frames of 160 x 128 px at 30 Hz (a spreading spot in raw counts)."""
    cam = Camera(emissivity=1.0, distance=0.0)
    blobs = []
    for k, frame in enumerate(counts_for(spot(30, 128, 160), cam)):
        ms = cam.seconds * 1000 + (1000 * k) // 30
        stamped = Camera(**{**cam.__dict__, "seconds": ms // 1000, "millis": ms % 1000})
        blobs.append(simple_frame(frame, stamped, encoding=encoding))
    path.write_bytes(b"".join(blobs))


def videos(folder: Path, n: int, size: tuple[int, int] = (54, 76)) -> None:
    folder.mkdir()
    for k in range(n):
        save_npz(folder / f"v{k}.npz", spot(12, *size, seed=k), dt=0.1, dx=0.2)


def plate(path: Path) -> None:
    frames, dt, dx = flash_plate_video(
        size=24, n_frames=40, plate=FlashPlate(layers=12, defect=(2.4, 2.4, 1.0, 0.6))
    )
    save_npz(path, frames, dt=dt, dx=dx)


def burn(path: Path) -> None:
    frames, dt, dx = burn_video()
    save_npz(path, frames.numpy(), dt=dt, dx=dx)


STAND_INS: dict[str, Callable[[Path], object]] = {
    "camera.npy": lambda f: np.save(f / "camera.npy", spot(24, 24, 24)),
    "PLATE.npz": lambda f: plate(f / "PLATE.npz"),
    "recording.seq": lambda f: flir_sequence(f / "recording.seq", "uint16"),
    "recording.csq": lambda f: flir_sequence(f / "recording.csq", "jpeg-ls"),
    "recording.npz": lambda f: save_npz(
        f / "recording.npz", blobs_video(size=49, n_frames=16).frames[0], dt=1 / 30, dx=0.5
    ),
    "burn.npz": lambda f: burn(f / "burn.npz"),
    "TRACE.npz": lambda f: save_npz(
        f / "TRACE.npz", (37 + 20 * np.sin(np.linspace(0, 3, 40)))[:, None, None], dt=0.5, dx=None
    ),
    "table.csv": lambda f: (f / "table.csv").write_text("true,apparent\n20,19.5\n60,58.0\n300,290.0\n"),
    "videos/": lambda f: videos(f / "videos", 2),
    "more/*.npz": lambda f: videos(f / "more", 1, (56, 76)),
}
"""The inputs a page names (as its commands write them) -> how to make a small one in a folder."""


def stand_ins(page: Path, folder: Path) -> None:
    """Make in ``folder`` the inputs ``page``'s commands read that no earlier command writes."""
    made: set[str] = set()
    for argv in commands(page):
        for k, arg in enumerate(argv):
            name = PLACEHOLDERS.get(arg, arg)
            if argv[k - 1] not in ("-o", "--out", "--report") and name in STAND_INS and name not in made:
                STAND_INS[name](folder)
            made.add(name)


def resolved(argv: list[str]) -> list[str]:
    return [PLACEHOLDERS.get(a, a.replace("../shared/data", str(DATA))) for a in argv[1:]]


# ------------------------------------------------------------------------------------------------ tests
def test_the_guides_blocks_are_found() -> None:
    """Every guide shows code, and every shell line of a guide is an ``anra`` command run below."""
    assert len(GUIDES) >= 9
    for page in GUIDES:
        found = blocks(page)
        assert found, page.name
        shell = [line for kind, text in found if kind == "bash" for line in text.splitlines()]
        ran = [line for line in shell if shlex.split(line, comments=True)[:1] == ["anra"]]
        setup = [
            line for line in shell if shlex.split(line, comments=True)[:1] in (["make"], ["git"], ["pip"])
        ]
        assert len(ran) + len(setup) == len([s for s in shell if shlex.split(s, comments=True)]), page.name


SLOW = {
    "flir-recording": "the measured recording's estimate and diagnosis with figures (about 30 s)",
    "what-the-model-misses": "three diagnoses of the page's 64 px, 91-frame scene (about 25 s)",
    "getting-started": "the paper's 224 px case estimated and diagnosed (about 20 s)",
    "folder-of-videos": "a Dask LocalCluster started and batches diagnosed (about 8 s)",
}
"""Guides whose commands take seconds as written (marked slow; ``make test`` runs them)."""


@pytest.mark.parametrize(
    "page",
    [pytest.param(p, marks=[pytest.mark.slow] if p.stem in SLOW else []) for p in GUIDES],
    ids=lambda p: p.stem,
)
def test_a_guides_blocks_run_as_pasted(
    page: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    diagnosed_once: None,
) -> None:
    """A page that diagnoses the same file twice (its report, then its JSON) renders one diagnosis."""
    if "../shared/data" in page.read_text() and not DATA.is_dir():
        pytest.skip(f"measured data folder {DATA} is absent")
    monkeypatch.chdir(tmp_path)
    stand_ins(page, tmp_path)
    threads = torch.get_num_threads()
    try:
        for kind, text in blocks(page):
            if kind == "python":
                exec(compile(text, page.name, "exec"), {"__name__": "__guide__"})  # noqa: S102 - the page's own
        for argv in commands(page):
            code, out, err = run(capsys, *resolved(argv))
            assert code == 0, f"{page.name}: {shlex.join(argv)}\n{err[-3000:]}"
    finally:
        torch.set_num_threads(threads)
