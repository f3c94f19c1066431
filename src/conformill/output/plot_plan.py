"""Figures of a plan: the paths in the domain and on the part (paper Figs. 6(c-e), 7), and
the side-interval error along two adjacent paths near the boundary (paper Fig. 8)."""

from __future__ import annotations

import numpy as np

from conformill.output.atomic import atomic_path


def _decimate(P, n=4000):
    if len(P) <= n:
        return P
    return P[np.linspace(0, len(P) - 1, n).astype(int)]


def near_boundary_pair(domain):
    """Indices (i, i+1) of two adjacent paths next to the boundary (Fig. 8's choice)."""
    k = len(domain.paths)
    if k < 3:
        return 0, min(1, k - 1)
    if domain.pattern == "zigzag":
        return 1, 2
    return k - 3, k - 2


def error_along(domain, i):
    """Position along path i (0..1) and the side-interval error e% to path i+1.

    e% = |l_s' - d| / l_s' * 100 with l_s' the metric's prediction for the step taken and
    d the realised 3D distance (METHOD section 6).
    """
    p = domain.paths[i]
    pred, real = p.side_predicted, p.side_realised
    ok = np.isfinite(pred) & np.isfinite(real) & (pred > 0)
    x = np.linspace(0.0, 1.0, len(pred))
    return x[ok], 100 * np.abs(pred[ok] - real[ok]) / pred[ok], 100 * real[ok] / p.side_allowed[ok]


def plot_plan(path, result, dpi: int = 110) -> None:
    """Write a PNG: domain paths, paths on the 3D part, and the Fig. 8 error plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    mesh, dom = result.mesh, result.domain_paths
    uv = result.param.uv
    V, F = mesh.V, mesh.F
    fig = plt.figure(figsize=(16, 5.6))
    ax0 = fig.add_subplot(1, 3, 1)
    ax0.set_title(f"{dom.pattern}: {len(dom.paths)} paths in the parameter domain", fontsize=10)
    b = np.append(result.param.boundary, result.param.boundary[0])
    ax0.plot(uv[b, 0], uv[b, 1], color="0.3", lw=0.8)
    cmap = matplotlib.colormaps["viridis"]
    n = max(len(dom.paths) - 1, 1)
    step = max(1, len(dom.paths) // 400)
    for i, p in enumerate(dom.paths[::step]):
        q = _decimate(p.uv)
        ax0.plot(q[:, 0], q[:, 1], lw=0.5, color=cmap(i * step / n))
    ax0.set_aspect("equal")
    ax0.set_xlabel("u")
    ax0.set_ylabel("v")

    ax1 = fig.add_subplot(1, 3, 2, projection="3d")
    ax1.set_title("tool tip paths on the part (mm), coloured by machining order", fontsize=10)
    Fd = F if len(F) <= 60000 else F[:: int(np.ceil(len(F) / 60000))]
    surf = ax1.plot_trisurf(V[:, 0], V[:, 1], V[:, 2], triangles=Fd, color="0.85", alpha=0.35, linewidth=0,
                            shade=True)
    surf.set_in_layout(False)  # inside the axes' limits: tight_layout need not project it
    unreach = result.report.get("reachability", {}).get("concave_regions", [])
    for reg in unreach:
        c = np.asarray(reg["centre"], dtype=float)
        ax1.scatter([c[0]], [c[1]], [c[2]], color="red", s=20)
    # colour by position in the program (machining order), so that neighbouring
    # revolutions of one spiral pass, or rows of one linked zigzag, are told apart
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    passes = result.toolpath.passes
    total = max(sum(len(P) for P in passes), 1)
    done = 0
    for P in passes:
        idx = np.linspace(0, len(P) - 1, min(len(P), max(2, 40000 * len(P) // total))).astype(int)
        q = P[idx]
        if len(q) >= 2:
            segs = np.stack([q[:-1], q[1:]], axis=1)
            lc = Line3DCollection(segs, colors=cmap((done + idx[:-1]) / total), linewidths=0.4)
            lc.set_in_layout(False)
            ax1.add_collection3d(lc)
        done += len(P)
    lo, hi = V.min(0), V.max(0)
    ctr, rad = 0.5 * (lo + hi), 0.5 * float(np.max(hi - lo))
    ax1.set_xlim(ctr[0] - rad, ctr[0] + rad)
    ax1.set_ylim(ctr[1] - rad, ctr[1] + rad)
    ax1.set_zlim(ctr[2] - rad, ctr[2] + rad)
    ax1.view_init(elev=55, azim=-60)

    ax2 = fig.add_subplot(1, 3, 3)
    i, j = near_boundary_pair(dom)
    if j > i:
        x, err, util = error_along(dom, i)
        ax2.plot(x, err, lw=0.8, label=f"e% = |l_s' - d| / l_s' (paths {i}-{j})")
        ax2.plot(x, util, lw=0.8, label="realised / allowed l_s (%)")
        ax2.set_ylim(bottom=0)
    ax2.set_title("side interval near the boundary (paper Fig. 8)", fontsize=10)
    ax2.set_xlabel("position along the path (0..1)")
    ax2.set_ylabel("%")
    ax2.legend(fontsize=8, loc="best")
    rep = result.report
    fig.suptitle(
        f"{mesh.name}: ball R{rep['job']['tool_radius']:g}, scallop {rep['job']['scallop']:g}, "
        f"tolerance {rep['job']['tolerance']:g}; concave below R (red dots): "
        f"{100 * rep['reachability']['concave_below_tool_radius_share']:.2f}% of the area",
        fontsize=10,
    )
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=dpi, format="png")
    plt.close(fig)
