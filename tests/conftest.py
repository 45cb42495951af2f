"""Shared fixtures: the location of ../shared/data and a small synthetic sequence."""
from __future__ import annotations

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def shared_sequence(name: str) -> Path:
    """Path of a shared sequence, or skip the test with a clear message when it is absent."""
    path = SHARED_DATA / name
    if not path.exists():
        pytest.skip(f"shared data {path} not found (tests on real sequences need ../shared/data beside the repo)")
    return path


@pytest.fixture(scope="session")
def synth_small(tmp_path_factory) -> Path:
    """45 frames (1.5 s) of the synthetic room, hand-held motion, 320x240, seed 0."""
    from lite_vo.synth import generate_sequence
    out = tmp_path_factory.mktemp("synth") / "room_handheld_320"
    generate_sequence(out, scene="room", trajectory="handheld", n_frames=45, seed=0, width=320, height=240)
    return out
