"""The README is the front door: its Python block runs as written (in a folder where the
``lite-vo synth ... --out synth_room`` command it refers to has been run, shortened to 40 frames)."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _python_blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "README.md").read_text(), flags=re.S)


def test_the_readme_python_block_runs_as_written(tmp_path):
    from lite_vo.synth import generate_sequence
    blocks = _python_blocks()
    assert blocks, "the README has no python block"
    generate_sequence(tmp_path / "synth_room", scene="room", trajectory="handheld", n_frames=40, seed=0,
                      width=320, height=240)
    for code in blocks:
        r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, f"README block failed:\n{code}\n{r.stderr[-3000:]}"
        assert "40 poses" in r.stdout and "(240, 320) map" in r.stdout, r.stdout
