"""Structural colour and texture transfer between regions (paper VII-C, cross mapping).

Every patch has the same normalised parameter square ``(S, T) in [0, 1]^2``
spanned by its four corners, so a source region's features map onto a target
region by their ``(S, T)`` alone: corner ``(0, 0)`` of the source patch goes
to corner ``(0, 0)`` of the target, and so on. The mapped features are then
rasterised through the target's own patch, with no forward splatting, holes
or resampling (the paper's argument against a dense forward map). The
target's shape (outline and patch) is kept; only its features change.

Correspondence
--------------
``(S, T) -> (S', T')``: first ``flip`` (``S -> 1 - S``), then ``rotate``
quarter turns of the parameter square about its centre, each
``(S, T) -> (1 - T, S)`` (90 degrees: source corner ``(0, 0)`` lands on
target corner ``(1, 0)``; for patches whose ``s`` axis points right this is
a clockwise quarter turn on screen).

Modes
-----
* **replace** (``alpha=None``): the target region's features are removed
  and the mapped source features take their place, with the source colours.
* **blend** (``alpha`` in ``[0, 1]``): both feature sets are kept and every
  feature gets the colour ``alpha * src(p) + (1 - alpha) * tgt(p)``, where
  ``src`` and ``tgt`` are the two images' rendered Lab colours (their
  blended, range-clamped TPS) at that feature's position in their own
  patches: a target feature keeps ``tgt`` = its own colour and samples
  ``src`` through the inverse correspondence; a mapped source feature keeps
  ``src`` = its own colour and samples ``tgt``. So the edited region
  interpolates the field ``alpha * source + (1 - alpha) * target`` at the
  union of both feature sets: ``alpha = 0`` renders (nearly) the target,
  ``alpha = 1`` (nearly) the mapped source, and values between give a
  cross-dissolve that keeps the structure of both (the paper's alpha map
  across patches, with one alpha per region).

Detail layer: the target region takes the source region's texture too (its
rest frame composed with the correspondence), in replace mode and in blend
mode with ``alpha >= 0.5`` (one texture per region: the one that dominates).
A source in another file has another texture: the target region's detail is
then switched off.

Curvilinear pairs: a mapped source feature keeps its partner when the
partner is mapped too (an edge inside the source region); a partner in
another source region is not mapped, and the feature becomes unpaired. In
replace mode the target's removed features unpair their partners in
neighbouring regions, which keep their colours (their side of the border
keeps its character).

Colour statistics (``match_stats=True``, Reinhard et al. 2001): before
mapping, the source features' colours are shifted and scaled per Lab
channel so that their mean and standard deviation equal those of the
target region's features (the source brings its structure, the target keeps
its palette).
"""

from __future__ import annotations

import numpy as np

from ..errors import TpsvError
from ..model import DETAIL_OFF, Features, Model
from .common import check_region, clip_lab, concat_features, copy_model, sort_by_region, tps_lab


def map_st(st, rotate: int = 0, flip: bool = False) -> np.ndarray:
    """Source ``(S, T)`` (n, 2) -> target ``(S', T')`` (see the module docstring)."""
    st = np.array(st, np.float64, copy=True).reshape(-1, 2)
    rot = _check_rotate(rotate)
    if flip:
        st[:, 0] = 1.0 - st[:, 0]
    for _ in range(rot // 90):
        st = np.column_stack([1.0 - st[:, 1], st[:, 0]])
    return st


def unmap_st(st, rotate: int = 0, flip: bool = False) -> np.ndarray:
    """The inverse of :func:`map_st`: target ``(S', T')`` -> source ``(S, T)``."""
    st = np.array(st, np.float64, copy=True).reshape(-1, 2)
    rot = _check_rotate(rotate)
    for _ in range(rot // 90):
        st = np.column_stack([st[:, 1], 1.0 - st[:, 0]])
    if flip:
        st[:, 0] = 1.0 - st[:, 0]
    return st


def _check_rotate(rotate) -> int:
    try:
        r = int(rotate)
    except (TypeError, ValueError):
        raise TpsvError(f"rotation {rotate!r} is not 0, 90, 180 or 270") from None
    if r != rotate or r not in (0, 90, 180, 270):
        raise TpsvError(f"rotation {rotate!r} is not 0, 90, 180 or 270")
    return r


def match_color_stats(src_lab, tgt_lab, values=None) -> np.ndarray:
    """Reinhard colour transfer in Lab.

    The per-channel affine map that gives ``src_lab`` (n, 3) the mean and
    standard deviation of ``tgt_lab`` (m, 3), applied to ``values`` (default
    ``src_lab``). A channel without spread in ``src_lab`` is only shifted.
    """
    s = np.asarray(src_lab, np.float64).reshape(-1, 3)
    t = np.asarray(tgt_lab, np.float64).reshape(-1, 3)
    v = s if values is None else np.asarray(values, np.float64).reshape(-1, 3)
    if s.shape[0] == 0 or t.shape[0] == 0:
        return v.copy()
    ms, ss = s.mean(0), s.std(0)
    mt, st = t.mean(0), t.std(0)
    k = np.where(ss > 1e-9, st / np.where(ss > 1e-9, ss, 1.0), 1.0)
    return (v - ms) * k + mt


def crossmap(
    target: Model,
    target_region,
    source: Model | None = None,
    source_region=None,
    rotate: int = 0,
    flip: bool = False,
    alpha: float | None = None,
    match_stats: bool = False,
    device: str = "cpu",
) -> Model:
    """Map a source region's features onto a target region; returns a new model (the target edited).

    Parameters
    ----------
    target : Model
    target_region : int
    source : Model, optional
        Default: ``target`` itself.
    source_region : int, optional
        Default: ``target_region``.
    rotate : {0, 90, 180, 270}
    flip : bool
    alpha : float in [0, 1], optional
        None: replace mode; a number: blend mode (module docstring).
    match_stats : bool
        Match the source colours' Lab mean and std to the target region's.
    device : str
        Warp device used to sample the TPS colours in blend mode.

    Raises
    ------
    TpsvError
        Unknown region, bad rotation or alpha, a source region without
        features.
    """
    source = target if source is None else source
    tr = check_region(target, target_region, "target region")
    sr = check_region(source, tr if source_region is None else source_region, "source region")
    rot = _check_rotate(rotate)
    if alpha is not None:
        alpha = float(alpha)
        if not (0.0 <= alpha <= 1.0):
            raise TpsvError(f"alpha {alpha} is not in [0, 1]")
    sf = source.features
    s_idx = np.flatnonzero(sf.region == sr)
    if s_idx.size == 0:
        raise TpsvError(f"source region {sr} has no colour features")
    src = sf.subset(s_idx)  # pairs to other regions become -1
    src_lab = src.lab.astype(np.float64)
    tf = target.features
    t_in = tf.region == tr
    if match_stats:
        src_lab = match_color_stats(src.lab, tf.lab[t_in])
    mapped = Features(
        region=np.full(len(src), tr, np.int32),
        st=np.clip(map_st(src.st, rot, flip), 0.0, 1.0),
        lab=clip_lab(src_lab),
        kind=src.kind.copy(),
        pair=src.pair.copy(),
    )
    out = copy_model(target)
    if alpha is None:
        kept = tf.subset(~t_in)
        feats = concat_features(kept, mapped)
    else:
        # colours of both sets from the blended field alpha * source + (1 - alpha) * target
        t_idx = np.flatnonzero(t_in)
        tgt_at_mapped = tps_lab(target, tr, mapped.st, device=device)
        src_at_target = tps_lab(source, sr, np.clip(unmap_st(tf.st[t_idx], rot, flip), 0.0, 1.0), device=device)
        if match_stats:
            src_at_target = match_color_stats(src.lab, tf.lab[t_in], values=src_at_target)
        mapped.lab = clip_lab(alpha * mapped.lab.astype(np.float64) + (1.0 - alpha) * tgt_at_mapped)
        lab = tf.lab.copy()
        lab[t_idx] = clip_lab(alpha * src_at_target + (1.0 - alpha) * tf.lab[t_idx].astype(np.float64))
        base = Features(region=tf.region.copy(), st=tf.st.copy(), lab=lab, kind=tf.kind.copy(), pair=tf.pair.copy())
        feats = concat_features(base, mapped)
    out.features = sort_by_region(feats)
    if out.detail is not None and (alpha is None or alpha >= 0.5):
        _carry_detail(out.detail, tr, source, sr, rot, flip)
    return out


def _carry_detail(detail, tr: int, source: Model, sr: int, rot: int, flip: bool) -> None:
    """Give target region ``tr`` the source region's texture, rotated and flipped as its features.

    The target's ``(S, T)`` goes back to the source's through ``unmap_st``
    (affine), then through the source's rest frame: the composition is the
    target's new (affine) frame. A source in another file has another
    texture, which one frame cannot point into: the target region's detail
    is then switched off (its vector colours are the source's).
    """
    if source.detail is None or source.detail.payload != detail.payload:
        detail.mode[tr] = DETAIL_OFF
        return
    O, dS, dT = source.detail.frame[sr]
    corners = unmap_st(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]), rot, flip)
    at = O + corners[:, :1] * dS + corners[:, 1:] * dT
    detail.frame[tr] = (at[0], at[1] - at[0], at[2] - at[0])
    detail.mode[tr] = source.detail.mode[sr]
