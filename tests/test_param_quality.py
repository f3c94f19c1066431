"""Conformal quality (METHOD 1d) against independent computations."""

import numpy as np
import pytest

from conformill.param.quality import quality, weighted_percentile


def _rot3(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


def _pair():
    """Two triangles in a randomly rotated plane, and their in-plane coordinates."""
    P2 = np.array([[0.0, 0.0], [4.0, 0.0], [1.0, 3.0], [5.0, 2.5]])
    F = np.array([[0, 1, 2], [1, 3, 2]])
    V = np.column_stack([P2, np.zeros(4)]) @ _rot3(1).T + [10.0, -3.0, 7.0]
    return V, F, P2


def _independent_qc(V, F, uv):
    out = []
    for f in F:
        E3 = np.column_stack([V[f[1]] - V[f[0]], V[f[2]] - V[f[0]]])  # 3x2
        E2 = np.column_stack([uv[f[1]] - uv[f[0]], uv[f[2]] - uv[f[0]]])  # 2x2
        # J maps the 3D plane to 2D: J E3 = E2 restricted to the plane -> use an orthonormal basis
        Q, R = np.linalg.qr(E3)
        J = E2 @ np.linalg.inv(R)
        s = np.linalg.svd(J, compute_uv=False)
        out.append(s[0] / s[1])
    return np.array(out)


def test_flat_patch_similarity_is_exactly_conformal():
    V, F, P2 = _pair()
    c, s = np.cos(0.7), np.sin(0.7)
    uv = 2.5 * P2 @ np.array([[c, -s], [s, c]]).T + [3.0, 1.0]
    q = quality(V, F, uv)
    assert np.allclose(q.qc, 1.0, atol=1e-12)
    assert q.qc_mean == pytest.approx(1.0, abs=1e-12) and q.qc_max == pytest.approx(1.0, abs=1e-12)
    assert q.angle_max < 1e-10
    assert q.flipped == 0
    assert np.allclose(q.sigma, 1 / 2.5, rtol=1e-12)


def test_qc_matches_independent_svd_and_flips_are_counted():
    V, F, P2 = _pair()
    A = np.array([[3.0, 0.4], [-0.2, 1.1]])
    uv = P2 @ A.T
    q = quality(V, F, uv)
    s = np.linalg.svd(A, compute_uv=False)
    assert np.allclose(q.qc, s[0] / s[1], rtol=1e-12)
    assert np.allclose(q.qc, _independent_qc(V, F, uv), rtol=1e-12)
    # a different map per face: nonlinear uv
    uv2 = uv.copy()
    uv2[3] += [1.0, -0.3]
    assert np.allclose(quality(V, F, uv2).qc, _independent_qc(V, F, uv2), rtol=1e-12)
    # a mirror image: same distortion, every face flipped
    qm = quality(V, F, uv * [-1.0, 1.0])
    assert qm.flipped == 2 and np.allclose(qm.qc, q.qc)


def test_angle_error_is_the_corner_angle_difference():
    V, F, P2 = _pair()
    uv = P2 * [2.0, 1.0]  # a stretch
    q = quality(V, F, uv)

    def angles(P, f):
        out = []
        for k in range(3):
            a, b, c = P[f[k]], P[f[(k + 1) % 3]], P[f[(k + 2) % 3]]
            u, v = b - a, c - a
            out.append(np.degrees(np.arccos(u @ v / np.linalg.norm(u) / np.linalg.norm(v))))
        return np.array(out)

    err = np.concatenate([np.abs(angles(uv, f) - angles(P2, f)) for f in F])
    assert q.angle_max == pytest.approx(err.max(), rel=1e-10)
    u, v = P2[3] - P2[1], P2[2] - P2[1]
    area = np.array([6.0, 0.5 * abs(u[0] * v[1] - u[1] * v[0])])
    w = np.repeat(area / area.sum() / 3, 3)
    assert q.angle_mean == pytest.approx(np.sum(w * err), rel=1e-10)


def test_weighted_percentile():
    x = np.array([1.0, 2.0, 3.0, 4.0])
    assert weighted_percentile(x, np.ones(4), 50) == 2.0
    assert weighted_percentile(x, np.array([0.0, 0.0, 0.0, 1.0]), 5) == 4.0
    assert weighted_percentile(x, np.array([10.0, 1.0, 1.0, 1.0]), 95) == 4.0
