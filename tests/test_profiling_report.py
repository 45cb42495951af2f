"""Tests of lite_vo.profiling.report, .plots and .machine."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from lite_vo.profiling import machine as M
from lite_vo.profiling import report as R


def test_machine_info_describes_this_machine():
    m = M.machine_info()
    assert m["cpu_count"] >= 1 and m["cores_available"] >= 1
    assert m["python"].count(".") == 2 and m["numpy"] == np.__version__
    assert "CPU:" in R.machine_lines(m)[0]


def test_accuracy_cells():
    ok = {"runs": 2, "ok": 2, "failed": 0, "crashed": 0, "x": {"mean": 0.625, "std": 0.05, "n": 2}, "y": None}
    assert R.format_cell(ok, "x") == "0.62 ± 0.05" or R.format_cell(ok, "x") == "0.63 ± 0.05"
    assert R.format_cell(ok, "y") == "n/a"  # evaluated, but e.g. shorter than the 1-s RPE interval
    part = dict(ok, ok=1, failed=1, x={"mean": 1.0, "std": 0.0, "n": 1})
    assert R.format_cell(part, "x") == "1.00 (1/2 fail)"
    assert R.format_cell({"runs": 1, "ok": 0, "failed": 1, "crashed": 0}, "x") == "fail"
    assert R.format_cell({"runs": 1, "ok": 0, "failed": 1, "crashed": 1}, "x") == "crash"
    assert R.format_cell({"runs": 0}, "x") == "-"


def test_report_json_has_no_nan_and_only_plain_types(tmp_path):
    report = {"a": float("nan"), "b": [np.float32(1.5), np.int64(3), np.array([1.0, np.inf])],
              "c": {1: Path("x/y")}, "d": (np.float64(-np.inf), "s"), "profiles": {}, "runs": []}
    paths = R.write_report(report, tmp_path, plots=False)
    assert [p.name for p in paths] == ["report.md", "report.json"]
    text = (tmp_path / "report.json").read_text()
    data = json.loads(text)
    assert "NaN" not in text and "Infinity" not in text
    assert data["a"] is None and data["b"] == [1.5, 3, [1.0, None]] and data["c"] == {"1": "x/y"}
    assert data["d"] == [None, "s"] and data["plots"] == []
    assert isinstance(R.json_ready(np.int64(3)), int) and not math.isnan(R.json_ready([np.float32(2)])[0])


def test_markdown_sections_in_order_and_init_study_criterion(tmp_path):
    report = {
        "created_utc": "2024-01-01T00:00:00Z", "elapsed_s": 1.0, "settings": {"repeat": 1, "init_study_len": 4.0},
        "profiles": {"phone": {"map_width": 320, "track_width": 160}},
        "accuracy": {"seqA": {"phone": {"runs": 1, "ok": 1, "failed": 0, "crashed": 0,
                                        "rpe_trans_cm_per_s": {"mean": 1.234, "std": 0.0, "n": 1}}}},
        "timing": {}, "runs": [],
        "init_study": {"seqA": {"runs": 2, "successes": 1, "success_rate": 0.5, "crashed": 0,
                                "criterion": {"depth_error_max": 0.16, "depth_at_s": 3.0, "drift_max": 0.6,
                                              "drift_frames": 15}}},
        "init_study_profile": "phone",
    }
    md = R.render_markdown(report, [str(tmp_path / "accuracy_vs_resolution.png")])
    heads = [ln for ln in md.splitlines() if ln.startswith("#")]
    assert heads == ["# lite-vo profile report", "## Accuracy (thesis Table 5.1)", "## Timing (thesis Table 5.2)",
                     "## Per-stage timings", "## Initialisation study (thesis Fig. 5.8)", "## Plots"]
    assert "| phone | 320 | 160 | 1.23 |" in md
    assert "at most 16% and the final relative translational drift over 15 frames" in md
    assert "![accuracy_vs_resolution](accuracy_vs_resolution.png)" in md
