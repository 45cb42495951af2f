"""The rerun viewer sink: options, a recorded .rrd that rerun reads back with the run's content, the AR
world and car in it, and zero cost when it is off."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lite_vo.cli.main import main
from lite_vo.errors import InputError
from lite_vo.viewer import colorize_idepth, parse_target

ROOT = Path(__file__).resolve().parents[1]


def _entities(path: Path) -> dict[str, int]:
    """Entity path -> rows of a recorded .rrd, read back with rerun itself."""
    from rerun.chunk import RrdReader
    rows: dict[str, int] = {}
    for chunk in RrdReader(str(path)).stream().to_chunks():
        rows[str(chunk.entity_path)] = rows.get(str(chunk.entity_path), 0) + chunk.num_rows
    return rows


def test_viewer_options_are_checked():
    assert parse_target() is None
    assert parse_target(viewer=True) == ("spawn", None)
    assert parse_target(rrd="run.rrd") == ("rrd", "run.rrd")
    assert parse_target(connect="192.168.1.20:9876") == ("connect", "192.168.1.20:9876")
    with pytest.raises(InputError, match="choose one"):
        parse_target(viewer=True, rrd="run.rrd")
    with pytest.raises(InputError, match="HOST:PORT"):
        parse_target(connect="laptop")
    with pytest.raises(InputError, match=r"\.rrd"):
        parse_target(rrd="run.txt")


def test_depth_colours_as_in_the_paper():
    d = np.full((4, 6), np.nan)
    d[1, 1], d[2, 4] = 2.0, 0.2                          # near and far
    img = colorize_idepth(d)
    assert img[0, 0].sum() == 0                           # empty: black
    assert img[1, 1, 0] > img[1, 1, 2] and img[2, 4, 2] > img[2, 4, 0]   # near red, far blue


def test_a_recorded_run_reads_back_with_its_content(synth_small, tmp_path):
    pytest.importorskip("rerun", reason="the viewer needs the [viewer] extra (rerun-sdk)")
    out, rrd = tmp_path / "out", tmp_path / "run.rrd"
    assert main(["run", str(synth_small), "--out", str(out), "--max-frames", "20", "--quiet", "--init", "depth",
                 "--rrd", str(rrd)]) == 0
    rows = _entities(rrd)
    for path in ("/world/camera", "/world/camera/image", "/world/camera/image/depth", "/world/trajectory",
                 "/world/map", "/world/scene", "/quality/residual", "/status/end"):
        assert rows.get(path, 0) > 0, (path, sorted(rows))
    assert rows["/world/camera"] == 20                   # one pose per tracked frame
    assert main(["run", str(synth_small), "--out", str(tmp_path / "o2"), "--max-frames", "5", "--quiet",
                 "--rrd", str(rrd)]) == 1                # an existing recording is not overwritten


def test_the_viewer_costs_nothing_when_off(synth_small, tmp_path):
    code = ("import sys; from lite_vo.cli.main import main; "
            f"rc = main(['run', {str(synth_small)!r}, '--out', {str(tmp_path / 'o')!r}, '--max-frames', '3', "
            "'--quiet', '--init', 'depth']); "
            "sys.exit(rc or (3 if 'rerun' in sys.modules else 0))")
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]


def test_the_ar_demo_shows_its_world_and_car(tmp_path):
    pytest.importorskip("rerun", reason="the viewer needs the [viewer] extra (rerun-sdk)")
    pytest.importorskip("pybullet", reason="the AR demo needs the [ar] extra")
    pytest.importorskip("moderngl", reason="the AR demo needs the [ar] extra")
    from ar_demo.render import RenderUnavailable, create_context
    try:
        create_context().release()
    except RenderUnavailable as err:
        pytest.skip(f"EGL off-screen OpenGL is unavailable here ({err})")
    from lite_vo.synth import generate_sequence
    seq = tmp_path / "room"
    generate_sequence(seq, scene="room", trajectory="handheld", n_frames=14, seed=1, width=160, height=120)
    rrd = tmp_path / "ar.rrd"
    assert main(["ar", str(seq), "--out", str(tmp_path / "ar.mp4"), "--quiet", "--ar-set", "start_after_s=0",
                 "--set", "resolution.map_width=160", "--rrd", str(rrd)]) == 0
    rows = _entities(rrd)
    assert rows.get("/world/ar/collision", 0) > 0 and rows.get("/world/ar/car/body", 0) > 0, sorted(rows)
    cars = len([r for r in (tmp_path / "car.txt").read_text().splitlines() if not r.startswith("#")])
    assert rows["/world/ar/car"] == cars                 # one car pose per frame where the car exists
