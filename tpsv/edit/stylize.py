"""Abstraction and stylisation (paper VII-E).

Abstraction (:func:`abstract`)
------------------------------
Level ``0`` is the model as it is. At level ``n >= 1``:

* **Gradation features are thinned** on a pixel grid whose cell grows with
  the level, ``cell = 3 * 2^(n-1)`` px (3, 6, 12, 24, ...): in each region,
  the gradation features whose image position falls in one cell are replaced
  by one feature at their mean ``(S, T)`` with their mean colour. Fewer,
  smoother samples remove high-frequency detail (the paper's larger
  ``T_super``), while
* **weak and short edges are dropped**: a curvilinear pair is kept when the
  colour difference of its two sides is at least ``6 n`` (CIE76; unpaired
  features pass) and when the linked edge (features linked as for strokes,
  below) of it or of its partner is at least ``4 * 2^(n-1)`` px long. Strong,
  long borders, which abstraction must preserve, stay crisp while texture
  dissolves into the gradation (the paper's coarser ``T_super`` /
  higher-threshold levels), and
* **gradation colours are quantised**: ``L`` to steps of ``4 n`` and ``a``,
  ``b`` to steps of ``3 n`` Lab units (flat areas of continuous colour).

The result is an ordinary model: it can be saved, rendered at any scale and
edited further.

Strokes (:func:`strokes`)
-------------------------
Curvilinear features of one region are linked into polylines: two features
are neighbours when they are at most ``link`` px apart (default 2.0, Canny
pairs sit about one pixel apart along an edge) and on the same side of their
edges (the unit vectors from their partners to them agree within 60
degrees). The minimum spanning forest of that neighbour graph is cut at
branch points into chains, and each chain of at least ``min_length``
features is drawn with OpenCV anti-aliased polylines, in runs of
:data:`RUN` features each in the mean colour of its features, ``width`` px
wide at scale 1.
Positions and widths follow the render scale.

:func:`stylize` renders the abstraction at ``scale`` and draws the strokes
over it; the result is deterministic. :func:`stylize_model` does the same and
also returns the abstraction and the number of strokes.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, minimum_spanning_tree
from scipy.spatial import cKDTree

from ..color import lab_to_srgb
from .common import concat_features, copy_model, feature_xy, sort_by_region
from ..errors import TpsvError
from ..image import to_uint8
from ..model import CURVILINEAR, GRADATION, Features, Model
from ..rendering.raster import render

#: Cell side (px) of the gradation thinning at level 1; doubles with each level.
BASE_CELL_PX = 3.0
#: Shortest linked curvilinear edge (px) kept at level 1; doubles with each level.
MIN_EDGE_PX = 4.0
#: Weakest curvilinear pair contrast (CIE76 Delta E between its two sides) kept, per level.
MIN_CONTRAST = 6.0
#: Quantisation steps per level (Lab units) of L and of a, b.
L_STEP, AB_STEP = 4.0, 3.0
#: Largest abstraction level.
MAX_LEVEL = 8
#: Features per stroke segment of one colour.
RUN = 6
#: Sub-pixel bits for OpenCV drawing.
_SHIFT = 4


def _check_level(level) -> int:
    try:
        n = int(level)
    except (TypeError, ValueError):
        raise TpsvError(f"level {level!r} is not a whole number") from None
    if n != level or not 0 <= n <= MAX_LEVEL:
        raise TpsvError(f"level {level!r} is not in 0..{MAX_LEVEL}")
    return n


def abstract(model: Model, level: int = 1) -> Model:
    """The model at abstraction ``level`` (see the module docstring); returns a new model."""
    n = _check_level(level)
    out = copy_model(model)
    out.detail = None  # an abstraction has no photographic texture
    if n == 0 or len(model.features) == 0:
        return out
    f = model.features
    graph = link_graph(model)
    xy = graph[2]
    cell = BASE_CELL_PX * 2 ** (n - 1)
    grad = np.flatnonzero(f.kind == GRADATION)
    # curvilinear pairs of weak contrast or on short edges (texture) go; a pair stays together
    clen = component_length(model, graph=graph)
    paired = f.pair >= 0
    pj = np.maximum(f.pair, 0)
    partner = np.where(paired, clen[pj], 0.0)
    contrast = np.where(paired, np.linalg.norm(f.lab.astype(np.float64) - f.lab[pj].astype(np.float64), axis=1), np.inf)
    keep_other = ((f.kind != GRADATION) & (np.maximum(clen, partner) >= MIN_EDGE_PX * 2 ** (n - 1))
                  & (contrast >= MIN_CONTRAST * n))
    # one representative per (region, cell): mean (S, T) and mean colour
    key = np.column_stack([f.region[grad].astype(np.int64), np.floor(xy[grad] / cell).astype(np.int64)])
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    cnt = np.bincount(inv, minlength=len(uniq)).astype(np.float64)[:, None]
    st = np.zeros((len(uniq), 2))
    lab = np.zeros((len(uniq), 3))
    np.add.at(st, inv, f.st[grad])
    np.add.at(lab, inv, f.lab[grad].astype(np.float64))
    st /= cnt
    lab /= cnt
    lab[:, 0] = np.clip(np.round(lab[:, 0] / (L_STEP * n)) * (L_STEP * n), 0.0, 100.0)
    lab[:, 1:] = np.clip(np.round(lab[:, 1:] / (AB_STEP * n)) * (AB_STEP * n), -128.0, 127.0)
    thinned = Features(
        region=uniq[:, 0].astype(np.int32),
        st=np.clip(st, 0.0, 1.0),
        lab=lab.astype(np.float32),
        kind=np.full(len(uniq), GRADATION, np.uint8),
        pair=np.full(len(uniq), -1, np.int32),
    )
    out.features = sort_by_region(concat_features(f.subset(keep_other), thinned))
    return out


def link_graph(model: Model, link: float = 2.0):
    """Neighbour forest of the curvilinear features (see the module docstring).

    Returns ``(cur, mst, xy)``: the curvilinear feature indices (n,), the
    symmetric minimum spanning forest of their neighbour graph (scipy CSR,
    n x n, weights = distances in px) and the features' pixel positions
    (F, 2) (all features).
    """
    f = model.features
    cur = np.flatnonzero(f.kind == CURVILINEAR)
    xy_all = feature_xy(model)
    n = cur.size
    empty = coo_matrix((n, n)).tocsr()
    if n < 2:
        return cur, empty, xy_all
    xy = xy_all[cur]
    side = np.zeros((n, 2))
    paired = f.pair[cur] >= 0
    d = xy_all[cur[paired]] - xy_all[f.pair[cur[paired]]]
    nrm = np.hypot(d[:, 0], d[:, 1])
    ok = nrm > 1e-9
    sd = np.zeros_like(d)
    sd[ok] = d[ok] / nrm[ok, None]
    side[paired] = sd
    pairs = _near_pairs(xy, float(link))
    if pairs.size == 0:
        return cur, empty, xy_all
    a, b = pairs[:, 0], pairs[:, 1]
    same_region = f.region[cur[a]] == f.region[cur[b]]
    has = (np.abs(side[a]).sum(1) > 0) & (np.abs(side[b]).sum(1) > 0)
    good = same_region & (~has | ((side[a] * side[b]).sum(1) >= 0.5))
    a, b = a[good], b[good]
    if a.size == 0:
        return cur, empty, xy_all
    w = np.hypot(*(xy[a] - xy[b]).T) + 1e-6  # zero weights would drop edges
    mst = minimum_spanning_tree(coo_matrix((w, (a, b)), shape=(n, n)).tocsr())
    return cur, (mst + mst.T).tocsr(), xy_all


#: Most neighbours a feature links to: real curvilinear features have far fewer
#: within the link distance; a pile of coincident ones would otherwise make
#: n^2 pairs (a 745-byte file asked for 17 GB).
MAX_LINK_NEIGHBOURS = 32

#: Points per k-d tree query batch (bounds the (batch, k) result arrays).
_QUERY_CHUNK = 1 << 15


def _near_pairs(xy: np.ndarray, link: float) -> np.ndarray:
    """Pairs ``(a, b)``, ``a < b``, of points within ``link`` px, each point's
    :data:`MAX_LINK_NEIGHBOURS` nearest at most, as an (m, 2) int array sorted
    like ``cKDTree.query_pairs`` (identical to it when no point has more
    neighbours than that)."""
    # coincident points (a k-d tree cannot split them: O(n^2) queries) link to one
    # representative each; the representatives link among themselves
    uniq, first, inverse = np.unique(xy, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.ravel()
    dup = np.flatnonzero(first[inverse] != np.arange(len(xy)))
    same = np.column_stack([first[inverse[dup]], dup])
    if len(uniq) < len(xy):
        near = _near_pairs(uniq, link)
        return np.unique(np.sort(np.concatenate([first[near], same]), axis=1), axis=0).astype(np.intp)
    tree = cKDTree(xy)
    k = min(MAX_LINK_NEIGHBOURS + 1, len(xy))
    parts = []
    for c in range(0, len(xy), _QUERY_CHUNK):
        chunk = xy[c:c + _QUERY_CHUNK]
        dist, idx = tree.query(chunk, k=k, distance_upper_bound=link)
        dist, idx = dist.reshape(len(chunk), -1), idx.reshape(len(chunk), -1)
        a = np.broadcast_to(np.arange(c, c + len(idx))[:, None], idx.shape)
        keep = np.isfinite(dist) & (idx != a) & (dist <= link)
        parts.append(np.column_stack([a[keep], idx[keep]]))
    pairs = np.concatenate(parts) if parts else np.zeros((0, 2), np.int64)
    # seen from both sides, or from one only when the other has more than k neighbours
    pairs = np.unique(np.sort(pairs, axis=1), axis=0)
    return pairs.astype(np.intp)


def stroke_chains(model: Model, link: float = 2.0, min_length: int = 3, graph=None) -> list[np.ndarray]:
    """Chains of linked curvilinear features (module docstring): a list of feature-index arrays.

    The forest of :func:`link_graph` is cut at its branch points. Chains of fewer than
    ``min_length`` features are dropped.
    """
    cur, mst, _ = graph if graph is not None else link_graph(model, link)
    n = cur.size
    if n < 2 or mst.nnz == 0:
        return []
    indptr, indices = mst.indptr, mst.indices
    deg = np.diff(indptr)
    visited = np.zeros(n, bool)  # interior (degree-2) vertices already on a chain
    chains = []
    # a spanning forest has no cycles: every chain runs between two vertices of degree != 2
    for s in np.flatnonzero((deg != 2) & (deg > 0)).tolist():
        for nb in indices[indptr[s] : indptr[s + 1]].tolist():
            if deg[nb] != 2:
                if s < nb:
                    chains.append([s, nb])
                continue
            if visited[nb]:
                continue
            path = [s]
            prev, c = s, nb
            while deg[c] == 2:
                visited[c] = True
                path.append(c)
                r0, r1 = indices[indptr[c]], indices[indptr[c] + 1]
                prev, c = c, int(r1 if r0 == prev else r0)
            path.append(c)
            chains.append(path)
    m = max(2, int(min_length))
    return [cur[np.asarray(c)] for c in chains if len(c) >= m]


def component_length(model: Model, link: float = 2.0, graph=None) -> np.ndarray:
    """Per feature: total length (px) of the linked curvilinear component it belongs to (0 for gradation)."""
    cur, mst, _ = graph if graph is not None else link_graph(model, link)
    out = np.zeros(len(model.features))
    if cur.size == 0:
        return out
    ncomp, comp = connected_components(mst, directed=False)
    rows = np.repeat(np.arange(cur.size), np.diff(mst.indptr))
    tot = np.bincount(comp[rows], weights=mst.data, minlength=ncomp) / 2.0  # each edge stored twice
    out[cur] = tot[comp]
    return out


def strokes(image: np.ndarray, model: Model, scale: float = 1.0, width: float = 1.0, link: float = 2.0,
            min_length: int = 3, graph=None) -> np.ndarray:
    """Draw strokes along linked curvilinear features onto an image; returns uint8 RGB.

    Parameters
    ----------
    image : ndarray (H, W, 3)
        Float in ``[0, 1]`` or uint8: the render of ``model`` at ``scale``.
    model : Model
    scale, width : float
        Render scale and stroke width in pixels at scale 1.
    link, min_length
        Linking distance and shortest chain (:func:`stroke_chains`).
    graph : tuple, optional
        A :func:`link_graph` of ``model`` to reuse.

    Returns
    -------
    ndarray (H, W, 3) uint8
    """
    _check_width(width)
    graph = graph if graph is not None else link_graph(model, link)
    chains = stroke_chains(model, link=link, min_length=min_length, graph=graph)
    return _draw_chains(image, model, chains, graph[2], scale, width)


def _check_width(width) -> None:
    if not (np.isfinite(width) and width > 0):
        raise TpsvError(f"stroke width {width} must be a positive number")


def _draw_chains(image, model: Model, chains, xy, scale, width) -> np.ndarray:
    """Draw ``chains`` (feature-index arrays) over ``image``; ``xy`` (F, 2) feature positions at scale 1."""
    img = np.ascontiguousarray(to_uint8(image)).copy()
    if not chains:
        return img
    xy = xy * float(scale)
    rgb = lab_to_srgb(model.features.lab.astype(np.float64))
    # 32767: OpenCV's largest line thickness (a wider stroke covers the image anyway)
    thick = max(1, int(round(min(float(width) * float(scale), 32767.0))))
    fix = np.round(xy * (1 << _SHIFT)).astype(np.int64)
    lim = 1 << 28
    for ch in chains:
        # runs of RUN features share one colour (their mean): one polyline call each
        for a in range(0, len(ch) - 1, RUN):
            run = ch[a : a + RUN + 1]
            pts = fix[run]
            if np.abs(pts).max() > lim:
                continue
            col = np.clip(np.rint(rgb[run].mean(0) * 255.0), 0, 255).astype(int)
            cv2.polylines(img, [pts.astype(np.int32).reshape(-1, 1, 2)], False,
                          (int(col[0]), int(col[1]), int(col[2])), thick, cv2.LINE_AA, _SHIFT)
    return img


@dataclass(frozen=True)
class Stylized:
    """The result of :func:`stylize_model`.

    Attributes
    ----------
    image : ndarray (H, W, 3) uint8
        The abstraction rendered at the scale, with strokes over it.
    model : Model
        The abstraction (:func:`abstract`); it can be saved and edited further.
    strokes : int
        Stroke chains drawn (0 without strokes).
    """

    image: np.ndarray
    model: Model
    strokes: int


def stylize_model(model: Model, level: int = 2, with_strokes: bool = True, stroke_width: float = 1.0,
                  scale: float = 1.0, device: str = "cpu", link: float = 2.0, min_length: int = 3) -> Stylized:
    """Abstraction at ``level`` rendered at ``scale``, with strokes over it, and what was made.

    Parameters
    ----------
    model : Model
    level : int
        Abstraction level, ``0..MAX_LEVEL`` (:func:`abstract`).
    with_strokes : bool
        Draw strokes along linked curvilinear features (:func:`strokes`).
    stroke_width, scale : float
        Stroke width in pixels at scale 1; render scale.
    device : str
        Warp device of the render.
    link, min_length
        Linking distance and shortest chain (:func:`stroke_chains`).

    Returns
    -------
    Stylized
        The image, the abstracted model and the number of strokes drawn.
    """
    m = abstract(model, level)
    img = render(m, scale=scale, device=device)
    if not with_strokes:
        return Stylized(to_uint8(img), m, 0)
    _check_width(stroke_width)
    graph = link_graph(m, link)
    chains = stroke_chains(m, link=link, min_length=min_length, graph=graph)
    return Stylized(_draw_chains(img, m, chains, graph[2], scale, stroke_width), m, len(chains))


def stylize(model: Model, level: int = 2, with_strokes: bool = True, stroke_width: float = 1.0, scale: float = 1.0,
            device: str = "cpu", link: float = 2.0, min_length: int = 3) -> np.ndarray:
    """Abstraction at ``level`` rendered at ``scale``, with strokes over it; uint8 RGB ``(H, W, 3)``.

    The image of :func:`stylize_model` (parameters there).

    Returns
    -------
    ndarray (H, W, 3) uint8
    """
    return stylize_model(model, level=level, with_strokes=with_strokes, stroke_width=stroke_width, scale=scale,
                         device=device, link=link, min_length=min_length).image
