"""Supervised heatmap keypoint extractor, keypoint data helpers and metrics (issue 6, item 2)."""
from __future__ import annotations


import numpy as np
import pytest
import torch

from softsbi.core.errors import DataError, ParameterError, ShapeError
from softsbi.perception.keypoints.heatmap import (
    HeatmapExtractor,
    decode_heatmaps,
    gaussian_heatmaps,
)
from softsbi.data.keypoints import (
    block_split,
    draw_keypoints,
    index_ranges,
    keypoint_distances,
    keypoint_errors,
    load_keypoint_folder,
    match_keypoints,
    wiping_frame_labels,
)
from softsbi.perception.keypoints.nets import HeatmapNet
from toy_helpers import DATA

pytestmark = pytest.mark.integration

WIPING = DATA / "wiping_keypoints"
TINY = dict(input_size=64, layers=[1, 1, 1, 1], width=8, epochs=60, batch_size=4, lr=3e-3, augment=False,
            val_fraction=0.0, patience=60, sigma=10.0, num_threads=1)
COLOURS = np.array([[255, 40, 40], [40, 255, 40], [60, 60, 255]], np.uint8)


def squares(n: int, size: int = 64, k: int = 3, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` dark images with one bright coloured 7x7 square per keypoint (centre = keypoint)."""
    rng = np.random.default_rng(seed)
    imgs = np.full((n, size, size, 3), 20, np.uint8)
    kps = np.empty((n, k, 2))
    for i in range(n):
        for j in range(k):
            while True:
                c = rng.integers(6, size - 6, 2)
                if j == 0 or np.abs(kps[i, :j] - c).max(axis=1).min() > 10:
                    break
            imgs[i, c[1] - 3:c[1] + 4, c[0] - 3:c[0] + 4] = COLOURS[j]
            kps[i, j] = c
    return imgs, kps


@pytest.fixture(scope="module")
def trained() -> tuple[HeatmapExtractor, np.ndarray, np.ndarray, dict]:
    torch.set_num_threads(1)
    imgs, kps = squares(8)
    ex = HeatmapExtractor(**TINY)
    info = ex.fit(imgs, kps, seed=0)
    return ex, imgs, kps, info


def test_overfits_squares(trained):
    ex, imgs, kps, info = trained
    assert ex.trained and ex.n_keypoints == 3
    err = keypoint_distances(ex.predict(imgs), kps).mean()
    assert err < 4.0, err  # chance (uniform in the image) is ~25 px
    assert {"epochs", "train_loss", "val_loss", "seconds", "history"} <= set(info)
    assert info["history"][-1]["train_loss"] < info["history"][0]["train_loss"]


def test_predictions_map_back_to_original_resolution(trained):
    ex, imgs, kps, _ = trained
    big = np.repeat(np.repeat(imgs, 3, axis=1), 3, axis=2)  # 192 x 192: same content
    pred = ex.predict(big)
    true = (kps + 0.5) * 3 - 0.5
    assert keypoint_distances(pred, true).mean() < 12.0
    np.testing.assert_allclose(pred, (ex.predict(imgs) + 0.5) * 3 - 0.5, atol=1e-6)  # area resize is exact


def test_save_load_round_trip(trained, tmp_path):
    ex, imgs, _, _ = trained
    ex.save(tmp_path / "hm.pt")
    ex2 = HeatmapExtractor.load(tmp_path / "hm.pt")
    assert ex2.config == ex.config and ex2.n_keypoints == 3
    np.testing.assert_array_equal(ex2.predict(imgs), ex.predict(imgs))
    ckpt = torch.load(tmp_path / "hm.pt", weights_only=True)
    assert ckpt["format"].startswith("softsbi.heatmap")


def test_load_errors(tmp_path):
    with pytest.raises(DataError, match="not found"):
        HeatmapExtractor.load(tmp_path / "missing.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DataError):
        HeatmapExtractor.load(tmp_path / "junk.pt")
    torch.save({"format": "other"}, tmp_path / "other.pt")
    with pytest.raises(DataError, match="not a heatmap"):
        HeatmapExtractor.load(tmp_path / "other.pt")


def test_bad_inputs():
    imgs, kps = squares(4)
    ex = HeatmapExtractor(**TINY)
    with pytest.raises(RuntimeError, match="train it first with .* or load a checkpoint"):
        ex.predict(imgs)
    with pytest.raises(ShapeError, match="greyscale"):
        ex.fit(imgs[..., 0], kps)
    with pytest.raises(ShapeError, match="RGBA"):
        ex.fit(np.concatenate([imgs, imgs[..., :1]], -1), kps)
    with pytest.raises(ShapeError, match="uint8"):
        ex.fit(imgs / 255.0, kps)
    with pytest.raises(ShapeError, match="one row per image"):
        ex.fit(imgs, kps[:3])
    far = kps.copy()
    far[1, 0] = (200.0, 10.0)
    with pytest.raises(DataError, match="outside"):
        ex.fit(imgs, far)
    with pytest.raises(ParameterError, match="Did you mean 'epochs'"):
        HeatmapExtractor(epoch=3)
    with pytest.raises(ParameterError, match="multiple of 32"):
        HeatmapExtractor(input_size=100)


def test_gaussian_targets_and_decoding():
    pts = np.array([[[5.3, 7.6], [0.0, 12.0]]])
    hm = gaussian_heatmaps(pts, 16, 16, 1.2)
    assert hm.shape == (1, 2, 16, 16) and hm[0, 1, 12, 0] == pytest.approx(1.0)
    dec = decode_heatmaps(torch.from_numpy(hm), refine_radius=2, probabilities=True)
    np.testing.assert_allclose(dec, pts, atol=0.25)
    np.testing.assert_array_equal(decode_heatmaps(torch.from_numpy(hm), 0, True), [[[5, 8], [0, 12]]])
    net = HeatmapNet(3, layers=[1, 1, 1, 1], width=8)
    assert net(torch.zeros(2, 3, 64, 96)).shape == (2, 3, 32, 48)


def test_order_invariant_loss():
    rng = np.random.default_rng(0)
    logits = torch.from_numpy(rng.normal(size=(2, 3, 8, 8)).astype(np.float32))
    target = torch.from_numpy(gaussian_heatmaps(rng.uniform(0, 7, (2, 3, 2)), 8, 8, 1.0))
    ex = HeatmapExtractor(order_invariant=True)
    a = ex._loss(logits, target, None)
    b = ex._loss(logits, target[:, [2, 0, 1]], None)
    assert float(a) == pytest.approx(float(b), rel=1e-6)
    assert float(a) <= float(HeatmapExtractor()._loss(logits, target, None)) + 1e-7


def test_metrics_exact():
    true = np.array([[[0.0, 0.0], [10.0, 0.0], [0.0, 10.0]]])
    pred = true + np.array([[[3.0, 4.0], [0.0, 0.0], [0.0, 20.0]]])  # distances 5, 0, 20
    e = keypoint_errors(pred, true)
    assert e["mean_px"] == pytest.approx(25 / 3) and e["median_px"] == pytest.approx(5.0)
    assert e["pck@10px"] == pytest.approx(2 / 3) and e["pck@5px"] == pytest.approx(2 / 3)
    assert e["max_px"] == pytest.approx(20.0) and e["n_frames"] == 1 and e["n_keypoints"] == 3
    perm = true[:, [2, 0, 1]]  # same set, other order
    e = keypoint_errors(perm, true)
    assert e["hungarian_mean_px"] == pytest.approx(0.0) and e["hungarian_pck@10px"] == 1.0
    assert e["mean_px"] == pytest.approx((10 + np.sqrt(200) + 10) / 3)
    d = keypoint_distances(perm + [1.0, 0.0], true, "hungarian")
    np.testing.assert_allclose(d, [[1.0, 1.0, 1.0]])
    np.testing.assert_allclose(match_keypoints(perm + [1.0, 0.0], true), true + [1.0, 0.0])


def test_block_split_contiguous_disjoint():
    s = block_split(100, (0.7, 0.15, 0.15), n_blocks=10)
    allidx = np.concatenate([s["train"], s["val"], s["test"]])
    assert sorted(allidx.tolist()) == list(range(100))
    assert len(s["test"]) == 20 and len(s["val"]) == 10  # 2 and 1 blocks of 10
    for name in ("val", "test"):
        for a, b in index_ranges(s[name]):
            assert (b - a + 1) % 10 == 0 and a % 10 == 0  # whole blocks
    groups = np.repeat(np.arange(25), 4)[np.random.default_rng(0).permutation(100)]
    g = block_split(100, n_blocks=5, groups=groups)
    for name in ("train", "val", "test"):
        others = np.setdiff1d(np.arange(100), g[name])
        assert not set(groups[g[name]]) & set(groups[others])  # no group is split


def test_draw_keypoints(tmp_path):
    imgs, kps = squares(3)
    sheet = draw_keypoints(imgs, kps + 1, kps, labels=["a", "b", "c"], ncols=2, path=tmp_path / "s.png")
    assert sheet.shape == (128, 128, 3) and sheet.dtype == np.uint8 and (tmp_path / "s.png").stat().st_size > 0


def test_plugin_registered():
    from softsbi.plugins import registry
    assert "heatmap" in registry().names("extractor")
    assert registry().extractor("heatmap") is HeatmapExtractor


def test_wiping_folder_loads():
    if not (WIPING / "images").is_dir():
        pytest.skip(f"wiping data not found at {WIPING}")
    imgs, kps, names = load_keypoint_folder(WIPING)
    assert imgs.shape == (449, 320, 320, 3) and imgs.dtype == np.uint8 and kps.shape == (449, 4, 2)
    assert names[0] == "00000" and names[-1] == "00448"
    lab = wiping_frame_labels(449)
    # a copy with colour jitter only has its source's keypoints
    np.testing.assert_array_equal(kps[61], kps[lab["source"][61]])
    s = block_split(449, groups=lab["source"])
    assert lab["real"][s["test"]].sum() >= 20 and lab["real"][s["val"]].sum() >= 20
    for name in ("train", "val", "test"):
        assert not set(lab["source"][s[name]]) & set(lab["source"][np.setdiff1d(np.arange(449), s[name])])


def test_folder_errors(tmp_path):
    import cv2
    (tmp_path / "images").mkdir()
    (tmp_path / "keypoints").mkdir()
    imgs, kps = squares(2)
    for i in range(2):
        cv2.imwrite(str(tmp_path / "images" / f"{i}.png"), imgs[i])
    np.save(tmp_path / "keypoints" / "0.npy", kps[0])
    with pytest.raises(DataError, match="without keypoints"):
        load_keypoint_folder(tmp_path)
    np.save(tmp_path / "keypoints" / "1.npy", kps[1][:, :1])
    with pytest.raises(DataError, match=r"\(K, 2\)"):
        load_keypoint_folder(tmp_path)
    np.save(tmp_path / "keypoints" / "1.npy", kps[1] * 10)
    with pytest.raises(DataError, match="outside"):
        load_keypoint_folder(tmp_path)
    np.save(tmp_path / "keypoints" / "1.npy", kps[1])
    cv2.imwrite(str(tmp_path / "images" / "1.png"), imgs[1, :32])
    with pytest.raises(DataError, match="mixed image sizes"):
        load_keypoint_folder(tmp_path)
    cv2.imwrite(str(tmp_path / "images" / "1.png"), imgs[1, ..., 0])
    with pytest.raises(DataError, match="channel"):
        load_keypoint_folder(tmp_path)
    cv2.imwrite(str(tmp_path / "images" / "1.png"), imgs[1])
    out, _, names = load_keypoint_folder(tmp_path)
    assert out.shape == (2, 64, 64, 3) and names == ["0", "1"]
    np.testing.assert_array_equal(out[..., 0], imgs[..., 2])  # BGR file -> RGB array
