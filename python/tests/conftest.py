"""Shared fixtures: the Rust fixture file, the CLI binary (episodes are skipped without one) and
a short episode run once per session."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

import activemap

HERE = Path(__file__).resolve().parent
#: The repository checkout (python/tests/ -> the root).
ROOT = HERE.parent.parent


@pytest.fixture(scope="session")
def splat_fixture() -> dict:
    """What the Rust crates compute for the fixture scene (tests/splat_fixture.rs)."""
    return json.loads((HERE / "data" / "splat_fixture.json").read_text())


@pytest.fixture(scope="session")
def binary() -> Path:
    """The activemap CLI binary, or skip the test (set ACTIVEMAP_BIN or build the workspace)."""
    try:
        return activemap.find_binary()
    except activemap.BinaryNotFoundError as e:
        if os.environ.get("ACTIVEMAP_REQUIRE_BIN"):
            raise
        pytest.skip(str(e))


@pytest.fixture(scope="session")
def episode(binary: Path, tmp_path_factory: pytest.TempPathFactory) -> activemap.Run:
    """A short FBE episode at 48x48 (about 2 s), not evaluated."""
    out = tmp_path_factory.mktemp("episode") / "run"
    return activemap.run(
        ROOT / "dataflow.yaml",
        out,
        sets={"sim.width": 48, "sim.height": 48, "sim.seed": 3},
        max_steps=15,
        evaluate=False,
        cwd=ROOT,
        timeout=300,
    )
