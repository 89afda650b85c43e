"""HSV colour masks and the mask Chamfer distance (softsbi.perception.masks)."""
from __future__ import annotations


import numpy as np
import pytest

from softsbi.core.camera import RenderStyle
from softsbi.core.errors import DataError, ShapeError
from softsbi.perception.masks import CLOTH_HSV, hsv_mask, mask_chamfer, mask_chamfer_per_frame
from toy_helpers import DATA

WIPING = DATA / "wiping_keypoints"


def _square(shape=(64, 64), top=10, left=10, side=20):
    m = np.zeros(shape, bool)
    m[top:top + side, left:left + side] = True
    return m


# -- Chamfer ---------------------------------------------------------------------------------
def test_identical_is_zero():
    a = _square()
    assert mask_chamfer(a, a) == 0.0


@pytest.mark.parametrize("d", [1, 3, 7])
def test_shifted_filled_square(d):
    """Filled s x s square vs itself shifted by d px: only the d uncovered columns contribute, at
    distances d, d-1, ..., 1 in each of s rows -> mean over the s^2 pixels d (d + 1) / (2 s), the same
    both ways."""
    s = 20
    a, b = _square(side=s), _square(side=s, left=10 + d)
    assert mask_chamfer(a, b) == pytest.approx(d * (d + 1) / (2 * s), abs=1e-6)
    # a vertical shift gives the same
    assert mask_chamfer(a, _square(side=s, top=10 + d)) == pytest.approx(d * (d + 1) / (2 * s), abs=1e-6)


@pytest.mark.parametrize("d", [1, 4, 9])
def test_shifted_line_is_d(d):
    """A one-pixel-wide line shifted perpendicular to itself by d px: every pixel is d away."""
    a = np.zeros((40, 40), bool)
    b = np.zeros((40, 40), bool)
    a[5:35, 10] = True
    b[5:35, 10 + d] = True
    assert mask_chamfer(a, b) == pytest.approx(d, abs=1e-6)


def test_asymmetric_and_diagonal():
    a = np.zeros((30, 30), bool)
    b = np.zeros((30, 30), bool)
    a[5, 5] = True
    b[5, 5] = True
    b[8, 9] = True  # 5 px away (3-4-5)
    # a -> b: 0; b -> a: (0 + 5) / 2
    assert mask_chamfer(a, b) == pytest.approx(0.5 * (0 + 2.5), abs=1e-5)
    assert mask_chamfer(b, a) == pytest.approx(mask_chamfer(a, b))


def test_empty_rules():
    e = np.zeros((30, 40), bool)
    assert mask_chamfer(e, e) == 0.0
    assert mask_chamfer(e, _square((30, 40), 2, 2, 5)) == pytest.approx(50.0)
    assert mask_chamfer(_square((30, 40), 2, 2, 5), e) == pytest.approx(50.0)


def test_per_frame():
    a = np.stack([_square(), _square(), np.zeros((64, 64), bool)])
    b = np.stack([_square(), _square(left=13), np.zeros((64, 64), bool)])
    out = mask_chamfer_per_frame(a, b)
    assert out.shape == (3,) and out.dtype == float
    assert out.tolist() == pytest.approx([0.0, 3 * 4 / 40, 0.0])


def test_chamfer_errors():
    a = _square()
    with pytest.raises(ShapeError, match="same shape"):
        mask_chamfer(a, a[:32])
    with pytest.raises(ShapeError, match=r"\(H, W\)"):
        mask_chamfer(a[None], a[None])
    with pytest.raises(DataError, match="bool"):
        mask_chamfer(a.astype(np.uint8), a)
    with pytest.raises(ShapeError, match=r"\(T, H, W\)"):
        mask_chamfer_per_frame(a, a)
    with pytest.raises(ShapeError, match="same shape"):
        mask_chamfer_per_frame(a[None], np.stack([a, a]))
    with pytest.raises(DataError, match="bool"):
        mask_chamfer_per_frame(a[None].astype(float), a[None])


# -- HSV masks --------------------------------------------------------------------------------
def test_hsv_mask_synthetic():
    st = RenderStyle()
    img = np.zeros((40, 60, 3), np.uint8)
    img[:, :30] = st.cloth
    img[:, 30:] = st.table
    img[5:10, 35:40] = (int(st.cloth[0] * 0.6), int(st.cloth[1] * 0.6), int(st.cloth[2] * 0.6))  # shaded cloth
    img[20, 50] = st.cloth  # a single speckle pixel
    m = hsv_mask(img)
    assert m.shape == (40, 60) and m.dtype == bool
    assert m[:, :30].all()
    assert m[5:10, 35:40].all()           # shaded cloth is still cloth
    assert not m[20, 50]                  # speckle removed by the opening
    assert hsv_mask(img, open_px=0)[20, 50]
    assert m[:, 30:].sum() == 25
    # batches of any shape
    assert hsv_mask(np.stack([img, img])[None]).shape == (1, 2, 40, 60)
    # hue wrap-around: the salmon table (H ~2) and a pink-red (H ~175) with lo_h > hi_h
    red = np.zeros((4, 4, 3), np.uint8)
    red[:2] = st.table
    red[2:] = (190, 60, 90)
    assert hsv_mask(red, lo=(170, 80, 80), hi=(10, 255, 255), open_px=0).all()
    assert not hsv_mask(red, lo=(10, 80, 80), hi=(170, 255, 255), open_px=0).any()


def test_hsv_mask_errors():
    img = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(DataError, match="uint8"):
        hsv_mask(img.astype(float))
    with pytest.raises(ShapeError, match="alpha"):
        hsv_mask(np.zeros((8, 8, 4), np.uint8))
    with pytest.raises(ShapeError):
        hsv_mask(np.zeros((8, 8), np.uint8))
    with pytest.raises(DataError, match="0..179"):
        hsv_mask(img, lo=(0, 0, 0), hi=(200, 255, 255))
    with pytest.raises(DataError, match="saturation"):
        hsv_mask(img, lo=(0, 100, 0), hi=(50, 50, 255))
    with pytest.raises(ShapeError, match="triples"):
        hsv_mask(img, lo=(0, 0), hi=(50, 255, 255))


@pytest.mark.parametrize("frame", [0, 280])
def test_hsv_mask_real_wiping_frames(frame):
    """On real wiping frames the default cloth mask covers a plausible area (the cloth is ~4-5 % of a
    frame) and lies on the labelled cloth (the keypoint quadrilateral)."""
    img_path = WIPING / "images" / f"{frame:05d}.jpg"
    if not img_path.is_file():
        pytest.skip(f"real wiping images not found at {WIPING}")
    import cv2
    from PIL import Image
    img = np.asarray(Image.open(img_path).convert("RGB"))
    m = hsv_mask(img, *CLOTH_HSV)
    assert 0.02 < m.mean() < 0.10, m.mean()
    k = np.load(WIPING / "keypoints" / f"{frame:05d}.npy")
    quad = np.zeros(m.shape, np.uint8)
    cv2.fillConvexPoly(quad, cv2.convexHull(k.astype(np.int32)), 1)
    near = cv2.dilate(quad, np.ones((15, 15), np.uint8)).astype(bool)
    assert (m & near).sum() / m.sum() > 0.97
    # the gripper covers part of the quadrilateral (about 15 % in frame 280)
    inner = cv2.erode(quad, np.ones((7, 7), np.uint8)).astype(bool)
    assert (m & inner).sum() / inner.sum() > 0.75
