"""Tests of the shipped resolution profiles (profiles/*.toml): each is the combination its name
promises, documents its choices, and the board profile saves work where it says it does."""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from lite_vo.config import load_profile, profile_names
from lite_vo.profiling import PAPER_PROFILES, profile_resolution

PROFILES = Path(__file__).resolve().parents[1] / "profiles"

# mapping width / tracking width of the paper's combinations (Table 5.1)
EXPECTED = {"desktop": (640, 640), "m640_t320": (640, 320), "m320_t320": (320, 320), "phone": (320, 160),
            "m160_t160": (160, 160), "m160_t80": (160, 80), "board": (320, 160)}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_profile_resolutions(name):
    r = profile_resolution(name)
    assert (r["map_width"], r["track_width"]) == EXPECTED[name]
    cfg = load_profile(name)
    # the coarsest pyramid level still has a usable image (>= 20 px wide)
    assert cfg.resolution.map_width >> (cfg.resolution.pyramid_levels - 1) >= 20


def test_paper_profiles_are_the_six_table_rows_finest_first():
    assert set(PAPER_PROFILES) == set(EXPECTED) - {"board"}
    sizes = [EXPECTED[p] for p in PAPER_PROFILES]
    assert sizes == sorted(sizes, reverse=True)
    assert set(EXPECTED) <= set(profile_names())


def test_phone_is_the_default_and_keeps_the_papers_startup_mapping_interval():
    phone = load_profile("phone")
    assert load_profile() == phone
    assert phone.system.map_every_startup == 4 and phone.system.map_every == 4


def test_board_saves_work_compared_to_phone():
    phone, board = load_profile("phone"), load_profile("board")
    assert board.resolution == phone.resolution
    assert board.tracking.max_iter_finest < phone.tracking.max_iter_finest
    assert board.tracking.max_iter_coarse < phone.tracking.max_iter_coarse
    assert board.system.map_every == 4 and board.system.numba_threads == 1
    assert board.mapping.budget_ms > 0


@pytest.mark.parametrize("path", sorted(PROFILES.glob("*.toml")), ids=lambda p: p.stem)
def test_each_profile_documents_its_choices(path):
    lines = path.read_text(encoding="utf-8").splitlines()
    assert lines[0].startswith(f"# {path.stem}:"), "first line: '# <name>: what it is for'"
    for ln in lines:
        if re.match(r"^\s*[a-z_]+\s*=", ln):
            assert "#" in ln or ln.startswith("base"), f"{path.name}: undocumented setting: {ln!r}"
    text = "\n".join(lines)
    base = re.search(r'^base\s*=\s*"([^"]+)"', text, re.M)
    if base:
        assert base.group(1) in profile_names()
