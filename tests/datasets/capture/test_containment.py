"""Every name a capture folder gives stays inside it (model.contained_path, capture_file)."""

import pytest

from spectralize.datasets.capture import CaptureError
from spectralize.datasets.capture.model import capture_file, contained_path


@pytest.fixture
def folder(tmp_path):
    root = tmp_path / "capture"
    (root / "rgb").mkdir(parents=True)
    (root / "rgb" / "a.tif").write_bytes(b"x")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "b.tif").write_bytes(b"y")
    (root / "inside.tif").symlink_to(root / "rgb" / "a.tif")
    (root / "outside.tif").symlink_to(tmp_path / "elsewhere" / "b.tif")
    (root / "linked").symlink_to(tmp_path / "elsewhere", target_is_directory=True)
    (root / "loop.tif").symlink_to(root / "loop.tif")
    return root


@pytest.mark.parametrize(
    "name, follow, why",
    [
        ("rgb/a.tif", False, ""),
        ("rgb/./a.tif", False, ""),
        ("rgb/../rgb/a.tif", False, "a path that leaves the capture folder"),
        ("../elsewhere/b.tif", False, "a path that leaves the capture folder"),
        ("/etc/passwd", False, "an absolute path '/etc/passwd'"),
        ("C:/data/a.tif", False, "an absolute path"),
        ("\\\\server\\share\\a.tif", False, "an absolute path"),
        ("", False, "an empty name"),
        ("rgb/a\x00.tif", False, "a name with a NUL character"),
        ("inside.tif", False, "a symbolic link (not followed: capture.toml has no follow_symlinks"),
        ("inside.tif", True, ""),
        ("outside.tif", False, "a symbolic link (not followed"),
        ("outside.tif", True, "a symbolic link to"),
        ("linked/b.tif", False, "in a symbolically linked folder 'linked'"),
        ("linked/b.tif", True, "outside the capture folder"),
        ("loop.tif", True, "a path that cannot be resolved"),
    ],
)
def test_a_name_is_inside_or_refused_with_why(folder, name, follow, why):
    path, found = contained_path(folder, name, follow_symlinks=follow)
    if not why:
        assert path is not None and found == "" and path.is_relative_to(folder)
    else:
        assert path is None and why in found, found


def test_capture_file_raises_one_problem_naming_the_file(folder):
    assert capture_file(folder, "rgb/a.tif") == folder / "rgb" / "a.tif"
    with pytest.raises(CaptureError) as info:
        capture_file(folder, "outside.tif")
    (problem,) = info.value.problems
    assert problem.where == "outside.tif" and problem.expected == "a path inside the capture folder"
