"""Colour editing in vector space (paper VII-B).

An edit is a *selection* of colour features and an *operation* on their Lab
colours; the TPS kernels are then rebuilt from the new colours (only the
kernels holding a changed feature: ``tpsv.rendering.live``). Geometry never changes.

Selection (:func:`select`)
--------------------------
* ``at=(x, y)``: a seed point in pixel space (pixel ``(r, c)`` covers
  ``[c, c+1] x [r, r+1]``). Its region is the one the renderer shows there
  (vector outlines, ``tpsv.edit.common.region_at``), or ``region`` when given;
  the seed feature is that region's feature nearest to the point (pixel
  distance, features placed by the patch's forward map), and its colour is
  the reference colour.
* ``color=(r, g, b)`` (sRGB in ``[0, 1]``): the reference colour directly.
* Propagation: a feature is selected when its CIE76 colour difference
  ``|Lab - Lab_ref|`` is at most ``tolerance`` (Lab units), when it lies
  within ``radius`` pixels of the seed point (``at`` needed; default: no
  limit) and, when ``region`` is given, when it belongs to that region. The
  test is per feature (no flood fill), so a colour that recurs across the
  image is selected wherever it recurs within the radius.
* Neither ``at`` nor ``color``: every feature (of ``region``, when given) is
  selected.

Curvilinear features are selected one by one like gradation features. The two
halves of a curvilinear pair sit on the two sides of an edge, often in two
regions; a selected half whose partner is not selected changes alone, so the
far side of the edge keeps its colour and the border keeps its character
(paper Fig. 13). Both halves change only when both are selected.

Operations (:func:`recolor_selected`), applied in this order
------------------------------------------------------------
1. ``matrix``: a 3 x 3 matrix applied to the colours of the selected
   *gradation* features (the paper's "shading" transform; curvilinear
   features keep their colours so that edges stay crisp), either to the
   column vector of gamma-encoded sRGB in ``[0, 1]`` (``matrix_space='rgb'``,
   the default, as colour-matrix filters such as sepia are written; the
   result is clipped to the sRGB cube) or to ``(L, a, b)`` itself
   (``matrix_space='lab'``).
2. ``hue``: rotation of the ``(a, b)`` vector by ``hue`` degrees (the
   paper's "ab-channel ring"; lightness and chroma are kept).
3. ``shift_ab``: ``(a, b) += (da, db)``.
4. ``lightness``: ``L += dL``.
5. ``harmonize``: hue harmonisation after Cohen-Or et al. (2006), see
   :func:`harmonic_template` and :func:`harmonize_hues`.

Every result is clipped to ``L`` in ``[0, 100]``, ``a`` and ``b`` in
``[-128, 127]``.

Harmonisation
-------------
Hues are the LCh angles ``h = atan2(b, a)`` of the Lab colours and chroma
``C = hypot(a, b)`` is the weight (Cohen-Or et al. use HSV hue and
saturation; Lab's ab ring is the space the paper edits in). The templates
(:data:`TEMPLATES`) are sets of sectors on the hue wheel: ``i`` (18 deg),
``V`` (93.6), ``L`` (18 and 79.2, centres 90 apart), ``I`` (18 and 18,
opposite), ``T`` (180), ``Y`` (93.6 and 18, opposite), ``X`` (93.6 and
93.6, opposite). The fit of template ``m`` at rotation ``alpha`` is
``F = sum_p C_p * d(h_p, sectors)``, ``d`` the arc distance to the nearest
sector border (0 inside), evaluated on a chroma-weighted histogram of
1-degree hue bins; ``alpha`` is searched in 1-degree steps, and among the
rotations of least ``F`` (often a range, when the hues fit inside) the one
that centres the sectors on the hues (least chroma-weighted distance to
the sector centres) is taken. With
``harmonize='auto'`` the template of least ``F`` wins, ties (e.g. hues that
already fit) going to the narrower template. Each hue then moves into the
sector it is nearest to, keeping its side of the sector centre ``c`` (Cohen-Or
et al. Eq. 2): ``h' = c + sign(h - c) (w / 2) (1 - G_sigma(|h - c|))`` with
``G`` a Gaussian of ``sigma = w / 2``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..color import lab_to_srgb, srgb_to_lab
from ..model import DETAIL_FULL, DETAIL_LUMA
from .common import check_point, check_region, clip_lab, copy_model, feature_xy, region_at
from ..errors import TpsvError
from ..model import GRADATION, Model

#: Default colour tolerance (CIE76 Delta E).
DEFAULT_TOLERANCE = 20.0

#: Harmonic templates: name -> sectors ``(centre offset, width)`` in degrees.
TEMPLATES = {
    "i": ((0.0, 18.0),),
    "V": ((0.0, 93.6),),
    "L": ((0.0, 18.0), (90.0, 79.2)),
    "I": ((0.0, 18.0), (180.0, 18.0)),
    "T": ((0.0, 180.0),),
    "Y": ((0.0, 93.6), (180.0, 18.0)),
    "X": ((0.0, 93.6), (180.0, 93.6)),
}
#: Tie-breaking order for ``harmonize='auto'``: narrowest total coverage first.
_NARROW_FIRST = ("i", "I", "V", "L", "Y", "T", "X")


# --------------------------------------------------------------------------- selection


def select(model: Model, at=None, color=None, radius=None, tolerance: float = DEFAULT_TOLERANCE, region=None) -> np.ndarray:
    """Features to edit, as a boolean mask ``(F,)`` (see the module docstring).

    Parameters
    ----------
    model : Model
    at : (x, y), optional
        Seed point in pixel coordinates (inside the image).
    color : (r, g, b), optional
        Reference colour, sRGB in ``[0, 1]`` (takes precedence over the seed
        feature's colour).
    radius : float, optional
        Largest pixel distance from ``at`` (needs ``at``).
    tolerance : float
        Largest CIE76 colour difference from the reference colour.
    region : int, optional
        Only features of this region (also the seed's region when given).

    Returns
    -------
    ndarray (F,) bool

    Raises
    ------
    TpsvError
        Unknown region, point outside the image, radius without a point,
        a seed region without features, bad numbers.
    """
    f = model.features
    F = len(f)
    mask = np.ones(F, bool)
    if region is not None:
        region = check_region(model, region)
        mask &= f.region == region
    if radius is not None:
        radius = float(radius)
        if not np.isfinite(radius) or radius <= 0:
            raise TpsvError(f"radius {radius} must be a positive number of pixels")
        if at is None:
            raise TpsvError("a radius needs a seed point (at)")
    tolerance = float(tolerance)
    if not np.isfinite(tolerance) or tolerance < 0:
        raise TpsvError(f"tolerance {tolerance} must be >= 0")
    ref = None
    if color is not None:
        c = np.asarray(color, np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)) or c.min() < 0 or c.max() > 1:
            raise TpsvError(f"colour {color!r} is not an sRGB triple in [0, 1]")
        ref = srgb_to_lab(c).astype(np.float64)
    xy = None
    if at is not None:
        p = check_point(model, at, "seed point")
        seed_region = region if region is not None else region_at(model, p)
        xy = feature_xy(model)
        cand = np.flatnonzero(f.region == seed_region)
        if cand.size == 0:
            raise TpsvError(f"region {seed_region} under the seed point has no colour features")
        if ref is None:
            d = np.hypot(*(xy[cand] - p).T)
            ref = f.lab[cand[int(np.argmin(d))]].astype(np.float64)
        if radius is not None:
            mask &= np.hypot(*(xy - p).T) <= radius
    if ref is not None:
        mask &= np.linalg.norm(f.lab.astype(np.float64) - ref, axis=1) <= tolerance
    return mask


# --------------------------------------------------------------------------- harmonisation


def _angdiff(a, b):
    """Signed angular difference ``a - b`` in degrees, in ``[-180, 180)``."""
    return (np.asarray(a, np.float64) - b + 180.0) % 360.0 - 180.0


def _template_distance(hue, name, alpha):
    """Per hue and rotation: arc distance to the template's sectors, nearest sector centre and width.

    ``hue`` (n,), ``alpha`` (m,) -> arrays (m, n).
    """
    best_d = best_c = best_w = None
    for off, w in TEMPLATES[name]:
        c = (alpha[:, None] + off) % 360.0
        dc = np.abs(_angdiff(hue[None, :], c))
        d = np.maximum(dc - w / 2.0, 0.0)
        if best_d is None:
            best_d, best_c, best_w, best_dc = d, np.broadcast_to(c, d.shape).copy(), np.full(d.shape, w), dc
        else:
            better = (d < best_d) | ((d == best_d) & (dc < best_dc))
            best_d = np.where(better, d, best_d)
            best_c = np.where(better, c, best_c)
            best_w = np.where(better, w, best_w)
            best_dc = np.where(better, dc, best_dc)
    return best_d, best_c, best_w


def harmonic_template(lab, template: str | None = "auto") -> tuple[str, float, float]:
    """Best harmonic template and rotation for colours ``lab`` (n, 3).

    Parameters
    ----------
    lab : array (n, 3)
        Colours; hue ``atan2(b, a)``, weight chroma ``hypot(a, b)``.
    template : str
        One of :data:`TEMPLATES`, or ``'auto'`` (least cost, ties to the
        narrower template).

    Returns
    -------
    (name, rotation_degrees, cost)
    """
    lab = np.asarray(lab, np.float64).reshape(-1, 3)
    names = _NARROW_FIRST if template in (None, "auto") else (template,)
    for n in names:
        if n not in TEMPLATES:
            raise TpsvError(f"unknown harmonic template {n!r}; use one of {', '.join(TEMPLATES)} or auto")
    hue = np.degrees(np.arctan2(lab[:, 2], lab[:, 1])) % 360.0
    chroma = np.hypot(lab[:, 1], lab[:, 2])
    # chroma-weighted histogram of 1-degree bins (the cost is evaluated at bin centres)
    weight = np.bincount(np.minimum(hue.astype(np.int64), 359), weights=chroma, minlength=360)
    hue = np.arange(360, dtype=np.float64) + 0.5
    chroma = weight
    alpha = np.arange(360, dtype=np.float64)
    best = None
    for n in names:
        d, cen, _ = _template_distance(hue, n, alpha)
        cost = (d * chroma[None, :]).sum(axis=1)
        # among rotations of (nearly) least cost, centre the sectors on the hues
        ties = cost <= cost.min() + 1e-9 * max(1.0, float(cost.min()))
        spread = (np.abs(_angdiff(hue[None, :], cen)) * chroma[None, :]).sum(axis=1)
        a = int(np.argmin(np.where(ties, spread, np.inf)))
        c = float(cost[a])
        if best is None or c < best[2] - 1e-9 * max(1.0, best[2]):
            best = (n, float(alpha[a]), c)
    return best


def harmonize_hues(lab, name: str, rotation: float) -> np.ndarray:
    """Move each colour's hue into the nearest sector of template ``name`` at ``rotation`` degrees.

    Lightness and chroma are kept. Returns (n, 3) float64.
    """
    lab = np.asarray(lab, np.float64).reshape(-1, 3)
    if lab.shape[0] == 0:
        return lab.copy()
    hue = np.degrees(np.arctan2(lab[:, 2], lab[:, 1])) % 360.0
    chroma = np.hypot(lab[:, 1], lab[:, 2])
    _, c, w = _template_distance(hue, name, np.array([float(rotation)]))
    c, w = c[0], w[0]
    dx = _angdiff(hue, c)
    sigma = w / 2.0
    new = c + np.sign(dx) * (w / 2.0) * (1.0 - np.exp(-(dx**2) / (2.0 * sigma**2)))
    rad = np.radians(new)
    out = lab.copy()
    out[:, 1] = chroma * np.cos(rad)
    out[:, 2] = chroma * np.sin(rad)
    return out


# --------------------------------------------------------------------------- operations


def parse_matrix(m) -> np.ndarray:
    """A 3 x 3 float64 matrix from an array-like; :class:`TpsvError` when it is not one."""
    try:
        a = np.asarray(m, np.float64)
    except (TypeError, ValueError):
        raise TpsvError(f"colour matrix {m!r} is not numeric") from None
    if a.size != 9 or not np.all(np.isfinite(a)):
        raise TpsvError("a colour matrix needs 9 finite numbers (3 x 3)")
    return a.reshape(3, 3)


@dataclass(frozen=True)
class Recolored:
    """The result of a colour edit: the new model and what the edit did.

    Attributes
    ----------
    model : Model
        The edited model (a new one; the input is not modified).
    selected : int
        Features in the selection.
    changed : int
        Features whose stored colour differs from the input's.
    template, rotation : str or None, float or None
        The harmonic template and its rotation (degrees) that ``harmonize``
        fitted; None when harmonisation was off.
    """

    model: Model
    selected: int
    changed: int
    template: str | None = None
    rotation: float | None = None

    def summary(self) -> dict:
        """``selected``, ``changed`` and, with harmonisation, ``template`` and ``rotation``."""
        out = {"selected": self.selected, "changed": self.changed}
        if self.template is not None:
            out["template"] = self.template
            out["rotation"] = self.rotation
        return out


def _check_operations(n_features: int, mask, hue, shift_ab, lightness, matrix_space) -> np.ndarray:
    mask = np.asarray(mask, bool).reshape(-1)
    if mask.shape[0] != n_features:
        raise TpsvError("the selection does not match the model's features")
    if matrix_space not in ("rgb", "lab"):
        raise TpsvError(f"matrix space {matrix_space!r} is not rgb or lab")
    vals = [float(hue), float(lightness)] + [float(v) for v in np.asarray(shift_ab, np.float64).reshape(-1)]
    if len(vals) != 4 or not np.all(np.isfinite(vals)):
        raise TpsvError("hue, lightness and ab shift must be finite numbers (shift: two of them)")
    return mask


def _apply_operations(cur, kind, hue, shift_ab, lightness, matrix, matrix_space) -> np.ndarray:
    """Steps 1-4 of the module docstring on colours ``cur`` (n, 3) float64 of kinds ``kind`` (n,)."""
    if matrix is not None:
        M = parse_matrix(matrix)
        grad = kind == GRADATION
        if grad.any():
            g = cur[grad]
            if matrix_space == "rgb":
                rgb = np.clip(lab_to_srgb(g).astype(np.float64) @ M.T, 0.0, 1.0)
                g = srgb_to_lab(rgb).astype(np.float64)
            else:
                g = g @ M.T
            cur[grad] = clip_lab(g)
    if hue:
        th = np.radians(float(hue))
        a, b = cur[:, 1].copy(), cur[:, 2].copy()
        cur[:, 1] = a * np.cos(th) - b * np.sin(th)
        cur[:, 2] = a * np.sin(th) + b * np.cos(th)
    da, db = (float(v) for v in np.asarray(shift_ab, np.float64).reshape(2))
    cur[:, 1] += da
    cur[:, 2] += db
    cur[:, 0] += float(lightness)
    return cur


def recolor_selected(
    model: Model,
    mask,
    hue: float = 0.0,
    shift_ab=(0.0, 0.0),
    lightness: float = 0.0,
    matrix=None,
    matrix_space: str = "rgb",
    harmonize: str | None = None,
) -> Recolored:
    """Apply the colour operations to the features in ``mask``, and report what was done.

    Parameters
    ----------
    model : Model
    mask : array (F,) bool
        The selection (:func:`select`).
    hue, shift_ab, lightness, matrix, matrix_space, harmonize
        The operations of the module docstring, applied in its order.
        ``harmonize``: None (off), ``'auto'`` or a template name; the
        template is fitted to the selected features' colours after steps 1-4.

    Returns
    -------
    Recolored
        The new model, the selected and changed feature counts and, with
        ``harmonize``, the template and rotation used (for an empty
        selection, those :func:`harmonic_template` gives for no colours).

    Raises
    ------
    TpsvError
        A selection of the wrong length, an unknown matrix space or
        template, non-finite numbers.
    """
    f = model.features
    mask = _check_operations(len(f), mask, hue, shift_ab, lightness, matrix_space)
    out = copy_model(model)
    lab = f.lab.astype(np.float64).copy()
    sel = np.flatnonzero(mask)
    harmony = None
    if sel.size:
        cur = _apply_operations(lab[sel], f.kind[sel], hue, shift_ab, lightness, matrix, matrix_space)
        if harmonize:
            harmony = harmonic_template(clip_lab(cur), harmonize)
            cur = harmonize_hues(cur, harmony[0], harmony[1])
        lab[sel] = clip_lab(cur)
    elif harmonize:
        harmony = harmonic_template(np.zeros((0, 3)), harmonize)
    new_lab = f.lab.copy()
    new_lab[sel] = lab[sel].astype(np.float32)
    out.features.lab = new_lab
    moved = (new_lab != f.lab).any(axis=1)
    changed = int(moved.sum())
    if out.detail is not None and changed:
        # the texture's colours belong to the old colours: keep only its luma
        d = out.detail
        hit = np.zeros(len(out.regions), bool)
        hit[f.region[moved]] = True
        d.mode = np.where(hit & (d.mode == DETAIL_FULL), DETAIL_LUMA, d.mode).astype(np.uint8)
    if harmony is None:
        return Recolored(out, int(sel.size), changed)
    return Recolored(out, int(sel.size), changed, template=harmony[0], rotation=harmony[1])


def recolor_features(
    model: Model,
    mask,
    hue: float = 0.0,
    shift_ab=(0.0, 0.0),
    lightness: float = 0.0,
    matrix=None,
    matrix_space: str = "rgb",
    harmonize: str | None = None,
) -> Model:
    """Apply the colour operations to the features in ``mask``; returns a new model.

    The model of :func:`recolor_selected` (which also reports the counts and
    the harmonic template); see the module docstring for the operations and
    their order.

    Returns
    -------
    Model
    """
    return recolor_selected(model, mask, hue=hue, shift_ab=shift_ab, lightness=lightness, matrix=matrix,
                            matrix_space=matrix_space, harmonize=harmonize).model


def recolor(
    model: Model,
    at=None,
    color=None,
    radius=None,
    tolerance: float = DEFAULT_TOLERANCE,
    region=None,
    hue: float = 0.0,
    shift_ab=(0.0, 0.0),
    lightness: float = 0.0,
    matrix=None,
    matrix_space: str = "rgb",
    harmonize: str | None = None,
) -> Model:
    """Select features (:func:`select`) and edit their colours (:func:`recolor_features`).

    Returns a new model; ``model`` is not modified. Features outside the
    selection keep their colours bit for bit.

    Examples
    --------
    >>> out = recolor(model, at=(120, 80), tolerance=15, hue=90)       # doctest: +SKIP
    >>> out = recolor(model, region=2, matrix=[[.39, .77, .19], [.35, .69, .17], [.27, .53, .13]])  # doctest: +SKIP
    """
    mask = select(model, at=at, color=color, radius=radius, tolerance=tolerance, region=region)
    return recolor_features(model, mask, hue=hue, shift_ab=shift_ab, lightness=lightness, matrix=matrix,
                            matrix_space=matrix_space, harmonize=harmonize)
