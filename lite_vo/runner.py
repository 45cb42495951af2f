"""``lite-vo run`` as a library call: the frame driver (:mod:`lite_vo.session`) with the output
sinks of :mod:`lite_vo.sinks`, writing the contract files into a folder (ARCHITECTURE.md):
``trajectory.txt`` (as the run goes), ``timing.json``, ``run.json``, ``map.ply`` and, when the
sequence has depth images, ``depth_accuracy.json`` (+ ``depth_error.png`` if matplotlib exists).

No argparse here; the CLI module parses and calls :func:`run_sequence`. Imports no GL or physics package.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .config import VOConfig
from .errors import InputError
from .io import prepare_output_dir
from .session import Session
from .sinks import MapSink, ProgressSink, RunInfoSink, TrajectoryExportSink, TrajectorySink

RUN_OUTPUTS = ("trajectory.txt", "timing.json", "run.json", "map.ply", "depth_accuracy.json", "depth_error.png",
               "trajectory_kitti.txt", "times.txt", "trajectory.png", "vignette.png", "vignette.json",
               "pcalib.txt")


@dataclass
class RunResult:
    """What a run produced (also written to disk when it had an output folder)."""
    out_dir: Path | None
    status: str
    timestamps: list = field(default_factory=list)
    poses: list = field(default_factory=list)
    timing: dict = field(default_factory=dict)
    info: dict = field(default_factory=dict)


def run_sequence(sequence, config: VOConfig, out_dir: Path | None = None, *, force: bool = False,
                 depth_source: str = "filter", pose_source: str = "estimate", max_frames: int | None = None,
                 start_frame: int = 0, quiet: bool = True, sinks=(), profile_name: str | None = None,
                 max_bad_frames: int = 10, calib=None, kitti: bool = False, plot: bool = False,
                 photometric=None, map_voxel: float = 0.0, estimate_vignette: bool = False) -> RunResult:
    """Run the visual odometry over ``sequence`` (a path, camera index or opened sequence).

    Writes the contract files into ``out_dir`` (when given) as the run goes; ``sinks`` are further
    :class:`~lite_vo.session.OutputSink` objects. ``pose_source="gt"`` takes the poses from the
    ground truth (mapping only); ``depth_source="images"`` tracks against the depth images
    (tracking only). ``kitti``: also ``trajectory_kitti.txt`` (+ ``times.txt``); ``plot``: also
    ``trajectory.png`` (against the ground truth when the sequence has it); ``map_voxel > 0``: ``map.ply``
    with one point per voxel of that size; ``estimate_vignette``: fit the camera's vignetting to the run's maps
    and write ``vignette.png`` / ``vignette.json`` (DSO's format: the folder then works as ``photometric``
    for the next run; :mod:`lite_vo.vignette`). Ctrl-C, SIGTERM and errors still finish the files (status ``interrupted at
    frame N`` or ``failed: ...``) and are then re-raised.
    """
    if estimate_vignette and out_dir is None:
        raise InputError("estimating the vignette needs an output folder to write vignette.png into")
    if plot:
        from .plots import require_matplotlib
        require_matplotlib()                  # before the run, not after it
    session = Session(sequence, config, depth_source=depth_source, pose_source=pose_source,
                      start_frame=start_frame, max_frames=max_frames, max_bad_frames=max_bad_frames,
                      profile_name=profile_name, calib=calib, photometric=photometric)
    run_info = RunInfoSink(None)
    own = [run_info]
    if out_dir is not None:  # only once the input is known to be usable
        out = prepare_output_dir(Path(out_dir), force, clean=RUN_OUTPUTS)
        run_info = RunInfoSink(out)
        trajectory = TrajectorySink(out / "trajectory.txt")
        own = [trajectory, run_info, MapSink(out / "map.ply", voxel=map_voxel)]
        if kitti or plot:
            own.append(TrajectoryExportSink(trajectory, out / "trajectory_kitti.txt" if kitti else None,
                                            out / "trajectory.png" if plot else None,
                                            session.sequence.groundtruth))
        if estimate_vignette:
            from .vignette import VignetteSink
            own.append(VignetteSink(out, session.sequence.camera, given=session.photometric))
    if not quiet:
        own.append(ProgressSink())
    session.sinks = own + list(sinks)
    res = session.run()
    info = run_info.info
    return RunResult(Path(out_dir) if out_dir is not None else None, res.status, res.timestamps, res.poses,
                     res.end.timing, info)
