"""``lite-vo calibrate`` on board sequences rendered here through a known pinhole + radtan camera:
it recovers the intrinsics, refuses too few views, and writes a calib.txt that ``run`` reads."""
from __future__ import annotations

import functools

import cv2
import numpy as np
import pytest

from lite_vo.calibrate import Board, View, calibrate_source, coverage, parse_pattern, select_views
from lite_vo.camera import Camera
from lite_vo.errors import InputError
from lite_vo.geometry import exp_so3
from lite_vo.io import open_sequence, read_calibration

TRUE = Camera.radtan(500.0, 503.0, 324.0, 236.5, 640, 480, -0.26, 0.085, 0.0012, -0.0008, 0.0)
BOARD = Board("chessboard", 9, 6, 0.03)
PX = 40                                   # texture pixels per square


def board_texture(board: Board) -> tuple[np.ndarray, float]:
    """A (cols+1) x (rows+1) squares chessboard with a one-square white margin; returns the
    texture and the texture coordinate of the first inner corner (both axes)."""
    nx, ny = board.cols + 1, board.rows + 1
    u, v = np.meshgrid(np.arange((nx + 2) * PX), np.arange((ny + 2) * PX))
    sq = ((u // PX - 1) + (v // PX - 1)) % 2 == 1
    inside = (u >= PX) & (u < (nx + 1) * PX) & (v >= PX) & (v < (ny + 1) * PX)
    tex = np.where(inside & sq, 30, 225).astype(np.float32)
    return tex, 2 * PX - 0.5             # first inner corner: two squares in (pixel-centre convention)


@functools.lru_cache(maxsize=4)
def _rays(cam: Camera, ss: int) -> np.ndarray:
    """(H*ss, W*ss, 3) rays (x, y, 1) of the sub-pixel centres, distortion removed."""
    i = cam.intrinsics
    u, v = np.meshgrid((np.arange(i.width * ss) + 0.5) / ss - 0.5, (np.arange(i.height * ss) + 0.5) / ss - 0.5)
    xy = cam.unproject(np.stack([u, v], -1))
    return np.stack([xy[..., 0], xy[..., 1], np.ones_like(u)], -1)


def render_view(cam: Camera, R: np.ndarray, t: np.ndarray, tex: np.ndarray, origin: float,
                rng: np.random.Generator, square: float = BOARD.square, background: float = 110.0,
                ss: int = 2) -> np.ndarray:
    """The board (plane z = 0 of its frame, posed by R, t in the camera) seen through ``cam``:
    each pixel's ray (distortion removed with the camera model) meets the board plane; the
    texture (``PX`` pixels per ``square`` metres, board origin at texture coordinate ``origin``)
    is sampled there. Rendered ``ss`` times larger and area-averaged; noise added."""
    i = cam.intrinsics
    Hinv = np.linalg.inv(np.column_stack([R[:, 0], R[:, 1], t]))
    ray = _rays(cam, ss) @ Hinv.T
    X, Y = ray[..., 0] / ray[..., 2], ray[..., 1] / ray[..., 2]
    s = square / PX
    mx = (X / s + origin).astype(np.float32)
    my = (Y / s + origin).astype(np.float32)
    big = cv2.remap(tex, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    img = cv2.resize(big, (i.width, i.height), interpolation=cv2.INTER_AREA)
    img = img + rng.normal(0, 2.0, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def random_poses(cam: Camera, n: int, rng: np.random.Generator, board: Board = BOARD):
    """Board poses seen whole by ``cam``: spread over the image, 0.35-0.8 m, tilted up to ~40 deg."""
    w, h = (board.cols - 1) * board.square, (board.rows - 1) * board.square
    corners = np.array([[-board.square, -board.square, 0], [w + board.square, -board.square, 0],
                        [w + board.square, h + board.square, 0], [-board.square, h + board.square, 0]])
    out = []
    while len(out) < n:
        R = exp_so3(np.array([rng.uniform(-0.7, 0.7), rng.uniform(-0.7, 0.7), rng.uniform(-0.4, 0.4)]))
        z = rng.uniform(0.35, 0.8)
        target = np.array([rng.uniform(-0.45, 0.45) * z, rng.uniform(-0.35, 0.35) * z, z])
        t = target - R @ np.array([w / 2, h / 2, 0.0])
        pc = corners @ R.T + t
        if np.any(pc[:, 2] < 0.1):
            continue
        uv = cam.project(pc)
        if uv[:, 0].min() < 5 or uv[:, 1].min() < 5 or uv[:, 0].max() > cam.width - 6 or uv[:, 1].max() > cam.height - 6:
            continue
        out.append((R, t))
    return out


@pytest.fixture(scope="module")
def board_folder(tmp_path_factory):
    rng = np.random.default_rng(7)
    folder = tmp_path_factory.mktemp("board") / "views"
    folder.mkdir()
    tex, origin = board_texture(BOARD)
    for k, (R, t) in enumerate(random_poses(TRUE, 30, rng)):
        cv2.imwrite(str(folder / f"view{k:02d}.png"), render_view(TRUE, R, t, tex, origin, rng))
    return folder


def test_calibrate_recovers_known_intrinsics(board_folder, tmp_path):
    from lite_vo.cli.main import main
    out = tmp_path / "calib.txt"
    assert main(["calibrate", str(board_folder), "--chessboard", "9x6", "--square", "0.03", "--out", str(out)]) == 0
    cam = read_calibration(out).camera
    i, t = cam.intrinsics, TRUE.intrinsics
    assert abs(i.fx / t.fx - 1) < 0.01 and abs(i.fy / t.fy - 1) < 0.01, cam.describe()
    assert abs(i.cx - t.cx) < 3.0 and abs(i.cy - t.cy) < 3.0, cam.describe()
    assert cam.model == "radtan" and abs(cam.params[0] - TRUE.params[0]) < 0.03, cam.describe()
    # the whole lens, not just the numbers: pixels agree with the true camera over the image
    rng = np.random.default_rng(1)
    pts = np.concatenate([rng.uniform(-0.55, 0.55, (300, 1)), rng.uniform(-0.42, 0.42, (300, 1)), np.ones((300, 1))], 1)
    assert np.abs(cam.project(pts) - TRUE.project(pts)).max() < 1.5
    # never overwritten without --force
    assert main(["calibrate", str(board_folder), "--chessboard", "9x6", "--square", "0.03", "--out", str(out)]) == 1
    # the written file is what `run` reads: an image folder with it opens with this camera
    seq = open_sequence(board_folder, calib=out)
    assert seq.camera == cam


def test_calibrate_report(board_folder, capsys):
    res = calibrate_source(board_folder, BOARD, max_views=20)
    assert res.boards_found == 30 and res.frames_read == 30
    assert len(res.view_errors) + len(res.dropped) == 20        # at most --max-views views are used
    assert 0.0 < res.rms < 0.5                                   # rendered with 2 grey levels of noise
    assert all(0 < e < 1.0 for _, e in res.view_errors)
    assert 0.5 < res.coverage <= 1.0 and res.coverage_map.count("#") == round(res.coverage * 48)


def test_calibrate_from_a_video(board_folder, tmp_path):
    video = tmp_path / "board.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 10.0, (640, 480))
    if not writer.isOpened():
        pytest.skip("this OpenCV build cannot write MJPG videos")
    for p in sorted(board_folder.iterdir())[:14]:
        img = cv2.imread(str(p))
        for _ in range(3):                      # each view held for 3 frames, as a hand-held sweep
            writer.write(img)
    writer.release()
    res = calibrate_source(video, BOARD, max_candidates=14)     # every 3rd frame is searched
    assert res.frames_read == 14 and res.boards_found == 14
    assert all(name.startswith("frame ") and int(name.split()[1]) % 3 == 0 for name, _ in res.view_errors)
    i = res.camera.intrinsics
    assert abs(i.fx / TRUE.intrinsics.fx - 1) < 0.02 and abs(i.cx - TRUE.intrinsics.cx) < 5.0


def test_too_few_views_is_refused(board_folder, tmp_path):
    few = tmp_path / "few"
    few.mkdir()
    for p in sorted(board_folder.iterdir())[:5]:
        (few / p.name).write_bytes(p.read_bytes())
    with pytest.raises(InputError, match=r"found in only 5 of 5 images \(need at least 8\)"):
        calibrate_source(few, BOARD)
    # a pattern larger than the board finds nothing and says what to check
    with pytest.raises(InputError, match=r"found in only 0 of 5 images .*check COLSxROWS"):
        calibrate_source(few, Board("chessboard", 11, 8, 0.03))


def test_view_selection_spreads_and_coverage_counts_cells():
    rng = np.random.default_rng(3)
    obj = BOARD.chessboard_points()
    views = []
    for k in range(60):                 # 50 near-identical views in the centre, 10 elsewhere
        c = np.array([320.0, 240.0]) if k < 50 else rng.uniform([60, 60], [580, 420])
        img = (obj[:, :2] / 0.03 * 8 + c - [32, 20] + rng.normal(0, 0.2, (len(obj), 2))).astype(np.float32)
        views.append(View(f"v{k}", img, obj))
    chosen = select_views(views, 640, 480, max_views=12)
    assert len(chosen) == 12
    assert sum(v.name in {f"v{k}" for k in range(50, 60)} for v in chosen) == 10   # all the spread ones
    cov, cmap = coverage(views[:1], 640, 480)
    assert cmap.count("#") == round(cov * 48) and 0 < cov < 0.2


def test_pattern_parsing_and_board_errors():
    assert parse_pattern("9x6", "--chessboard") == (9, 6)
    with pytest.raises(InputError, match=r"--chessboard must be COLSxROWS"):
        parse_pattern("9*6", "--chessboard")
    with pytest.raises(InputError, match=r"--square must be a positive length"):
        Board("chessboard", 9, 6, -1.0)


def test_charuco_board(tmp_path):
    if not hasattr(cv2, "aruco") or not hasattr(cv2.aruco, "CharucoDetector"):
        pytest.skip("this OpenCV has no ChArUco detector")
    board = Board("charuco", 7, 5, 0.04, 0.03, "DICT_5X5_100")
    cb = cv2.aruco.CharucoBoard((7, 5), 0.04, 0.03, cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_5X5_100))
    margin = PX
    tex = cb.generateImage((7 * PX + 2 * margin, 5 * PX + 2 * margin), marginSize=margin).astype(np.float32)
    tex = 30 + tex * (195 / 255)
    rng = np.random.default_rng(11)
    folder = tmp_path / "charuco"
    folder.mkdir()
    # the ChArUco object points start at the board's outer corner, texture coordinate margin - 0.5;
    # the pose sampler places a 6x4 inner-corner board of the same outer size (7x5 squares)
    for k, (R, t) in enumerate(random_poses(TRUE, 24, rng, Board("chessboard", 6, 4, 0.04))):
        t = t - R @ np.array([0.04, 0.04, 0.0])
        img = render_view(TRUE, R, t, tex, margin - 0.5, rng, square=0.04, background=225.0)
        cv2.imwrite(str(folder / f"c{k:02d}.png"), img)
    res = calibrate_source(folder, board)
    i, t = res.camera.intrinsics, TRUE.intrinsics
    assert res.boards_found >= 20
    assert abs(i.fx / t.fx - 1) < 0.01 and abs(i.fy / t.fy - 1) < 0.01, res.camera.describe()
    assert abs(i.cx - t.cx) < 3.0 and abs(i.cy - t.cy) < 3.0
    assert abs(res.camera.params[0] - TRUE.params[0]) < 0.03
