"""Does the car live in the real room? Measured against a sequence's depth images (issue 15 targets).

For every frame from the car's spawn on, the car's footprint centre (``car.txt``, ``T_world_car``) is
taken into the camera with the run's own camera pose (``trajectory.txt``, what the video shows) and
projected with the sequence's camera:

* **in view**: in front of the camera and inside the image (frames without a car count as not in view);
* **on a surface**: its depth is within ``tol`` (8 %) of the true depth image at that pixel;
* **hidden**: it lies more than ``tol`` behind the true surface (behind or inside real geometry);
* **tilt**: the angle between the car's z axis and the ground-plane normal of the run.

Imports: numpy, lite_vo (io, geometry).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from lite_vo.geometry import inverse_se3, transform_points


def read_tum(path) -> tuple[np.ndarray, np.ndarray]:
    """(timestamps, poses (N, 4, 4)) of a TUM file (``#`` comments allowed)."""
    from lite_vo.io import read_trajectory
    tr = read_trajectory(path)
    return tr.timestamps, tr.poses


def evaluate_ar_run(sequence, out_dir, tol: float = 0.08) -> dict:
    """The issue-15 measures of an ``lite-vo ar`` run whose outputs are in ``out_dir``."""
    from lite_vo.io import open_sequence
    out_dir = Path(out_dir)
    summary = json.loads((out_dir / "ar_summary.json").read_text())
    t_cam, T_cam = read_tum(out_dir / "trajectory.txt")
    try:
        t_car, T_car = read_tum(out_dir / "car.txt")
    except Exception:                                        # no car line at all
        t_car, T_car = np.zeros(0), np.zeros((0, 4, 4))
    seq = open_sequence(sequence)
    intr = seq.camera.intrinsics
    normal = np.asarray((summary.get("ground_plane") or {}).get("normal_world", [0, 0, 1]), dtype=np.float64)
    cam_at = {round(float(t), 6): T for t, T in zip(t_cam, T_cam)}
    car_at = {round(float(t), 6): T for t, T in zip(t_car, T_car)}
    rows = []
    spawned = False
    last_t = float(t_cam[-1]) if len(t_cam) else -np.inf
    for i in range(len(seq)):
        ts = float(seq.timestamps[i])
        if ts > last_t + 1e-6:
            break                                            # the run ended here (--max-frames)
        key = round(ts, 6)
        if key in car_at:
            spawned = True
        if not spawned:
            continue
        row = {"frame": i, "t": ts, "car": key in car_at, "in_view": False, "on_surface": False, "hidden": False,
               "tilt_deg": np.nan}
        rows.append(row)
        if key not in car_at or key not in cam_at:
            continue
        Tc = car_at[key]
        row["tilt_deg"] = float(np.degrees(np.arccos(np.clip(Tc[:3, 2] @ normal, -1, 1))))
        p = transform_points(inverse_se3(cam_at[key]), Tc[:3, 3][None])[0]
        if p[2] <= 0:
            continue
        u, v = intr.fx * p[0] / p[2] + intr.cx, intr.fy * p[1] / p[2] + intr.cy
        if not (-0.5 <= u < intr.width - 0.5 and -0.5 <= v < intr.height - 0.5):
            continue
        row["in_view"] = True
        depth = seq.frame(i).depth
        if depth is None:
            continue
        D = float(depth[int(round(v)), int(round(u))])
        if D <= 0:
            continue
        row["true_depth"], row["car_depth"] = D, float(p[2])
        row["on_surface"] = abs(p[2] - D) <= tol * D
        row["hidden"] = p[2] > (1 + tol) * D
    seq.close()
    n = len(rows)
    inv = [r for r in rows if r["in_view"]]
    with_depth = [r for r in inv if "true_depth" in r]
    tilts = np.array([r["tilt_deg"] for r in rows if np.isfinite(r["tilt_deg"])])
    res = {
        "frames_from_spawn": n,
        "in_view": len(inv) / n if n else 0.0,
        "on_surface_in_view": float(np.mean([r["on_surface"] for r in with_depth])) if with_depth else 0.0,
        "hidden_in_view": float(np.mean([r["hidden"] for r in with_depth])) if with_depth else 0.0,
        "tilt_p90_deg": float(np.percentile(tilts, 90)) if len(tilts) else float("nan"),
        "upright_20deg": float(np.mean(tilts <= 20.0)) if len(tilts) else 0.0,
        "car_frames": int(sum(r["car"] for r in rows)),
        "spawns": summary.get("car_spawns"), "spawn_reasons": summary.get("car_spawn_reasons"),
        "car_length": (summary.get("car_size") or {}).get("length"),
        "tol": tol,
    }
    res["targets"] = {"in_view >= 0.70": res["in_view"] >= 0.70,
                      "on_surface_in_view >= 0.90": res["on_surface_in_view"] >= 0.90,
                      "hidden_in_view <= 0.05": res["hidden_in_view"] <= 0.05,
                      "upright_20deg >= 0.90": res["upright_20deg"] >= 0.90}
    return res
