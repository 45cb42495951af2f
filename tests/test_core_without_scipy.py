"""The core install is numpy + numba + OpenCV only: no kernel may need SciPy (numba routes
np.dot / @ / np.linalg inside kernels to SciPy's BLAS/LAPACK). Runs every core kernel and a few
frames of the system in a subprocess where importing scipy fails."""
import subprocess
import sys
import textwrap


def test_core_kernels_and_system_run_without_scipy(synth_small):
    code = textwrap.dedent(f"""
        import sys
        sys.modules["scipy"] = None  # any "import scipy..." now raises ImportError
        from lite_vo.warmup import warmup
        results = warmup(["lite_vo.image", "lite_vo.tracking._kernels", "lite_vo.mapping._kernels",
                          "lite_vo.synth._kernels", "lite_vo._cloud_kernels"])
        bad = [(r.module, r.message) for r in results if r.status != "ok"]
        assert not bad, bad
        import lite_vo
        seq = lite_vo.open_sequence({str(synth_small)!r})
        for init in ("depth", "random"):
            cfg = lite_vo.load_profile("phone", ['system.init="' + init + '"'])
            with lite_vo.VisualOdometry(seq.camera, cfg) as vo:
                for fr, _ in zip(seq, range(12)):
                    res = vo.process(fr.image, fr.timestamp, depth=fr.depth)
            assert not res.lost
        print("OK")
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("OK"), proc.stderr[-2000:]
