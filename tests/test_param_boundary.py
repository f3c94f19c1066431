"""Boundary maps (METHOD 1c): circle, rectangle, corners."""

import numpy as np
import pytest

from conformill.errors import ParameterizationError
from conformill.mesh import synthetic as syn
from conformill.mesh.topology import boundary_loops
from conformill.param import parameterize
from conformill.param.boundary import (
    auto_corners,
    boundary_turning,
    chord_lengths,
    circle_map,
    corner_positions,
    rectangle_map,
)
from conformill.param.weights import corner_angles


def _signed_areas(uv, F):
    a, b, c = uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]
    return 0.5 * ((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def _auto(m):
    loop = boundary_loops(m.F, m.n_vertices)[0]
    return loop, auto_corners(m.V, loop, boundary_turning(m.V, m.F, loop, corner_angles(m.V, m.F)))


def test_circle_radius_and_chord_length_angles():
    m = syn.freeform_patch(spacing=4.0)
    loop = boundary_loops(m.F, m.n_vertices)[0]
    uv, R = circle_map(m.V, loop)
    s = chord_lengths(m.V, loop)
    assert R == pytest.approx(s[-1] / (2 * np.pi), rel=1e-14)
    assert np.allclose(np.linalg.norm(uv, axis=1), R, rtol=1e-14)
    ang = np.unwrap(np.arctan2(uv[:, 1], uv[:, 0]))
    assert np.allclose(ang - ang[0], 2 * np.pi * s[:-1] / s[-1], atol=1e-12)  # counter-clockwise


def test_rectangle_sides_and_corners():
    m = syn.freeform_patch(spacing=4.0)
    loop, corners = _auto(m)
    uv, (X, Y) = rectangle_map(m.V, loop, corners)
    pos = corner_positions(loop, corners)
    s = chord_lengths(m.V, np.roll(loop, -pos[0]))
    p = np.append((pos - pos[0]) % len(loop), len(loop))
    L = np.diff(s[p])
    assert X == pytest.approx(0.5 * (L[0] + L[2]), rel=1e-14)
    assert Y == pytest.approx(0.5 * (L[1] + L[3]), rel=1e-14)
    where = {int(v): i for i, v in enumerate(loop)}
    got = np.array([uv[where[c]] for c in corners])
    assert np.allclose(got, [[0, 0], [X, 0], [X, Y], [0, Y]], atol=1e-12)
    # every boundary point on the rectangle outline
    on_edge = (np.isclose(uv[:, 0], 0) | np.isclose(uv[:, 0], X) | np.isclose(uv[:, 1], 0) | np.isclose(uv[:, 1], Y))
    assert on_edge.all()
    # proportional to chord length along the first side: uv[k, 0] / X = s_k / L1
    k = np.arange(p[1])
    assert np.allclose(uv[(pos[0] + k) % len(loop), 0], X * s[k] / L[0], atol=1e-12)


def test_auto_corners_on_square_and_notched_outlines_pick_real_corners():
    m = syn.plane(size=100, spacing=5.0, jitter=0.3)
    _, c = _auto(m)
    xy = m.V[list(c), :2]
    assert np.allclose(np.abs(xy), 50.0)
    n = syn.height_field(syn.notched_outline(), lambda x, y: 0 * x, 5.0, jitter=0.2)
    _, c = _auto(n)
    xy = n.V[list(c), :2]
    assert np.allclose(np.abs(xy), [60.0, 40.0])  # the four outer corners, not the notch


@pytest.mark.parametrize("V", [[[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]],  # a square of two triangles
                               [[0, 0, 0], [10, 0, 0], [10, 10, 1], [0, 10, 0]],  # one corner raised
                               [[0, 0, 0], [20, 0, 1], [20, 10, 2], [0, 10, 1]]])  # a tilted 2:1 rectangle
def test_auto_corners_of_a_four_vertex_boundary_are_its_vertices(V):
    from conformill.types import Mesh

    m = Mesh(V=np.array(V, dtype=float), F=np.array([[0, 1, 2], [0, 2, 3]]))
    _, c = _auto(m)
    assert sorted(c) == [0, 1, 2, 3]
    p = parameterize(m, boundary="rectangle")
    assert np.all(_signed_areas(p.uv, m.F) > 0)


def test_auto_corners_on_rounded_outline_are_spread_out():
    m = syn.sphere_cap(R=60, radius_xy=30, spacing=2.5)
    loop, c = _auto(m)
    pos = corner_positions(loop, c)
    s = chord_lengths(m.V, loop)
    arcs = (s[np.roll(pos, -1)] - s[pos]) % s[-1]
    assert np.all(arcs > 0.2 * s[-1]) and np.all(arcs < 0.3 * s[-1])


@pytest.mark.parametrize("boundary", ["circle", "rectangle"])
@pytest.mark.parametrize("maker", ["dome", "bowl", "freeform"])
def test_positive_orientation_no_global_flip(boundary, maker):
    m = {"dome": lambda: syn.sphere_cap(spacing=3.0), "bowl": lambda: syn.sphere_cap(spacing=3.0, concave=True),
         "freeform": lambda: syn.freeform_patch(spacing=4.0)}[maker]()
    p = parameterize(m, boundary=boundary)
    area = _signed_areas(p.uv, m.F)
    # faces with three vertices on one rectangle side collapse to a segment (area 0)
    assert np.all(area >= 0) and np.sum(area > 0) >= len(area) - 4


def test_user_corners_are_validated():
    m = syn.plane(size=60, spacing=6.0)
    loop = boundary_loops(m.F, m.n_vertices)[0]
    interior = int(np.setdiff1d(np.arange(m.n_vertices), loop)[0])
    c = loop[[0, 5, 10, 15]]
    p = parameterize(m, boundary="rectangle", corners=tuple(c))
    assert p.corners == tuple(int(x) for x in c)
    # any cyclic rotation is in boundary order too
    parameterize(m, boundary="rectangle", corners=tuple(np.roll(c, 1)))
    with pytest.raises(ParameterizationError, match=rf"corner vertices \[{interior}\] are not on the boundary"):
        parameterize(m, boundary="rectangle", corners=(c[0], c[1], c[2], interior))
    with pytest.raises(ParameterizationError, match="not in boundary order"):
        parameterize(m, boundary="rectangle", corners=(c[0], c[2], c[1], c[3]))
    with pytest.raises(ParameterizationError, match="four distinct"):
        parameterize(m, boundary="rectangle", corners=(c[0], c[0], c[1], c[2]))
    with pytest.raises(ParameterizationError, match="four distinct"):
        parameterize(m, boundary="rectangle", corners=(c[0], c[1], c[2]))
    with pytest.raises(ParameterizationError, match="four vertex ids"):
        parameterize(m, boundary="rectangle", corners="abcd")
    # ids outside the mesh are named as such (a huge id allocated an array that large)
    n = m.n_vertices
    for bad in (-1, n, 10**15):
        with pytest.raises(ParameterizationError, match=rf"^corner vertex id {bad} is not in the mesh \(ids 0..{n - 1}\)$"):
            parameterize(m, boundary="rectangle", corners=(c[0], c[1], c[2], bad))
    with pytest.raises(ParameterizationError, match=r"corner vertex id -3 is not in the mesh \(ids are 0 or more\)"):
        corner_positions(loop, (c[0], c[1], c[2], -3))
    with pytest.raises(ParameterizationError, match=r"corner vertices \[1000000000000000\] are not on the boundary"):
        corner_positions(loop, (c[0], c[1], c[2], 10**15))
    with pytest.raises(ParameterizationError, match="only used with the rectangle"):
        parameterize(m, boundary="circle", corners=tuple(c))


def test_turning_from_the_boundary_faces_alone_is_the_same():
    # parameterize sums the angles of the faces at the boundary only: every face at a
    # boundary vertex is among them, so the sums there are the full mesh's, bit for bit
    m = syn.freeform_patch(spacing=2.0)
    loop = boundary_loops(m.F, m.n_vertices)[0]
    on = np.zeros(m.n_vertices, dtype=bool)
    on[loop] = True
    Fb = m.F[on[m.F].any(axis=1)]
    assert len(Fb) < len(m.F) // 4
    full = boundary_turning(m.V, m.F, loop, corner_angles(m.V, m.F))
    assert np.array_equal(boundary_turning(m.V, Fb, loop, corner_angles(m.V, Fb)), full)
    p = parameterize(m, boundary="rectangle")
    assert p.corners == tuple(int(c) for c in auto_corners(m.V, loop, full))
