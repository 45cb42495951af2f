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
