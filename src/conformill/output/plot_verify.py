"""Figure of a verification: remaining material on the part (top view) and its histogram."""

from __future__ import annotations

import numpy as np

from conformill.errors import OutputError
from conformill.output.atomic import atomic_path


def overlay_masks(result) -> list:
    """The sample sets the top view marks: ``[(mask, colour, label), ...]``.

    Uncut samples (black); gouges deeper than the limit G when given, else 1 um
    (magenta); with a scallop limit H, the judged samples left above it (red: what fails
    the check; judged = reachable or interior, as the check was made) and the samples
    excused because no ball position brings them within the reach depth (orange: rest
    material for a smaller tool).

    Parameters
    ----------
    result : conformill.verify.simulate.VerifyResult

    Returns
    -------
    list of (mask, colour, label)
        ``mask`` is an (n,) bool over the samples, ``colour`` a matplotlib colour name.
    """
    s = result.summary
    rem, gouge = result.remaining, result.gouge
    g_lim = s.get("thresholds", {}).get("gouge")
    g_show = max(float(g_lim), 1e-3) if g_lim is not None else 1e-3
    g_label = (f"gouge > G = {g_show:g} mm" if g_lim is not None else "gouge > 1 um")
    out = [(~np.isfinite(rem), "black", "uncut"),
           (gouge > g_show, "magenta", f"{g_label} (max {s['all']['gouge_max']:.3g} mm)")]
    H = s.get("thresholds", {}).get("scallop")
    if H is not None:
        judged = result.reachable if s.get("judged_on") == "reachable" and result.reachable is not None \
            else result.interior
        scope = "reachable" if s.get("judged_on") == "reachable" else "interior"
        out.append((judged & np.isfinite(rem) & (rem > H), "red", f"{scope}, above H = {H:g} mm"))
        if result.excused is not None:
            out.append((result.excused, "orange", "no ball position within the depth (rest material)"))
    return out


def plot_verify(path, result, max_pixels: int = 700, dpi: int = 110, title: str = "") -> None:
    """Write a PNG of a :class:`conformill.verify.simulate.VerifyResult`.

    Left: the samples seen from +Z (top view) binned into pixels, each pixel coloured by the
    largest remaining material along the normal of its samples (mm, colour bar; the scale
    is clipped at twice the scallop limit, or at the p99.9); pixels with a gouged sample
    (deeper than the gouge limit G when given, else 1 um) in magenta, with an uncut sample in black; with a
    scallop limit, the judged samples above it as red dots and the rest material no ball can remove as
    orange ones (:func:`overlay_masks`). Right: histogram of the remaining material
    over the interior samples, with the scallop limit and the percentiles marked.

    Parameters
    ----------
    path : str or Path
        Output ``.png`` (written atomically).
    result : VerifyResult
    max_pixels : int
        Pixels along the longer side of the top view.

    Raises
    ------
    OutputError
        The folder does not exist or the file cannot be written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = result.summary
    P = result.samples.points
    rem, interior = result.remaining, result.interior
    H = s["thresholds"].get("scallop")
    finite = np.isfinite(rem)
    p999 = s["scallop"]["p999"]
    vmax = 2 * H if H else (p999 if np.isfinite(p999) and p999 > 0 else max(float(np.max(rem[finite], initial=0)), 1e-6))

    fig, (ax, axh) = plt.subplots(1, 2, figsize=(14, 6.2), gridspec_kw={"width_ratios": [1.5, 1]})
    # top view as an image: each pixel shows the largest remaining material of its samples
    lo, hi = P[:, :2].min(0), P[:, :2].max(0)
    ext = np.maximum(hi - lo, 1e-9)
    # about 4 samples per pixel on a filled bounding box, so that the image has few holes
    px = max(max(ext) / max_pixels, float(np.sqrt(ext[0] * ext[1] * 4.0 / max(len(P), 1))))
    nx, ny = int(np.ceil(ext[0] / px)) + 1, int(np.ceil(ext[1] / px)) + 1
    ix = np.minimum(((P[:, 0] - lo[0]) / px).astype(np.int64), nx - 1)
    iy = np.minimum(((P[:, 1] - lo[1]) / px).astype(np.int64), ny - 1)
    cellid = iy * nx + ix
    img = np.full(nx * ny, -np.inf)
    np.maximum.at(img, cellid[finite], np.clip(rem[finite], 0, vmax))
    img = img.reshape(ny, nx)
    empty = np.isneginf(img)
    if empty.any() and (~empty).any():
        # fill isolated empty pixels with their nearest filled neighbour (one pixel away)
        from scipy.ndimage import distance_transform_edt

        d, (jy, jx) = distance_transform_edt(empty, return_indices=True)
        fill = empty & (d <= 1.5)
        img[fill] = img[jy[fill], jx[fill]]
    img[np.isneginf(img)] = np.nan
    extent = (lo[0], lo[0] + nx * px, lo[1], lo[1] + ny * px)
    sc = ax.imshow(img, origin="lower", extent=extent, cmap="viridis", vmin=0, vmax=vmax,
                   interpolation="nearest")
    handles = []
    from matplotlib.patches import Patch

    marks = overlay_masks(result)
    for mask, colour, label in marks[:2][::-1]:  # pixels with an uncut or gouged sample
        if mask.any():
            over = np.zeros(nx * ny)
            over[cellid[mask]] = 1.0
            rgba = np.zeros((ny, nx, 4))
            rgba[..., :3] = matplotlib.colors.to_rgb(colour)
            rgba[..., 3] = over.reshape(ny, nx)
            ax.imshow(rgba, origin="lower", extent=extent, interpolation="nearest")
            handles.append(Patch(color=colour, label=label))
    # the few samples above the limit and the rest material: dots, so that isolated ones show
    for mask, colour, label in marks[2:]:
        idx = np.flatnonzero(mask)[:50_000]
        if idx.size:
            ax.scatter(P[idx, 0], P[idx, 1], s=4.0, c=colour, linewidths=0)
            handles.append(Patch(color=colour, label=f"{label}: {int(mask.sum())}"))
    if handles:
        ax.legend(handles=handles, loc="upper right", fontsize=8)
    cb = fig.colorbar(sc, ax=ax, shrink=0.85)
    cb.set_label("remaining material along the normal (mm)")
    ax.set_aspect("equal")
    ax.set_xlabel("X (mm)")
    ax.set_ylabel("Y (mm)")
    verdict = "" if H is None and s["thresholds"].get("gouge") is None else ("  PASS" if s["pass"] else "  FAIL")
    ax.set_title((title + "\n" if title else "")
                 + f"ball r = {s['tool_radius']:g} mm, {s['samples']} samples (top view){verdict}", fontsize=10)

    ri = rem[interior & finite]
    if len(ri):
        hi = max(vmax, float(np.percentile(ri, 99.9)))
        axh.hist(np.clip(ri, 0, hi), bins=120, range=(0, hi), color="0.35")
    axh.set_yscale("log")
    axh.set_xlabel("remaining material (mm), interior samples")
    axh.set_ylabel("samples")
    sc_ = s["scallop"]
    for key, col in (("p50", "tab:blue"), ("p99", "tab:orange"), ("p999", "tab:red")):
        if np.isfinite(sc_[key]):
            axh.axvline(sc_[key], color=col, lw=1, label=f"{key} {sc_[key]:.4g} mm")
    if H:
        axh.axvline(H, color="k", ls="--", lw=1.2, label=f"limit H {H:g} mm")
    axh.legend(fontsize=8)
    axh.set_title(f"max {sc_['max']:.4g} mm, uncut {100 * s['uncut_fraction']:.3g} %, "
                  f"gouge max {s['gouge_max']:.3g} mm, rapid clearance {s['rapid_min_clearance']:.3g} mm",
                  fontsize=9)
    fig.tight_layout()
    with atomic_path(path, suffix=".png") as tmp:
        try:
            fig.savefig(tmp, dpi=dpi, format="png")
        except OSError as exc:
            raise OutputError(f"cannot write {path}: {exc.strerror}") from None
        finally:
            plt.close(fig)
