"""rgbd_envmap.envmap_io: Radiance RGBE and OpenEXR map files, and the orientation conventions.

Independent references:
    - RGBE files are decoded by OpenCV (``cv2.imread`` with IMREAD_ANYDEPTH | IMREAD_ANYCOLOR, BGR),
      EXR files by the ``OpenEXR`` package directly, never by the module's own readers.
    - Each convention's direction → pixel formula is written out here from its tool's source, not
      taken from the module: Blender's Cycles ``direction_to_equirectangular``
      (u = (atan2(d.y, d.x) − π)/(−2π), v = (acos d.z − π)/(−π), v = 0 at the image's bottom row) and
      Mitsuba 3's ``envmap`` emitter (``direction_to_uv``: u = atan2(d.x, −d.z)/2π wrapped to [0, 1),
      v = acos(d.y)/π; column c spans u ∈ [c/W, (c+1)/W), row r sits at v = r/(H − 1)), with our
      world mapped into Mitsuba's y-up one by (x, y, z) ↦ (x, z, −y); ours from the conventions page
      (φ = atan2(y, x), u = (φ + π)/2π · W, θ = acos z, v = θ/π · H).

RGBE bound (derived in the module docstring): the writer truncates, m = ⌊x · 2^(8−e)⌋ with the largest
channel M ∈ [2^(e−1), 2^e); OpenCV decodes m · 2^(e−8), so 0 ≤ x − x̂ < 2^(e−8) ≤ 2^-7 · M.
"""

from __future__ import annotations

import cv2
import numpy as np
import OpenEXR
import pytest

from rgbd_envmap.envmap_io import (
    CONVENTIONS,
    from_convention,
    read_envmap,
    read_hdr,
    to_convention,
    write_envmap,
    write_exr,
    write_hdr,
)
from rgbd_envmap.errors import InvalidInputError, UnknownMethodError


def cv2_read(path) -> np.ndarray:
    img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
    assert img is not None and img.dtype == np.float32
    return img[..., ::-1]  # BGR → RGB


def exr_read(path) -> tuple[dict[str, np.ndarray], dict]:
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return {k: np.asarray(c.pixels) for k, c in f.channels().items()}, dict(f.header())


def hdr_values(rng, shape) -> np.ndarray:
    """Radiance over many magnitudes (1e-6 … 1e4), with exact powers of two and zeros among it."""
    rad = rng.random((*shape, 3)) * 10.0 ** rng.integers(-6, 5, (*shape, 1))
    rad.reshape(-1, 3)[:5] = [[1.0, 0.5, 0.25], [2.0 ** -20, 0, 0], [0, 0, 0], [4096.0, 4095.0, 1.0], [1.0, 1.0, 1.0]]
    return rad.astype(np.float32)


# ---------------------------------------------------------------------------------------- RGBE

def check_rgbe(decoded: np.ndarray, truth: np.ndarray) -> None:
    truth = np.maximum(truth.astype(np.float64), 0.0)
    M = truth.max(axis=-1, keepdims=True)
    _, e = np.frexp(M)
    q = np.ldexp(1.0, e - 8)  # one step of the 8-bit mantissa at the pixel's shared exponent
    err = truth - decoded
    dark = M < 1e-32
    assert np.all(decoded[np.broadcast_to(dark, decoded.shape)] == 0)
    ok = ~dark[..., 0]
    assert np.all(err[ok] >= 0), "truncation: OpenCV's decode never exceeds the value"
    assert np.all(err[ok] < q[ok]), "less than one mantissa step"
    assert np.all(err[ok] <= 2.0 ** -7 * M[ok]), "≤ 2^-7 of the largest channel"


@pytest.mark.parametrize("shape", [(40, 80), (3, 6), (1, 32768), (2, 7)])
def test_hdr_read_by_opencv_equals_the_radiance_to_rgbe_precision(tmp_path, shape):
    rng = np.random.default_rng(1)
    rad = hdr_values(rng, shape)
    write_hdr(tmp_path / "m.hdr", rad)
    got = cv2_read(tmp_path / "m.hdr")
    assert got.shape == rad.shape
    check_rgbe(got, rad)


def test_hdr_run_length_encoding_of_runs_and_literals(tmp_path):
    rng = np.random.default_rng(2)
    rad = np.zeros((6, 700, 3), np.float32)
    rad[0] = 3.0                                           # one run longer than 127 (split)
    rad[1, ::2] = 1.0                                       # no run at all
    rad[2] = np.repeat(rng.random((175, 3)), 4, axis=0)    # runs of exactly 4
    rad[3] = np.repeat(rng.random((234, 3)), 3, axis=0)[:700]  # runs of 3: literals
    rad[4] = hdr_values(rng, (700,))                        # noise
    rad[5, 300:] = 0.5                                      # literals, then a long run
    write_hdr(tmp_path / "rle.hdr", rad)
    data = (tmp_path / "rle.hdr").read_bytes()
    assert data.count(bytes((2, 2, 700 >> 8, 700 & 0xFF))) >= 6  # every scanline starts with the RLE marker
    assert len(data) < 6 * 700 * 4  # the runs compressed
    check_rgbe(cv2_read(tmp_path / "rle.hdr"), rad)


def test_hdr_invalid_negative_and_non_finite_pixels_are_black(tmp_path):
    rad = np.full((4, 8, 3), 0.75, np.float32)
    valid = np.ones((4, 8), bool)
    valid[1, 2] = False
    rad[2, 3] = [-1.0, 0.5, 0.25]
    rad[3, 4] = [np.nan, 1.0, 1.0]
    write_hdr(tmp_path / "m.hdr", rad, valid)
    got = cv2_read(tmp_path / "m.hdr")
    np.testing.assert_array_equal(got[1, 2], 0)
    np.testing.assert_array_equal(got[3, 4], 0)
    assert got[2, 3, 0] == 0 and got[2, 3, 1] == 0.5 and got[2, 3, 2] == 0.25
    np.testing.assert_array_equal(got[0, 0], 0.75)


def test_hdr_header_records_the_convention_and_origin_and_reads_exposure(tmp_path):
    rad = np.full((4, 8, 3), 2.0, np.float32)
    write_hdr(tmp_path / "m.hdr", rad, convention="blender", origin=[0.5, -1.0, 0.8])
    head = (tmp_path / "m.hdr").read_bytes().split(b"\n\n")[0].decode()
    assert head.startswith("#?RADIANCE\n") and "RGBD_ENVMAP_CONVENTION=blender" in head
    assert head.endswith("FORMAT=32-bit_rle_rgbe")
    f = read_envmap(tmp_path / "m.hdr")
    assert f.convention == "blender" and f.depth_m is None and f.valid.all()
    np.testing.assert_array_equal(f.origin, [0.5, -1.0, 0.8])
    # A foreign file with EXPOSURE: the stored values were multiplied by it.
    data = (tmp_path / "m.hdr").read_bytes().replace(b"FORMAT=", b"EXPOSURE=4\nFORMAT=", 1)
    (tmp_path / "e.hdr").write_bytes(data)
    rad_e, variables = read_hdr(tmp_path / "e.hdr")
    np.testing.assert_array_equal(rad_e, 0.5)
    assert variables["EXPOSURE"] == "4"


def test_hdr_written_by_opencv_reads_as_ours(tmp_path):
    rng = np.random.default_rng(3)
    rad = hdr_values(rng, (16, 32))
    assert cv2.imwrite(str(tmp_path / "cv.hdr"), np.ascontiguousarray(rad[..., ::-1]))
    f = read_envmap(tmp_path / "cv.hdr")
    assert f.convention == "ours" and f.origin is None
    np.testing.assert_array_equal(f.radiance, cv2_read(tmp_path / "cv.hdr"))


@pytest.mark.parametrize("damage, message", [
    (lambda d: d.replace(b"-Y 4 +X 8", b"+Y 4 +X 8"), "not supported"),
    (lambda d: d.replace(b"32-bit_rle_rgbe", b"32-bit_rle_xyze"), "xyze"),
    (lambda d: b"P6\n" + d, "not a Radiance"),
    (lambda d: d.split(b"\n\n")[0], "blank line"),
])
def test_hdr_headers_this_reader_does_not_support_fail_naming_the_file(tmp_path, damage, message):
    write_hdr(tmp_path / "m.hdr", np.ones((4, 8, 3), np.float32))
    (tmp_path / "bad.hdr").write_bytes(damage((tmp_path / "m.hdr").read_bytes()))
    with pytest.raises(InvalidInputError, match=message) as err:
        read_envmap(tmp_path / "bad.hdr")
    assert "bad.hdr" in str(err.value)


# ---------------------------------------------------------------------------------------- OpenEXR

def random_map(rng, H, W):
    rad = hdr_values(rng, (H, W))
    valid = rng.random((H, W)) > 0.2
    depth = (rng.random((H, W)) * 5).astype(np.float32)
    return rad, valid, depth


def test_exr_float_channels_read_by_openexr_equal_the_map_exactly(tmp_path):
    rng = np.random.default_rng(4)
    rad, valid, depth = random_map(rng, 20, 40)
    write_exr(tmp_path / "m.exr", rad, valid, depth, convention="mitsuba", origin=[0.0, 0.0, 0.8])
    ch, header = exr_read(tmp_path / "m.exr")
    assert set(ch) == {"R", "G", "B", "valid", "depth"}
    for i, c in enumerate("RGB"):
        assert ch[c].dtype == np.float32
        np.testing.assert_array_equal(ch[c], np.where(valid, rad[..., i], 0))
    assert ch["depth"].dtype == np.float32 and ch["valid"].dtype == np.float16
    np.testing.assert_array_equal(ch["valid"], valid.astype(np.float16))
    np.testing.assert_array_equal(ch["depth"], np.where(valid, depth, 0))
    assert header["rgbd_envmap_convention"] == "mitsuba"
    np.testing.assert_array_equal(header["rgbd_envmap_origin"], [0.0, 0.0, 0.8])
    assert header["compression"] == OpenEXR.ZIP_COMPRESSION


def test_exr_half_channels_equal_the_map_to_half_precision(tmp_path):
    rng = np.random.default_rng(5)
    rad, valid, depth = random_map(rng, 20, 40)
    rad[0, 0] = [1e6, 1.0, 0.0]  # beyond half's range: clamped to 65504
    write_exr(tmp_path / "h.exr", rad, valid, depth, half=True)
    ch, _ = exr_read(tmp_path / "h.exr")
    for i, c in enumerate("RGB"):
        assert ch[c].dtype == np.float16
        truth = np.where(valid, rad[..., i], 0).astype(np.float64)
        got = ch[c].astype(np.float64)
        normal = truth >= 2.0 ** -14  # half's normal range: relative error ≤ 2^-11
        big = truth > 65504
        assert np.all(np.abs(got - truth)[normal & ~big] <= 2.0 ** -11 * truth[normal & ~big])
        assert np.all(np.abs(got - truth)[~normal] <= 2.0 ** -25)  # subnormals: half a step of 2^-24
        assert np.all(got[big] == 65504)
    np.testing.assert_array_equal(ch["depth"], np.where(valid, depth, 0))


def test_foreign_exr_with_rgb_or_y_only_reads_with_non_finite_pixels_invalid(tmp_path):
    rng = np.random.default_rng(6)
    rgb = rng.random((8, 16, 3)).astype(np.float32)
    rgb[2, 3, 1] = np.inf
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": rgb}) as f:
        f.write(str(tmp_path / "rgb.exr"))
    m = read_envmap(tmp_path / "rgb.exr")
    assert m.convention == "ours" and m.depth_m is None and m.origin is None
    assert not m.valid[2, 3] and m.valid.sum() == 8 * 16 - 1
    np.testing.assert_array_equal(m.radiance[m.valid], rgb[m.valid])
    np.testing.assert_array_equal(m.radiance[2, 3], 0)
    with OpenEXR.File(header, {"Y": rgb[..., 0].copy()}) as f:
        f.write(str(tmp_path / "y.exr"))
    y = read_envmap(tmp_path / "y.exr")
    np.testing.assert_array_equal(y.radiance, np.repeat(rgb[..., :1], 3, axis=-1))
    with OpenEXR.File(header, {"Z": rgb[..., 0].copy()}) as f:
        f.write(str(tmp_path / "z.exr"))
    with pytest.raises(InvalidInputError, match="no R, G, B"):
        read_envmap(tmp_path / "z.exr")


@pytest.mark.parametrize("fmt", ["hdr", "exr"])
@pytest.mark.parametrize("convention", CONVENTIONS)
def test_write_then_read_gives_the_map_back_in_our_orientation(tmp_path, fmt, convention):
    rng = np.random.default_rng(7)
    rad, valid, depth = random_map(rng, 16, 32)
    path = write_envmap(tmp_path / f"m.{fmt}", rad, valid, depth, convention=convention, origin=[1.0, 2.0, 3.0])
    back = read_envmap(path)  # the recorded convention
    assert back.convention == convention
    np.testing.assert_array_equal(back.origin, [1.0, 2.0, 3.0])
    if fmt == "exr":
        np.testing.assert_array_equal(back.valid, valid)
        np.testing.assert_array_equal(back.radiance, np.where(valid[..., None], rad, 0))
        np.testing.assert_array_equal(back.depth_m, np.where(valid, depth, 0))
    else:
        assert back.valid.all() and back.depth_m is None
        check_rgbe(back.radiance, np.where(valid[..., None], rad, 0))
    # an explicit convention overrides the recorded one
    assert read_envmap(path, "ours").convention == "ours"


def test_read_envmap_errors_name_the_file(tmp_path):
    with pytest.raises(InvalidInputError, match="no such file"):
        read_envmap(tmp_path / "missing.exr")
    with pytest.raises(InvalidInputError, match=r"\.hdr or \.exr"):
        read_envmap(tmp_path / "map.png")
    (tmp_path / "junk.exr").write_bytes(b"not an exr")
    with pytest.raises(InvalidInputError, match="junk.exr"):
        read_envmap(tmp_path / "junk.exr")
    write_exr(tmp_path / "m.exr", np.ones((2, 4, 3), np.float32))
    with pytest.raises(UnknownMethodError):
        read_envmap(tmp_path / "m.exr", "unity")
    write_exr(tmp_path / "none.exr", np.ones((2, 4, 3), np.float32), np.zeros((2, 4), bool))
    with pytest.raises(InvalidInputError, match="no valid"):
        read_envmap(tmp_path / "none.exr")


# ---------------------------------------------------------------------------------------- conventions

def ours_pixel(d, H, W):
    phi = np.arctan2(d[..., 1], d[..., 0])
    theta = np.arccos(np.clip(d[..., 2], -1, 1))
    return np.minimum(np.floor(theta / np.pi * H), H - 1).astype(int), (np.floor((phi + np.pi) / (2 * np.pi) * W) % W).astype(int)


def blender_uv(d):
    """Cycles' direction_to_equirectangular: range (−2π, π, −π, π)."""
    u = (np.arctan2(d[..., 1], d[..., 0]) - np.pi) / (-2 * np.pi)
    v = (np.arccos(np.clip(d[..., 2], -1, 1)) - np.pi) / (-np.pi)
    return u, v


def blender_pixel(d, H, W):
    u, v = blender_uv(d)
    row_from_bottom = np.minimum(np.floor(v * H), H - 1).astype(int)  # Blender's images: row 0 at the bottom
    return H - 1 - row_from_bottom, (np.floor(u * W) % W).astype(int)


def mitsuba_uv(d):
    """Mitsuba 3's envmap direction_to_uv on our world in Mitsuba's y-up frame (x, z, −y)."""
    dm = np.stack([d[..., 0], d[..., 2], -d[..., 1]], axis=-1)
    u = np.arctan2(dm[..., 0], -dm[..., 2]) / (2 * np.pi)
    return u - np.floor(u), np.arccos(np.clip(dm[..., 1], -1, 1)) / np.pi


def mitsuba_pixel(d, H, W):
    u, v = mitsuba_uv(d)
    return np.rint(v * (H - 1)).astype(int), (np.floor(u * W) % W).astype(int)


AXES = {"+x": (1, 0, 0), "+y": (0, 1, 0), "-x": (-1, 0, 0), "-y": (0, -1, 0), "+z": (0, 0, 1), "-z": (0, 0, -1)}
#: where each horizontal axis sits, as a fraction of the width (0 = the left edge = the seam).
COLUMN_FRACTION = {
    "ours": {"+x": 0.5, "+y": 0.75, "-x": 0.0, "-y": 0.25},
    "blender": {"+x": 0.5, "+y": 0.25, "-x": 0.0, "-y": 0.75},
    "mitsuba": {"+x": 0.25, "+y": 0.0, "-x": 0.75, "-y": 0.5},
}


def test_the_axes_sit_where_each_tool_documents_them():
    from rgbd_envmap.geometry import directions_to_equirect, equirect_directions

    H, W = 8, 16
    d = {k: np.array(v, float) for k, v in AXES.items()}
    for name, frac in COLUMN_FRACTION["ours"].items():
        u = directions_to_equirect(d[name], H, W)[0]
        assert (u + 0.5) / W == pytest.approx(frac)
    # +y on the left edge of our column 3W/4: the two columns that share it point most towards +y
    y = equirect_directions(H, W)[H // 2, :, 1]
    assert set(np.argsort(y)[-2:].tolist()) == {3 * W // 4 - 1, 3 * W // 4}
    for name, frac in COLUMN_FRACTION["blender"].items():
        assert blender_uv(d[name])[0] % 1.0 == pytest.approx(frac)
        assert blender_uv(d[name])[1] == pytest.approx(0.5)
    for name, frac in COLUMN_FRACTION["mitsuba"].items():
        assert mitsuba_uv(d[name])[0] % 1.0 == pytest.approx(frac)
        assert mitsuba_uv(d[name])[1] == pytest.approx(0.5)
    for uv in (blender_uv, mitsuba_uv):
        assert uv(d["+z"])[1] in (0.0, 1.0) and uv(d["-z"])[1] in (0.0, 1.0)
    assert blender_uv(d["+z"])[1] == 1.0 and mitsuba_uv(d["+z"])[1] == 0.0  # both: the zenith at the top row


def near(d, eps=(2e-3, 1e-3, 1.5e-3)):
    v = np.asarray(d, float) + np.asarray(eps)
    return v / np.linalg.norm(v)


@pytest.mark.parametrize("H, W", [(8, 16), (50, 100), (125, 250)])
@pytest.mark.parametrize("convention, theirs", [("blender", blender_pixel), ("mitsuba", mitsuba_pixel)])
def test_each_axis_lands_in_the_pixel_the_tool_looks_up(H, W, convention, theirs):
    rng = np.random.default_rng(8)
    ours_img = rng.random((H, W, 3)).astype(np.float32)
    img = to_convention(ours_img, convention)
    for name, axis in AXES.items():
        d = near(axis)
        r0, c0 = ours_pixel(d, H, W)
        r1, c1 = theirs(d, H, W)
        if convention == "mitsuba" and W % 4:  # half a column off: the two neighbours averaged
            c_a, c_b = (3 * W // 4 - 1 - c1) % W, (3 * W // 4 - c1) % W
            np.testing.assert_allclose(img[r1, c1], 0.5 * (ours_img[r0, c_a].astype(np.float64) + ours_img[r0, c_b]), rtol=1e-6)
            continue
        np.testing.assert_array_equal(img[r1, c1], ours_img[r0, c0], err_msg=f"{convention} {name}")


@pytest.mark.parametrize("convention, theirs", [("blender", blender_pixel), ("mitsuba", mitsuba_pixel)])
def test_every_direction_reads_the_same_value_in_ours_and_theirs(convention, theirs):
    H, W = 60, 120
    rng = np.random.default_rng(9)
    ours_img = rng.random((H, W)).astype(np.float32)
    img = to_convention(ours_img, convention)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r0, c0 = ours_pixel(d, H, W)
    r1, c1 = theirs(d, H, W)
    # Columns: the same pixel, exactly, for every direction (pixel edges aside: measure zero).
    np.testing.assert_array_equal(img[r0, c1], ours_img[r0, c0])
    if convention == "blender":
        np.testing.assert_array_equal(r1, r0)  # Blender's rows are pixel centres too
    else:
        # Mitsuba's rows sit on the poles (θ = π r/(H − 1)): at most one row apart from ours, and the
        # continuous row offset is at most half a row (0 at the horizon).
        assert np.abs(r1 - r0).max() <= 1
        theta = np.arccos(d[:, 2])
        offset = theta / np.pi * (H - 1) - (theta / np.pi * H - 0.5)  # Mitsuba's row coordinate − ours
        assert np.abs(offset).max() <= 0.5 + 1e-12
        horizon = np.abs(theta - np.pi / 2) < np.pi / H
        np.testing.assert_array_equal(r1[horizon], r0[horizon])


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize("W", [16, 10])
def test_from_convention_undoes_to_convention(convention, W):
    rng = np.random.default_rng(10)
    H = W // 2
    img = rng.random((H, W, 3)).astype(np.float32)
    mask = rng.random((H, W)) > 0.3
    out = to_convention(img, convention)
    assert out.shape == img.shape and out.dtype == img.dtype and out is not img
    if convention == "mitsuba" and W % 4:
        # half-column turn: averaging neighbours (not invertible); masks need both neighbours
        m = to_convention(mask, convention)
        np.testing.assert_array_equal(m, np.roll(mask[:, ::-1], -(W // 4), axis=1) & np.roll(mask[:, ::-1], -(W // 4) - 1, axis=1))
        return
    np.testing.assert_array_equal(from_convention(out, convention), img)
    np.testing.assert_array_equal(from_convention(to_convention(mask, convention), convention), mask)


def test_convention_errors():
    with pytest.raises(UnknownMethodError):
        to_convention(np.zeros((2, 4)), "unity")
    with pytest.raises(InvalidInputError):
        to_convention(np.zeros(4), "blender")
