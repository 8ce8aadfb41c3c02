"""Episodes and run folders from Python: a short episode through the CLI, its folder read back
(and compared with the files themselves), the errors of missing and malformed files, and the
``bench results`` table."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import activemap
from conftest import ROOT


def test_an_episode_runs_and_its_folder_reads_back(episode: activemap.Run):
    s = episode.summary
    assert s["steps"] == 16 and s["valid"] is True and s["scene"] == "house:7"
    assert s["episode"].startswith("Finished at step 15")
    for name, array in (("trajectory_est.tum", episode.trajectory_est),
                        ("trajectory_true.tum", episode.trajectory_true)):
        assert array.dtype == np.float64 and array.shape == (16, 8)
        # The file itself, as numbers: the reader keeps every value.
        np.testing.assert_allclose(array, np.loadtxt(episode.path / name, comments="#"), rtol=1e-12, atol=1e-12)
    g = episode.map()
    assert len(g) == s["map_gaussians"] > 0
    assert g.means.dtype == np.float32 and g.rotations.shape == (len(g), 4)
    assert np.all((g.opacities > 0) & (g.opacities < 1)) and np.all(g.scales > 0)
    cov = episode.coverage()
    assert list(cov.columns) == ["step", "coverage"] and len(cov) > 0
    assert cov["coverage"].between(0, 1).all()
    assert cov["coverage"].iloc[-1] == pytest.approx(s["coverage"], abs=1e-6)
    timings = episode.timings()
    assert {"tracker", "mapper", "sim"} <= set(timings["stage"])
    assert episode.metrics is None  # not evaluated
    assert episode.fisher() is None and episode.llm_exchanges() == []
    assert episode.checkpoints() == []
    assert episode.trajectory_final() is None


def test_a_step_budget_and_a_render_of_the_map(episode: activemap.Run):
    """The map of a run renders from its own first pose (the camera saw it there)."""
    g = episode.map()
    t = episode.trajectory_est[0]
    from_quat = _matrix(t[1:4], t[4:8])
    k = activemap.Intrinsics.from_hfov(48, 48, 90)
    out = activemap.render(g, from_quat, k)
    assert out.opacity.mean() > 0.5


def _matrix(position: np.ndarray, xyzw: np.ndarray) -> np.ndarray:
    x, y, z, w = xyzw / np.linalg.norm(xyzw)
    m = np.eye(4)
    m[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    m[:3, 3] = position
    return m


def test_missing_and_malformed_files_name_the_file(episode: activemap.Run, tmp_path: Path):
    copy = tmp_path / "run"
    shutil.copytree(episode.path, copy, ignore=shutil.ignore_patterns("logs"))
    (copy / "coverage.csv").write_text("step,coverage\n0,0.5\n1,1.5\n")
    with pytest.raises(activemap.RunFolderError, match=r"coverage\.csv.*line 3.*outside \[0, 1\]"):
        activemap.Run(copy).coverage()
    (copy / "summary.json").write_text("[1, 2]")
    with pytest.raises(activemap.RunFolderError, match=r"summary\.json.*JSON object"):
        activemap.Run(copy).summary
    (copy / "map.ply").unlink()
    with pytest.raises(FileNotFoundError, match=r"map\.ply"):
        activemap.Run(copy).map()
    (copy / "trajectory_est.tum").write_text("# nothing\n")
    with pytest.raises(activemap.RunFolderError, match="no pose"):
        activemap.Run(copy).trajectory_est
    with pytest.raises(FileNotFoundError, match="not a run folder"):
        activemap.Run(tmp_path / "absent")


def test_metrics_fisher_and_llm_files_read_through_the_rust_types(episode: activemap.Run, tmp_path: Path):
    copy = tmp_path / "run"
    shutil.copytree(episode.path, copy, ignore=shutil.ignore_patterns("logs"))
    # What `activemap eval` wrote for a 15-step episode, its PSNR set to +inf (identical images).
    shutil.copy(Path(__file__).parent / "data" / "metrics.json", copy / "metrics.json")
    (copy / "fisher.csv").write_text(
        "step,refine,candidates,paths,chosen,objective,eig_sum,eig_first,c_local_sum,actions,"
        "total_ms,model_reused,fallback\n"
        "10,false,12,4,2,-3.5,1.25,0.5,inf,7,40.5,false,false\n"
        "30,true,0,0,-1,,,,,,2.0,true,true\n"
    )
    (copy / "llm.jsonl").write_text(
        json.dumps({"step": 5, "model": "m", "decision": 1, "prompt_tokens": 10}) + "\n\n"
        + json.dumps({"step": 9, "failure": "timeout"}) + "\n"
    )
    run = activemap.Run(copy)
    assert run.metrics["psnr_db"] == float("inf") and run.metrics["test_views"] == 5
    assert 0 < run.metrics["completeness"] < 1 and run.metrics["valid"] is True
    f = run.fisher()
    assert list(f["step"]) == [10, 30] and list(f["refine"]) == [False, True]
    assert f["c_local_sum"][0] == float("inf") and np.isnan(f["objective"][1])
    assert f["actions"][0] == 7 and f["chosen"].dtype == np.int64
    llm = run.llm_exchanges()
    assert [e["step"] for e in llm] == [5, 9] and llm[1]["failure"] == "timeout"
    assert run.test_poses() is None
    (copy / "eval").mkdir(exist_ok=True)
    (copy / "eval" / "test_poses.csv").write_text(
        "view,x_m,y_m,yaw_deg\n0,1.5,-2.25,90.0\n1,0.0,3.0,-179.5\n"
    )
    poses = run.test_poses()
    assert list(poses["view"]) == [0, 1] and list(poses["yaw_deg"]) == [90.0, -179.5]
    assert poses["x_m"][0] == 1.5 and poses["y_m"][0] == -2.25
    (copy / "fisher.csv").write_text(
        "step,refine,candidates,paths,chosen,objective,eig_sum,eig_first,c_local_sum,actions,"
        "total_ms,model_reused,fallback\n"
        "10,false,12,4,9,-3.5,1.25,0.5,1,7,40.5,false,false\n"
    )
    with pytest.raises(activemap.RunFolderError, match=r"fisher\.csv.*line 2.*chosen 9"):
        activemap.Run(copy).fisher()


def test_run_errors_name_the_command(binary, tmp_path: Path):
    with pytest.raises(activemap.EpisodeError, match="exited with"):
        activemap.run(tmp_path / "no-such-flow.yaml", tmp_path / "out", max_steps=1)


def test_a_missing_binary_says_how_to_get_one(monkeypatch, tmp_path: Path):
    monkeypatch.setenv("ACTIVEMAP_BIN", str(tmp_path / "nothing"))
    with pytest.raises(activemap.BinaryNotFoundError, match="ACTIVEMAP_BIN"):
        activemap.find_binary()


def check_table(folder: Path) -> None:
    table = activemap.results(folder)
    assert isinstance(table, pd.DataFrame)
    assert list(table.columns[:4]) == ["method", "scene", "complete", "cells"]
    assert table.loc[table["scene"] == "all", "method"].tolist() == ["fbe"]
    assert table["complete"].iloc[0] == 1 and table["psnr_db"].dtype == np.float64
    assert np.isnan(table["psnr_db_std"].iloc[0])  # one seed: no spread
    paired = activemap.results(folder, table="paired")
    assert isinstance(paired, pd.DataFrame)


def test_results_reads_the_bench_results_table(tmp_path: Path):
    """The tables `activemap bench results --method fbe --houses 7 --seeds 1 --steps 10
    --resolution 32 --eval-views 4` wrote (tests/data/bench/)."""
    check_table(Path(__file__).parent / "data" / "bench")
    with pytest.raises(FileNotFoundError, match="results.csv"):
        activemap.results(tmp_path)
    with pytest.raises(ValueError, match="table must be"):
        activemap.results(tmp_path, table="bogus")


@pytest.mark.skipif(not os.environ.get("ACTIVEMAP_PY_BENCH"), reason="set ACTIVEMAP_PY_BENCH=1 (runs one evaluated cell, 5-20 s)")
def test_bench_results_runs_a_suite_cell(binary, tmp_path: Path):
    """The same one-cell table made now through activemap.bench_results."""
    out = tmp_path / "bench"
    table = activemap.bench_results(
        None, out, cwd=ROOT, timeout=600,
        extra_args=["--method", "fbe", "--houses", "7", "--seeds", "1", "--steps", "10",
                    "--resolution", "32", "--eval-views", "4"],
    )
    assert table.equals(activemap.results(out))
    check_table(out)
