"""Step lengths between and along tool paths for a ball-end cutter (METHOD sections 2 and 4).

Exact circle geometry in the plane normal to the path (side step) or in the osculating
plane of the path (forward step), not the small-step limits of the paper.

Curvature sign (as in :mod:`conformill.geometry.differential`): ``kappa > 0`` means the
surface curves towards the tool (concave, a bowl or trough), ``kappa < 0`` away from it
(convex, a dome), ``R = 1/|kappa|``.

Side interval: derivation
-------------------------
Cut the surface by the plane across the paths; there it is a circle of radius ``R``
centred at ``O``. Two adjacent CC points ``P1, P2`` on it, chord ``w = |P1 P2|``, subtend
``2 alpha`` at ``O`` with ``w = 2 R sin(alpha)``. The ball centres lie on the surface
normals at distance ``r`` from the CC points, i.e. on the circle of radius
``D = R + r`` (convex: tool outside the circle) or ``D = R - r`` (concave: tool inside,
needs ``R > r``), at the same angles ``+-alpha``. By symmetry the cusp ``X`` of material
left between the two balls lies on the bisector, at distance ``d`` from ``O`` with
``|X - C1| = r``, law of cosines::

    d^2 + D^2 - 2 d D cos(alpha) = r^2.

Convex: the cusp is the lower root and ``d = R + h``; concave: it is the upper root and
``d = R - h``. In both cases ``D - d = +-(r - h)``, so
``1 - cos(alpha) = (r^2 - (D - d)^2) / (2 d D) = h (2r - h) / (2 d D)``. With the signed
curvature ``kappa`` (``d D = R^2 (1 - h kappa)(1 - r kappa)`` in both cases)::

    Q = h (2r - h) / (2 (1 - h kappa)(1 - r kappa)),   1 - cos(alpha) = Q kappa^2,
    w = 2 R sin(alpha) = 2 sqrt(Q (2 - Q kappa^2)),

which is continuous through ``kappa = 0``, where it is the flat interval
``2 sqrt(h (2r - h))`` (two circles of radius ``r`` whose centres are ``w`` apart meet at
height ``r - sqrt(r^2 - w^2/4) = h``). The paper's forms ``sqrt(8 h r R / (R +- r))`` are
the limit ``h << r`` of this.

Validity: convex, the lower root is the cusp only while ``d^2 <= D^2 - r^2``, i.e.
``R >= h^2 / (2 (r - h))``; on sharper convex curvature even the widest chord at which the
two balls still meet on the bisector (``sin(alpha) = r / (R + r)``, chord
``2 r / (1 + r |kappa|)``) leaves less than ``h``, so that chord is returned. Concave,
``alpha`` is capped at 90 degrees (the chord at most the diameter) and ``R <= r`` means the
ball cannot follow the surface: ``reachable`` is False and the flat interval is returned
as a conservative step.

Inverse (cusp height of chord ``w``, ``s = w / 2``, ``sin(alpha) = s |kappa|``,
``a = |D| sin(alpha) = (1 - r kappa) s``)::

    h = s^2 (1 - 2 r kappa) / (r cos(alpha) + sqrt(r^2 - a^2)) + s^2 kappa / (1 + cos(alpha)),

from ``h = +-(d - R)``, ``d = D cos(alpha) -+ sqrt(r^2 - a^2)``, written without
cancellation (``R (1 - cos alpha) = s^2 |kappa| / (1 + cos alpha)`` and
``r cos(alpha) - sqrt(r^2 - a^2) = (a^2 - r^2 sin^2 alpha) / (r cos(alpha) + sqrt(r^2 - a^2))``).

Forward step: the longest chord of a circle of radius ``R`` whose sagitta is ``e`` is
``2 sqrt(e (2R - e))`` (METHOD: ``sqrt(8 e R cos(theta) - 4 e^2)`` with ``cos(theta) = 1``).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from conformill.errors import JobValueError, PlanningError
from conformill.geometry.differential import _flat, curvature_in
from conformill.types import PathParams


#: The program's resolution (mm): coordinates are written with 4 decimals
#: (:mod:`conformill.output.gcode`). A ball radius, scallop or chord tolerance below it
#: cannot be held by the program written (and 1e-300 ended in a division by zero or a
#: ``linspace`` beyond memory, with a traceback).
RESOLUTION = 1e-4


def check_resolution(name: str, value: float, error: type[Exception] = JobValueError) -> None:
    """Refuse a length (mm) below :data:`RESOLUTION`: the one check behind the ball radius,
    scallop and chord tolerance (:func:`check_params`), ``max_step``
    (:func:`conformill.pipeline.check_job`) and ``verify``'s and ``view``'s radius
    (:func:`check_ball_size`)."""
    if value < RESOLUTION:
        raise error(f"{name} {value:g} mm is below {RESOLUTION:g} mm, the resolution the program is written to "
                    f"(4 decimals)")


def _positive(name: str, value) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise JobValueError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(x) or x <= 0.0:
        raise JobValueError(f"{name} must be finite and > 0 mm, got {value!r}")
    check_resolution(name, x)
    return x


def check_params(tool_radius, scallop, tolerance, stock=0.0, *, together: bool = True) -> PathParams:
    """Validate cutting parameters (ball radius ``r``, scallop ``h``, chord tolerance ``e``,
    stock ``s`` left on the part).

    Parameters
    ----------
    tool_radius, scallop, tolerance : float
        Millimetres.
    stock : float
        Millimetres, ``s > -r``: the surface the ball finishes is the part offset by ``s``
        along its normal (negative: into the part).
    together : bool
        Also check the values against each other (:func:`check_meetable`, exit code 3);
        False checks each value on its own (exit code 2), for a caller that has more
        single values to check first.

    Returns
    -------
    PathParams
        The values as floats.

    Raises
    ------
    JobValueError
        A value is not a finite positive number, or below :data:`RESOLUTION`, or the stock
        is not a finite number above ``-r`` (exit code 2: malformed values).
    PlanningError
        With ``together``: :func:`check_meetable`. Raised only once every value passed on
        its own, so a malformed value is named first (exit code 2).
    """
    r = _positive("tool radius", tool_radius)
    h = _positive("scallop height", scallop)
    e = _positive("chord tolerance", tolerance)
    s = check_stock(stock, r)
    params = PathParams(tool_radius=r, scallop=h, tolerance=e, stock=s)
    if together:
        check_meetable(params)
    return params


def check_meetable(params: PathParams) -> None:
    """Refuse checked parameters that cannot be met together.

    Raises
    ------
    PlanningError
        ``scallop >= tool_radius``: a ball of radius ``r`` cannot leave a cusp of ``r`` or
        more between touching passes (exit code 3: a plan that cannot be met).
    """
    if params.scallop >= params.tool_radius:
        raise PlanningError(f"scallop height {params.scallop:g} mm must be smaller than the tool radius "
                            f"{params.tool_radius:g} mm")


def check_stock(stock, tool_radius: float | None, error: type[Exception] = JobValueError,
                name: str = "stock") -> float:
    """The stock to leave as a float, checked: a finite number of mm above ``-tool_radius``.

    The one check behind ``plan --stock`` (a :class:`~conformill.errors.JobValueError`),
    ``verify`` and ``view --stock`` (a :class:`~conformill.errors.ConformillError`) and
    :func:`conformill.verify.simulate.verify`: exit code 2 from each (a stock at or below
    ``-tool_radius`` leaves a ball of no size, a malformed value like a negative radius).

    Parameters
    ----------
    stock : float
        Material left on the part (mm); negative cuts into it (an electrode's gap).
    tool_radius : float or None
        Ball radius (mm); None checks only that the stock is a finite number.
    error : type of Exception
        What to raise.
    name : str
        How the message names the value (``"--stock"`` for an option).

    Returns
    -------
    float
        The stock, with ``-0.0`` made ``0.0``.

    Raises
    ------
    error
        Not a number, not finite, a bool, or not above ``-tool_radius``.
    """
    try:
        s = float(stock) + 0.0  # -0.0 -> 0.0
    except (TypeError, ValueError):
        raise error(f"{name} must be a number (mm), got {stock!r}") from None
    if isinstance(stock, bool) or not math.isfinite(s) or (tool_radius is not None and s <= -tool_radius):
        bound = "" if tool_radius is None else f" above minus the tool radius ({-tool_radius:g})"
        raise error(f"{name} must be a finite number of mm{bound}, got {stock!r}")
    return s


#: A ball whose radius is more than this many times the part's largest extent is refused
#: (:func:`check_ball_size`).
BALL_OVER_PART = 100.0


def check_ball_size(tool_radius: float, V: np.ndarray, error: type[Exception] = JobValueError,
                    name: str = "tool radius", stock: float = 0.0) -> None:
    """Refuse a ball far larger than the part: a radius more than :data:`BALL_OVER_PART`
    times the largest side of the part's bounding box.

    Such a radius is a mistake of units (a radius in micrometres, a part in metres), not a
    tool for this part, and the work does not end or ends in nonsense: every face of the
    part lies within the ball's reach of every point, so the drop-cutter's time grows with
    the radius (``sample:patch``, 120 mm across: 20 s at r = 1e6 mm, 89 s at 1e7, not done
    in 5 minutes at 1e9), and near 1e150 mm its squares overflow (the plan failed with
    "not within the ball's reach", ``verify`` with an IndexError). The check behind
    :func:`conformill.pipeline.plan` (a :class:`~conformill.errors.JobValueError`),
    :func:`conformill.verify.simulate.verify` and ``view`` (a
    :class:`~conformill.errors.ConformillError`): exit code 2 from each.

    Parameters
    ----------
    tool_radius : float
        Ball radius (mm), finite and positive (checked before).
    V : (n, 3) float64
        The part's vertices (mm).
    error : type of Exception
        What to raise.
    name : str
        How the message names the radius.
    stock : float
        Stock to leave (mm, checked before): the ball that touches the part is of radius
        ``tool_radius + stock``, and a positive stock counts.

    Raises
    ------
    error
        The radius (with a positive stock) is more than ``BALL_OVER_PART`` times the part's
        largest extent, or the radius is below :data:`RESOLUTION`.
    """
    V = np.asarray(V, dtype=np.float64)
    if V.size == 0:
        return
    ext = V.max(axis=0) - V.min(axis=0)
    r = float(tool_radius)
    s = max(float(stock), 0.0)
    check_resolution(name, r, error)
    if r + s > BALL_OVER_PART * float(ext.max()):
        what = f"{name} {r:g} mm" + (f" plus the stock {s:g} mm" if s > 0 else "")
        raise error(f"{what} is more than {BALL_OVER_PART:g} times the part's size ({ext[0]:.4g} x "
                    f"{ext[1]:.4g} x {ext[2]:.4g} mm): no ball that large can finish it; check the units of the "
                    f"radius{', the stock' if s > 0 else ''} and of the mesh (--scale)")


def side_interval(h, r, kappa):
    """Exact chord between adjacent CC points leaving a cusp of height ``h``.

    See the module notes for the derivation:
    ``Q = h (2r - h) / (2 (1 - h kappa)(1 - r kappa))``, ``l_s = 2 sqrt(Q (2 - Q kappa^2))``.

    Parameters
    ----------
    h : float or ndarray
        Scallop height (mm), ``0 < h < r``.
    r : float
        Ball radius (mm).
    kappa : float or ndarray
        Signed normal curvature across the paths (1/mm), > 0 concave.

    Returns
    -------
    l_s : ndarray of float64
        Chord between the CC points of adjacent paths (mm).
    reachable : ndarray of bool
        False where the surface is concave with ``R <= r`` (the ball cannot follow; ``l_s``
        is then the flat interval ``2 sqrt(h (2r - h))``) or ``kappa`` is not finite
        (same fallback).
    """
    h = np.asarray(h, dtype=np.float64)
    k = np.asarray(kappa, dtype=np.float64)
    r = float(r)
    shape = np.broadcast_shapes(h.shape, k.shape)
    h = np.broadcast_to(h, shape).flatten()  # flat, contiguous, writeable copies
    k = np.broadcast_to(k, shape).flatten()
    reachable = np.isfinite(k) & (r * k < 1.0)
    return _side_interval_w(h, k, r).reshape(shape), reachable.reshape(shape)


@njit(cache=True, nogil=True, error_model="numpy")
def _side_interval_w(h, k, r):
    """:func:`side_interval`'s chord over flat arrays (compiled: the planner calls it on
    every dense sample of every curve it evaluates)."""
    out = np.empty(h.size)
    for i in range(h.size):
        out[i] = _side_interval_one(h[i], k[i], r)
    return out


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _side_interval_one(h, k, r):
    flat = 2.0 * math.sqrt(h * (2.0 * r - h))
    if not (math.isfinite(k) and r * k < 1.0):
        return flat
    ak = abs(k)
    Q = h * (2.0 * r - h) / (2.0 * (1.0 - h * k) * (1.0 - r * k))
    q = Q * k * k
    if q >= 1.0:  # 1 - cos(alpha) capped at 1: alpha <= 90 degrees
        w = 2.0 / (ak if ak > 0 else 1.0)
    else:
        w = 2.0 * math.sqrt(Q * (2.0 - q))
    # sharp convex: even the widest chord at which the balls still meet leaves < h
    if k < 0 and ak * h * h > 2.0 * (r - h):
        w = 2.0 * r / (1.0 + r * ak)
    return w


def side_interval_stock(h, r, kappa, stock: float, cap: float | None = None):
    """:func:`side_interval` for a ball finishing the part's offset by ``stock``, as a chord
    between CC points on the part itself.

    With stock ``s`` the ball of radius ``r`` rolls on the surface offset by ``s`` along the
    normal; its centre is ``r + s`` from the part. Where the part has the signed normal
    curvature ``kappa`` across the paths (> 0 concave, radius ``1 / |kappa|``), the offset
    has ``kappa' = kappa / (1 - kappa s)`` (a concave radius shrinks by ``s``, a convex one
    grows by it). Two CC points of the part and the two on the offset along the same
    normals subtend the same angle, so the chords scale with the radii:
    ``l_part = l_offset / (1 - kappa s)``, where ``l_offset`` is :func:`side_interval`
    ``(h, r, kappa')``, capped at ``cap`` (on the offset, where the ball rolls). Where
    ``1 - kappa s <= 0`` the offset folds over (a concave radius below ``s``, or with a
    negative stock a convex radius below ``-s``): unreachable, with the flat interval.
    ``stock = 0`` gives :func:`side_interval` (and the cap) unchanged.

    Parameters
    ----------
    h, r, kappa
        As for :func:`side_interval`.
    stock : float
        Material left on the part, mm (``> -r``).
    cap : float, optional
        Upper bound of the chord on the offset (mm).

    Returns
    -------
    l_s : ndarray of float64
        Chord between the CC points of adjacent paths on the part (mm).
    reachable : ndarray of bool
        False where the ball cannot follow the offset's concave curvature (``kappa >= 1 /
        (r + s)``: the ball of radius ``r + s`` cannot follow the part), where the offset
        folds over, or ``kappa`` is not finite.
    """
    k = np.asarray(kappa, dtype=np.float64)
    s = float(stock)
    if s == 0.0:
        ls, reach = side_interval(h, r, k)
    else:
        f = 1.0 - k * s
        good = np.isfinite(f) & (f > 0.0)
        fs = np.where(good, f, 1.0)
        ls, reach = side_interval(h, r, np.where(good, k / fs, np.nan))
        reach &= good
    if cap is not None:
        ls = np.minimum(ls, cap)
    if s != 0.0:
        ls = np.where(reach, ls / fs, ls)
    return ls, reach


_FLOAT_MAX = float(np.finfo(np.float64).max)


@njit(cache=True, nogil=True, error_model="numpy")
def allowed_across(I, II, n, t, scallop, r, stock, cap, rise_tol, max_step2, undercut_nz, flat):
    """The planner's allowed side interval at surface samples, in one compiled pass.

    What :meth:`conformill.patterns.family.Planner.allowed` computes with numpy, operation
    for operation (the same bits): the normal curvature across the domain tangent ``t``
    (``kappa``, :func:`conformill.geometry.differential.normal_curvature` in the direction
    of :func:`conformill.geometry.differential.perpendicular_direction`); with
    ``rise_tol > 0`` the chord rise over a path concave along ``t``, ``min(rise_tol,
    kappa_t max_step^2 / 8)`` (``rise_tol`` where that is NaN), taken off ``scallop``;
    :func:`side_interval_stock` of what is left, capped at ``cap`` (``inf``: none) on the
    offset; and at least ``flat`` where the normal's ``n_z`` is below ``undercut_nz``.

    Parameters
    ----------
    I, II, n : (k, 3) float64
        First and second fundamental forms and unit normals at the samples.
    t : (k, 2) float64
        Domain tangents of the path.
    scallop, r, stock, cap, rise_tol : float
        ``h``, the ball radius, the stock, the cap of the chord (``inf``: none) and the
        forward chord tolerance (0: no rise).
    max_step2 : float
        The longest forward step, squared.
    undercut_nz : float
        Samples with ``n_z`` below this get at least ``flat``.
    flat : float
        The flat interval with the stock and the cap (the caller's
        :func:`side_interval_stock` of ``kappa = 0``).

    Returns
    -------
    ls : (k,) float64
    reach : (k,) bool
    """
    k = I.shape[0]
    ls = np.empty(k)
    reach = np.empty(k, dtype=np.bool_)
    for i in range(k):
        E, F, G = I[i, 0], I[i, 1], I[i, 2]
        L, M, N = II[i, 0], II[i, 1], II[i, 2]
        tu, tv = t[i, 0], t[i, 1]
        # across the path: perpendicular_direction's (-(F tu + G tv), E tu + F tv)
        kap = curvature_in(E, F, G, L, M, N, -(F * tu + G * tv), E * tu + F * tv)
        h = scallop
        if rise_tol > 0:
            along = curvature_in(E, F, G, L, M, N, tu, tv)
            if along < 0.0:  # (np.maximum: NaN stays NaN)
                along = 0.0
            rise = along * max_step2 / 8.0
            if rise_tol < rise:  # (np.minimum: NaN stays NaN)
                rise = rise_tol
            if rise != rise:  # (np.nan_to_num: NaN -> rise_tol, +inf -> the largest float)
                rise = rise_tol
            elif rise == np.inf:
                rise = _FLOAT_MAX
            h = h - rise
        # with stock, the curvature of the offset the ball rolls on (side_interval_stock)
        kk, good, fs = kap, True, 1.0
        if stock != 0.0:
            f = 1.0 - kap * stock
            good = math.isfinite(f) and f > 0.0
            fs = f if good else 1.0
            kk = kap / fs if good else np.nan
        w = _side_interval_one(h, kk, r)
        ok = math.isfinite(kk) and r * kk < 1.0 and good
        if cap < w:
            w = cap
        if stock != 0.0 and ok:
            w = w / fs
        if n[i, 2] < undercut_nz and flat > w:  # (np.maximum: NaN stays NaN)
            w = flat
        ls[i] = w
        reach[i] = ok
    return ls, reach


def scallop_height(w, r, kappa):
    """Cusp height left between two passes whose CC points are a chord ``w`` apart.

    Inverse of :func:`side_interval` (module notes):
    ``h = s^2 (1 - 2 r kappa) / (r cos(alpha) + sqrt(r^2 - a^2)) + s^2 kappa / (1 + cos(alpha))``
    with ``s = w/2``, ``sin(alpha) = s |kappa|``, ``a = (1 - r kappa) s``.

    Parameters
    ----------
    w : float or ndarray
        Chord between adjacent CC points (mm), >= 0.
    r : float
        Ball radius (mm).
    kappa : float or ndarray
        Signed normal curvature across the paths (1/mm).

    Returns
    -------
    ndarray of float64
        ``inf`` where the two balls do not meet on the bisector (nothing cuts the middle)
        or the chord exceeds the diameter ``2R``; NaN where concave with ``R <= r``.
    """
    w = np.asarray(w, dtype=np.float64)
    k = np.asarray(kappa, dtype=np.float64)
    r = float(r)
    w, k = np.broadcast_arrays(w, k)
    s = 0.5 * w
    sa = s * np.abs(k)
    a = (1.0 - r * k) * s
    with np.errstate(invalid="ignore", divide="ignore"):
        ca = np.sqrt(np.maximum(1.0 - sa * sa, 0.0))
        root = np.sqrt(np.maximum(r * r - a * a, 0.0))
        h = s * s * (1.0 - 2.0 * r * k) / (r * ca + root) + s * s * k / (1.0 + ca)
    # (relative slack 1e-12 so that side_interval's widest chord maps back to a finite h)
    h = np.where((sa > 1.0 + 1e-12) | (np.abs(a) > r * (1.0 + 1e-12)), np.inf, h)
    h = np.where(r * k >= 1.0, np.nan, h)
    return h


def side_interval_paper(h, r, kappa):
    """The paper's small-``h`` side interval (METHOD section 4), for comparison only.

    ``sqrt(8 h r R / (R + r))`` convex, ``sqrt(8 h r R / (R - r))`` concave (NaN where
    ``R <= r``), ``sqrt(8 h r)`` flat; in curvature form ``sqrt(8 h r / (1 - r kappa))``.
    """
    h = np.asarray(h, dtype=np.float64)
    k = np.asarray(kappa, dtype=np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        den = 1.0 - float(r) * k
        return np.where(den > 0, np.sqrt(8.0 * h * float(r) / np.where(den > 0, den, 1.0)), np.nan)


def forward_step(e, kappa, max_step):
    """Longest chord along the path whose deviation from the surface stays below ``e``.

    ``l_f = 2 sqrt(e (2R - e))``, ``R = 1/|kappa|`` (METHOD section 4 with
    ``cos(theta) = 1``), computed as ``2 sqrt(e (2 - e |kappa|) / |kappa|)``.

    Parameters
    ----------
    e : float or ndarray
        Chord tolerance (mm), > 0.
    kappa : float or ndarray
        Normal curvature along the path (1/mm); only ``|kappa|`` matters.
    max_step : float or ndarray
        Upper bound (mm), returned where ``kappa`` is 0 (or not finite) or ``2R <= e``
        (every chord of the circle is within tolerance).

    Returns
    -------
    ndarray of float64
    """
    args = [np.asarray(a, dtype=np.float64) for a in (e, kappa, max_step)]
    shape = np.broadcast_shapes(*(a.shape for a in args))
    return _forward_steps(*(_flat(a, shape) for a in args)).reshape(shape)  # (as normal_curvature broadcasts)


@njit(cache=True, nogil=True, inline="always", error_model="numpy")
def forward_step_one(e, kappa, max_step):
    """:func:`forward_step` of one sample (compiled; the forward steps call it per sample)."""
    ak = abs(kappa)
    if np.isfinite(ak) and ak > 0 and e * ak < 2.0:
        # a subnormal |kappa| overflows to inf, which the cap then bounds
        w = 2.0 * np.sqrt(e * (2.0 - e * ak) / ak)
        return w if (w < max_step or w != w) else max_step  # np.minimum: NaN from either, the cap on a tie
    return max_step


@njit(cache=True, nogil=True, error_model="numpy")
def _forward_steps(e, kappa, max_step):
    """:func:`forward_step_one` over flat arrays."""
    out = np.empty(e.size)
    for i in range(e.size):
        out[i] = forward_step_one(e[i], kappa[i], max_step[i])
    return out


def _det(E, F, G):
    E, F, G = (np.asarray(a, dtype=np.float64) for a in (E, F, G))
    det = E * G - F * F
    return E, F, G, np.where(det > 0, det, np.nan)


def domain_side_step(l_s, E, F, G, across: str = "u"):
    """Domain step between iso-parameter paths that are ``l_s`` apart on the surface.

    Paths ``u = const`` (``across="u"``): the surface distance between the lines ``u`` and
    ``u + du`` is ``du sqrt(E) sin(phi)`` with ``sin(phi) = sqrt(EG - F^2) / sqrt(EG)``
    (METHOD section 2), so ``du = l_s sqrt(G) / sqrt(EG - F^2)``; ``across="v"``:
    ``dv = l_s sqrt(E) / sqrt(EG - F^2)``. Conformal maps give ``l_s / sigma``.

    Parameters
    ----------
    l_s : float or ndarray
        Surface interval (mm).
    E, F, G : float or ndarray
        First fundamental form at the points (``F = r_u . r_v``).
    across : {"u", "v"}

    Returns
    -------
    ndarray of float64
        NaN where the metric is degenerate (``EG - F^2 <= 0``).

    Raises
    ------
    JobValueError
        ``across`` is not "u" or "v".
    """
    E, F, G, det = _det(E, F, G)
    if across == "u":
        num = G
    elif across == "v":
        num = E
    else:
        raise JobValueError(f"domain_side_step: across must be 'u' or 'v', got {across!r}")
    return np.asarray(l_s, dtype=np.float64) * np.sqrt(num / det)


def domain_forward_step(l_f, E, F, G, along: str = "v"):
    """Domain step along an iso-parameter path: ``dv = l_f / sqrt(G)`` or ``du = l_f / sqrt(E)``.

    Parameters
    ----------
    l_f : float or ndarray
        Surface chord (mm).
    E, F, G : float or ndarray
    along : {"v", "u"}

    Returns
    -------
    ndarray of float64
        NaN where the metric is degenerate.

    Raises
    ------
    JobValueError
        ``along`` is not "u" or "v".
    """
    E, F, G, det = _det(E, F, G)
    if along == "v":
        g = G
    elif along == "u":
        g = E
    else:
        raise JobValueError(f"domain_forward_step: along must be 'u' or 'v', got {along!r}")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(np.isfinite(det), np.asarray(l_f, dtype=np.float64) / np.sqrt(g), np.nan)


def polar_metric(E, F, G, theta, rho):
    """First fundamental form in polar domain coordinates ``u = rho cos(theta), v = rho sin(theta)``.

    ``r_rho = c r_u + s r_v``, ``r_theta = rho (-s r_u + c r_v)`` give
    ``E_rho = E c^2 + 2 F c s + G s^2``,
    ``F_rt = rho ((G - E) c s + F (c^2 - s^2))``,
    ``G_theta = rho^2 (E s^2 - 2 F c s + G c^2)``, and ``E_rho G_theta - F_rt^2 = rho^2 (EG - F^2)``.

    Returns
    -------
    E_rho, F_rt, G_theta : ndarray of float64
    """
    E, F, G = (np.asarray(a, dtype=np.float64) for a in (E, F, G))
    c, s = np.cos(theta), np.sin(theta)
    rho = np.asarray(rho, dtype=np.float64)
    Er = E * c * c + 2 * F * c * s + G * s * s
    Frt = rho * ((G - E) * c * s + F * (c * c - s * s))
    Gt = rho * rho * (E * s * s - 2 * F * c * s + G * c * c)
    return Er, Frt, Gt


def polar_side_step(l_s, E, F, G, theta):
    """Radial domain step between rings ``rho = const`` that are ``l_s`` apart on the surface.

    The distance between the iso-``rho`` lines is ``drho sqrt(E_rho G_theta - F_rt^2) /
    sqrt(G_theta)`` (:func:`polar_metric`), hence
    ``drho = l_s sqrt(E s^2 - 2 F c s + G c^2) / sqrt(EG - F^2)``, independent of ``rho``
    (well defined at the centre). Conformal: ``l_s / sigma``.

    Parameters
    ----------
    l_s : float or ndarray
    E, F, G : float or ndarray
        First fundamental form in ``(u, v)`` at the points.
    theta : float or ndarray
        Polar angle of the points in the domain.

    Returns
    -------
    ndarray of float64
        NaN where the metric is degenerate.
    """
    E, F, G, det = _det(E, F, G)
    c, s = np.cos(theta), np.sin(theta)
    gt = E * s * s - 2 * F * c * s + G * c * c
    return np.asarray(l_s, dtype=np.float64) * np.sqrt(gt / det)


def polar_forward_step(l_f, E, F, G, theta, rho):
    """Angular domain step along a ring ``rho = const``: ``dtheta = l_f / sqrt(G_theta)``.

    ``sqrt(G_theta) = rho sqrt(E s^2 - 2 F c s + G c^2)`` (:func:`polar_metric`); METHOD
    section 5 writes ``l_f / (rho sigma)`` for a conformal map. Capped at ``2 pi`` (one
    turn; at ``rho = 0`` the ring is a point).

    Returns
    -------
    ndarray of float64
        NaN where the metric is degenerate.
    """
    E, F, G, det = _det(E, F, G)
    c, s = np.cos(theta), np.sin(theta)
    speed = np.asarray(rho, dtype=np.float64) * np.sqrt(E * s * s - 2 * F * c * s + G * c * c)
    with np.errstate(invalid="ignore", divide="ignore"):
        d = np.where(speed > 0, np.asarray(l_f, dtype=np.float64) / np.where(speed > 0, speed, 1.0), 2 * np.pi)
    d = np.minimum(d, 2 * np.pi)
    return np.where(np.isfinite(det), d, np.nan)


__all__ = [
    "allowed_across",
    "check_meetable",
    "check_params",
    "side_interval_stock",
    "check_stock",
    "side_interval",
    "scallop_height",
    "side_interval_paper",
    "forward_step",
    "domain_side_step",
    "domain_forward_step",
    "polar_metric",
    "polar_side_step",
    "polar_forward_step",
]
