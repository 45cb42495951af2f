"""The finest tracking level of wide cameras (issue 14): a KITTI-like 1226x370 camera is mapped at
320x96 by the `phone` profile, and one level coarser (160x48) leaves too few rows for the pose; the
rule ``resolution.min_track_row_share`` tracks it at the mapping resolution instead, and leaves 4:3,
16:9 and EuRoC-like cameras at their profile's level."""
from __future__ import annotations

import pytest

import lite_vo
from lite_vo.camera import PinholeIntrinsics
from lite_vo.config import ResolutionConfig, tracking_level
from lite_vo.system import VisualOdometry


def _camera(w, h):
    return PinholeIntrinsics(fx=0.7 * w, fy=0.7 * w, cx=w / 2, cy=h / 2, width=w, height=h)


def test_rule_goes_finer_one_level_at_a_time_while_the_rows_are_too_few():
    r = ResolutionConfig(map_width=320, track_level=3, pyramid_levels=5, min_track_row_share=0.2)  # >= 64 rows
    assert tracking_level(r, 320, 544) == 3          # 68 rows at level 3
    assert tracking_level(r, 320, 512) == 3          # exactly 64: enough
    assert tracking_level(r, 320, 496) == 2          # 62 rows at level 3, 124 at level 2
    assert tracking_level(r, 320, 240) == 1          # 30, 60, then 120 rows
    assert tracking_level(r, 320, 96) == 0           # 12, 24, 48, then the mapping image's 96
    assert tracking_level(r, 320, 32) == 0           # never below 0, even when level 0 has too few rows
    off = ResolutionConfig(map_width=320, track_level=3, pyramid_levels=5, min_track_row_share=0.0)
    assert tracking_level(off, 320, 32) == 3


@pytest.mark.parametrize("size", [(640, 480), (752, 480), (1280, 720), (1226, 370)])
def test_shipped_profiles_change_the_level_only_for_the_wide_camera(size):
    for name in lite_vo.config.profile_names():
        cfg = lite_vo.load_profile(name, ['system.init="random"'])
        with VisualOdometry(_camera(*size), cfg) as vo:
            m = vo.map_intrinsics
            expected = cfg.resolution.track_level
            if size == (1226, 370) and expected > 0:
                expected = 0                             # 96 or 192 rows of mapping: track at the mapping size
            assert vo.track_level == expected, (name, size, (m.width, m.height))
            assert m.level(vo.track_level).height >= 0.2 * m.width or vo.track_level == 0


def test_run_json_records_the_tracking_resolution(tmp_path):
    import json

    from lite_vo.runner import run_sequence
    from lite_vo.synth import generate_sequence
    seq = tmp_path / "wide"
    generate_sequence(seq, scene="room", trajectory="handheld", n_frames=3, seed=0, width=640, height=192)
    out = tmp_path / "out"
    run_sequence(seq, lite_vo.load_profile("phone"), out, max_frames=3)
    res = json.loads((out / "run.json").read_text())["resolution"]
    assert res["map"] == [320, 96] and res["track_level"] == 0 and res["track"] == [320, 96]
