"""Shared fixtures: the repository, the CLI built by `cargo test --release` (or
OPTISTIM_BIN), ../shared, and a reduced-resolution NRHO scene."""

from __future__ import annotations

import csv
import os
import pathlib
import tomllib

import pytest

import optistim

REPO = pathlib.Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared"
NRHO = SHARED / "trajectories" / "nrho_2orbits.csv"


@pytest.fixture(scope="session")
def cli() -> str:
    path = os.environ.get("OPTISTIM_BIN", str(REPO / "target" / "release" / "optistim"))
    if not os.access(path, os.X_OK):
        pytest.fail(f"the optistim binary is not built at {path} (cargo build --release, or set OPTISTIM_BIN)")
    return path


def small_scene_dict(px: int = 256) -> dict:
    """config/nrho_bench.toml at px x px with the same field of view."""
    with open(REPO / "config" / "nrho_bench.toml", "rb") as f:
        d = tomllib.load(f)
    scale = 1024 / px
    d["camera"]["resolution_px"] = [px, px]
    d["camera"]["pixel_pitch_m"] = d["camera"]["pixel_pitch_m"] * scale
    return d


@pytest.fixture(scope="session")
def small_scene_file(tmp_path_factory) -> pathlib.Path:
    """The reduced scene as a TOML file (the text Scene.from_dict made of the dict)."""
    scene = optistim.Scene.from_dict(small_scene_dict(), base_dir=REPO / "config")
    path = tmp_path_factory.mktemp("scene") / "nrho_small.toml"
    path.write_text(scene.toml)
    return path


@pytest.fixture(scope="session")
def nrho64(tmp_path_factory) -> pathlib.Path:
    """64 poses spread over the NRHO file (every 11th row: perilune included), as a CSV."""
    with open(NRHO, newline="") as f:
        rows = list(csv.reader(f))
    header, body = rows[0], rows[1:]
    picked = body[:: len(body) // 64][:64]
    path = tmp_path_factory.mktemp("traj") / "nrho64.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(picked)
    return path
