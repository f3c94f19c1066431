"""Build the sample meshes shipped in ``src/conformill/data/`` (deterministic).

    python tools/make_samples.py [--meshes /work/shared/meshes] [--out src/conformill/data]

Samples (see ``src/conformill/data/SAMPLES.md``):

- ``face.ply``: ``face_choi.ply`` (Choi & Lui, Apache-2.0; metres) x 1000 -> mm, turned so
  that its area-weighted mean normal is +Z, lowest point at z = 0, centred in XY, then
  decimated by quadric-error half-edge collapses (the kept vertices are original scan
  points, the boundary is kept exactly) to fit the ~400 kB budget.
- ``lion.ply``: ``relief_chinese_lion_choi.ply`` the same way, scaled to 120 mm wide.
- ``patch.ply``: a CAD-like free-form patch generated from
  :func:`conformill.mesh.synthetic.height_field` over a curved non-convex outline.

Everything uses numpy/scipy only and no randomness beyond seeded generators, so a rerun
writes byte-identical files. Files are binary little-endian PLY, float32 xyz, int32
triangles (``list uchar int``), in mm.
"""

from __future__ import annotations

import argparse
import hashlib
import heapq
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from conformill.mesh.io import read_mesh  # noqa: E402
from conformill.mesh.synthetic import height_field  # noqa: E402
from conformill.mesh.topology import boundary_loops  # noqa: E402
from conformill.mesh.validate import validate_disk  # noqa: E402
from conformill.types import Mesh  # noqa: E402

#: size budget per sample file
MAX_BYTES = 400_000


# --------------------------------------------------------------------------- placement
def face_normals_weighted(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``(b - a) x (c - a)`` per face: normal times twice the area, ``(m, 3)``."""
    return np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])


def rotation_to_z(d: np.ndarray) -> np.ndarray:
    """Smallest rotation taking unit vector ``d`` to +Z (Rodrigues), ``(3, 3)``."""
    d = d / np.linalg.norm(d)
    z = np.array([0.0, 0.0, 1.0])
    v = np.cross(d, z)
    s, c = np.linalg.norm(v), float(d @ z)
    if s < 1e-15:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]]) / s
    ang = np.arctan2(s, c)
    return np.eye(3) + np.sin(ang) * K + (1 - np.cos(ang)) * K @ K


def place_facing_z(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Turn a mesh so its area-weighted mean normal is +Z; lowest point z = 0, XY centred.

    The faces keep their winding, so their normals (consistent by validation) point to
    +Z on average: the tool comes from above.
    """
    nsum = face_normals_weighted(V, F).sum(axis=0)
    R = rotation_to_z(nsum)
    W = V @ R.T
    lo, hi = W.min(axis=0), W.max(axis=0)
    W = W - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    return W, F


# --------------------------------------------------------------------------- decimation
def _plane_quadrics(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted plane quadrics summed per vertex (Garland & Heckbert 1997), ``(n, 4, 4)``."""
    N = face_normals_weighted(V, F)
    area2 = np.linalg.norm(N, axis=1)
    nrm = N / np.maximum(area2, 1e-300)[:, None]
    p = np.column_stack([nrm, -np.einsum("ij,ij->i", nrm, V[F[:, 0]])])
    K = 0.5 * area2[:, None, None] * p[:, :, None] * p[:, None, :]
    Q = np.zeros((len(V), 4, 4))
    for k in range(3):
        np.add.at(Q, F[:, k], K)
    return Q


def decimate(V: np.ndarray, F: np.ndarray, target_vertices: int,
             min_cos: float = 0.5, min_quality: float = 0.08) -> tuple[np.ndarray, np.ndarray]:
    """Quadric-error half-edge collapses ``a -> b`` of interior vertices ``a``.

    The surviving vertices are a subset of the input (the scan points stay where they
    were), the boundary loop is unchanged, and a collapse is refused when it breaks the
    link condition (``N(a) & N(b)`` must be the two opposite vertices), turns a face by
    more than ``acos(min_cos)``, or makes a face of shape quality ``4 sqrt(3) A / sum l^2``
    below ``min_quality``. Ties are broken by vertex ids, so the result is deterministic.

    Returns
    -------
    V : (n', 3) float64
        Surviving vertices in input order.
    F : (m', 3) int64
    """
    n = len(V)
    F = np.array(F, dtype=np.int64)
    alive_f = np.ones(len(F), dtype=bool)
    alive_v = np.ones(n, dtype=bool)
    bnd = np.zeros(n, dtype=bool)
    for loop in boundary_loops(F, n):
        bnd[loop] = True
    Q = _plane_quadrics(V, F)
    vf = [set() for _ in range(n)]
    for f, tri in enumerate(F.tolist()):
        for v in tri:
            vf[v].add(f)

    def nbrs(v):
        return set(F[list(vf[v])].ravel().tolist()) - {v}

    def cost(a, b):
        h = np.append(V[b], 1.0)
        return float(h @ (Q[a] + Q[b]) @ h)

    def ok(a, b):
        if not alive_v[a] or not alive_v[b] or bnd[a]:
            return False
        fa = vf[a]
        shared = [f for f in fa if b in F[f]]
        if len(shared) != 2:
            return False
        if len(nbrs(a) & nbrs(b)) != 2:
            return False
        for f in fa:
            if f in shared:
                continue
            tri = F[f]
            P = V[tri]
            n0 = np.cross(P[1] - P[0], P[2] - P[0])
            P2 = P.copy()
            P2[tri == a] = V[b]
            n1 = np.cross(P2[1] - P2[0], P2[2] - P2[0])
            a1 = np.linalg.norm(n1)
            if a1 == 0 or n0 @ n1 < min_cos * np.linalg.norm(n0) * a1:
                return False
            l2 = ((P2 - P2[[1, 2, 0]]) ** 2).sum()
            if 2 * np.sqrt(3) * a1 / l2 < min_quality:
                return False
        return True

    heap = []
    he = np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    he = np.unique(np.vstack([he, he[:, ::-1]]), axis=0)
    he = he[~bnd[he[:, 0]]]
    H = np.concatenate([V[he[:, 1]], np.ones((len(he), 1))], axis=1)
    c0 = np.einsum("ki,kij,kj->k", H, Q[he[:, 0]] + Q[he[:, 1]], H)
    heap = [(float(c), int(a), int(b)) for c, (a, b) in zip(c0, he)]
    heapq.heapify(heap)

    n_alive = n
    while n_alive > target_vertices and heap:
        c, a, b = heapq.heappop(heap)
        if not alive_v[a] or not alive_v[b]:
            continue
        cnow = cost(a, b)
        if cnow > c * (1 + 1e-12) + 1e-300:
            heapq.heappush(heap, (cnow, a, b))  # stale entry: requeue at its true cost
            continue
        if not ok(a, b):
            continue
        for f in list(vf[a]):
            tri = F[f]
            if b in tri:
                alive_f[f] = False
                for v in tri.tolist():
                    vf[v].discard(f)
            else:
                tri[tri == a] = b
                vf[b].add(f)
        vf[a] = set()
        alive_v[a] = False
        Q[b] += Q[a]
        n_alive -= 1
        for x in sorted(nbrs(b)):
            if not bnd[b]:
                heapq.heappush(heap, (cost(b, x), b, x))
            if not bnd[x]:
                heapq.heappush(heap, (cost(x, b), x, b))
    keep = np.flatnonzero(alive_v)
    new_id = np.full(n, -1, dtype=np.int64)
    new_id[keep] = np.arange(len(keep))
    return V[keep].copy(), new_id[F[alive_f]]


# --------------------------------------------------------------------------- patch
def patch_outline(samples: int = 360) -> np.ndarray:
    """A 120 x 80 mm rounded outline with a smooth bay in its upper edge (non-convex), CCW.

    A superellipse of exponent 2.5: flatter sides (exponent >= 3) make
    :func:`conformill.mesh.synthetic.polygon_disk` keep sliver triangles between nearly
    collinear boundary points (bow-tie vertices, flipped faces).
    """
    t = 2 * np.pi * np.arange(samples) / samples
    p = 2.5
    c, s = np.cos(t), np.sin(t)
    x = 60.0 * np.sign(c) * np.abs(c) ** (2 / p)
    y = 40.0 * np.sign(s) * np.abs(s) ** (2 / p)
    bay = 20.0 * np.exp(-(((x - 8.0) / 20.0) ** 2)) * np.clip(y / 40.0, 0.0, 1.0) ** 2
    return np.column_stack([x, y - bay])


def patch_z(x, y):
    """Smooth free-form heights (a tilted saddle, a dome and a soft trough), mm."""
    return 1.4 * (
        11.0
        + 7.0 * np.exp(-((x - 28.0) ** 2 / 900.0 + (y + 8.0) ** 2 / 700.0))
        - 5.0 * np.exp(-((x + 25.0) ** 2 / 700.0 + (y - 2.0) ** 2 / 1100.0))
        + 0.0012 * (x * x - 0.8 * y * y)
        + 0.06 * x
        + 3.0 * np.sin(y / 22.0 + 0.4) * np.cos(x / 45.0)
    )


def patch_surface_stats(outline: np.ndarray) -> dict:
    """Relief, largest slope and smallest concave radius of :func:`patch_z` on a grid inside."""
    from matplotlib.path import Path as MplPath

    xs, ys = np.meshgrid(np.linspace(-60, 60, 601), np.linspace(-40, 40, 401))
    P = np.column_stack([xs.ravel(), ys.ravel()])
    P = P[MplPath(outline).contains_points(P)]
    x, y, h = P[:, 0], P[:, 1], 1e-3
    z = patch_z(x, y)
    zx = (patch_z(x + h, y) - patch_z(x - h, y)) / (2 * h)
    zy = (patch_z(x, y + h) - patch_z(x, y - h)) / (2 * h)
    zxx = (patch_z(x + h, y) - 2 * z + patch_z(x - h, y)) / h**2
    zyy = (patch_z(x, y + h) - 2 * z + patch_z(x, y - h)) / h**2
    zxy = (patch_z(x + h, y + h) - patch_z(x + h, y - h) - patch_z(x - h, y + h) + patch_z(x - h, y - h)) / (4 * h * h)
    # shape operator of a graph: I^-1 II, II = Hess / sqrt(1 + |grad|^2)
    w = np.sqrt(1 + zx**2 + zy**2)
    I = np.stack([np.stack([1 + zx**2, zx * zy], -1), np.stack([zx * zy, 1 + zy**2], -1)], -2)
    II = np.stack([np.stack([zxx, zxy], -1), np.stack([zxy, zyy], -1)], -2) / w[:, None, None]
    k = np.linalg.eigvals(np.linalg.solve(I, II)).real
    kmax = k.max(axis=1)  # > 0: concave seen from above (a valley the ball must fit)
    return {
        "relief_mm": float(z.max() - z.min()),
        "max_slope_deg": float(np.degrees(np.arctan(np.sqrt(zx**2 + zy**2).max()))),
        "min_concave_radius_mm": float(1 / kmax.max()) if kmax.max() > 0 else float("inf"),
    }


def make_patch(spacing: float = 1.3) -> Mesh:
    outline = patch_outline()
    m = height_field(outline, patch_z, spacing=spacing, jitter=0.3, seed=7, name="patch")
    V, F = drop_boundary_slivers(m.V, m.F)
    lo, hi = V.min(axis=0), V.max(axis=0)
    V = V - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])
    return Mesh(V=V, F=F, name="patch")


def drop_boundary_slivers(V: np.ndarray, F: np.ndarray, min_quality: float = 0.05):
    """Remove sliver faces spanning a nearly straight stretch of the outline.

    Along nearly straight outline stretches, Delaunay may join boundary points ``i`` and
    ``i + 2`` and the centroid test keeps the sliver ``(i, i + 1, i + 2)``: it stands almost
    vertical and buries boundary point ``i + 1`` inside. A face with one boundary edge
    and an interior opposite vertex can be dropped without leaving the disk topology (the
    vertex returns to the boundary); repeat until none is left.
    """
    F = F.copy()
    while True:
        n = len(V)
        he = np.stack([F, np.roll(F, -1, axis=1)], axis=2)  # (m, 3, 2)
        bhe = boundary_loops(F, n)
        on_b = np.zeros(n, dtype=bool)
        on_b[np.concatenate(bhe)] = True
        nxt = np.full(n, -1)
        for loop in bhe:
            nxt[loop] = np.roll(loop, -1)
        is_b = nxt[he[:, :, 0]] == he[:, :, 1]  # (m, 3) boundary half-edges
        opp = F[:, [2, 0, 1]]  # vertex opposite half-edge k
        P = V[F]
        area2 = np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1)
        q = 2 * np.sqrt(3) * area2 / ((P - P[:, [1, 2, 0]]) ** 2).sum(axis=(1, 2))
        drop = (is_b.sum(axis=1) == 1) & (q < min_quality) & ~(is_b & on_b[opp]).any(axis=1) \
            & (~on_b[opp] & is_b).any(axis=1)
        if not drop.any():
            return V, F
        F = F[~drop]


# --------------------------------------------------------------------------- output
def ply_bytes(V: np.ndarray, F: np.ndarray, comments: list[str]) -> bytes:
    """Binary little-endian PLY: float32 xyz, ``list uchar int`` triangles."""
    head = ["ply", "format binary_little_endian 1.0"]
    head += [f"comment {c}" for c in comments]
    head += [f"element vertex {len(V)}", "property float x", "property float y", "property float z",
             f"element face {len(F)}", "property list uchar int vertex_indices", "end_header"]
    vert = np.ascontiguousarray(V, dtype="<f4").tobytes()
    rec = np.zeros(len(F), dtype=[("k", "u1"), ("i", "<i4", (3,))])
    rec["k"] = 3
    rec["i"] = F
    return ("\n".join(head) + "\n").encode("ascii") + vert + rec.tobytes()


def build_scan(src: Path, scale, target: int, name: str, extra: list[str]) -> tuple[bytes, dict]:
    t0 = time.perf_counter()
    m = read_mesh(src)
    V = m.V
    if scale == "width120":
        V0, _ = place_facing_z(V, m.F)
        scale = 120.0 / float(np.ptp(V0[:, 0]))
    V, F = place_facing_z(V * float(scale), m.F)
    Vd, Fd = decimate(V, F, target)
    Vd, Fd = place_facing_z(Vd, Fd)  # re-centre: decimation keeps the boundary, not the extremes
    validate_disk(Mesh(V=Vd, F=Fd, name=name))
    data = ply_bytes(Vd, Fd, [f"conformill sample '{name}' built by tools/make_samples.py"] + extra)
    stats = {"V": len(Vd), "F": len(Fd), "seconds": time.perf_counter() - t0,
             "bbox": np.ptp(Vd, axis=0).round(1).tolist(), "scale": float(scale)}
    return data, stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--meshes", type=Path, default=Path("/work/shared/meshes"))
    ap.add_argument("--out", type=Path, default=ROOT / "src" / "conformill" / "data")
    ap.add_argument("--target", type=int, default=10000, help="vertices kept by the decimation")
    args = ap.parse_args(argv)

    outputs = {}
    outputs["face"] = build_scan(
        args.meshes / "face_choi.ply", 1000.0, args.target, "face",
        ["source: face_choi.ply = human_face.mat of garyptchoi/disk-conformal-map (Apache-2.0)",
         "units: mm (metres x 1000), mean normal +Z, min z = 0, XY centred, decimated"])
    outputs["lion"] = build_scan(
        args.meshes / "relief_chinese_lion_choi.ply", "width120", args.target, "lion",
        ["source: relief_chinese_lion_choi.ply = chinese_lion.mat of garyptchoi/disk-conformal-map (Apache-2.0)",
         "units: mm (scaled to 120 mm wide), mean normal +Z, min z = 0, XY centred, decimated"])
    t0 = time.perf_counter()
    pm = make_patch()
    validate_disk(pm)
    st = patch_surface_stats(patch_outline())
    outputs["patch"] = (
        ply_bytes(pm.V, pm.F, ["conformill sample 'patch' built by tools/make_samples.py",
                               "generated free-form height field, mm, min z = 0"]),
        {"V": len(pm.V), "F": len(pm.F), "seconds": time.perf_counter() - t0,
         "bbox": np.ptp(pm.V, axis=0).round(1).tolist(), **{k: round(v, 2) for k, v in st.items()}},
    )

    args.out.mkdir(parents=True, exist_ok=True)
    status = 0
    for name, (data, stats) in outputs.items():
        path = args.out / f"{name}.ply"
        path.write_bytes(data)
        back = read_mesh(path)  # the float32 file must still be a valid disk
        flag = "" if len(data) <= MAX_BYTES else "  OVER BUDGET"
        status |= bool(flag)
        print(f"{name}: {len(data) / 1000:.1f} kB, V={back.n_vertices} F={back.n_faces} "
              f"sha256={hashlib.sha256(data).hexdigest()[:12]} {stats}{flag}")
    return status


if __name__ == "__main__":
    sys.exit(main())
