"""tools/arm_report.py: the trajectory comparison, pip's report and the report of tools/arm_check.sh
(the check itself runs tens of minutes under emulation and is not part of the tests)."""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

_PATH = Path(__file__).resolve().parents[1] / "tools" / "arm_report.py"
_spec = importlib.util.spec_from_file_location("arm_report", _PATH)
arm_report = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(arm_report)


def _quat_about_z(deg: float) -> tuple[float, float, float, float]:
    h = math.radians(deg) / 2.0
    return (0.0, 0.0, math.sin(h), math.cos(h))


def _random_trajectory(rng, n=20) -> dict:
    poses = {}
    for i in range(n):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        poses[round(i / 30.0, 6)] = (tuple(rng.normal(size=3)), tuple(q))
    return poses


def _write_tum(path: Path, poses: dict) -> None:
    path.write_text("".join(f"{t:.6f} " + " ".join(f"{v:.9f}" for v in (*p[0], *p[1])) + "\n"
                            for t, p in sorted(poses.items())))


def _rotate_z(q, deg):
    """q * rz(deg) (Hamilton product, x y z w)."""
    x1, y1, z1, w1 = q
    x2, y2, z2, w2 = _quat_about_z(deg)
    return (w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2)


def test_compare_finds_the_translation_and_rotation_offsets():
    rng = np.random.default_rng(0)
    a = _random_trajectory(rng)
    b = dict(a)
    times = sorted(a)
    t_shift, t_rot = times[5], times[11]
    (x, y, z), q = a[t_shift]
    b[t_shift] = ((x + 0.0003, y - 0.0004, z), q)          # 0.5 mm
    b[t_rot] = (a[t_rot][0], _rotate_z(a[t_rot][1], 0.07))  # 0.07 deg
    b[99.0] = a[times[0]]                                   # a pose only in b
    del b[times[-1]]                                        # a pose only in a
    c = arm_report.compare_trajectories(a, b)
    assert c["matched"] == len(times) - 1
    assert (c["only_a"], c["only_b"]) == (1, 1)
    assert c["max_mm"] == pytest.approx(0.5, abs=1e-9)
    assert c["max_deg"] == pytest.approx(0.07, abs=1e-6)
    assert c["mean_mm"] == pytest.approx(0.5 / (len(times) - 1), abs=1e-9)


def test_rotation_angle_ignores_the_quaternion_sign_and_scale():
    q = _quat_about_z(30.0)
    assert arm_report.rotation_angle_deg(q, tuple(-c for c in q)) == pytest.approx(0.0, abs=1e-6)
    assert arm_report.rotation_angle_deg(q, tuple(2 * c for c in _quat_about_z(40.0))) == pytest.approx(10.0)


def test_read_tum_names_the_bad_line(tmp_path):
    p = tmp_path / "t.txt"
    p.write_text("# comment\n0.0 0 0 0 0 0 0 1\n0.1 0 0 0 0 0 1\n")
    with pytest.raises(arm_report.ReportError, match=r"t\.txt:3: expected 8 numbers"):
        arm_report.read_tum(p)


PIP_REPORT = {"install": [
    {"metadata": {"name": "numba", "version": "0.61.2"},
     "download_info": {"url": "https://files.pythonhosted.org/x/numba-0.61.2-cp311-cp311-"
                              "manylinux2014_aarch64.manylinux_2_17_aarch64.whl", "archive_info": {}}},
    {"metadata": {"name": "Some_Pkg", "version": "1.0"},
     "download_info": {"url": "https://files.pythonhosted.org/y/some_pkg-1.0.tar.gz", "archive_info": {}}},
    {"metadata": {"name": "lite-vo", "version": "0.1.0"},
     "download_info": {"url": "file:///opt/lite_vo/src", "dir_info": {}}},
]}


def test_package_sources_tells_wheels_from_source_builds():
    s = arm_report.package_sources(PIP_REPORT)
    assert s["numba"]["kind"] == "wheel"
    assert arm_report.wheel_tag(s["numba"]["file"]) == "manylinux2014_aarch64.manylinux_2_17_aarch64"
    assert s["some-pkg"] == {"version": "1.0", "kind": "source", "file": "some_pkg-1.0.tar.gz"}
    assert s["lite-vo"]["kind"] == "local"


def _fake_check(out: Path, shift_mm: float) -> None:
    rng = np.random.default_rng(1)
    traj = _random_trajectory(rng, 30)
    moved = {t: ((p[0][0] + shift_mm / 1000.0, p[0][1], p[0][2]), p[1]) for t, p in traj.items()}
    (out / "logs").mkdir(parents=True)
    (out / "check.env").write_text("frames=30\ndate=2026-01-01T00:00:00Z\ncommit=abc\nqemu=1:7.2\n")
    (out / "steps.tsv").write_text("side\tstep\tseconds\tstatus\nhost\ttools\t1.0\tok\n"
                                   "aarch64\twarmup\t400.5\tok\nhost\twarmup\t30.0\tok\n")
    (out / "logs" / "aarch64-warmup.log").write_text("  lite_vo.x  1.00 s\ndone: 5 module(s) warmed up in 398.25 s\n")
    for side, poses, wall, machine in (("aarch64", moved, 60.0, "aarch64"), ("host", traj, 2.0, "x86_64")):
        (out / side).mkdir()
        _write_tum(out / side / "trajectory.txt", poses)
        run = {"status": "ok", "frames": {"in": 30, "tracked": 30}, "sequence": {"name": "icl"},
               "machine": {"machine": machine, "cpu": "AMD EPYC", "cores": 2},
               "versions": {"machine": machine, "numba": "0.61.2"}}
        (out / side / "run.json").write_text(json.dumps(run))
        (out / side / "timing.json").write_text(json.dumps({"wall_s": wall, "tracking": {"median": 5.0, "count": 30},
                                                            "mapping": {"median": 20.0, "count": 10}}))
        (out / side / "pip_report.json").write_text(json.dumps(PIP_REPORT))


def test_report_passes_within_tolerance_and_lists_the_numbers(tmp_path):
    _fake_check(tmp_path, shift_mm=0.02)
    assert arm_report.main(["--out", str(tmp_path)]) == 0
    text = (tmp_path / "report.md").read_text()
    assert "max **0.0200 mm**" in text and "**within**" in text
    assert "30x the host's wall time" in text
    assert "aarch64 398.2 s" in text or "aarch64 398.3 s" in text
    assert "Built from source on aarch64: some-pkg." in text


def test_report_fails_when_the_trajectories_differ(tmp_path, capsys):
    _fake_check(tmp_path, shift_mm=3.0)
    assert arm_report.main(["--out", str(tmp_path), "--tol-mm", "1"]) == 1
    assert "**exceeded**" in (tmp_path / "report.md").read_text()
    assert "trajectories differ" in capsys.readouterr().err


def test_report_fails_on_a_failed_step_and_a_bad_json(tmp_path, capsys):
    _fake_check(tmp_path, shift_mm=0.0)
    with (tmp_path / "steps.tsv").open("a") as f:
        f.write("aarch64\trun\t12.0\texit 1\n")
    assert arm_report.main(["--out", str(tmp_path)]) == 1
    assert "step 'aarch64: run' exit 1" in capsys.readouterr().err
    (tmp_path / "host" / "run.json").write_text("{oops")
    assert arm_report.main(["--out", str(tmp_path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "run.json: not valid JSON" in err[0]
