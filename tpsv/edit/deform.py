"""Shape manipulation by control points (paper VII-D).

A region's Hermite patch is changed; its features stay where they are in the
normalised patch parameters ``(S, T)``, so they ride along with the surface
(the paper's "reconstructs the parametric space to relocate detailed
features"), and its outline follows the patch: each outline vertex is mapped
``x -> M_old^-1(x) = (s, t) -> (S, T) -> M_new(S (M'-1), T (N'-1))``. Other
regions keep their patches and features; only their outline vertices on the
deformed region's border follow it (below).

Edits
-----
* :func:`move_points`: translate control points by ``(dx, dy)`` pixels.
  With ``derivatives='catmull-rom'`` (the default) the ``s`` and ``t``
  derivatives of every control point whose finite-difference stencil
  contains a moved point are re-estimated as Catmull-Rom tangents (central
  differences ``(P[i+1] - P[i-1]) / 2`` inside the grid, one-sided
  ``P[1] - P[0]`` at its border; on an untouched grid from ``build_patch``
  these are exactly the stored derivatives), and the twists around them are
  recomputed by Adini's formula (``tpsv.geometry.patch.adini_twist``). Control
  vectors farther away keep their values, so a patch loaded with its own
  derivatives (``--grid``) is only changed near the moved points. With
  ``derivatives='keep'`` the point is translated and its derivatives and
  twist are kept.
* :func:`affine`: ``x' = A x + c`` for the whole region, about the region's
  area centroid (``about='centroid'``: ``x' = A (x - g) + g + c``) or the
  image origin (``about='origin'``). Positions, derivatives and twists are
  mapped exactly (a Hermite surface is affine-covariant) and so are the
  outline vertices. A reflection (``det A < 0``) is re-parametrised so that
  the patch keeps a positive Jacobian: ``s`` is reversed, and the region's
  features get ``S -> 1 - S`` (the same image points).
* :func:`set_grid`: replace the control grid, from arrays or a JSON
  document (:func:`grid_from_json`); the grid size may change (features are
  normalised, so they follow).

A deformation that folds the patch (a Jacobian determinant ``<= 0`` anywhere
on it, sampled 8 x 8 per cell by ``tpsv.geometry.patch.fold_free``) is refused with a
:class:`TpsvError`.

Uncovered pixels and overlaps
-----------------------------
With ``attach=True`` (the default) neighbours stay attached: outline
vertices of other regions within :data:`GLUE_PX` (1 px) of a deformed
region's old border follow the same map (their polygons are split to 1 px
first and simplified after), so shared borders stay shared, e.g. the hole a
background has around an object moves with the object. The pixels the object
leaves behind then belong to that neighbour, whose TPS continues into them
(each kernel clamped to the range of its own features, so the gap is filled
from the surrounding colours, like a simple inpainting).

Islands are carried along: with ``attach=True`` a region whose whole outer
outline lies on a deformed region's border (an eye in a face, found by
:func:`enclosed_regions`, transitively) is deformed with it. Under
:func:`affine` it gets the same affine map, exactly; under :func:`move_points`
and :func:`set_grid` its control positions are mapped by the deformed region's
map ``phi`` and its derivatives and twists by the Jacobian of ``phi`` (central
differences, 0.25 px), so its features stay on the content around them; an
island that would fold is refused like the region itself.

Pixels that no outline covers (``attach=False``, or a gap at the image border)
follow the renderer's rule for every such pixel
(``tpsv.geometry.outline.rasterize_regions``): they take the region of the nearest
covered pixel, and that region's TPS at the clamped ``(S, T)``.

The blur map (``Model.blur_map``: edge widths point by point) follows the
deformed borders: the widths along a deformed region's old outline go where
its points move, and the map is kept as the file will hold it.

Where a moved outline overlaps another region, the region drawn first wins:
every region a call deforms is put in front (``Params.extra["front"]``, see
``tpsv.rendering.pixelmap.draw_order``), the most recently deformed first, unless
``keep_order=True``. Region indices never change, so later edits of the same
file can name the same regions.

JSON control grid
-----------------
::

    {
      "positions": [[[x, y], ... N points along t], ... M rows along s],
      "ds":    [[[dx, dy], ...], ...],   optional, default Catmull-Rom
      "dt":    [[[dx, dy], ...], ...],   optional, default Catmull-Rom
      "twist": [[[dx, dy], ...], ...]    optional, default Adini
    }

``positions[i][j]`` is control point ``(i, j)`` in pixel coordinates (``i``
along ``s``); every given array is ``M x N x 2`` with ``2 <= M, N <= 256``.
:func:`grid_to_json` writes a region's current grid in this schema.
"""

from __future__ import annotations

import json

import numpy as np

from ..geometry import patch as hpatch
from .common import check_region, copy_model
from ..errors import TpsvError
from ..model import Model, Patch
from ..rendering.pixelmap import FRONT_KEY, draw_order

#: Outline edges are split to at most this length (px) before a non-affine map.
SUBDIVIDE_PX = 1.0
#: Tolerance (px) of the simplification after a non-affine map (a file quantum, 1/16 px).
SIMPLIFY_PX = 1.0 / 16.0
#: Outline vertices of other regions within this distance (px) of a deformed region's border follow it.
GLUE_PX = 1.0
#: Control grid sizes a file can hold.
MIN_GRID, MAX_GRID = 2, 256


# --------------------------------------------------------------------------- derivative estimates


def catmull_rom(pos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Catmull-Rom derivatives ``(Ds, Dt)`` (M, N, 2) of control positions (M, N, 2).

    Central differences inside, one-sided differences at the border; exact
    for an affine grid.
    """
    P = np.asarray(pos, np.float64)
    Ds = np.empty_like(P)
    Dt = np.empty_like(P)
    Ds[1:-1] = (P[2:] - P[:-2]) / 2.0
    Ds[0] = P[1] - P[0]
    Ds[-1] = P[-1] - P[-2]
    Dt[:, 1:-1] = (P[:, 2:] - P[:, :-2]) / 2.0
    Dt[:, 0] = P[:, 1] - P[:, 0]
    Dt[:, -1] = P[:, -1] - P[:, -2]
    return Ds, Dt


def _dilate(mask: np.ndarray, di: int, dj: int) -> np.ndarray:
    out = mask.copy()
    M, N = mask.shape
    for a in range(-di, di + 1):
        for b in range(-dj, dj + 1):
            src = mask[max(0, -a) : M - max(0, a), max(0, -b) : N - max(0, b)]
            out[max(0, a) : M - max(0, -a), max(0, b) : N - max(0, -b)] |= src
    return out


def refresh_derivatives(ctrl: np.ndarray, moved: np.ndarray) -> np.ndarray:
    """Re-estimate derivatives near the moved control points (see the module docstring).

    ``ctrl`` (M, N, 4, 2) with the new positions; ``moved`` (M, N) bool.
    Returns a new array.
    """
    ctrl = np.array(ctrl, np.float64, copy=True)
    Ds, Dt = catmull_rom(ctrl[..., 0, :])
    ms = _dilate(moved, 1, 0)
    mt = _dilate(moved, 0, 1)
    ctrl[ms, 1, :] = Ds[ms]
    ctrl[mt, 2, :] = Dt[mt]
    tw = hpatch.adini_twist(ctrl)
    mw = _dilate(ms | mt, 1, 1)
    ctrl[mw, 3, :] = tw[mw]
    return ctrl


# --------------------------------------------------------------------------- outlines


#: Most outline points one deformation maps (after subdivision at 0.25 px for the
#: glue step): real outlines stay far below; a hostile one is refused before any work.
MAX_MAPPED_POINTS = 1 << 23

#: Points mapped per batch through the inverse patch map (bounds its scratch memory).
MAP_CHUNK = 1 << 16


def _subdivide(poly: np.ndarray, step: float) -> np.ndarray:
    nxt = np.roll(poly, -1, axis=0)
    seg = np.hypot(*(nxt - poly).T)
    k = np.maximum(1, np.ceil(seg / step).astype(np.int64))
    if not np.all(np.isfinite(seg)) or int(k.sum()) > MAX_MAPPED_POINTS:
        raise TpsvError(f"outline too long to deform (more than {MAX_MAPPED_POINTS} points at {step} px)")
    # vectorised: a Python loop over edges costs seconds on a hostile 100k-vertex outline
    i = np.repeat(np.arange(len(poly)), k)
    first = np.cumsum(k) - k
    t = (np.arange(int(k.sum())) - first[i]) / k[i]
    return poly[i] + t[:, None] * (nxt[i] - poly[i])


#: Douglas-Peucker runs on pieces of at most this many points: it is quadratic
#: in the worst case, and a hostile zig-zag outline of 10^5 points took 10 s.
SIMPLIFY_PIECE = 1024


def _approx(poly: np.ndarray, tol: float) -> np.ndarray:
    """``cv2.approxPolyDP`` of a closed polygon, piece by piece (each piece keeps its first point)."""
    import cv2

    def dp(q, closed):
        return cv2.approxPolyDP(q.reshape(-1, 1, 2).astype(np.float32), tol, closed).reshape(-1, 2)

    if len(poly) <= SIMPLIFY_PIECE:
        return dp(poly, True).astype(np.float64)
    ends = list(range(0, len(poly), SIMPLIFY_PIECE)) + [len(poly)]
    closed = np.concatenate([poly, poly[:1]])
    # each open piece runs to the next piece's first point, which is dropped here and kept there
    return np.concatenate([dp(closed[a:b + 1], False)[:-1] for a, b in zip(ends[:-1], ends[1:])]).astype(np.float64)


def _simplify(poly: np.ndarray, tol: float) -> np.ndarray:
    from ..geometry.outline import signed_area

    s = _approx(poly, tol)
    a0 = signed_area(poly)
    if len(s) < 3 or np.sign(signed_area(s)) != np.sign(a0) or abs(signed_area(s)) < 0.5 * abs(a0):
        return poly
    # approxPolyDP keeps input vertices (as float32): take them back in full precision
    from scipy.spatial import cKDTree

    _, idx = cKDTree(poly).query(s)
    if len(np.unique(idx)) != len(s):
        return s
    return poly[np.sort(idx)]


def patch_mapper(old: Patch, new: Patch):
    """``phi(xy) = M_new(M_old^-1(xy))`` through normalised ``(S, T)`` (not clamped), for (n, 2) points."""
    Mo, No = old.shape
    Mn, Nn = new.shape
    scale = np.array([(Mn - 1) / (Mo - 1), (Nn - 1) / (No - 1)])

    def phi(xy):
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        if xy.shape[0] == 0:
            return xy.copy()
        parts = []
        for c in range(0, xy.shape[0], MAP_CHUNK):
            st = hpatch.inverse(old, xy[c:c + MAP_CHUNK]) * scale
            parts.append(hpatch.forward(new, st[:, 0], st[:, 1]))
        return np.concatenate(parts)

    def with_jacobian(xy):
        """``(phi(xy), J)`` with ``J = J_new diag(scale) J_old^-1`` (n, 2, 2): one inverse per point."""
        xy = np.asarray(xy, np.float64).reshape(-1, 2)
        out, jac = [], []
        for c in range(0, xy.shape[0], MAP_CHUNK):
            st = hpatch.inverse(old, xy[c:c + MAP_CHUNK])
            sn = st * scale
            out.append(hpatch.forward(new, sn[:, 0], sn[:, 1]))
            Jo = hpatch.jacobian(old, st[:, 0], st[:, 1])
            Jn = hpatch.jacobian(new, sn[:, 0], sn[:, 1]) * scale[None, None, :]
            det = Jo[:, 0, 0] * Jo[:, 1, 1] - Jo[:, 0, 1] * Jo[:, 1, 0]
            det = np.where(np.abs(det) < 1e-12, 1e-12, det)
            inv = np.stack([np.stack([Jo[:, 1, 1], -Jo[:, 0, 1]], -1),
                            np.stack([-Jo[:, 1, 0], Jo[:, 0, 0]], -1)], 1) / det[:, None, None]
            jac.append(Jn @ inv)
        if not out:
            return xy.copy(), np.zeros((0, 2, 2))
        return np.concatenate(out), np.concatenate(jac)

    phi.with_jacobian = with_jacobian
    return phi


#: Most outline length (px) of the regions one deformation moves: their
#: outlines are subdivided at 0.25 px, mapped and searched (about 10 us a
#: pixel of outline on one core), so this keeps an edit within a few seconds.
#: A region of a 4096 x 4096 photo with a thousand holes stays well below it.
MAX_DEFORMED_PX = 1 << 18


def _outline_length(outline) -> float:
    total = 0.0
    for p in outline:
        p = np.asarray(p, np.float64)
        total += float(np.hypot(*(np.roll(p, -1, axis=0) - p).T).sum())
    return total


def _check_outline_budget(model: Model, regions=()) -> None:
    """Refuse, before any work, a model whose outlines are too long to deform.

    The glue step subdivides deformed outlines at 0.25 px and every mapped
    outline at :data:`SUBDIVIDE_PX`; a hostile file with a few kilobytes of
    long zig-zag edges would otherwise cost minutes and gigabytes. The
    ``regions`` to deform (and their islands, which move with them) have
    the tighter :data:`MAX_DEFORMED_PX`.
    """
    moved = sum(_outline_length(model.regions[r].outline) for r in set(regions))
    if not moved <= MAX_DEFORMED_PX:
        raise TpsvError(f"the outlines to deform are too long ({moved:.0f} px; at most {MAX_DEFORMED_PX} px)")
    total = sum(_outline_length(reg.outline) for reg in model.regions)
    # traced outlines follow pixel edges (at most 2 per pixel, RDP only shortens them);
    # twice that leaves room for earlier deformations that stretched them
    cap = min(MAX_MAPPED_POINTS // 4, 4 * model.width * model.height + 16 * (model.width + model.height))
    if not total <= cap:
        raise TpsvError(f"outlines too long to deform ({total:.0f} px in all; at most {cap} px for this canvas)")


def map_outline(outline, old: Patch, new: Patch) -> list[np.ndarray]:
    """Outline polygons of a region whose patch changes from ``old`` to ``new`` (general map).

    Edges are split to :data:`SUBDIVIDE_PX`, every vertex goes through
    ``(S, T)`` (not clamped: the border cells extrapolate), and the result is
    simplified by RDP at :data:`SIMPLIFY_PX`.
    """
    phi = patch_mapper(old, new)
    total = sum(float(np.hypot(*(np.roll(p, -1, axis=0) - p).T).sum()) for p in map(np.asarray, outline))
    if not total <= MAX_MAPPED_POINTS * SUBDIVIDE_PX:
        raise TpsvError(f"outline too long to deform (more than {MAX_MAPPED_POINTS} points at {SUBDIVIDE_PX} px)")
    subs = [_subdivide(np.asarray(poly, np.float64), SUBDIVIDE_PX) for poly in outline]
    if not subs:
        return []
    # one pass through the patch maps for all polygons: per call they cost
    # set-up (coefficients, frames), which a region with thousands of holes pays thousands of times
    mapped = np.split(phi(np.concatenate(subs)), np.cumsum([len(q) for q in subs])[:-1])
    return [_simplify(q, SIMPLIFY_PX) for q in mapped]


def _glue(model: Model, out: Model, mappers: dict, eps: float) -> list[int]:
    """Move other regions' outline vertices within ``eps`` px of a deformed region's old outline along with it.

    ``mappers``: deformed region -> ``phi`` (old pixel position -> new). A
    vertex near several deformed regions follows the nearest. Polygons with
    no vertex near a deformed region are left exactly as they are; a polygon
    the map would turn inside out is left as it is too. Returns the regions
    whose outlines changed.
    """
    from scipy.spatial import cKDTree

    from ..geometry.outline import signed_area

    if not mappers:
        return []
    trees, boxes = {}, {}
    for r in mappers:
        pts = np.concatenate([_subdivide(np.asarray(p, np.float64), 0.25) for p in model.regions[r].outline])
        trees[r] = cKDTree(pts)
        boxes[r] = (pts.min(0) - eps - 1.0, pts.max(0) + eps + 1.0)
    changed = []
    for q, reg in enumerate(model.regions):
        if q in mappers:
            continue
        new_polys, moved_any = [], False
        for k, poly in enumerate(reg.outline):
            poly = np.asarray(poly, np.float64)
            lo, hi = poly.min(0), poly.max(0)
            near = [r for r in mappers if np.all(hi >= boxes[r][0]) and np.all(lo <= boxes[r][1])]
            if not near:
                new_polys.append(poly)
                continue
            sub = _subdivide(poly, SUBDIVIDE_PX)
            best = np.full(sub.shape[0], np.inf)
            who = np.full(sub.shape[0], -1)
            for r in near:
                d, _ = trees[r].query(sub, distance_upper_bound=eps + 0.25)
                better = d < best
                best[better] = d[better]
                who[better] = r
            hit = best <= eps + 0.25
            if not hit.any():
                new_polys.append(poly)
                continue
            moved = sub.copy()
            for r in np.unique(who[hit]):
                sel = hit & (who == r)
                moved[sel] = mappers[int(r)](sub[sel])
            a0 = signed_area(poly)
            if hit.all() and np.sign(signed_area(moved)) != np.sign(a0):
                moved = moved[::-1].copy()  # a whole polygon under a reflection: keep its orientation
            moved = _simplify(moved, SIMPLIFY_PX)
            a1 = signed_area(moved)
            if not np.all(np.isfinite(moved)) or np.sign(a1) != np.sign(a0) or a1 == 0:
                new_polys.append(poly)
                continue
            new_polys.append(moved)
            moved_any = True
        if moved_any:
            out.regions[q].outline = new_polys
            changed.append(q)
    return changed


def _check_outline(r: int, outline) -> None:
    from ..geometry.outline import signed_area

    for k, p in enumerate(outline):
        if not np.all(np.isfinite(p)):
            raise TpsvError(f"region {r}: the deformed outline is not finite")
        a = signed_area(p)
        if (k == 0 and a <= 0) or (k > 0 and a >= 0):
            raise TpsvError(f"region {r}: the deformation turns the outline inside out (it folds)")


# --------------------------------------------------------------------------- core


def _check_patch(r: int, ctrl: np.ndarray) -> Patch:
    ctrl = np.asarray(ctrl, np.float64)
    if ctrl.ndim != 4 or ctrl.shape[2:] != (4, 2):
        raise TpsvError(f"region {r}: control grid has shape {ctrl.shape}, expected (M, N, 4, 2)")
    M, N = ctrl.shape[:2]
    if not (MIN_GRID <= M <= MAX_GRID and MIN_GRID <= N <= MAX_GRID):
        raise TpsvError(f"region {r}: control grid {M}x{N} is not within {MIN_GRID}..{MAX_GRID} per side")
    if not np.all(np.isfinite(ctrl)):
        raise TpsvError(f"region {r}: control vectors must be finite")
    if np.abs(ctrl).max() > 1e6:
        raise TpsvError(f"region {r}: control vectors beyond 1e6 px")
    p = Patch(ctrl=ctrl)
    if not hpatch.fold_free(p):
        raise TpsvError(
            f"region {r}: the deformation folds the patch (its Jacobian is <= 0 somewhere); use smaller moves"
        )
    return p


def front_regions(model: Model) -> list[int]:
    """The regions listed in ``Params.extra["front"]`` (drawn first, on top), validated."""
    order = draw_order(model)
    text = str((model.params.extra or {}).get(FRONT_KEY, "") or "")
    return order[: len(text.split(","))] if text else []


def _finish(model: Model, out: Model, regions: list[int], keep_order: bool, mappers: dict | None = None,
            attach: bool = True) -> Model:
    if attach and mappers:
        _glue(model, out, mappers, GLUE_PX)
    if not keep_order and regions:
        new_front = []
        for r in reversed(regions):  # the most recently deformed first
            if r not in new_front:
                new_front.append(r)
        new_front += [r for r in front_regions(model) if r not in new_front]
        extra = dict(out.params.extra)
        extra[FRONT_KEY] = ",".join(str(r) for r in new_front)
        out.params.extra = extra
    out.blur_map = _carried_blur_map(model, out, mappers or {})
    return out


def _carried_blur_map(model: Model, out: Model, mappers: dict):
    """``model``'s blur map with the widths of each deformed region's border carried along with it.

    The widths along a deformed region's old outline go to the cells its
    points move to; then the cells the new borders pass through keep their
    widths (on the file's 1/16 px grid) and the rings around them are filled
    again (``geometry.edgewidth.fill_map``): the map the file will hold, up
    to the file's rounding of the outlines.
    """
    bm = model.blur_map
    if bm is None or not mappers:
        return bm
    from ..codec.quant import BLUR_SCALE, MAX_BLUR
    from ..geometry.edgewidth import border_cells, fill_map, map_at

    old = np.asarray(bm.sigma, np.float64)
    grid = old.copy()
    gh, gw = grid.shape
    for r, phi in mappers.items():
        pts = np.concatenate([_subdivide(np.asarray(p, np.float64), 0.5) for p in model.regions[r].outline])
        width = map_at(old, bm.cell, bm.cell, pts[:, 0], pts[:, 1])
        new = phi(pts)
        ok = np.isfinite(new).all(axis=1)
        i = np.clip(np.floor(new[ok, 1] / bm.cell).astype(np.int64), 0, gh - 1)
        j = np.clip(np.floor(new[ok, 0] / bm.cell).astype(np.int64), 0, gw - 1)
        grid[i, j] = width[ok]
    try:
        cells = border_cells(out.regions, out.width, out.height, bm.cell)
    except ValueError:
        return None
    # on the file's 1/16 px grid, so that a render before saving is the render after
    values = np.rint(np.clip(grid.ravel()[cells], 0.0, MAX_BLUR / BLUR_SCALE) * BLUR_SCALE) / BLUR_SCALE
    return fill_map(out.width, out.height, bm.cell, cells, values.astype(np.float32))


def _replace_patch(out: Model, r: int, new: Patch, outline) -> None:
    _check_outline(r, outline)
    out.regions[r].patch = new
    out.regions[r].outline = [np.ascontiguousarray(p, np.float64) for p in outline]


def move_points(model: Model, moves, derivatives: str = "catmull-rom", keep_order: bool = False,
                attach: bool = True) -> Model:
    """Translate control points; returns a new model.

    Parameters
    ----------
    model : Model
    moves : iterable of (region, i, j, dx, dy)
        Control point ``(i, j)`` (``i`` along ``s``) of ``region`` moves by
        ``(dx, dy)`` pixels; several moves of one point add up.
    derivatives : {'catmull-rom', 'keep'}
        How derivatives follow (module docstring).
    keep_order : bool
        Do not put the deformed regions in front.
    attach : bool
        Neighbours' outlines follow the deformed regions' borders (module
        docstring).

    Raises
    ------
    TpsvError
        Unknown region or control point, a fold.
    """
    if derivatives not in ("catmull-rom", "keep"):
        raise TpsvError(f"derivatives {derivatives!r} is not catmull-rom or keep")
    per_region: dict[int, list] = {}
    order: list[int] = []
    for mv in moves:
        try:
            r, i, j, dx, dy = mv
        except (TypeError, ValueError):
            raise TpsvError(f"move {mv!r} is not (region, i, j, dx, dy)") from None
        r = check_region(model, r)
        M, N = model.regions[r].patch.shape
        if int(i) != i or int(j) != j or not (0 <= i < M and 0 <= j < N):
            raise TpsvError(f"region {r} has control points (0..{M - 1}, 0..{N - 1}); there is no ({i}, {j})")
        if not (np.isfinite(dx) and np.isfinite(dy)):
            raise TpsvError(f"move of ({i}, {j}) in region {r} is not finite")
        per_region.setdefault(r, []).append((int(i), int(j), float(dx), float(dy)))
        if r in order:
            order.remove(r)
        order.append(r)
    _check_outline_budget(model, order)
    out = copy_model(model)
    mappers = {}
    for r in order:
        old = model.regions[r].patch
        ctrl = np.array(old.ctrl, np.float64, copy=True)
        moved = np.zeros(old.shape, bool)
        for i, j, dx, dy in per_region[r]:
            ctrl[i, j, 0] += (dx, dy)
            moved[i, j] = True
        if derivatives == "catmull-rom":
            ctrl = refresh_derivatives(ctrl, moved)
        new = _check_patch(r, ctrl)
        _replace_patch(out, r, new, map_outline(model.regions[r].outline, old, new))
        mappers[r] = patch_mapper(old, new)
    if attach:
        order = order + _carry_islands(model, out, mappers)
    return _finish(model, out, order, keep_order, mappers, attach)


def region_centroid(model: Model, region: int) -> np.ndarray:
    """Area centroid ``(x, y)`` of a region's outline (outer polygon minus holes)."""
    r = check_region(model, region)
    A = 0.0
    C = np.zeros(2)
    for p in model.regions[r].outline:
        p = np.asarray(p, np.float64)
        q = np.roll(p, -1, axis=0)
        cr = p[:, 0] * q[:, 1] - q[:, 0] * p[:, 1]
        A += cr.sum() / 2.0
        C += np.array([((p[:, 0] + q[:, 0]) * cr).sum(), ((p[:, 1] + q[:, 1]) * cr).sum()]) / 6.0
    if abs(A) < 1e-12:
        return np.asarray(model.regions[r].outline[0], np.float64).mean(axis=0)
    return C / A


def affine(model: Model, region, matrix, about: str = "centroid", keep_order: bool = False,
           attach: bool = True) -> Model:
    """Apply ``x' = A x + c`` to a region (patch, outline; features ride along); returns a new model.

    Parameters
    ----------
    matrix : array-like
        ``[[a, b, c], [d, e, f]]`` (6 numbers: ``x' = a x + b y + c``,
        ``y' = d x + e y + f``) or a 2 x 2 ``A`` (no translation).
    about : {'centroid', 'origin'}
        ``A`` acts about the region's area centroid or the image origin.

    Raises
    ------
    TpsvError
        Unknown region, singular or non-finite matrix, a result beyond the
        file's limits.
    """
    r = check_region(model, region)
    m = np.asarray(matrix, np.float64)
    if m.size == 4:
        m = np.concatenate([m.reshape(2, 2), np.zeros((2, 1))], axis=1)
    if m.size != 6 or not np.all(np.isfinite(m)):
        raise TpsvError("an affine map needs 6 finite numbers a,b,c,d,e,f (x' = a x + b y + c, y' = d x + e y + f)")
    m = m.reshape(2, 3)
    A, c = m[:, :2], m[:, 2].copy()
    det = float(np.linalg.det(A))
    if not abs(det) > 1e-9:
        raise TpsvError(f"the affine map of region {r} is singular (determinant {det:g})")
    if about == "centroid":
        g = region_centroid(model, r)
        c = c + g - A @ g
    elif about != "origin":
        raise TpsvError(f"about {about!r} is not centroid or origin")
    _check_outline_budget(model, [r])
    out = copy_model(model)
    moved = [r] + (enclosed_regions(model, [r]) if attach else [])
    phi = lambda xy: np.asarray(xy, np.float64) @ A.T + c  # noqa: E731
    for q in moved:
        _affine_region(model, out, q, A, c, det)
    return _finish(model, out, moved, keep_order, {q: phi for q in moved}, attach)


def _affine_region(model: Model, out: Model, r: int, A: np.ndarray, c: np.ndarray, det: float) -> None:
    ctrl = np.array(model.regions[r].patch.ctrl, np.float64, copy=True) @ A.T
    ctrl[..., 0, :] += c
    outline = [np.asarray(p, np.float64) @ A.T + c for p in model.regions[r].outline]
    if det < 0:
        # reflection: reverse s (P(i) -> P(M-1-i), Ds -> -Ds, twist -> -twist) and S -> 1 - S
        ctrl = ctrl[::-1].copy()
        ctrl[..., 1, :] *= -1
        ctrl[..., 3, :] *= -1
        outline = [p[::-1].copy() for p in outline]
        f = out.features
        sel = f.region == r
        st = f.st.copy()
        st[sel, 0] = 1.0 - st[sel, 0]
        f.st = st
    new = _check_patch(r, ctrl)
    _replace_patch(out, r, new, outline)


def _push_region(model: Model, out: Model, q: int, phi, owner: int) -> None:
    """Carry island ``q`` along a (non-affine) map ``phi``: positions ``phi(P)``, derivatives and twists by its Jacobian."""
    ctrl = np.asarray(model.regions[q].patch.ctrl, np.float64)
    M, N = ctrl.shape[:2]
    P = ctrl[..., 0, :].reshape(-1, 2)
    if hasattr(phi, "with_jacobian"):
        moved, J = phi.with_jacobian(P)
    else:
        h = 0.25
        ex, ey = np.array([h, 0.0]), np.array([0.0, h])
        J = np.stack([(phi(P + ex) - phi(P - ex)) / (2 * h), (phi(P + ey) - phi(P - ey)) / (2 * h)], axis=-1)
        moved = phi(P)
    new = np.empty_like(ctrl)
    new[..., 0, :] = moved.reshape(M, N, 2)
    for k in (1, 2, 3):
        new[..., k, :] = np.einsum("nij,nj->ni", J, ctrl[..., k, :].reshape(-1, 2)).reshape(M, N, 2)
    try:
        patch_new = _check_patch(q, new)
    except TpsvError:
        raise TpsvError(f"region {q}, enclosed by region {owner}, would fold when carried along; "
                        f"use smaller moves or --detach") from None
    outline = [_simplify(phi(_subdivide(np.asarray(p, np.float64), SUBDIVIDE_PX)), SIMPLIFY_PX)
               for p in model.regions[q].outline]
    _replace_patch(out, q, patch_new, outline)


def _carry_islands(model: Model, out: Model, mappers: dict) -> list[int]:
    """Push the islands of each deformed region along its map; returns them (their maps added to ``mappers``)."""
    carried = []
    for r in list(mappers):
        for q in enclosed_regions(model, [r]):
            if q in mappers:
                continue
            _push_region(model, out, q, mappers[r], r)
            mappers[q] = mappers[r]
            carried.append(q)
    return carried


def enclosed_regions(model: Model, regions, eps: float = None) -> list[int]:
    """Regions enclosed by ``regions``: islands whose whole outer outline lies within ``eps`` px of their borders.

    Transitive (an island's islands are included). Used so that an affine
    deformation carries a region's islands along, and so that attached
    outlines never pull an island's outline away from its own patch.
    """
    from scipy.spatial import cKDTree

    eps = GLUE_PX if eps is None else eps
    found: list[int] = []
    frontier = [int(r) for r in regions]
    done = set(frontier)
    while frontier:
        pts = np.concatenate([_subdivide(np.asarray(p, np.float64), 0.25)
                              for r in frontier for p in model.regions[r].outline])
        tree = cKDTree(pts)
        lo, hi = pts.min(0) - eps, pts.max(0) + eps
        frontier = []
        for q, reg in enumerate(model.regions):
            if q in done:
                continue
            outer = np.asarray(reg.outline[0], np.float64)
            if np.any(outer.min(0) < lo) or np.any(outer.max(0) > hi):
                continue
            d, _ = tree.query(_subdivide(outer, SUBDIVIDE_PX), distance_upper_bound=eps + 0.25)
            if np.all(d <= eps + 0.25):
                found.append(q)
                frontier.append(q)
                done.add(q)
    return found


def _grid_array(doc, key, shape=None):
    a = doc.get(key)
    if a is None:
        return None
    try:
        arr = np.asarray(a, np.float64)
    except (TypeError, ValueError):
        raise TpsvError(f"control grid: {key!r} is not an array of numbers") from None
    if arr.ndim != 3 or arr.shape[2] != 2 or (shape is not None and arr.shape[:2] != shape):
        want = "M x N x 2" if shape is None else f"{shape[0]} x {shape[1]} x 2"
        raise TpsvError(f"control grid: {key!r} has shape {' x '.join(map(str, arr.shape))}, expected {want}")
    return arr


def grid_from_json(doc) -> np.ndarray:
    """Control vectors ``(M, N, 4, 2)`` from the JSON schema of the module docstring.

    ``doc`` is a parsed JSON object, JSON text, or a path to a JSON file.
    Missing derivatives are Catmull-Rom estimates, a missing twist is Adini's.
    """
    if isinstance(doc, (str, bytes)) and not str(doc).lstrip().startswith("{"):
        try:
            with open(doc, "rb") as fh:
                doc = fh.read()
        except OSError as exc:
            raise TpsvError(f"{doc}: cannot read ({exc.strerror or exc})") from None
    if isinstance(doc, (str, bytes)):
        try:
            doc = json.loads(doc)
        except (ValueError, UnicodeDecodeError) as exc:
            raise TpsvError(f"control grid is not valid JSON ({exc})") from None
    if not isinstance(doc, dict):
        raise TpsvError("control grid JSON must be an object with 'positions'")
    unknown = set(doc) - {"positions", "ds", "dt", "twist"}
    if unknown:
        raise TpsvError(f"control grid JSON has unknown keys: {', '.join(sorted(unknown))}")
    pos = _grid_array(doc, "positions")
    if pos is None:
        raise TpsvError("control grid JSON has no 'positions'")
    M, N = pos.shape[:2]
    if not (MIN_GRID <= M <= MAX_GRID and MIN_GRID <= N <= MAX_GRID):
        raise TpsvError(f"control grid {M}x{N} is not within {MIN_GRID}..{MAX_GRID} per side")
    ctrl = np.zeros((M, N, 4, 2))
    ctrl[..., 0, :] = pos
    Ds, Dt = catmull_rom(pos)
    ds = _grid_array(doc, "ds", (M, N))
    dt = _grid_array(doc, "dt", (M, N))
    ctrl[..., 1, :] = Ds if ds is None else ds
    ctrl[..., 2, :] = Dt if dt is None else dt
    tw = _grid_array(doc, "twist", (M, N))
    ctrl[..., 3, :] = hpatch.adini_twist(ctrl) if tw is None else tw
    return ctrl


def grid_to_json(model: Model, region) -> dict:
    """A region's control grid in the JSON schema of the module docstring."""
    r = check_region(model, region)
    c = np.asarray(model.regions[r].patch.ctrl, np.float64)
    return {"positions": c[..., 0, :].tolist(), "ds": c[..., 1, :].tolist(),
            "dt": c[..., 2, :].tolist(), "twist": c[..., 3, :].tolist()}


def set_grid(model: Model, region, grid, keep_order: bool = False, attach: bool = True) -> Model:
    """Replace a region's control grid; returns a new model.

    ``grid``: control vectors ``(M, N, 4, 2)``, or anything
    :func:`grid_from_json` reads (a dict, JSON text or a path).
    """
    r = check_region(model, region)
    if isinstance(grid, np.ndarray) and grid.ndim == 4:
        ctrl = grid
    else:
        ctrl = grid_from_json(grid)
    old = model.regions[r].patch
    new = _check_patch(r, ctrl)
    _check_outline_budget(model, [r])
    out = copy_model(model)
    _replace_patch(out, r, new, map_outline(model.regions[r].outline, old, new))
    mappers = {r: patch_mapper(old, new)}
    order = [r] + (_carry_islands(model, out, mappers) if attach else [])
    return _finish(model, out, order, keep_order, mappers, attach)
