"""Tests of lite_vo.profiling.startup (cold vs warm start-up, the warm-up before a sweep) and of
lite_vo.warmup, which both rely on."""
from __future__ import annotations

import subprocess

from lite_vo.profiling import startup as St
from lite_vo.warmup import warmup


def test_warmup_reports_each_module_and_skips_missing_ones(tmp_path, monkeypatch):
    pkg = tmp_path / "wpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "good.py").write_text("CALLS = []\ndef warmup():\n    CALLS.append(1)\n")
    (pkg / "bad.py").write_text("def warmup():\n    raise ValueError('kernel broke')\n")
    (pkg / "plain.py").write_text("X = 1\n")
    (pkg / "needs.py").write_text("import not_installed_dep_xyz\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    seen = []
    res = warmup(["wpkg.good", "wpkg.bad", "wpkg.plain", "wpkg.nothere", "nopkg_xyz.k", "wpkg.needs"],
                 on_result=seen.append)
    status = {r.module: r.status for r in res}
    assert status == {"wpkg.good": "ok", "wpkg.bad": "error", "wpkg.plain": "no_warmup",
                      "wpkg.nothere": "missing", "nopkg_xyz.k": "missing", "wpkg.needs": "error"}
    assert len(seen) == 6
    import wpkg.good
    assert wpkg.good.CALLS == [1]
    assert "kernel broke" in res[1].message
    assert "not_installed_dep_xyz" in res[5].message


def test_warmup_cli_prints_each_module_and_fails_on_errors(tmp_path, monkeypatch, capsys):
    import lite_vo.warmup as W
    from lite_vo.cli.main import main
    assert {"lite_vo.image", "lite_vo.tracking._kernels", "lite_vo.mapping._kernels",
            "lite_vo.synth._kernels"} <= set(W.KERNEL_MODULES)
    assert "ar_demo._kernels" in W.plugin_kernel_modules()            # registered by the plug-in
    assert not any(m.startswith("ar_demo") for m in W.KERNEL_MODULES)  # the core names no plug-in
    monkeypatch.setattr(W, "plugin_kernel_modules", lambda: ())
    pkg = tmp_path / "wpkg2"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "good.py").write_text("def warmup():\n    pass\n")
    (pkg / "bad.py").write_text("def warmup():\n    raise ValueError('kernel broke')\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(W, "KERNEL_MODULES", ("wpkg2.good", "wpkg2.absent"))
    assert main(["warmup"]) == 0
    out = capsys.readouterr().out
    assert "wpkg2.good" in out and "wpkg2.absent" in out and "skipped" in out
    assert main(["warmup", "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    monkeypatch.setattr(W, "KERNEL_MODULES", ("wpkg2.good", "wpkg2.bad"))
    assert main(["warmup", "--quiet"]) == 1
    assert "kernel broke" in capsys.readouterr().err


def test_compiled_kernels_from_numba_debug_output():
    text = ("[cache] index saved to '/tmp/c/tracking_9eea/_kernels.accumulate-89.py311.nbi'\n"
            "[cache] data saved to '/tmp/c/tracking_9eea/_kernels.accumulate-89.py311.2.nbc'\n"
            "[cache] data loaded from '/tmp/c/mapping_12ab/_kernels.observe-10.py311.1.nbc'\n"
            "[cache] data saved to '/tmp/c/tracking_9eea/_kernels.lm_level-307.py311.2.nbc'\n"
            "[cache] data saved to '/tmp/c/lite_vo_77aa/image._blur_separable-151.py311.1.nbc'\n")
    assert St.compiled_kernels(text) == ["lite_vo/image._blur_separable", "tracking/_kernels.accumulate",
                                        "tracking/_kernels.lm_level"]
    assert St.compiled_kernels("") == []


def test_probe_times_exactly_the_first_frames_through_the_session(synth_small):
    import lite_vo
    from lite_vo.session import Session
    session = Session(synth_small, lite_vo.load_profile("phone", ['system.init="depth"']), max_frames=3,
                      warm_up_kernels=False)
    ms = St.first_frames_ms(session)
    assert len(ms) == 3 and all(m > 0.0 for m in ms)
    probe = St.startup_probe(str(synth_small), "phone", 2)
    assert len(probe["frame_ms"]) == 2 and probe["total_s"] * 1e3 >= sum(probe["frame_ms"])


def test_warm_up_says_what_it_does_before_and_after(monkeypatch):
    results = iter([subprocess.CompletedProcess([], 0, "", ""),
                    subprocess.CompletedProcess([], 1, "", "x\nValueError: x\n")])
    seen = []
    monkeypatch.setattr(St.subprocess, "run", lambda cmd, **kw: seen.append(cmd) or next(results))
    msgs: list[str] = []
    assert St.run_warmup(log=msgs.append)["ok"]
    assert seen[0][1:] == ["-m", "lite_vo.cli.main", "warmup", "--quiet"]
    assert msgs[0] == "warming up numba kernels (lite-vo warmup) ..." and msgs[1].startswith("warm-up done in ")
    res = St.run_warmup(log=msgs.append)
    assert not res["ok"] and res["error"] == "ValueError: x" and "warm-up failed after" in msgs[-1]


def test_start_up_measurement_says_what_each_process_does(monkeypatch):
    calls = []

    def fake_python_json(code, args, env, timeout):
        calls.append((code, env.get("NUMBA_CACHE_DIR"), env.get("NUMBA_DEBUG_CACHE")))
        return {"ok": len(calls) != 2, "process_s": 10.0 * len(calls), "error": "broken warm-up"}

    monkeypatch.setattr(St, "python_json", fake_python_json)
    msgs: list[str] = []
    res = St.measure_startup("seq", "phone", 2, log=msgs.append)
    assert [m.split(":")[0] for m in msgs] == ["start-up 1/3"] * 2 + ["start-up 2/3"] * 2 + ["start-up 3/3"] * 2
    assert msgs[0].endswith("...") and msgs[1].endswith("10.0 s") and msgs[3].endswith("failed: broken warm-up")
    assert res["cold"]["process_s"] == 10.0 and res["warm"]["process_s"] == 30.0
    # cold and warm probes use different, fresh caches; only the warm one lists compiled kernels
    assert calls[0][0] == calls[2][0] == St.PROBE_CODE and calls[1][0] == St.WARMUP_CODE
    assert calls[0][1] != calls[2][1] == calls[1][1] and calls[2][2] == "1" and calls[0][2] is None
