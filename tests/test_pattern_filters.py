"""The pattern stage's 1-D filters against scipy.ndimage's, to the bit."""

import numpy as np
import pytest
from scipy import ndimage

from conformill.patterns.filters import gaussian_rows, gaussian_weights, running_min


@pytest.mark.parametrize("wrap", [True, False])
@pytest.mark.parametrize("n, half", [(1, 1), (2, 1), (7, 3), (8, 4), (50, 1), (50, 12), (301, 40), (6, 9)])
def test_running_min_is_scipys(n, half, wrap):
    rng = np.random.default_rng(n * 100 + half)
    x = rng.random(n)
    x[rng.random(n) < 0.2] = 1.0  # ties
    want = ndimage.minimum_filter1d(x, 2 * half + 1, mode="wrap" if wrap else "nearest")
    got = running_min(x, half, wrap)
    np.testing.assert_array_equal(got, want)
    # the least within half places (wrapped or clipped), by brute force
    idx = np.arange(n)[:, None] + np.arange(-half, half + 1)[None, :]
    idx = idx % n if wrap else np.clip(idx, 0, n - 1)
    np.testing.assert_array_equal(got, x[idx].min(axis=1))


@pytest.mark.parametrize("wrap", [True, False])
@pytest.mark.parametrize("shape, sigma", [((3, 64), 2.0), ((5, 200), 0.55), ((4, 33), 7.3), ((2, 10), 6.0),
                                          ((6, 1), 1.5), ((1, 512), 25.6), ((3, 97), 0.2)])
def test_gaussian_rows_are_scipys(shape, sigma, wrap):
    rng = np.random.default_rng(shape[1])
    F = np.cumsum(rng.random(shape), axis=1) / shape[1]
    want = ndimage.gaussian_filter1d(F, sigma, axis=1, mode="wrap" if wrap else "nearest")
    got = gaussian_rows(F, sigma, wrap)
    np.testing.assert_allclose(got, want, rtol=1e-14, atol=0)
    # to the bit where scipy's weights are these (its private _gaussian_kernel1d: another
    # scipy may compute them otherwise, and the programs then differ in the last digits)
    radius = int(4.0 * sigma + 0.5)
    from scipy.ndimage import _filters

    if np.array_equal(_filters._gaussian_kernel1d(sigma, 0, radius), gaussian_weights(sigma, radius)):
        np.testing.assert_array_equal(got, want)


def test_gaussian_rows_keep_a_constant_and_the_mean_on_a_circle():
    # the weights sum to 1: a constant row stays (to rounding), and on a closed curve the
    # row's mean is kept
    F = np.vstack([np.full(40, 0.3), np.sin(np.linspace(0, 6 * np.pi, 120, endpoint=False))[:40] + 2.0])
    for wrap in (True, False):
        G = gaussian_rows(F, 3.0, wrap)
        np.testing.assert_allclose(G[0], 0.3, rtol=1e-14)
    G = gaussian_rows(F, 3.0, True)
    assert abs(G[1].mean() - F[1].mean()) < 1e-12


def test_bad_arguments():
    with pytest.raises(ValueError, match="half"):
        running_min(np.ones(4), -1, True)
    with pytest.raises(ValueError, match="1-D"):
        running_min(np.ones((2, 4)), 1, True)
    np.testing.assert_array_equal(running_min(np.arange(3.0), 0, False), np.arange(3.0))
    with pytest.raises(ValueError, match="sigma"):
        gaussian_rows(np.ones((2, 4)), 0.0, True)
    with pytest.raises(ValueError, match="2-D"):
        gaussian_rows(np.ones(4), 1.0, True)
