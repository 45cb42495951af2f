"""The overwrite rule shared by every command (lite_vo.io.outputs)."""
import pytest

from lite_vo.errors import InputError
from lite_vo.io import check_output_file, prepare_output_dir


def test_non_empty_folder_needs_force_and_force_removes_only_our_outputs(tmp_path):
    out = tmp_path / "out"
    prepare_output_dir(out, force=False)  # new folder: created
    (out / "run.json").write_text("old")
    (out / "notes.txt").write_text("user's")
    with pytest.raises(InputError, match="--force"):
        prepare_output_dir(out, force=False)
    prepare_output_dir(out, force=True, clean=("run.json",))
    assert not (out / "run.json").exists()
    assert (out / "notes.txt").read_text() == "user's"


def test_a_file_in_place_of_the_folder_is_an_error(tmp_path):
    f = tmp_path / "x"
    f.write_text("")
    with pytest.raises(InputError, match="not a folder"):
        prepare_output_dir(f, force=True)


def test_existing_file_needs_force(tmp_path):
    f = tmp_path / "v.mp4"
    check_output_file(f, force=False)
    f.write_text("")
    with pytest.raises(InputError, match="already exists"):
        check_output_file(f, force=False)
    check_output_file(f, force=True)


def test_trajectory_gives_frames_lost_during_the_start_up_the_pose_a_correction_brings(tmp_path):
    """Frames lost while a monocular start-up is unresolved get the two-view start-up's poses when
    the bootstrap corrects the earlier frames: trajectory.txt has them, in frame order."""
    import numpy as np

    from lite_vo.io import read_trajectory
    from lite_vo.session import FrameEvent
    from lite_vo.sinks import TrajectorySink
    from lite_vo.system import FrameResult

    def pose(x):
        T = np.eye(4)
        T[0, 3] = x
        return T

    sink = TrajectorySink(tmp_path / "trajectory.txt")
    sink.on_start(None)
    img = np.zeros((4, 4), np.float32)
    for i in range(6):
        lost = i in (2, 3, 4)
        sink.on_frame(FrameEvent(FrameResult(i, 0.1 * i, None if lost else pose(i), lost), img))
    assert len(read_trajectory(tmp_path / "trajectory.txt")) == 3          # 0, 1, 5 so far
    sink.on_corrections({2: pose(2.5), 3: pose(3.5), 4: None, 1: pose(1.5)})
    traj = read_trajectory(tmp_path / "trajectory.txt")
    np.testing.assert_allclose(traj.timestamps, [0.0, 0.1, 0.2, 0.3, 0.5])
    np.testing.assert_allclose(traj.poses[:, 0, 3], [0.0, 1.5, 2.5, 3.5, 5.0])
    sink.on_frame(FrameEvent(FrameResult(6, 0.6, pose(6), False), img))   # appending goes on
    sink.on_finish(None)
    traj = read_trajectory(tmp_path / "trajectory.txt")
    np.testing.assert_allclose(traj.poses[:, 0, 3], [0.0, 1.5, 2.5, 3.5, 5.0, 6.0])
