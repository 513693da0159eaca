"""``run_batch_dask`` (:mod:`anra_torch.batch.dask`): a two-worker cluster gives the local run's rows."""

from __future__ import annotations

from pathlib import Path

import pytest

from anra_torch.batch import read_table, run_batch


@pytest.mark.slow
def test_dask_two_worker_cluster_gives_the_local_rows(video_folder: Path, tmp_path: Path) -> None:
    pytest.importorskip("distributed", reason="the Dask engine needs the 'dask' extra")
    from anra_torch.batch.dask import run_batch_dask

    local, remote = tmp_path / "local.csv", tmp_path / "dask.csv"
    run_batch([video_folder], local, batch_size=2, progress=False)
    summary = run_batch_dask([video_folder], remote, workers=2, batch_size=2, progress=False)
    assert (summary.ok, summary.failed) == (4, 2)
    by_path = {r["path"]: r for r in read_table(local)}
    for row in read_table(remote):
        assert row["status"] == by_path[row["path"]]["status"]
        assert row["error"] == by_path[row["path"]]["error"]
        if row["status"] == "ok":
            assert row["diffusivity"] == pytest.approx(by_path[row["path"]]["diffusivity"], rel=1e-6)
