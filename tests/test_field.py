"""Event distance field against OpenCV's exact Euclidean distance transform."""

import cv2
import numpy as np
import pytest

from evservo import _evcore


def rounded_distance(d, tau):
    """The field's f: D²/2 below 1 px, D − ½ beyond, capped at f(tau)."""
    d = np.minimum(d, tau)
    return np.where(d < 1.0, 0.5 * d * d, d - 0.5)


def cv2_distance(mask):
    """Distance from each pixel to the nearest active (nonzero) mask pixel."""
    src = (mask == 0).astype(np.uint8)
    return cv2.distanceTransform(src, cv2.DIST_L2, cv2.DIST_MASK_PRECISE)


def random_mask(rng, h, w, density):
    mask = (rng.random((h, w)) < density).astype(np.uint8)
    mask[rng.integers(h), rng.integers(w)] = 1  # never empty: cv2 has no "infinite" distance
    return mask


CASES = [
    (1, 1, 0.5),
    (1, 57, 0.05),
    (64, 1, 0.05),
    (37, 53, 0.001),
    (120, 90, 0.02),
    (200, 333, 0.15),
    (400, 400, 0.005),
]


@pytest.mark.parametrize(("h", "w", "density"), CASES)
def test_euclidean_distance_matches_opencv(h, w, density):
    rng = np.random.default_rng(h * 1000 + w)
    mask = random_mask(rng, h, w, density)
    d = _evcore.euclidean_distance(mask)
    assert d.dtype == np.float32 and d.shape == (h, w)
    np.testing.assert_allclose(d, cv2_distance(mask), rtol=0, atol=0.01)


@pytest.mark.parametrize(("h", "w", "density"), CASES)
@pytest.mark.parametrize("tau", [10.0, 3.5, 30.0, 200.0])
def test_level0_is_rounded_truncated_opencv_distance(h, w, density, tau):
    rng = np.random.default_rng(h * 7 + w)
    mask = random_mask(rng, h, w, density)
    (f0,) = _evcore.distance_field(mask, tau_px=tau, levels=1)
    assert f0.shape == (h, w)
    np.testing.assert_allclose(f0, rounded_distance(cv2_distance(mask), tau), rtol=0, atol=0.01)


@pytest.mark.parametrize(("x0", "y0"), [(0, 0), (3, 1), (6, 5)])
def test_coarse_levels_pool_on_the_absolute_grid(x0, y0):
    rng = np.random.default_rng(x0 + 10 * y0)
    h, w, tau = 90, 131, 10.0
    mask = random_mask(rng, h, w, 0.01)
    levels = _evcore.distance_field(mask, tau_px=tau, levels=3, x0=x0, y0=y0)
    assert len(levels) == 3
    for lvl, field in enumerate(levels):
        s = 1 << lvl
        # OR-pool of s×s blocks aligned to the full image: pad to whole blocks, then reduce.
        ax, ay = x0 % s, y0 % s
        hh, ww = -(-(ay + h) // s), -(-(ax + w) // s)
        padded = np.zeros((hh * s, ww * s), np.uint8)
        padded[ay : ay + h, ax : ax + w] = mask
        pooled = padded.reshape(hh, s, ww, s).max(axis=(1, 3))
        assert field.shape == pooled.shape
        np.testing.assert_allclose(field, rounded_distance(cv2_distance(pooled), tau), rtol=0, atol=0.01)


def test_empty_mask_is_flat_at_the_cap():
    (f0, f1) = _evcore.distance_field(np.zeros((20, 30), np.uint8), tau_px=4.0, levels=2)
    assert np.all(f0 == 3.5) and np.all(f1 == 3.5) and f1.shape == (10, 15)
    assert np.all(np.isinf(_evcore.euclidean_distance(np.zeros((4, 5), np.uint8))))


@pytest.mark.parametrize(
    ("tau", "levels"), [(0.0, 3), (-1.0, 3), (float("nan"), 3), (float("inf"), 1), (10.0, 0), (10.0, 4)]
)
def test_bad_parameters_raise(tau, levels):
    with pytest.raises(ValueError):
        _evcore.distance_field(np.ones((8, 8), np.uint8), tau_px=tau, levels=levels)
