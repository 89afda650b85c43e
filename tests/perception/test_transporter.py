"""Tests of the unsupervised Transporter keypoint extractor (softsbi.perception.keypoints.transporter).

Data: tiny synthetic sequences drawn with cv2 (salmon table, a green deforming quadrilateral "cloth"
moving across it, a white/black "robot" rectangle moving independently and partly over the cloth), so
the cloth and robot masks are known exactly.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

from softsbi.core.errors import DataError, ParameterError, ShapeError
from softsbi.inference.training import torch_threads
from softsbi.perception.keypoints.transporter import (TransporterExtractor, gaussian_maps, keypoints_in_mask,
                                            masked_reconstruction_loss, sample_pairs, spatial_softmax, transport)

pytestmark = pytest.mark.integration

TABLE, CLOTH, ARM, GRIPPER = (214, 104, 98), (112, 150, 86), (225, 225, 225), (30, 30, 34)


def synthetic_sequences(n_seq: int = 3, T: int = 8, size: int = 64, seed: int = 0):
    """``images (N, size, size, 3)`` uint8, ``cloth (N, H, W)`` bool (visible cloth), ``robot (N, H, W)``
    bool, ``seq (N,)`` with ``N = n_seq * T``."""
    rng = np.random.default_rng(seed)
    imgs, cloth, robot, seq = [], [], [], []
    s = size / 64.0
    for k in range(n_seq):
        c0, vc = rng.uniform(18, 30, 2) * s, rng.uniform(1.0, 2.0, 2) * s
        r0, vr = rng.uniform([40, 8], [52, 20]) * s, rng.uniform([-2.5, 1.0], [-1.5, 2.0]) * s
        base = np.array([[-10, -8], [10, -8], [10, 8], [-10, 8]], float) * s
        for t in range(T):
            im = np.empty((size, size, 3), np.uint8)
            im[:] = TABLE
            quad = c0 + vc * t + base + rng.normal(0, 1.2 * s, (4, 2))
            cm = np.zeros((size, size), np.uint8)
            cv2.fillPoly(cm, [np.round(quad).astype(np.int32)], 1)
            rc = r0 + vr * t
            rm = np.zeros((size, size), np.uint8)
            arm = cv2.boxPoints(((float(rc[0]), float(rc[1])), (6 * s, 22 * s), 20.0))
            grip = cv2.boxPoints(((float(rc[0] - 3 * s), float(rc[1] + 10 * s)), (8 * s, 5 * s), 20.0))
            cv2.fillPoly(rm, [np.round(arm).astype(np.int32)], 1)
            cv2.fillPoly(rm, [np.round(grip).astype(np.int32)], 2)
            im[cm > 0] = CLOTH
            im[rm == 1] = ARM
            im[rm == 2] = GRIPPER
            imgs.append(im)
            cloth.append((cm > 0) & (rm == 0))
            robot.append(rm > 0)
            seq.append(k)
    return np.stack(imgs), np.stack(cloth), np.stack(robot), np.array(seq)


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    with torch_threads(1):
        yield


@pytest.fixture(scope="module")
def data():
    return synthetic_sequences(n_seq=4, T=8, size=64, seed=0)


SMALL = dict(image_size=32, n_keypoints=4, channels=8, hidden=8, batch_size=8)


@pytest.fixture(scope="module")
def trained(data):
    images, _, robot, seq = data
    ext = TransporterExtractor(**SMALL, epochs=12, lr=3e-3, val_fraction=0.0)
    info = ext.fit(images, masks=robot, sequence_ids=seq, seed=0)
    return ext, info


# ------------------------------------------------------------------ building blocks
def test_transport_shapes_and_properties():
    g = torch.Generator().manual_seed(0)
    B, C, K, h, w = 2, 5, 3, 6, 7
    phi_s, phi_t = torch.randn(B, C, h, w, generator=g), torch.randn(B, C, h, w, generator=g)
    hs, ht = torch.rand(B, K, h, w, generator=g), torch.rand(B, K, h, w, generator=g)
    out = transport(phi_s, phi_t, hs, ht)
    assert out.shape == (B, C, h, w)
    # K = 1: exactly the paper's Eq. 1
    o1 = transport(phi_s, phi_t, hs[:, :1], ht[:, :1])
    torch.testing.assert_close(o1, (1 - hs[:, :1]) * (1 - ht[:, :1]) * phi_s + ht[:, :1] * phi_t)
    # no keypoint anywhere -> the source features pass unchanged
    z = torch.zeros(B, K, h, w)
    torch.testing.assert_close(transport(phi_s, phi_t, z, z), phi_s)
    # where the last target map is 1, the output is the target's features
    ht1 = ht.clone()
    ht1[:, -1, 2, 3] = 1.0
    torch.testing.assert_close(transport(phi_s, phi_t, hs, ht1)[:, :, 2, 3], phi_t[:, :, 2, 3])
    # identity: source == target frame with binary maps -> features unchanged
    hb = (torch.rand(B, K, h, w, generator=g) > 0.7).float()
    torch.testing.assert_close(transport(phi_t, phi_t, hb, hb), phi_t)
    with pytest.raises(ShapeError):
        transport(phi_s, phi_t[:, :2], hs, ht)


def test_spatial_softmax_and_gaussians():
    logits = torch.full((1, 2, 8, 8), -50.0)
    logits[0, 0, 1, 6] = 50.0  # row 1, column 6
    logits[0, 1, 7, 0] = 50.0
    mu = spatial_softmax(logits)
    torch.testing.assert_close(mu[0, 0], torch.tensor([(2 * 6 + 1) / 8 - 1, (2 * 1 + 1) / 8 - 1]))
    torch.testing.assert_close(mu[0, 1], torch.tensor([(2 * 0 + 1) / 8 - 1, (2 * 7 + 1) / 8 - 1]))
    hm = gaussian_maps(mu, 8, 8, 0.1)
    assert hm.shape == (1, 2, 8, 8)
    assert float(hm[0, 0, 1, 6]) == pytest.approx(1.0) and float(hm[0, 0].max()) == pytest.approx(1.0)
    assert float(hm[0, 0, 7, 0]) < 1e-6


def test_masked_loss_ignores_masked_pixels():
    g = torch.Generator().manual_seed(1)
    pred = torch.rand(2, 3, 8, 8, generator=g, requires_grad=True)
    target = torch.rand(2, 3, 8, 8, generator=g, requires_grad=True)
    ignore = torch.zeros(2, 8, 8, dtype=torch.bool)
    ignore[:, 2:5, 3:7] = True
    loss = masked_reconstruction_loss(pred, target, ignore)
    loss.backward()
    m = ignore[:, None].expand(-1, 3, -1, -1)
    assert float(target.grad[m].abs().max()) == 0.0 and float(pred.grad[m].abs().max()) == 0.0
    assert float(target.grad[~m].abs().max()) > 0.0
    # the value ignores them too (even non-finite ones), and equals the MSE over the kept pixels
    t2 = target.detach().clone()
    t2[m] = float("nan")
    with torch.no_grad():
        assert float(masked_reconstruction_loss(pred, t2, ignore)) == pytest.approx(loss.item())
        assert loss.item() == pytest.approx(float(((pred - target)[~m] ** 2).mean()))
        torch.testing.assert_close(masked_reconstruction_loss(pred, target, None), ((pred - target) ** 2).mean())


def test_sample_pairs_same_sequence_within_gap():
    seq = np.array([0] * 6 + [1] * 5 + [2])
    src, tgt = sample_pairs(seq, 2, np.random.default_rng(0))
    assert np.array_equal(tgt, np.arange(12))
    assert np.all(seq[src] == seq[tgt])
    assert np.all(np.abs(src - tgt) <= 2)
    assert np.all((src != tgt) | (seq == 2))  # a one-frame sequence pairs with itself
    sub = np.array([0, 2, 3, 7, 9])
    s2, t2 = sample_pairs(seq, 3, np.random.default_rng(1), sub)
    assert np.array_equal(t2, sub) and np.all(np.isin(s2, sub)) and np.all(seq[s2] == seq[t2])


def test_keypoints_in_mask():
    masks = np.zeros((2, 10, 10), bool)
    masks[:, 2:4, 5:8] = True  # rows 2-3, columns 5-7
    kp = np.array([[[6.0, 2.4], [0.0, 0.0]], [[7.4, 3.0], [20.0, 3.0]]])
    assert keypoints_in_mask(kp, masks) == pytest.approx(0.5)
    kp2 = np.array([[[6.0, 4.4], [np.nan, 1.0]], [[8.0, 3.0], [-1.0, 3.0]]])
    assert keypoints_in_mask(kp2, masks) == 0.0
    assert keypoints_in_mask(kp2, masks, dilate=1) == pytest.approx(0.5)
    with pytest.raises(ShapeError):
        keypoints_in_mask(kp, masks[:1])


# ------------------------------------------------------------------ extractor
def test_training_reduces_loss_and_predicts_caller_pixels(data, trained):
    images, cloth, robot, seq = data
    ext, info = trained
    hist = np.array(info["history"])[:, 0]
    assert info["epochs"] == 12 and info["masked"] and info["n_sequences"] == 4
    assert hist[-3:].mean() < 0.7 * hist[0], hist
    # a fresh (untrained) network reconstructs worse than the trained one
    fresh = TransporterExtractor(**SMALL, epochs=1, lr=1e-12, val_fraction=0.0)
    fresh.fit(images[:2], seed=0)
    src, tgt = sample_pairs(seq, 10, np.random.default_rng(3))
    assert ext.reconstruction_loss(images[src], images[tgt], robot[tgt]) < \
        fresh.reconstruction_loss(images[src], images[tgt], robot[tgt])
    kp = ext.predict(images)
    assert kp.shape == (len(images), 4, 2) and kp.dtype == np.float64
    # coordinates are in the caller's pixels: the same frames upscaled 2x give ~2x the coordinates
    big = np.repeat(np.repeat(images, 2, axis=1), 2, axis=2)
    kp_big = ext.predict(big)
    np.testing.assert_allclose(kp_big, (kp + 0.5) * 2 - 0.5, atol=1.5)
    assert np.all((kp >= -0.5) & (kp <= 63.5))
    # a non-square image: u scales with the width, v with the height
    wide = np.repeat(images[:3], 2, axis=2)
    kw = ext.predict(wide)
    np.testing.assert_allclose(kw[..., 1], kp[:3, :, 1], atol=1.0)
    np.testing.assert_allclose(kw[..., 0], (kp[:3, :, 0] + 0.5) * 2 - 0.5, atol=2.0)


def test_save_load_round_trip(tmp_path, data, trained):
    images = data[0]
    ext, _ = trained
    ext.save(tmp_path / "sub" / "t.pt")
    back = TransporterExtractor.load(tmp_path / "sub" / "t.pt")
    assert back.trained and back.n_keypoints == ext.n_keypoints and back.config == ext.config
    np.testing.assert_array_equal(back.predict(images), ext.predict(images))
    assert back.fit_info["epochs"] == ext.fit_info["epochs"]
    with pytest.raises(DataError, match="not found"):
        TransporterExtractor.load(tmp_path / "missing.pt")
    torch.save({"format": "something-else"}, tmp_path / "other.pt")
    with pytest.raises(DataError, match="not a transporter checkpoint"):
        TransporterExtractor.load(tmp_path / "other.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match="not a transporter checkpoint"):
        TransporterExtractor.load(tmp_path / "junk.pt")


def test_early_stopping_and_determinism(data):
    images, _, robot, seq = data
    cfg = dict(SMALL, epochs=4, patience=1, min_epochs=1, val_fraction=0.25)
    a = TransporterExtractor(**cfg)
    ia = a.fit(images, masks=robot, sequence_ids=seq, seed=3)
    b = TransporterExtractor(**cfg, seed=3)
    ib = b.fit(images, masks=robot, sequence_ids=seq)
    assert ia["n_val"] == 8 and ia["n_train"] == 24  # one whole sequence of 4 held out
    assert ia["history"] == ib["history"]
    np.testing.assert_array_equal(a.predict(images[:4]), b.predict(images[:4]))
    assert 1 <= ia["best_epoch"] <= ia["epochs"] <= 4 and ia["val_loss"] == min(h[1] for h in ia["history"])


def test_bad_inputs_raise_clear_errors(data):
    images, _, robot, seq = data
    ext = TransporterExtractor(**SMALL, epochs=1)
    with pytest.raises(RuntimeError, match="fit.*load"):
        ext.predict(images)
    with pytest.raises(RuntimeError, match="fit"):
        ext.save("x.pt")
    with pytest.raises(ParameterError, match="Did you mean 'n_keypoints'"):
        TransporterExtractor(n_keypoint=4)
    with pytest.raises(ParameterError, match="multiple of 4"):
        TransporterExtractor(image_size=30)
    with pytest.raises(ParameterError, match="std"):
        TransporterExtractor(std=0)
    with pytest.raises(ShapeError, match="uint8"):
        ext.fit(images.astype(np.float32))
    with pytest.raises(ShapeError, match=r"images\[None\]"):
        ext.fit(images[0])
    with pytest.raises(ShapeError, match="greyscale"):
        ext.fit(images[..., :1])
    with pytest.raises(ShapeError, match="masks"):
        ext.fit(images, masks=robot[:, :10])
    with pytest.raises(ShapeError, match="bool"):
        ext.fit(images, masks=robot.astype(np.uint8))
    with pytest.raises(ShapeError, match="sequence_ids"):
        ext.fit(images, sequence_ids=seq[:-1])
    with pytest.raises(DataError, match="at least 2 frames"):
        ext.fit(images[:1])
    with pytest.raises(DataError, match="every pixel"):
        ext.fit(images, masks=np.ones(images.shape[:3], bool))
    with pytest.raises(ShapeError):
        ext.fit([[1, 2, 3]])


def test_plugin_registered():
    from softsbi.plugins import registry
    reg = registry()
    assert "transporter" in reg.names("extractor")
    cls = reg.extractor("transporter")
    assert cls is TransporterExtractor and cls.supervised is False
