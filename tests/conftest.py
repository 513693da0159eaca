"""Shared fixtures: a fixed seed for every test, the two floating dtypes with their tolerances, the video
files that tests in several folders read (written once per test process where no test changes them), and a
cache on disk that the xdist workers share for results several tests compute alike."""

from __future__ import annotations

import os

_WORKERS = os.environ.get("PYTEST_XDIST_WORKER_COUNT")
_THREADS = max(1, (os.cpu_count() or 1) // int(_WORKERS)) if _WORKERS else None
if _THREADS is not None:
    # Under `pytest -n N` each worker gets its share of the cores, set before NumPy and torch load: NumPy's
    # OpenBLAS reads OMP_NUM_THREADS only then, and with all cores per worker its threads spin beside the
    # other worker (the reference plates' solves: a 48 px flash plate 22 CPU-s, 7 with one thread). The
    # processes tests start (examples, entry points) inherit it: unset, each took all cores and spun (59
    # CPU-s, 24 with one thread).
    os.environ.setdefault("OMP_NUM_THREADS", str(_THREADS))

import hashlib  # noqa: E402 - after the thread share above, which NumPy's BLAS reads as it loads
import pickle  # noqa: E402
import re  # noqa: E402
from collections.abc import Callable, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import torch  # noqa: E402
from filelock import FileLock  # noqa: E402

import anra_torch.cli.diagnose as diagnose_command  # noqa: E402
from anra_torch.cli import main  # noqa: E402
from anra_torch.effects import HiddenEffectVideo, hidden_effect_video  # noqa: E402
from anra_torch.simulation.synthetic import paper_video  # noqa: E402
from anra_torch.video import save_npz  # noqa: E402

if _THREADS is not None:
    # torch's default (all cores per worker) oversubscribes them too, and its OpenMP kernels (e.g. reflect
    # padding) then spin for ~10 ms per call.
    torch.set_num_threads(_THREADS)

TOLERANCES = {torch.float32: 1e-4, torch.float64: 1e-10}
"""Relative tolerance for results that are exact up to rounding, per dtype."""


@pytest.fixture(autouse=True)
def _seed() -> None:
    """Seed torch and NumPy (seed 0) so every test sees the same random draws, alone or under xdist."""
    torch.manual_seed(0)
    np.random.seed(0)  # noqa: NPY002 - seeds the legacy global state that library code might use


@pytest.fixture(params=[torch.float32, torch.float64], ids=["float32", "float64"])
def dtype(request: pytest.FixtureRequest) -> torch.dtype:
    """Both floating dtypes the package supports."""
    return request.param


@pytest.fixture
def tol(dtype: torch.dtype) -> float:
    """Relative tolerance for an exact-up-to-rounding comparison in ``dtype``."""
    return TOLERANCES[dtype]


@pytest.fixture(scope="session")
def paper96(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The paper's case cropped to its central 96 x 96 px, written by ``anra simulate`` (read only)."""
    path = tmp_path_factory.mktemp("cli") / "paper96.npz"
    assert main(["simulate", "--crop", "96", "-o", str(path)]) == 0
    return path


@pytest.fixture(scope="session")
def video_folder(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Folder of batch inputs (read only): 3 paper videos 64 px, one 72 px in ``sub/``, a corrupt file, a
    .npy without dt, a text file."""
    root = tmp_path_factory.mktemp("videos")
    small = paper_video(n_videos=3, seed=5, crop=64)
    for i in range(3):
        save_npz(root / f"p{i}.npz", small.frames[i], dt=small.dt, dx=small.dx, a_true=0.2)
    other = paper_video(n_videos=1, seed=6, crop=72)
    (root / "sub").mkdir()
    save_npz(root / "sub" / "q.npz", other.frames[0], dt=other.dt, dx=other.dx)
    (root / "broken.npz").write_bytes(b"not a zip archive")
    np.save(root / "nodt.npy", np.zeros((6, 40, 40)))
    (root / "notes.txt").write_text("not a video")
    return root


@pytest.fixture
def one_video(tmp_path: Path) -> Path:
    """One paper video cropped to 40 px (seed 5) in the test's own folder (tests may rewrite it)."""
    video = paper_video(n_videos=1, seed=5, crop=40)
    return save_npz(tmp_path / "v.npz", video.frames[0], dt=video.dt, dx=video.dx)


@pytest.fixture(scope="session")
def disk_cache(tmp_path_factory: pytest.TempPathFactory) -> Callable[[str, Callable[[], Any]], Any]:
    """``disk_cache(key, make)``: what ``make()`` returns, made once per test run and shared by the xdist
    workers (a diagnosis of a recording, a simulated video that several tests read). Pickled under the run's
    temporary folder as ``<key>.pkl`` (the key spells the parameters); the first worker to ask makes it while
    the others wait on its lock. Callers must not change what they get in place."""
    base = tmp_path_factory.getbasetemp()
    root = (base.parent if "PYTEST_XDIST_WORKER" in os.environ else base) / "disk-cache"
    root.mkdir(exist_ok=True)

    def cached(key: str, make: Callable[[], Any]) -> Any:
        path = root / f"{re.sub(r'[^A-Za-z0-9_.=-]', '_', key)}.pkl"
        with FileLock(path.with_suffix(".lock")):
            if path.exists():
                return pickle.loads(path.read_bytes())
            value = make()
            partial = path.with_suffix(".part")
            partial.write_bytes(pickle.dumps(value))
            partial.replace(path)
            return value

    return cached


@pytest.fixture(scope="session")
def hidden_video(disk_cache: Callable[[str, Callable[[], Any]], Any]) -> Callable[..., HiddenEffectVideo]:
    """``hidden_video(names, seed=..., **kwargs)``: :func:`~anra_torch.effects.hidden_effect_video` with
    these arguments, simulated once per test run and shared by the tests (and xdist workers) that ask for
    the same scene. Read only."""

    def shared(names: Sequence[str] = (), **kwargs: Any) -> HiddenEffectVideo:
        spelled = "+".join(names) + "".join(f"-{k}={v!r}" for k, v in sorted(kwargs.items()))
        key = f"hidden-{spelled[:100]}-{hashlib.sha1(spelled.encode()).hexdigest()[:12]}"
        return disk_cache(key, lambda: hidden_effect_video(tuple(names), **kwargs))

    return shared


def _digest(value: Any) -> str:
    """A short hash of what ``value`` holds (an array's dtype, shape and bytes; else its repr)."""
    if value is None or isinstance(value, (str, int, float, Path)):
        return repr(value)
    array = np.ascontiguousarray(torch.as_tensor(value).detach().cpu().numpy())
    return f"{array.dtype}{array.shape}" + hashlib.sha1(array.tobytes()).hexdigest()


@pytest.fixture
def diagnosed_once(monkeypatch: pytest.MonkeyPatch) -> None:
    """``anra diagnose`` run more than once in a test on the same recording with the same options (its
    JSON, then its human summary or report) diagnoses it once: the later runs render the first run's
    diagnosis (the same recording, frames, spacing, times and options; anything else diagnoses anew)."""
    real, made = diagnose_command.diagnose_video, {}

    def once(video: Any, **options: Any) -> Any:
        measured = video.meta.get("measured_t")
        spelled = [
            video.source,
            video.frames,
            video.dt,
            video.dx,
            video.t,
            measured,
            repr(sorted(options.items())),
        ]
        key = tuple(_digest(part) for part in spelled)
        if key not in made:
            made[key] = real(video, **options)
        return made[key]

    monkeypatch.setattr(diagnose_command, "diagnose_video", once)


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """Run the tests marked slow first (in their usual order): under ``pytest -n 2`` the long ones then
    start while the other worker still has short ones left, instead of one running alone at the end."""
    items.sort(key=lambda item: item.get_closest_marker("slow") is None)
