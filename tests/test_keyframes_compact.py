"""The compact keyframe: every public array decodes exactly to what it was made from (the colour image,
stored as a JPEG, within a grey level or two), ``nbytes`` is what is stored, and the store's bound counts
those bytes."""
from __future__ import annotations

import numpy as np
import pytest

from lite_vo.camera import PinholeIntrinsics
from lite_vo.geometry import make_pose
from lite_vo.keyframes import Keyframe, KeyframeStore, scene_cloud, scene_cloud_parts

H, W = 48, 64
CAM = PinholeIntrinsics(50.0, 50.0, 31.5, 23.5, W, H)


def _inputs(seed: int, colour: bool = True):
    """A keyframe's dense inputs: ~40 % of the pixels with a hypothesis, some empty pixels holding
    zeros, negatives or infinities (not hypotheses), a few NaN variances at valid pixels."""
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.2, 2.0, (H, W)).astype(np.float32)
    empty = rng.random((H, W)) > 0.4
    d[empty] = np.nan
    d[0, :3] = (0.0, -1.0, np.inf)
    var = rng.uniform(1e-6, 1e-2, (H, W)).astype(np.float32)
    var[5, 5] = np.nan
    d[5, 5] = 1.0
    image = rng.integers(0, 256, (H, W), dtype=np.uint8)
    color = None
    if colour:      # a camera image: smooth shading, a few sharp coloured edges, a little noise
        yy, xx = np.mgrid[0:H, 0:W]
        color = np.stack([40 + 2 * xx, 60 + 3 * yy, 200 - xx - yy], -1).astype(np.float64)
        color[H // 3:, W // 2:] = rng.uniform(0, 255, 3)
        color += rng.normal(0, 1, color.shape)
        color = np.clip(color + 0.5, 0, 255).astype(np.uint8)
    return image, d, var, color


def _close_colour(a, b) -> bool:
    """The stored JPEG's round trip (quality 95, 4:4:4: mean error 0.9, at most 5 grey levels here):
    a mean error below 1.05, none above 10. Quality 75 (mean 1.2) or 4:2:0 chroma (edges off by 18-38) fail."""
    err = np.abs(a.astype(np.int16) - b.astype(np.int16))
    return a.shape == b.shape and err.mean() < 1.05 and err.max() <= 10


def _kf(seed: int, x: float = 0.0, colour: bool = True) -> Keyframe:
    image, d, var, color = _inputs(seed, colour)
    return Keyframe.make(seed, seed / 30, make_pose(np.eye(3), [x, 0, 0]), CAM, image, d, var, color)


@pytest.mark.parametrize("colour", [True, False])
def test_every_attribute_round_trips_exactly(colour):
    image, d, var, color = _inputs(3, colour)
    kf = Keyframe.make(3, 0.1, np.eye(4), CAM, image, d, var, color)
    ok = np.isfinite(d) & (d > 0)
    assert np.array_equal(kf.image, image)
    assert kf.idepth.dtype == np.float32 and kf.idepth_var.dtype == np.float32
    assert np.array_equal(kf.idepth, np.where(ok, d, np.nan), equal_nan=True)
    assert np.array_equal(kf.idepth_var, np.where(ok, var, np.nan), equal_nan=True)
    assert np.isnan(kf.idepth_var[5, 5]) and kf.idepth[5, 5] == 1.0   # a NaN variance survives as it was
    if colour:
        assert kf.color.dtype == np.uint8 and _close_colour(kf.color, color)
    else:
        assert kf.color is None
    for a in (kf.image, kf.idepth, kf.idepth_var) + ((kf.color,) if colour else ()):
        assert not a.flags.writeable
    moved = kf.with_pose(make_pose(np.eye(3), [1.0, 0, 0]))
    assert np.array_equal(moved.idepth, kf.idepth, equal_nan=True) and moved.T_world_cam[0, 3] == 1.0


def test_float_images_are_rounded_as_before():
    image, d, var, color = _inputs(4)
    kf = Keyframe.make(0, 0.0, np.eye(4), CAM, image.astype(np.float32) + 0.4, d, var, color.astype(np.float64) - 0.4)
    assert np.array_equal(kf.image, image) and _close_colour(kf.color, color)


def test_points_match_the_dense_computation():
    kf = _kf(5)
    D, V = kf.idepth, kf.idepth_var
    for max_rel_std in (np.inf, 0.1):
        ok = np.isfinite(D) & (D > 0) & np.isfinite(V)
        if np.isfinite(max_rel_std):
            ok &= np.sqrt(np.where(ok, V, 0.0)) < max_rel_std * np.where(ok, D, 0.0)
        v, u = np.nonzero(ok)
        p, (pv, pu), var = kf.points(max_rel_std)
        assert np.array_equal(pv, v) and np.array_equal(pu, u)
        assert np.array_equal(p, CAM.unproject_idepth(u, v, D[v, u]))
        assert np.array_equal(var, V[v, u].astype(np.float64))


@pytest.mark.parametrize("colour", [True, False])
def test_nbytes_is_the_stored_size(colour):
    kf = _kf(6, colour=colour)
    n_valid = int(np.count_nonzero(np.isfinite(kf.idepth)))
    jpg = kf.color_jpg.nbytes if colour else 0
    assert kf.nbytes == H * W + (H * W + 7) // 8 + 2 * 4 * n_valid + 16 * 8 + jpg
    assert kf.nbytes == sum(a.nbytes for a in (kf.image, kf.valid_bits, kf.idepth_values, kf.var_values,
                                               kf.T_world_cam)) + jpg
    dense = kf.image.nbytes + kf.idepth.nbytes + kf.idepth_var.nbytes + (kf.color.nbytes if colour else 0)
    assert kf.nbytes < 0.75 * dense


def test_store_bound_counts_compact_bytes():
    kfs = [_kf(i, x=float(i)) for i in range(12)]
    dense = max(k.image.nbytes + k.idepth.nbytes + k.idepth_var.nbytes + k.color.nbytes for k in kfs)
    st = KeyframeStore(max_bytes=3 * dense, max_keyframes=1000)
    for k in kfs:
        st.add(k)
        assert st.nbytes == sum(k.nbytes for k in st) <= st.max_bytes
    assert st.removed > 0 and len(st) > 3                # more keyframes than dense ones would fit
    assert st.nbytes > st.max_bytes - max(k.nbytes for k in kfs)   # thinned only as far as the bound needs


def test_cloud_parts_are_the_cloud():
    kfs = [_kf(i, x=0.01 * i) for i in range(4)]
    whole = scene_cloud(kfs, min_support=0, max_jump=np.inf)
    parts = list(scene_cloud_parts(kfs, min_support=0, max_jump=np.inf))
    assert len(parts) == 4 and len(whole.points) > 0
    assert np.array_equal(np.concatenate([p.points for p in parts]), whole.points)
    assert np.array_equal(np.concatenate([p.colors for p in parts]), whole.colors)
    assert np.array_equal(np.concatenate([p.keyframe for p in parts]), whole.keyframe)


@pytest.mark.parametrize("binary", [True, False])
def test_streamed_ply_is_the_one_shot_ply(tmp_path, binary):
    from lite_vo.io import read_ply, write_ply, write_ply_parts
    kfs = [_kf(i, x=0.01 * i) for i in range(4)]
    whole = scene_cloud(kfs, min_support=0, max_jump=np.inf)
    write_ply(tmp_path / "one.ply", whole.points, whole.idepth_var, whole.colors, binary=binary)
    n = write_ply_parts(tmp_path / "parts.ply", ((p.points, p.idepth_var, p.colors) for p in
                                                 scene_cloud_parts(kfs, min_support=0, max_jump=np.inf)), binary=binary)
    assert n == len(whole.points)
    assert (tmp_path / "parts.ply").read_bytes() == (tmp_path / "one.ply").read_bytes()
    assert np.array_equal(read_ply(tmp_path / "parts.ply")["red"], whole.colors[:, 0])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.ply", "parts.ply"]   # no temporary left
    with pytest.raises(ValueError):
        write_ply_parts(tmp_path / "bad.ply", [(whole.points, None, whole.colors)])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["one.ply", "parts.ply"]


def test_map_sink_streams_the_same_cloud(tmp_path):
    from types import SimpleNamespace

    from lite_vo.io import read_ply
    from lite_vo.sinks import MapSink
    st = KeyframeStore()
    for i in range(4):                                    # a wall at depth 2, 40 % of it mapped
        image, d, var, color = _inputs(i)
        d[np.isfinite(d)] = 0.5
        st.add(Keyframe.make(i, i / 30, make_pose(np.eye(3), [0.01 * i, 0, 0]), CAM, image, d, var, color))
    whole = scene_cloud(st)
    sink = MapSink(tmp_path / "map.ply")
    sink.on_start(SimpleNamespace(keyframes=st))
    sink.on_finish(None)
    got = read_ply(tmp_path / "map.ply")
    assert sink.points == len(whole.points) == len(got["x"]) > 0
    assert np.array_equal(np.stack([got["x"], got["y"], got["z"]], 1), whole.points)


def test_a_variance_map_of_another_shape_is_refused():
    image, d, var, color = _inputs(5)
    with pytest.raises(ValueError, match="idepth_var"):
        Keyframe.make(5, 0.2, np.eye(4), CAM, image, d, var[:-1], color)
