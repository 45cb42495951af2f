"""Interrupted runs keep their work: a killed process leaves its poses, Ctrl-C and SIGTERM finish
every output file with status ``interrupted at frame N`` and exit with 130 / 143, an error after
some frames still writes the files."""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import lite_vo
from lite_vo.errors import InputError
from lite_vo.io import read_trajectory
from lite_vo.runner import run_sequence
from lite_vo.session import OutputSink

ROOT = Path(__file__).resolve().parents[1]


def _poses_in(path: Path) -> int:
    """Valid TUM pose lines in a trajectory file (a half-written last line would not count)."""
    n = 0
    for line in path.read_text().splitlines():
        f = line.split()
        if line.startswith("#") or len(f) != 8:
            continue
        vals = np.array([float(x) for x in f])
        n += int(np.all(np.isfinite(vals)))
    return n


def test_kill_9_after_n_frames_leaves_the_poses(synth_small, tmp_path):
    n = 25
    out = tmp_path / "out"
    code = f"""
import os, signal
import lite_vo
from lite_vo.runner import run_sequence
from lite_vo.session import OutputSink
class Kill(OutputSink):
    seen = 0
    def on_frame(self, event):
        self.seen += 1
        if self.seen == {n}:
            os.kill(os.getpid(), signal.SIGKILL)
run_sequence({str(synth_small)!r}, lite_vo.load_profile("phone", ['system.init="depth"']), {str(out)!r},
             sinks=[Kill()])
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=900)
    assert r.returncode == -signal.SIGKILL, r.stderr[-2000:]
    assert _poses_in(out / "trajectory.txt") >= n - 30
    assert _poses_in(out / "trajectory.txt") == n             # in fact every pose of a tracked frame
    assert json.loads((out / "run.json").read_text())["status"] == "running"   # honest: never finished


@pytest.mark.parametrize("sig, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_finishes_the_files_and_exits_with_its_code(synth_small, tmp_path, sig, code):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "lite_vo.cli.main", "run", str(synth_small), "--out", str(out), "--quiet",
           "--init", "depth", "--mode", "realtime", "--set", "system.realtime_speed=0.3"]
    proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    traj = out / "trajectory.txt"
    t0 = time.monotonic()
    while time.monotonic() - t0 < 600 and proc.poll() is None:
        if traj.is_file() and _poses_in(traj) >= 5:
            break
        time.sleep(0.05)
    assert proc.poll() is None, "the run ended before it could be interrupted"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == code, err[-2000:]
    info = json.loads((out / "run.json").read_text())
    assert info["status"].startswith("interrupted at frame ")
    assert int(info["status"].rsplit(" ", 1)[1]) < 45
    assert info["frames"]["tracked"] >= 5 and "config" in info and "versions" in info
    timing = json.loads((out / "timing.json").read_text())
    assert timing["tracking"]["count"] >= 5
    assert len(read_trajectory(traj)) == info["frames"]["tracked"]
    assert (out / "map.ply").stat().st_size > 0
    assert "interrupted" in err or "terminated" in err


class _FailAt(OutputSink):
    def __init__(self, n):
        self.n, self.seen = n, 0

    def on_frame(self, event):
        self.seen += 1
        if self.seen == self.n:
            raise InputError("the sink gave up")


def test_an_error_after_some_frames_still_writes_the_files(synth_small, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(InputError, match="gave up"):
        run_sequence(synth_small, lite_vo.load_profile("phone", ['system.init="depth"']), out,
                     sinks=[_FailAt(12)])
    info = json.loads((out / "run.json").read_text())
    assert info["status"] == "failed: the sink gave up" and info["error"] == "the sink gave up"
    assert len(read_trajectory(out / "trajectory.txt")) == 12
    assert json.loads((out / "timing.json").read_text())["tracking"]["count"] == 12


def _copy_with_bad_frames(src: Path, dst: Path, bad: dict[int, str]) -> list[str]:
    """A copy of a TUM folder where frame k is truncated ("truncate") or deleted ("delete")."""
    import shutil
    shutil.copytree(src, dst)
    rows = [r.split() for r in (dst / "rgb.txt").read_text().splitlines() if r and not r.startswith("#")]
    names = []
    for k, how in bad.items():
        f = dst / rows[k][1]
        names.append(f.name)
        if how == "truncate":
            f.write_bytes(f.read_bytes()[:200])
        else:
            f.unlink()
    return names


def test_unreadable_frames_are_skipped_counted_and_left_out(synth_small, tmp_path, caplog):
    seq = _copy_with_bad_frames(synth_small, tmp_path / "seq", {10: "truncate", 11: "delete", 30: "truncate"})
    out = tmp_path / "out"
    res = run_sequence(tmp_path / "seq", lite_vo.load_profile("phone", ['system.init="depth"']), out)
    assert res.status == "ok_with_skipped_frames"
    info = json.loads((out / "run.json").read_text())
    assert info["frames"]["skipped"] == 3 and info["frames"]["in"] == 42 and info["frames"]["tracked"] == 42
    assert len(read_trajectory(out / "trajectory.txt")) == 42
    warned = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert all(any(name in w for w in warned) for name in seq), warned


def test_too_many_bad_frames_in_a_row_stop_the_run_naming_the_last_file(synth_small, tmp_path):
    names = _copy_with_bad_frames(synth_small, tmp_path / "seq", {k: "truncate" for k in range(5, 9)})
    out = tmp_path / "out"
    with pytest.raises(InputError, match=f"4 unreadable frames in a row.*{names[-1]}"):
        run_sequence(tmp_path / "seq", lite_vo.load_profile("phone", ['system.init="depth"']), out,
                     max_bad_frames=3)
    info = json.loads((out / "run.json").read_text())
    assert info["status"].startswith("failed: 4 unreadable frames in a row")
    assert len(read_trajectory(out / "trajectory.txt")) == 5            # what came before is kept
