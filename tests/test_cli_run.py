"""`lite-vo run`: the file contract, the overwrite rule and one-line errors."""
from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from lite_vo.cli.main import main
from lite_vo.io import read_ply, read_trajectory

STAT_KEYS = {"count", "mean", "std", "median", "p95"}


def test_run_writes_the_contract_files(synth_small, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", str(synth_small), "--out", str(out), "--max-frames", "16", "--quiet", "--init", "depth"])
    assert code == 0
    assert "16 of 16 frames tracked" in capsys.readouterr().out
    traj = read_trajectory(out / "trajectory.txt")
    assert len(traj) == 16 and np.all(np.diff(traj.timestamps) > 0)
    timing = json.loads((out / "timing.json").read_text())
    assert STAT_KEYS <= set(timing["tracking"]) and STAT_KEYS <= set(timing["mapping"])
    assert timing["tracking"]["count"] == 16 and timing["mapping"]["count"] >= 3
    assert {"propagate", "observe", "regularize", "fill"} <= set(timing["stages"])
    assert timing["frames"] == {"in": 16, "tracked": 16, "lost": 0, "dropped": 0}
    # CPU time of the process over the frame loop: positive, and no more than all cores for the whole span
    assert timing["wall_s"] > 0 and 0 < timing["cpu_s"] <= (os.cpu_count() or 1) * timing["wall_s"] + 0.05
    run = json.loads((out / "run.json").read_text())
    assert {"profile", "config", "versions", "sequence", "status", "depth_accuracy"} <= set(run)
    assert run["profile"] == "phone" and run["status"] == "ok"
    assert run["config"]["resolution"]["map_width"] == 320
    assert set(run["depth_accuracy"]) == {"density", "median_abs_rel_error", "within_5pct", "within_10pct", "frames"}
    ply = read_ply(out / "map.ply")
    xyz = np.stack([ply["x"], ply["y"], ply["z"]], axis=1)
    assert xyz.shape[0] > 1000 and np.all(np.isfinite(xyz))
    assert "idepth_var" in ply and np.all(ply["idepth_var"] > 0)


def test_existing_output_is_not_overwritten_without_force(synth_small, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("user data")
    assert main(["run", str(synth_small), "--out", str(out), "--max-frames", "3", "--quiet"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--force" in err
    assert (out / "keep.txt").read_text() == "user data"
    assert main(["run", str(synth_small), "--out", str(out), "--max-frames", "3", "--quiet", "--force"]) == 0
    assert (out / "trajectory.txt").exists()


@pytest.mark.parametrize("args, message", [
    (["run", "/nonexistent/seq"], "/nonexistent/seq"),
    (["run", "{seq}", "--profile", "nosuchprofile"], "unknown profile"),
    (["run", "{seq}", "--set", "tracking.nosuchkey=1"], "tracking.nosuchkey"),
    (["run", "{seq}", "--set", "resolution.map_width=-5"], "resolution.map_width"),
    (["run", "{seq}", "--max-frames", "0"], "--max-frames"),
    (["run", "{seq}", "--start-frame", "1000"], "--start-frame"),
])
def test_bad_input_gives_one_line_error(synth_small, tmp_path, capsys, args, message):
    args = [a.replace("{seq}", str(synth_small)) for a in args] + ["--out", str(tmp_path / "o"), "--quiet"]
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert message in err


def test_poses_gt_needs_ground_truth(tmp_path, capsys):
    from data_helpers import write_image_folder
    folder = write_image_folder(tmp_path, n=3)
    assert main(["run", str(folder), "--poses", "gt", "--out", str(tmp_path / "o"), "--quiet"]) == 1
    assert "ground truth" in capsys.readouterr().err


def test_console_script_help_lists_commands():
    out = subprocess.run([sys.executable, "-m", "lite_vo.cli.main", "--help"], capture_output=True, text=True, check=True).stdout
    for cmd in ("run", "eval", "synth", "profile", "warmup"):
        assert cmd in out


def test_rejected_input_leaves_previous_results_alone(synth_small, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["run", str(synth_small), "--out", str(out), "--max-frames", "3", "--quiet"]) == 0
    before = (out / "trajectory.txt").read_text()
    assert main(["run", str(synth_small), "--out", str(out), "--start-frame", "1000", "--force", "--quiet"]) == 1
    assert (out / "trajectory.txt").read_text() == before
    fresh = tmp_path / "fresh"
    assert main(["run", str(synth_small), "--out", str(fresh), "--start-frame", "1000", "--quiet"]) == 1
    assert not fresh.exists()


def test_run_writes_kitti_and_a_picture_on_request(synth_small, tmp_path):
    from lite_vo.io.trajectory import read_pose_file
    out = tmp_path / "out"
    assert main(["run", str(synth_small), "--out", str(out), "--max-frames", "16", "--quiet", "--init", "depth",
                 "--format", "kitti", "--plot"]) == 0
    tum = read_trajectory(out / "trajectory.txt")
    kitti = read_pose_file(out / "trajectory_kitti.txt")          # times.txt beside it pairs the lines
    np.testing.assert_allclose(kitti.timestamps, tum.timestamps, atol=1e-6)
    np.testing.assert_allclose(kitti.poses, tum.poses, atol=1e-6)
    import cv2
    img = cv2.imread(str(out / "trajectory.png"))
    assert img is not None and img.shape[:2] == (1000, 1500) and img.std() > 5


def test_run_calib_option_on_an_image_folder_without_calib_txt(synth_small, tmp_path, capsys):
    import shutil

    import cv2

    from lite_vo.io import read_calib_txt
    folder = tmp_path / "images"
    folder.mkdir()
    for f in sorted((synth_small / "rgb").iterdir())[:12]:
        shutil.copy(f, folder / f.name)
    assert main(["run", str(folder), "--out", str(tmp_path / "no"), "--quiet"]) == 1
    assert "calib" in capsys.readouterr().err                     # says what is missing
    cam = read_calib_txt(synth_small / "calib.txt").camera
    yaml = tmp_path / "camera.yaml"                                # OpenCV's own format
    fs = cv2.FileStorage(str(yaml), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", cam.width)
    fs.write("image_height", cam.height)
    fs.write("camera_matrix", cam.intrinsics.K)
    fs.write("distortion_coefficients", np.zeros((1, 5)))
    fs.release()
    out = tmp_path / "out"
    assert main(["run", str(folder), "--out", str(out), "--quiet", "--calib", str(yaml), "--init", "random"]) == 0
    assert "12 of 12 frames tracked" in capsys.readouterr().out
    assert len(read_trajectory(out / "trajectory.txt")) == 12


def test_run_poses_the_blown_out_frames_its_start_skipped(tmp_path, capsys):
    """A recording whose first frames are blown out (auto-exposure settling): the start-up skips them and
    poses them afterwards; the summary says so, trajectory.txt has every frame, run.json counts them."""
    import cv2
    from lite_vo.synth import generate_sequence
    seq = tmp_path / "fast"
    generate_sequence(seq, scene="room", trajectory="fast", n_frames=45, seed=1, width=320, height=240)
    names = [line.split()[1] for line in (seq / "rgb.txt").read_text().splitlines() if not line.startswith("#")]
    for k, name in enumerate(names[:4]):
        img = cv2.imread(str(seq / name), cv2.IMREAD_UNCHANGED).astype(np.float32)
        assert cv2.imwrite(str(seq / name), np.clip(2.0 * img + 60 - 3 * k, 0, 255).astype(np.uint8))
    out = tmp_path / "out"
    assert main(["run", str(seq), "--out", str(out), "--init", "random", "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "41 of 45 frames tracked" in said and "4 blown out or too dark to start on (4 of them posed afterwards)" in said
    assert len(read_trajectory(out / "trajectory.txt")) == 45
    frames = json.loads((out / "run.json").read_text())["frames"]
    assert frames["waited"] == 4 and frames["backfilled"] == 4 and frames["posed"] == 45
    timing = json.loads((out / "timing.json").read_text())
    assert timing["frames"]["waited"] == 4 and timing["frames"]["backfilled"] == 4
