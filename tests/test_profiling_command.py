"""Tests of lite_vo.profiling.command: the whole ``lite-vo profile`` (run_profile and the CLI) with a
fake launcher, a fake ground truth and a small fake evaluator, and its progress lines."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from lite_vo.errors import InputError
from lite_vo.profiling import command as C
from lite_vo.profiling import results as Res
from lite_vo.profiling import sweep as S
from profiling_fakes import FakeEvaluator, FakeLauncher, make_sequence, settings


def test_sweep_with_crash_missing_and_lost_runs(tmp_path):
    seq_a = make_sequence(tmp_path / "data", "seqA")
    seq_b = make_sequence(tmp_path / "data", "seqB")
    launcher = FakeLauncher({"m160_t80": "crash"}, noise={"desktop": 0.001, "phone": 0.004})
    ev = FakeEvaluator()
    s = settings(tmp_path, [seq_a, seq_b], repeat=2)
    startup = {"sequence": str(seq_a), "profile": "phone", "n_frames": 2,
               "cold": {"ok": True, "import_s": 0.5, "setup_s": 0.1, "frame_ms": [9000.0, 4000.0], "process_s": 15.0},
               "warmup": {"ok": True, "warmup_s": 30.0, "process_s": 31.0},
               "warm": {"ok": True, "import_s": 0.5, "setup_s": 0.1, "frame_ms": [80.0, 20.0], "process_s": 2.0}}
    s.startup = True
    report = C.run_profile(s, launcher=launcher, evaluator=ev, startup_fn=lambda *a, **k: startup)
    out = tmp_path / "report"

    assert len(launcher.calls) == 2 * 3 * 2
    assert report["counts"] == {"ok": 8, "fail": 0, "crash": 4}
    assert set(ev.aligns) == {"se3"}  # depth-initialised runs are evaluated without scale
    acc = report["accuracy"]
    assert acc["seqA"]["m160_t80"]["crashed"] == 2 and acc["seqA"]["m160_t80"]["ok"] == 0
    assert acc["seqA"]["phone"]["ok"] == 2
    # less noise -> less drift in the table
    assert acc["seqB"]["desktop"]["rpe_trans_cm_per_s"]["mean"] < acc["seqB"]["phone"]["rpe_trans_cm_per_s"]["mean"]
    # timing pooled over 4 runs of 3 tracked frames each
    trk = report["timing"]["phone"]["tracking"]
    assert trk["count"] == 12 and trk["mean"] == pytest.approx(5.0) and trk["std"] == pytest.approx(np.std([4, 5, 6]))
    assert report["timing"]["desktop"]["stages"]["propagate"]["count"] == 8
    assert report["timing"]["m160_t80"]["tracking"] is None

    md = (out / "report.md").read_text()
    js = json.loads((out / "report.json").read_text())
    assert js["machine"]["cpu_model"] and js["machine"]["python"] and "numba" in js["machine"]
    assert js["profiles"]["m160_t80"]["label"] == "160/80"
    assert "crash" in md and "ValueError: boom in mapping" in md
    assert "5.0 ± 0.8" in md  # phone tracking ms
    assert "| frame 0 (ms) |" in md and "9000" in md
    for png in ("accuracy_vs_resolution.png", "time_vs_resolution.png"):
        assert (out / png).stat().st_size > 1000
        assert f"({png})" in md
    # run folders follow DIR/runs/<seq>/<profile>/<rep>
    assert (out / "runs" / "seqB" / "desktop" / "1" / "timing.json").is_file()


def test_fail_when_lost_or_status_not_ok_and_missing_files_crash(tmp_path):
    seq = make_sequence(tmp_path / "data")
    launcher = FakeLauncher({"phone": "lost", "desktop": "status", "m160_t80": "missing"})
    report = C.run_profile(settings(tmp_path, [seq]), launcher=launcher, evaluator=FakeEvaluator())
    by = {r["profile"]: r for r in report["runs"]}
    assert by["phone"]["status"] == "fail" and "lost on 5/150" in by["phone"]["reason"]
    assert by["phone"]["eval"] is not None  # numbers are still kept in report.json
    assert by["desktop"]["status"] == "fail" and "'error'" in by["desktop"]["reason"]
    assert by["m160_t80"]["status"] == "crash" and "timing.json" in by["m160_t80"]["reason"]
    md = (tmp_path / "report" / "report.md").read_text()
    row = next(ln for ln in md.splitlines() if ln.startswith("| phone | 320 | 160 |"))
    assert row.count("fail") == 2
    # tolerated when the user allows lost frames
    rec = Res.collect_run(launcher.calls[0][0], S.RunOutcome(0), Res.load_groundtruth(seq), FakeEvaluator(),
                          max_lost_ratio=0.1)
    assert rec["status"] == "ok"


def test_random_init_runs_use_sim3_and_recover_scale(tmp_path):
    seq = make_sequence(tmp_path / "data", depth=False)
    ev = FakeEvaluator()
    s = settings(tmp_path, [seq], profiles=["phone"], init="random")
    report = C.run_profile(s, launcher=FakeLauncher(scale=4.0, noise={"phone": 0.0}), evaluator=ev)
    assert ev.aligns == ["sim3"]
    assert report["accuracy"]["seqA"]["phone"]["scale"]["mean"] == pytest.approx(4.0, rel=1e-3)
    assert "--init" in S.build_run_command(report_spec(report, tmp_path))
    spec = S.RunSpec("s", "s", "phone", 0, tmp_path / "x", overrides=("tracking.huber=2",))
    assert "--set tracking.huber=2" in " ".join(S.build_run_command(spec))


def report_spec(report, tmp_path) -> S.RunSpec:
    r = report["runs"][0]
    return S.RunSpec(r["sequence"], r["seq_name"], r["profile"], r["rep"], Path(r["dir"]), init="random")


def test_output_folder_is_never_overwritten_without_force(tmp_path):
    seq = make_sequence(tmp_path / "data")
    out = tmp_path / "report"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    (out / "report.md").write_text("old")
    with pytest.raises(InputError, match="--force"):
        C.run_profile(settings(tmp_path, [seq]), launcher=FakeLauncher(), evaluator=FakeEvaluator())
    assert (out / "report.md").read_text() == "old"
    C.run_profile(settings(tmp_path, [seq], force=True), launcher=FakeLauncher(), evaluator=FakeEvaluator())
    assert (out / "notes.txt").read_text() == "mine"  # only our own entries are replaced
    assert (out / "report.md").read_text().startswith("# lite-vo profile report")
    # the CLI says so in one line and exits 1
    from lite_vo.cli.main import main
    assert main(["profile", str(seq), "--out", str(out), "--profiles", "phone"]) == 1


def test_bad_profile_and_missing_sequence_are_input_errors(tmp_path):
    seq = make_sequence(tmp_path / "data")
    from lite_vo.errors import ConfigError
    with pytest.raises(ConfigError, match="nosuch"):
        C.run_profile(settings(tmp_path, [seq], profiles=["phone", "nosuch"]), launcher=FakeLauncher())
    with pytest.raises(InputError, match="not found"):
        C.run_profile(settings(tmp_path, [tmp_path / "nope"]), launcher=FakeLauncher())
    assert not (tmp_path / "report").exists()


def test_plots_missing_matplotlib_is_a_clear_note(tmp_path, monkeypatch):
    seq = make_sequence(tmp_path / "data")
    import builtins
    real_import = builtins.__import__

    def no_mpl(name, *a, **k):
        if name.startswith("matplotlib"):
            raise ImportError("no matplotlib")
        return real_import(name, *a, **k)

    monkeypatch.setattr(builtins, "__import__", no_mpl)
    msgs = []
    C.run_profile(settings(tmp_path, [seq], profiles=["phone"]), launcher=FakeLauncher(),
                  evaluator=FakeEvaluator(), log=msgs.append)
    md = (tmp_path / "report" / "report.md").read_text()
    assert "Plots skipped" in md and "lite-vo[plot]" in md
    assert not list((tmp_path / "report").glob("*.png"))
    assert any("matplotlib" in m for m in msgs)


def test_cli_passes_its_options_to_the_profiler(tmp_path, monkeypatch, capsys):
    from lite_vo.cli.main import main
    seen = {}

    def fake_run_profile(settings, log=None, command=None):
        seen["s"] = settings
        return {"counts": {"ok": 1, "fail": 0, "crash": 0}}

    monkeypatch.setattr(C, "run_profile", fake_run_profile)
    seq = make_sequence(tmp_path / "d")
    rc = main(["profile", str(seq), "--profiles", "phone,board", "--repeat", "2", "--workers", "1", "--pin-core",
               "--max-frames", "40", "--init", "depth", "--out", str(tmp_path / "o"), "--no-startup", "--force",
               "--set", "tracking.huber=2", "--set", "system.map_every=2"])
    s = seen["s"]
    assert rc == 0 and "1 ok" in capsys.readouterr().out
    assert (s.profiles, s.repeat, s.workers, s.pin_core, s.max_frames, s.init, s.force, s.startup) == \
        (["phone", "board"], 2, 1, True, 40, "depth", True, False)
    assert s.overrides == ["tracking.huber=2", "system.map_every=2"]
    assert main(["profile", str(seq), "--set", "tracking.hubr=2"]) == 1
    assert "tracking.hubr" in capsys.readouterr().err
    assert main(["profile", str(seq), "--init-study", "3", "--out", str(tmp_path / "o2")]) == 0
    assert seen["s"].init_study == 3 and seen["s"].profiles == ["phone"]  # the paper's study used phone
    assert main(["profile", str(seq), "--workers", "0"]) == 1
    assert main(["profile", str(seq), "--profiles", "phone,nosuch"]) == 1
    assert "nosuch" in capsys.readouterr().err


def test_every_run_says_when_it_starts_and_ends(tmp_path):
    seq = make_sequence(tmp_path / "data")
    msgs: list[str] = []
    s = settings(tmp_path, [seq], profiles=["phone", "desktop"], repeat=2, workers=1)
    C.run_profile(s, launcher=FakeLauncher({"desktop": "crash"}), evaluator=FakeEvaluator(), log=msgs.append)
    keys = [f"seqA/{p}/{k}" for k in (0, 1) for p in ("phone", "desktop")]
    starts = [m for m in msgs if m.startswith("started ")]
    ends = [m for m in msgs if m.startswith("[")]
    assert [m.split()[1] for m in starts] == keys and [f"({i}/4)" for i in range(1, 5)] == [m.split()[2] for m in starts]
    assert [m.split()[1].rstrip(":") for m in ends] == keys
    assert "seqA/desktop/0: exit 1" in ends[1] and "seqA/phone/0: ok" in ends[0]
    # one line per step, in order: the sweep announces its runs before the first starts
    assert msgs.index(starts[0]) > next(i for i, m in enumerate(msgs) if m.startswith("4 runs"))


def test_cli_progress_goes_to_stderr_and_quiet_keeps_only_warnings(tmp_path, monkeypatch, capsys):
    from lite_vo.cli.main import main

    def fake_run_profile(settings, log=None, command=None):
        log("started seqA/phone/0 (1/1)")
        log("warning: seqA: no ground truth")
        return {"counts": {"ok": 1, "fail": 0, "crash": 0}}

    monkeypatch.setattr(C, "run_profile", fake_run_profile)
    seq = make_sequence(tmp_path / "d")
    assert main(["profile", str(seq), "--profiles", "phone", "--out", str(tmp_path / "o")]) == 0
    cap = capsys.readouterr()
    assert cap.err.splitlines() == ["started seqA/phone/0 (1/1)", "warning: seqA: no ground truth"]
    assert "started" not in cap.out and "report:" in cap.out
    assert main(["profile", str(seq), "--profiles", "phone", "--out", str(tmp_path / "o"), "--quiet"]) == 0
    assert capsys.readouterr().err.splitlines() == ["warning: seqA: no ground truth"]


def test_cli_parser_reads_the_paper_profiles_without_numpy():
    code = ("import sys; import lite_vo.cli.profile as p; from lite_vo.profiling import PAPER_PROFILES; "
            "assert p.PAPER_PROFILES is PAPER_PROFILES; print('numpy' in sys.modules)")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "False"


def test_cpu_model_names_x86_raspberry_pi_and_jetson(tmp_path):
    from lite_vo.profiling.machine import cpu_model
    x86 = tmp_path / "x86"
    x86.write_text("processor\t: 0\nmodel name\t: AMD EPYC 7B13\nflags\t: fpu\n")
    pi = tmp_path / "pi"
    pi.write_text("processor\t: 0\nBogoMIPS\t: 108.00\nHardware\t: BCM2835\nModel\t: Raspberry Pi 4 Model B Rev 1.4\n")
    jetson = tmp_path / "jetson"
    jetson.write_text("processor\t: 0\nBogoMIPS\t: 62.50\nCPU part\t: 0xd42\n")
    tree = tmp_path / "model"
    tree.write_bytes(b"NVIDIA Jetson Orin Nano Developer Kit\x00")
    none = tmp_path / "absent"
    assert cpu_model(x86, none) == "AMD EPYC 7B13"
    assert cpu_model(pi, tree) == "Raspberry Pi 4 Model B Rev 1.4"
    assert cpu_model(jetson, tree) == "NVIDIA Jetson Orin Nano Developer Kit"
    hw_only = tmp_path / "hw"
    hw_only.write_text("Hardware\t: BCM2835\n")
    assert cpu_model(hw_only, none) == "BCM2835"
