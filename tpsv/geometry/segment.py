"""Label maps: automatic segmentation, stroke-guided segmentation, clean-up.

Connectivity: a region is a 4-connected set of pixels of one label (pixels
that touch only diagonally belong to different regions), matching
``tpsv.geometry.outline`` whose outlines cut between diagonal neighbours.
"""

from __future__ import annotations

import colorsys
import heapq

import cv2
import numpy as np
from skimage.measure import label as cc_label
from skimage.segmentation import find_boundaries, random_walker, slic

from ..errors import TpsvError
from ..threads import host_cores, pool
from .bands import for_bands, lab_image, map_bands, row_bands


def default_min_size(shape: tuple[int, int]) -> int:
    """Smallest region kept by default: 1/4000 of the image area, at least 4 px (65 px at 512x512)."""
    return int(max(4, round(shape[0] * shape[1] / 4000.0)))


def _components(labels: np.ndarray) -> tuple[np.ndarray, int]:
    """4-connected components of equal labels, numbered 0..n-1 in raster order of first pixel."""
    comp = cc_label(labels, background=-(1 << 40), connectivity=1)  # background value never occurs
    comp -= 1  # labels 1..n (no background) -> 0..n-1
    return _renumber(comp)


def _renumber(comp: np.ndarray, lut: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """``lut[comp]`` (``comp`` itself without ``lut``; values >= 0) renumbered ``0..n-1`` in raster order
    of each value's first pixel, as int32.

    Band by band (:func:`tpsv.geometry.bands.row_bands`), so that nothing of
    more than 4 bytes a pixel is made for the whole image.
    """
    h, w = comp.shape
    top = int(comp.max()) + 1 if lut is None else len(lut)
    first = np.full(top, comp.size, np.int64)  # first flat index of every value (comp.size: absent)
    for a, b in row_bands(h, w):
        band = comp[a:b].ravel() if lut is None else lut[comp[a:b].ravel()]
        # only values not seen in an earlier band need their first pixel here (few, past the first bands)
        fresh = np.flatnonzero((first == comp.size)[band])
        if fresh.size:
            vals, at = np.unique(band[fresh], return_index=True)
            first[vals] = fresh[at] + a * w
    seen = np.nonzero(first < comp.size)[0]
    rank = np.zeros(top, np.int32)
    rank[seen[np.argsort(first[seen])]] = np.arange(seen.size, dtype=np.int32)
    if lut is not None:
        rank = rank[lut]
    out = np.empty(comp.shape, np.int32)
    for a, b in row_bands(h, w):
        out[a:b] = rank[comp[a:b]]
    return out, int(seen.size)


def _border_pairs(comp: np.ndarray, n: int, col: np.ndarray | None = None):
    """Every pair of 4-neighbour pixels of different labels: the key ``a * n + b`` (``a < b``) of its
    two labels, and with ``col`` (H, W, C) the squared colour difference of the two pixels (else None)."""
    keys, steps = [], []
    for x, y, cx, cy in ((comp[:, :-1], comp[:, 1:], np.s_[:, :-1], np.s_[:, 1:]),
                         (comp[:-1, :], comp[1:, :], np.s_[:-1, :], np.s_[1:, :])):
        d = x != y
        a, b = x[d].astype(np.int64), y[d].astype(np.int64)
        keys.append(np.minimum(a, b) * n + np.maximum(a, b))
        if col is not None:
            steps.append(((col[cx][d].astype(np.float64) - col[cy][d]) ** 2).sum(axis=1))
    return np.concatenate(keys), (np.concatenate(steps) if col is not None else None)


def _borders(comp: np.ndarray, n: int, col: np.ndarray | None = None):
    """Shared border lengths: (a, b, count) arrays for every adjacent pair a < b (4-neighbours).

    With ``col`` (H, W, C), also the sum over the border's pixel pairs of their squared
    colour difference: (a, b, count, steps).
    """
    keys, steps = _border_pairs(comp, n, col)
    key, inv, cnt = np.unique(keys, return_inverse=True, return_counts=True)
    if col is None:
        return key // n, key % n, cnt
    return key // n, key % n, cnt, np.bincount(inv.ravel(), steps, minlength=key.size)


def split_connected(
    labels: np.ndarray,
    min_size: int | None = None,
    keep: np.ndarray | None = None,
    sliver_width: float | None = None,
) -> np.ndarray:
    """Relabel so that each label is one 4-connected region, and drop tiny ones.

    Parameters
    ----------
    labels : ndarray (H, W) int
    min_size : int, optional
        Components smaller than this (pixels) are merged into the neighbour
        they share the longest border with (repeatedly, smallest first, so a
        cluster of tiny pieces ends up in a real region). Default
        :func:`default_min_size`; ``1`` keeps everything, single pixels
        included.
    keep : ndarray (H, W) bool, optional
        Pixels whose component is never merged away (user strokes).
    sliver_width : float, optional
        Also merge components whose mean width ``2 * area / perimeter`` is
        below this many pixels (thin slivers along boundaries), when they are
        smaller than ``20 * min_size``.

    Returns
    -------
    labels : ndarray (H, W) int32
        Values ``0..n-1`` numbered in raster order of each region's first
        pixel; each value is one 4-connected region.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or labels.size == 0:
        raise TpsvError("label map must be a non-empty 2D array")
    if min_size is None:
        min_size = default_min_size(labels.shape)
    min_size = max(1, int(min_size))
    comp, n = _components(labels)
    if n == 1 or (min_size <= 1 and sliver_width is None):
        return comp
    for _ in range(64):
        size = np.bincount(comp.ravel(), minlength=n)
        ka, kb, cnt = _borders(comp, n)
        small = size < min_size
        if sliver_width is not None:
            per = np.bincount(ka, cnt, minlength=n) + np.bincount(kb, cnt, minlength=n)
            # image-border edges count too
            per = per + np.bincount(comp[0], minlength=n) + np.bincount(comp[-1], minlength=n)
            per = per + np.bincount(comp[:, 0], minlength=n) + np.bincount(comp[:, -1], minlength=n)
            width = 2.0 * size / np.maximum(per, 1)
            small |= (width < sliver_width) & (size < 20 * min_size)
        if keep is not None:
            protected = np.bincount(comp[keep], minlength=n) > 0
            small &= ~protected
        if not small.any() or ka.size == 0:
            break
        # best neighbour of every small component: longest shared border,
        # preferring neighbours that are not small themselves
        src = np.concatenate([ka, kb])
        dst = np.concatenate([kb, ka])
        c = np.concatenate([cnt, cnt]).astype(np.float64)
        c = c + np.where(small[dst], 0.0, 1e9)  # non-small neighbours first
        sel = small[src]
        src, dst, c = src[sel], dst[sel], c[sel]
        if src.size == 0:
            break
        order = np.lexsort((-c, src))
        src, dst = src[order], dst[order]
        first = np.r_[True, src[1:] != src[:-1]]
        target = np.arange(n)
        # merge the smallest first; a small target that is itself merged follows it
        movers = src[first]
        dests = dst[first]
        by_size = np.argsort(size[movers], kind="stable")
        parent = np.arange(n)

        def find(x):
            while parent[x] != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        for k in by_size:
            a, b = find(movers[k]), find(dests[k])
            if a != b:
                parent[a] = b
        for x in range(n):
            target[x] = find(x)
        comp, n = _renumber(comp, target)
        if n == 1:
            break
    return comp


# --------------------------------------------------------------------------- automatic


def _check_rgb(rgb: np.ndarray) -> np.ndarray:
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] < 2 or rgb.shape[1] < 2:
        raise TpsvError(f"expected an RGB image of at least 2x2, got shape {rgb.shape}")
    if rgb.dtype == np.uint8:
        rgb = rgb.astype(np.float32) / 255.0
    return rgb.astype(np.float32, copy=False)


#: Most SLIC superpixels :func:`segment_auto` starts from (one per 64 px on small images, at least 8).
MAX_SUPERPIXELS = 300
#: Region counts :func:`segment_auto` chooses from when none is asked for.
AUTO_COUNTS = (4, 12)
#: The fewer counts a small photo's coarser candidate chooses from (``tpsv.encode.rate``: its
#: outlines can outweigh its texture).
FEW_COUNTS = (3, 6)


#: Above this many pixels SLIC runs on a copy area-downscaled by a whole factor to at most this
#: size, and the superpixels' borders are then placed again at full size (:func:`_refine`). A
#: 12-megapixel photo's 300 superpixels are 40 000 px each: SLIC's ten passes over every pixel
#: (most of its 17 s segmentation on 2 cores; 11 s from a 4x smaller copy) place borders that the
#: smaller copy places as well (docs/DESIGN.md, "Automatic regions").
SLIC_PIXELS = 1 << 20
#: Border pixels :func:`_refine` reassigns at a time (a chunk's temporaries: about 100 bytes each).
REFINE_CHUNK = 1 << 17
#: SLIC's compactness (``m``): colour distance against spatial distance over the grid step.
COMPACTNESS = 10.0


def _superpixels(rgb: np.ndarray, lab: np.ndarray | None = None) -> tuple[np.ndarray, int]:
    """SLIC superpixels of an RGB float image, numbered ``0..n-1`` in raster order; returns (map, n).

    ``lab`` (``lab_image(rgb, clip=True)``) is needed only above :data:`SLIC_PIXELS`
    pixels, where the borders are placed again at full size (made here when absent).
    """
    H, W = rgb.shape[:2]
    n_sp = int(min(MAX_SUPERPIXELS, max(8, H * W // 64)))
    f = int(np.ceil(np.sqrt(H * W / SLIC_PIXELS)))
    if f <= 1:
        sp = slic(rgb, n_segments=n_sp, compactness=COMPACTNESS, channel_axis=2, start_label=0,
                  enforce_connectivity=True)
        return _renumber(sp)
    small = cv2.resize(np.ascontiguousarray(rgb, np.float32), (-(-W // f), -(-H // f)), interpolation=cv2.INTER_AREA)
    sp, n = _renumber(slic(small, n_segments=n_sp, compactness=COMPACTNESS, channel_axis=2, start_label=0,
                           enforce_connectivity=True))
    sp = np.repeat(np.repeat(sp, f, axis=0), f, axis=1)[:H, :W]
    if lab is None:
        lab = lab_image(rgb, clip=True)
    return _renumber(_refine(sp, n, lab, f, np.sqrt(H * W / n_sp)))


def _refine(sp: np.ndarray, n: int, lab: np.ndarray, reach: int, step: float) -> np.ndarray:
    """One SLIC assignment pass at full size over the pixels within ``reach`` px of a superpixel border.

    Each such pixel takes, of the superpixels at ``(0, +-reach)`` around it in
    each direction, the one nearest in SLIC's distance ``|dLab|^2 + (m /
    step)^2 |dxy|^2`` to its centre (mean Lab and position at full size).
    Superpixels upsampled from a ``reach`` times smaller copy have borders of
    ``reach`` px steps; this puts them back on the image's own edges.

    Returns
    -------
    ndarray (H, W) int32
        ``sp`` with the border pixels reassigned (a superpixel may lose a few
        pixels to a neighbour; labels stay ``0..n-1``).
    """
    H, W = sp.shape
    count = np.zeros(n)
    sums = np.zeros((n, 5))  # L, a, b, y, x
    for a, b in row_bands(H, W):
        lbl = sp[a:b].ravel()
        count += np.bincount(lbl, minlength=n)
        for k in range(3):
            sums[:, k] += np.bincount(lbl, lab[a:b, :, k].ravel(), n)
        yy, xx = np.mgrid[a:b, :W]
        sums[:, 3] += np.bincount(lbl, yy.ravel(), n)
        sums[:, 4] += np.bincount(lbl, xx.ravel(), n)
    centre = sums / np.maximum(count, 1)[:, None]
    ratio = (COMPACTNESS / step) ** 2
    kernel = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    code = sp.astype(np.uint16)  # n <= MAX_SUPERPIXELS: OpenCV's max and min filters take 16 bits
    ys, xs = np.nonzero(cv2.dilate(code, kernel) != cv2.erode(code, kernel))
    out = sp.copy()

    def chunk(rows: tuple[int, int]) -> None:
        # each listed pixel on its own: chunks run on a few threads (about 12 MB of temporaries each)
        y, x = ys[rows[0]:rows[1]], xs[rows[0]:rows[1]]
        colour = lab[y, x].astype(np.float64)
        best = np.full(y.size, np.inf)
        pick = sp[y, x].copy()
        for dy in (-reach, 0, reach):
            for dx in (-reach, 0, reach):
                c = sp[np.clip(y + dy, 0, H - 1), np.clip(x + dx, 0, W - 1)]
                d = ((colour - centre[c, :3]) ** 2).sum(axis=1) + ratio * (
                    (y - centre[c, 3]) ** 2 + (x - centre[c, 4]) ** 2)
                better = d < best
                best[better] = d[better]
                pick[better] = c[better]
        out[y, x] = pick

    for_bands(chunk, ys.size, 1, pixels=REFINE_CHUNK)
    return out


def _fold(border: list[dict[int, float]], a: int, b: int) -> None:
    """Per-border sums (``border[x][y]``, kept both ways) after ``b`` went into ``a``: the border
    between them is gone, and ``b``'s borders with others add to ``a``'s."""
    del border[a][b]
    del border[b][a]
    for x, v in border[b].items():
        border[x].pop(b, None)
        border[a][x] = border[a].get(x, 0.0) + v
        border[x][a] = border[a][x]
    border[b] = {}


class _WardMerge:
    """The superpixel adjacency graph, merged greedily by shape-weighted Ward cost.

    Per live node: pixel count, sum of Lab colours, perimeter, and shared
    border lengths with its neighbours. ``parent`` records every merge
    (``parent[b] = a``: b went into a).

    With ``boundary``, the colour difference of two neighbours is the smaller
    of their means' difference and the mean step across their shared border
    (squared Lab difference of the pixel pairs the border separates; the sums
    are kept per border and add up when regions merge). A smooth gradient cut
    in two has halves of very different means but no step between them, so
    it is merged first; a small shape of another colour keeps its step.
    """

    def __init__(self, sp: np.ndarray, n: int, lab: np.ndarray, seed: int, boundary: bool = False):
        flat = sp.ravel()
        size = np.bincount(flat, minlength=n).astype(np.float64)
        csum = np.stack([np.bincount(flat, lab[..., k].ravel(), minlength=n) for k in range(3)], axis=1)
        if boundary:
            ka, kb, cnt, steps = _borders(sp, n, lab)
        else:
            ka, kb, cnt = _borders(sp, n)
            steps = None
        per = np.bincount(ka, cnt, minlength=n) + np.bincount(kb, cnt, minlength=n)
        # the seed only breaks exact cost ties
        self.jitter = 1.0 + 1e-9 * np.random.default_rng(seed).random(n)
        self.n = n
        self.alive = np.ones(n, bool)
        self.nbr: list[dict[int, float]] = [dict() for _ in range(n)]
        for a, b, c in zip(ka.tolist(), kb.tolist(), cnt.tolist()):
            self.nbr[a][b] = float(c)
            self.nbr[b][a] = float(c)
        self.size = size.tolist()
        self.csum = [list(r) for r in csum]
        self.per = [float(p) for p in per]
        self.parent = list(range(n))
        self.step: list[dict[int, float]] | None = None  # summed squared steps across each border
        if steps is not None:
            self.step = [dict() for _ in range(n)]
            for a, b, v in zip(ka.tolist(), kb.tolist(), steps.tolist()):
                self.step[a][b] = float(v)
                self.step[b][a] = float(v)

    def difference(self, a: int, b: int) -> float:
        """Squared colour difference (Lab) of neighbours ``a`` and ``b``: of their means, or, with
        ``boundary``, the smaller of that and their border's mean squared step."""
        na, nb = self.size[a], self.size[b]
        ca = [x / na for x in self.csum[a]]
        cb = [x / nb for x in self.csum[b]]
        d2 = sum((x - y) ** 2 for x, y in zip(ca, cb))
        if self.step is not None:
            d2 = min(d2, self.step[a][b] / max(1.0, self.nbr[a][b]))
        return d2

    def cost(self, a: int, b: int) -> float:
        """Ward cost of merging neighbours ``a`` and ``b``, times 1..4 for a short shared border."""
        na, nb = self.size[a], self.size[b]
        frac = self.nbr[a][b] / max(1.0, min(self.per[a], self.per[b]))
        shape = 1.0 + 3.0 * max(0.0, 1.0 - 4.0 * frac)  # short shared border: merge later
        return na * nb / (na + nb) * self.difference(a, b) * shape * self.jitter[min(a, b)]

    def _entry(self, a: int, x: int):
        return (self.cost(a, x), min(a, x), max(a, x)) if a < x else (self.cost(x, a), x, a)

    def _merge(self, a: int, b: int) -> None:
        """Merge ``b`` into ``a``: sums, perimeter, and the borders ``b`` had with others."""
        nbr = self.nbr
        self.alive[b] = False
        self.parent[b] = a
        self.size[a] += self.size[b]
        self.csum[a] = [x + y for x, y in zip(self.csum[a], self.csum[b])]
        self.per[a] = self.per[a] + self.per[b] - 2 * nbr[a][b]
        for border in (nbr,) if self.step is None else (nbr, self.step):
            _fold(border, a, b)

    def run(self, target: int, snapshot_below: int = 0):
        """Merge down to ``target`` nodes, cheapest pair first.

        Returns
        -------
        history : list of (int, float, float)
            ``(node count after the merge, its cost, its colour difference)``
            for every merge (the difference as :meth:`difference`'s square root).
        snapshots : dict
            ``parent`` (a list) after each merge that left at most
            ``snapshot_below`` nodes, by node count.
        """
        n, nbr = self.n, self.nbr
        heap = [(self.cost(a, b), a, b) for a in range(n) for b in nbr[a] if a < b]
        heapq.heapify(heap)
        history = []
        snapshots = {}
        count = n
        while count > target and heap:
            c, a, b = heapq.heappop(heap)
            if not (self.alive[a] and self.alive[b]) or b not in nbr[a]:
                continue
            if abs(c - self.cost(a, b)) > 1e-9 * max(1.0, abs(c)):
                continue  # stale entry
            step = float(np.sqrt(self.difference(a, b)))
            self._merge(a, b)
            for x in nbr[a]:
                heapq.heappush(heap, self._entry(a, x))
            count -= 1
            history.append((count, c, step))
            if count <= snapshot_below:
                snapshots[count] = list(self.parent)
        return history, snapshots


def _root(parent: list[int], x: int) -> int:
    """The root of node ``x`` of a merge forest (``parent[r] == r`` at a root)."""
    while parent[x] != x:
        x = parent[x]
    return x


def _roots(parent: list[int]) -> np.ndarray:
    """The root of every node of a merge forest."""
    par = list(parent)
    for x in range(len(par)):
        par[x] = _root(par, x)
    return np.array(par)


def _elbow(history, snapshots: dict, default: list[int], counts=AUTO_COUNTS) -> list[int]:
    """The merge forest at the region count in ``counts`` where the next merge's cost jumps most.

    Merging from ``k + 1`` to ``k`` regions cost ``costs[k]``; the jump at
    ``k`` is ``costs[k - 1] / costs[k]``. Ties keep the smaller ``k``;
    without any candidate the count is the middle of ``counts`` (8 of the
    default), or ``default`` when that was not recorded.
    """
    costs = {k: c for k, c, _ in history}
    best_k, best_jump = (counts[0] + counts[1]) // 2, -1.0
    for k in range(counts[0], counts[1] + 1):
        if k in snapshots and (k - 1) in costs and k in costs:
            jump = costs[k - 1] / max(costs[k], 1e-12)
            if jump > best_jump:
                best_jump, best_k = jump, k
    par = snapshots.get(best_k)
    return default if par is None else par


def _merged(sp: np.ndarray, n: int, lab: np.ndarray, seed: int, n_regions: int | None,
            boundary: bool, counts=AUTO_COUNTS) -> np.ndarray:
    """Superpixels ``sp`` merged (:class:`_WardMerge`) to ``n_regions``, else to the elbow's count
    (:func:`_elbow`) or, with ``boundary``, to the first edge (:func:`_edge_stop`); slivers and tiny
    pieces then merged by :func:`split_connected`, and with ``boundary`` neighbours without an edge
    between them joined (:func:`_join_seamless`)."""
    graph = _WardMerge(sp, n, lab, seed, boundary=boundary)
    if n_regions is None:
        history, snapshots = graph.run(1, snapshot_below=counts[1])
        pick = _edge_stop if boundary else _elbow
        parent = pick(history, snapshots, graph.parent, counts)
    else:
        graph.run(n_regions)
        parent = graph.parent
    labels = _roots(parent)[sp]
    labels = split_connected(labels, min_size=default_min_size(sp.shape), sliver_width=1.5)
    return _join_seamless(labels, lab) if boundary else labels


#: The boundary merge stops before its first merge of two regions this different (Lab units,
#: :meth:`_WardMerge.difference`): an edge. The edge table's shapes give the same regions from 8 to 15.
EDGE_STEP = 10.0


def _edge_stop(history, snapshots: dict, default: list[int], counts=AUTO_COUNTS) -> list[int]:
    """The merge forest just before the first merge across an edge (:data:`EDGE_STEP`), its region
    count held within ``counts``; ``default`` when that count was not recorded.

    The boundary merge's costs do not rise steadily (a merge can leave a
    neighbour's border cheaper than the merge before), so their largest jump,
    which the Ward merge reads, stopped it too early or too late: a ring's hole
    went into the ring, a background stayed cut.
    """
    k = next((count + 1 for count, _, step in history if step > EDGE_STEP), counts[0])
    par = snapshots.get(min(max(k, counts[0]), counts[1]))
    return default if par is None else par


#: Regions whose shared border steps by less than this (median of its pixel pairs, Lab units) show no
#: edge there and are joined (:func:`_join_seamless`). The edge table's shapes give the same regions
#: from 2 to 3; at 5 one sample's map (rocket area-downscaled 4x) would change.
SEAMLESS = 3.0


def _border_medians(key: np.ndarray, step: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per border (``key`` of its pixel pairs, as :func:`_border_pairs` makes them): the keys in
    increasing order, the pairs each has, and the upper median of its pairs' ``step``."""
    order = np.lexsort((step, key))
    key, step = key[order], step[order]
    pairs, first, count = np.unique(key, return_index=True, return_counts=True)
    return pairs, count, step[first + count // 2]


def _join_seamless(labels: np.ndarray, lab: np.ndarray) -> np.ndarray:
    """``labels`` with neighbours joined where the image shows no edge between them.

    The boundary merge reads a border's mean step, which the few pixel pairs
    where the border meets a third region's anti-aliased pixels can carry
    past :data:`EDGE_STEP`: it stopped short of a gradient's halves in 3 of
    the edge table's first 8 variants. Here the median step is read.
    """
    m = int(labels.max()) + 1
    pairs, count, median2 = _border_medians(*_border_pairs(labels, m, lab))
    median = np.sqrt(median2)
    parent = list(range(m))
    for k in pairs[(median < SEAMLESS) & (count >= 8)]:
        a, b = _root(parent, int(k // m)), _root(parent, int(k % m))
        parent[max(a, b)] = min(a, b)
    if all(parent[r] == r for r in range(m)):
        return labels
    return _renumber(labels, _roots(parent))[0]


def fill_residual(lab: np.ndarray, labels: np.ndarray) -> float:
    """RMS (Lab units) of the image around one affine colour field per region: how well the
    regions explain the image as smooth fills.

    Parameters
    ----------
    lab : ndarray (H, W, 3)
        The image in CIE Lab.
    labels : ndarray (H, W) int
        Regions ``0..n-1``.

    Returns
    -------
    float
    """
    h, w = labels.shape
    n = int(labels.max()) + 1
    # per region the normal equations of the fit over X = (x / w, y / h, 1), summed run by run of
    # one label along a row: sums over a run are differences of prefix sums along the row
    xs = np.arange(w, dtype=np.float64) / max(w, 1)
    px = np.concatenate([[0.0], np.cumsum(xs)])
    pxx = np.concatenate([[0.0], np.cumsum(xs * xs)])

    def band(rows_ab):
        # one band's sums, on a host thread; added up below in band order (the same values as one
        # thread adding band after band)
        a, b = rows_ab
        xtx = np.zeros((n, 3, 3))
        xtc = np.zeros((n, 3, 3))
        L = labels[a:b]
        rows = b - a
        start = np.ones((rows, w), bool)
        start[:, 1:] = L[:, 1:] != L[:, :-1]
        rr, c0 = np.nonzero(start)
        c1 = np.empty_like(c0)
        c1[:-1] = c0[1:]
        c1[np.r_[rr[1:] != rr[:-1], True]] = w  # a run ends where the next one starts, or at the row's end
        lab_r = L[rr, c0].astype(np.int64)
        C = lab[a:b].astype(np.float64)
        pc = np.zeros((rows, w + 1, 3))
        np.cumsum(C, axis=1, out=pc[:, 1:])
        pxc = np.zeros((rows, w + 1, 3))
        np.cumsum(C * xs[None, :, None], axis=1, out=pxc[:, 1:])
        pcc = np.zeros((rows, w + 1))
        np.cumsum((C * C).sum(axis=2), axis=1, out=pcc[:, 1:])
        y = (a + rr) / max(h, 1)
        cnt = (c1 - c0).astype(np.float64)
        sx = px[c1] - px[c0]
        sums = {
            (0, 0): pxx[c1] - pxx[c0], (0, 1): y * sx, (0, 2): sx,
            (1, 1): y * y * cnt, (1, 2): y * cnt, (2, 2): cnt,
        }
        for (i, j), v in sums.items():
            t = np.bincount(lab_r, v, n)
            xtx[:, i, j] += t
            if i != j:
                xtx[:, j, i] += t
        sc = pc[rr, c1] - pc[rr, c0]
        sxc = pxc[rr, c1] - pxc[rr, c0]
        for j in range(3):
            xtc[:, 0, j] += np.bincount(lab_r, sxc[:, j], n)
            xtc[:, 1, j] += np.bincount(lab_r, y * sc[:, j], n)
            xtc[:, 2, j] += np.bincount(lab_r, sc[:, j], n)
        return xtx, xtc, np.bincount(lab_r, pcc[rr, c1] - pcc[rr, c0], n)

    xtx = np.zeros((n, 3, 3))
    xtc = np.zeros((n, 3, 3))
    ctc = np.zeros(n)
    for bx, bc, bcc in map_bands(band, h, w):
        xtx += bx
        xtc += bc
        ctc += bcc
    sq = ctc.copy()
    for r in range(n):
        beta = np.linalg.pinv(xtx[r]) @ xtc[r]
        sq[r] -= float((beta * xtc[r]).sum())
    return float(np.sqrt(max(sq.sum(), 0.0) / max(labels.size, 1)))


#: Share of the pixels that must lie in patches of one exact colour, each with an interior pixel,
#: for :func:`flat_regions` to read a picture as a flat-colour graphic (a drawing, a logo, a
#: screenshot, pixel art). Photos hold almost none: noise makes neighbours differ.
FLAT_SHARE = 0.7
#: A pixel whose colour lies within this distance (sRGB 0-1, Euclidean) of a mix of the patch it
#: joined and a patch around it is their anti-aliased border, not a shape of its own.
FLAT_MIX = 0.03
#: Share of the pixels that may lie in thick shapes of varied colour or in crumbs (neither in a
#: patch nor a mix of the patches around them, nor a thin shape); beyond it the picture holds
#: content of another kind (a photo on a flat background) and the general segmentation runs.
FLAT_LEFT = 0.02
#: A shape of its own in a flat graphic (pixels that are no mix of the patches around them) at most
#: this many pixels from its edge everywhere is thin (a line, a stroke of anti-aliased text); thicker
#: ones count towards :data:`FLAT_LEFT`.
FLAT_THIN = 4
#: Pixels the first look of :func:`flat_regions` compares with their neighbours (rows spread over the picture).
FLAT_LOOK = 1 << 18
#: Most regions :func:`flat_regions` gives; a picture with more flat patches takes the general path.
FLAT_MAX_REGIONS = 1024


def _mix_distance(c: np.ndarray, own: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Per pixel, the least distance from its colour ``c`` (n, 3) to a mix of its region's colour
    ``own`` (n, 3) and one of the colours ``cols`` (n, k, 3) around it (the segment between them)."""
    best = np.full(len(c), np.inf)
    for j in range(cols.shape[1]):
        d = cols[:, j] - own
        dd = (d * d).sum(axis=1)
        t = np.clip(((c - own) * d).sum(axis=1) / np.maximum(dd, 1e-12), 0.0, 1.0)
        e = c - own - t[:, None] * d
        np.minimum(best, np.sqrt((e * e).sum(axis=1)), out=best)
    return best


#: Pixels (4-neighbour steps) the patches of a flat graphic are grown over its anti-aliased borders.
FLAT_REACH = 8


def _grow(labels: np.ndarray, rgb: np.ndarray, colour: np.ndarray, steps: int | None) -> bool:
    """Give unlabelled pixels (``-1``) of ``labels`` (H, W) the label of a 4-neighbour, the one whose
    ``colour`` is nearest theirs (``rgb``: (H * W, 3)), a ring at a time, ``steps`` rings (None: until
    none is left). Returns whether every pixel got one."""
    H, W = labels.shape
    flat = labels.ravel()
    todo = np.flatnonzero(flat < 0)
    done = 0
    while todo.size and (steps is None or done < steps):
        ys, xs = np.divmod(todo, W)
        best = np.full(todo.size, np.inf)
        pick = np.full(todo.size, -1, np.int64)
        for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
            qy, qx = ys + dy, xs + dx
            ok = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
            lab = np.full(todo.size, -1, np.int64)
            lab[ok] = labels[qy[ok], qx[ok]]
            ok = lab >= 0
            d = np.full(todo.size, np.inf)
            d[ok] = ((colour[lab[ok]] - rgb[todo[ok]]) ** 2).sum(axis=1)
            better = d < best
            best[better], pick[better] = d[better], lab[better]
        got = pick >= 0
        if not got.any():
            break
        flat[todo[got]] = pick[got]
        todo = todo[~got]
        done += 1
    return todo.size == 0


def _no_mixes(labels: np.ndarray, rgb: np.ndarray, colour: np.ndarray, outside: np.ndarray) -> tuple[np.ndarray, float]:
    """Which pixels ``outside`` the patches (H, W) are no mix of the patch they grew into (``labels``,
    -1: none reached them) and a patch around them, 1 to :data:`FLAT_REACH` px away in 8 directions
    (an anti-aliased border may be wider than the 3 x 3 neighbourhood); ``rgb`` (H, W, 3).

    Returns the flat mask of those pixels and the share of all pixels that are mixes.
    """
    H, W = labels.shape
    rest = np.flatnonzero(outside.ravel())
    odd = np.zeros(H * W, bool)
    if rest.size == 0:
        return odd, 0.0
    ys, xs = np.divmod(rest, W)
    own = labels.ravel()[rest]
    around = []
    for r in sorted({1, 2, 4, FLAT_REACH}):
        for dy in (-r, 0, r):
            for dx in (-r, 0, r) if dy else (-r, r):
                lab = labels[np.clip(ys + dy, 0, H - 1), np.clip(xs + dx, 0, W - 1)]
                around.append(np.where(lab >= 0, lab, own))
    reached = own >= 0
    err = np.full(rest.size, np.inf)
    err[reached] = _mix_distance(rgb.reshape(-1, 3)[rest[reached]].astype(np.float64), colour[own[reached]],
                                 colour[np.stack(around, axis=1)[reached]])
    odd[rest[err > FLAT_MIX]] = True
    return odd, float((err <= FLAT_MIX).sum()) / (H * W)


def _shapes_cut_at_half(labels: np.ndarray, rgb: np.ndarray, colour: np.ndarray, shapes: np.ndarray, k: int,
                        mine: np.ndarray) -> np.ndarray:
    """Label the pixels ``mine`` of the shapes ``shapes`` (``0 .. k-1``) ``len(colour) + shape`` in
    ``labels``, in place, but for each shape's anti-aliased rim: its pixels less than half of the
    shape's own colour over the colour of the patch they grew into stay with that patch. A shape's
    own colour is the mean of its pixels at least 3/4 as far from their patches' colours as its
    farthest. Returns the shapes' colours (k, 3); ``rgb``: (H * W, 3).
    """
    W = labels.shape[1]
    n = len(colour)
    ys, xs = np.nonzero(mine)
    sid, grown = shapes[ys, xs], labels[ys, xs]
    c = rgb[ys * W + xs].astype(np.float64)
    base = colour[np.maximum(grown, 0)]
    dist = np.where(grown >= 0, np.sqrt(((c - base) ** 2).sum(axis=1)), np.inf)
    far = np.zeros(k)
    np.maximum.at(far, sid, np.where(np.isfinite(dist), dist, 0.0))
    core = dist >= 0.75 * far[sid]
    cnt = np.maximum(np.bincount(sid[core], minlength=k), 1)
    own = np.stack([np.bincount(sid[core], weights=c[core, j], minlength=k) for j in range(3)],
                   axis=1).astype(np.float64) / cnt[:, None]
    d = own[sid] - base
    t = ((c - base) * d).sum(axis=1) / np.maximum((d * d).sum(axis=1), 1e-12)
    stay = (grown < 0) | (t >= 0.5)
    labels[ys[stay], xs[stay]] = n + sid[stay]
    return own


def flat_regions(rgb: np.ndarray, min_size: int | None = None, mixed: bool = False):
    """The regions of a flat-colour graphic, or None when ``rgb`` is not one.

    A drawing, a logo, a diagram or a screenshot is made of patches of one
    exact colour with anti-aliased borders between them; superpixels merged by
    colour (:func:`segment_auto`'s general path) lose its small shapes and
    lines (a grid of 64 squares came back as 7 regions). Here every
    4-connected patch of one exact colour with an interior pixel (its four
    neighbours the same colour) and at least ``min_size`` pixels is a region,
    when such patches hold at least :data:`FLAT_SHARE` of the pixels. The
    other pixels join the neighbouring patch nearest in colour, grown out
    :data:`FLAT_REACH` px from the patches: anti-aliased borders. Those whose
    colour is no mix (within :data:`FLAT_MIX`) of the patch they joined and a
    patch around them, or that no patch reached, are a shape of their own
    where they connect into ``min_size`` pixels or more (a line one pixel
    wide, anti-aliased text whose strokes hold no pixel of their pure colour,
    a small picture on the page). When shapes thicker than :data:`FLAT_THIN`
    px and crumbs hold more than :data:`FLAT_LEFT` of the pixels (a photo on a
    flat background), or there would be more than :data:`FLAT_MAX_REGIONS`
    regions, None.

    Parameters
    ----------
    rgb : ndarray (H, W, 3)
        uint8, or float in ``[0, 1]``.
    min_size : int, optional
        Smallest patch that is a region (default :func:`default_min_size`).
    mixed : bool
        Also return the share of the pixels read as anti-aliased borders (0:
        a crisp graphic, pixel art).

    Returns
    -------
    labels : ndarray (H, W) int32, values ``0..n-1``, or None
        (``(labels, share)`` with ``mixed``; ``(None, 0.0)`` when not a graphic.)
    """
    if mixed:
        return _flat_regions(rgb, min_size)
    return _flat_regions(rgb, min_size)[0]


def _flat_regions(rgb: np.ndarray, min_size: int | None) -> tuple[np.ndarray | None, float]:
    """:func:`flat_regions` and the share of its pixels read as anti-aliased borders."""
    none = (None, 0.0)
    rgb = _check_rgb(rgb)
    H, W = rgb.shape[:2]
    n_px = H * W
    min_size = default_min_size((H, W)) if min_size is None else max(1, int(min_size))
    # a cheap look first, at about FLAT_LOOK pixels of rows spread over the picture: in a photo hardly a
    # pixel equals its neighbours
    rows = np.arange(0, H - 1, max(1, (H - 1) * W // FLAT_LOOK))
    same = (int((rgb[rows, 1:] == rgb[rows, :-1]).all(axis=2).sum())
            + int((rgb[rows + 1] == rgb[rows]).all(axis=2).sum()))
    if same < FLAT_SHARE * len(rows) * (2 * W - 1):
        return none
    # colours as exact integer keys (16 bits a channel holds every 8- and 16-bit value apart)
    q = np.rint(rgb.astype(np.float64) * 65535.0).astype(np.int64)
    key = (q[..., 0] << 32) | (q[..., 1] << 16) | q[..., 2]
    del q
    comp, n = _components(key)
    size = np.bincount(comp.ravel(), minlength=n)
    pad = np.pad(comp, 1, mode="edge")
    interior = ((pad[:-2, 1:-1] == comp) & (pad[2:, 1:-1] == comp) & (pad[1:-1, :-2] == comp)
                & (pad[1:-1, 2:] == comp))
    del pad
    thick = np.zeros(n, bool)
    thick[comp[interior]] = True
    seed = thick & (size >= min_size)
    if size[seed].sum() < FLAT_SHARE * n_px or seed.sum() > FLAT_MAX_REGIONS:
        return none
    flat_rgb = rgb.reshape(-1, 3)
    colour = np.stack([np.bincount(comp.ravel(), weights=flat_rgb[:, c], minlength=n) for c in range(3)], axis=1)
    colour /= np.maximum(size, 1)[:, None]
    labels = np.where(seed[comp], comp, -1)
    # anti-aliased borders are a few pixels wide: the patches grown that far, each pixel to the
    # neighbouring region nearest in colour
    _grow(labels, flat_rgb, colour, FLAT_REACH)
    # the pixels outside the patches: a mix of the regions around them, or a shape of their own
    odd, mix = _no_mixes(labels, rgb, colour, ~seed[comp])
    # connected pixels that are no mix, enough of them: a shape of its own (a line one pixel wide,
    # anti-aliased text whose strokes hold no pixel of their pure colour, a small picture on the page)
    odd2 = odd.reshape(H, W)
    shapes, k = _components(odd2.astype(np.int8))
    big = np.bincount(shapes.ravel(), minlength=k) >= min_size
    mine = odd2 & big[shapes]
    # but thick patches of varied colours are little of a drawing: a photo on a flat background
    core = cv2.erode(odd2.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3)),
                     iterations=FLAT_THIN) > 0
    thick_shape = np.zeros(k, bool)
    thick_shape[shapes[core]] = True
    if int(odd.sum()) - int(mine.sum()) + int((mine & thick_shape[shapes]).sum()) > FLAT_LEFT * n_px:
        return none
    # the shapes without their anti-aliased rims, numbered from n
    shape_colour = _shapes_cut_at_half(labels, flat_rgb, colour, shapes, k, mine)
    labels[odd2 & ~mine] = -1
    # what is left (a few crumbs) to the neighbouring region nearest in colour
    if not _grow(labels, flat_rgb, np.concatenate([colour, shape_colour]), None):
        return none
    labels, count = _renumber(labels)
    if count > FLAT_MAX_REGIONS:
        return none
    # one label a 4-connected piece (pixels grown around a thin shape may be cut off), crumbs merged
    return split_connected(labels, min_size=min_size), mix


#: :func:`segment_auto` keeps the boundary-merged regions when their :func:`fill_residual`, times
#: ``1 + REGION_COST`` per region, is at most this fraction of the Ward-merged ones'. A region
#: costs bytes and a border, and more regions always fit better: without the cost, 3 of the edge
#: table's first 8 variants kept Ward regions that cut the background (8-9 regions, where the
#: boundary merge found the 5 shapes); at 0.15 three of the samples (chelsea 4x-downscaled,
#: rocket at both sizes) would change, at 0.1 none does, nor do 9 of 10 more scikit-image pictures
#: (coins changes, 11 -> 4 regions, 21091 B / 37.66 dB -> 19026 B / 37.81 dB).
FILL_GAIN = 0.9
REGION_COST = 0.1


def segment_auto(rgb: np.ndarray, n_regions: int | None = None, seed: int = 0, counts=AUTO_COUNTS) -> np.ndarray:
    """A handful of coherent object regions, automatically.

    SLIC superpixels (about 300; SLIC converts to Lab itself; above :data:`SLIC_PIXELS`
    from a smaller copy, their borders placed again at full size) are merged greedily, always
    the adjacent pair of smallest Ward cost ``n_a n_b / (n_a + n_b) |c_a -
    c_b|^2`` (mean Lab colours ``c`` by :func:`tpsv.color.srgb_to_lab`, sizes ``n``) scaled up by a factor 1..4
    when the shared border is short relative to the smaller region's
    perimeter (keeps regions compact), down to ``n_regions``. Without
    ``n_regions`` the count is chosen in ``counts`` (4 to 12) at the largest relative
    jump of the merge cost (the elbow). Slivers and tiny pieces are then
    merged by :func:`split_connected`.

    A second merge of the same superpixels measures colour differences by the
    step across the shared border where that is smaller than the means'
    difference (:class:`_WardMerge` with ``boundary``), stops before its first
    merge across an edge (:func:`_edge_stop`) and joins neighbours the image
    shows no edge between (:func:`_join_seamless`): a gradient is not cut and
    a small shape of another colour is not swallowed. Its regions are
    kept when they explain the image as smooth fills clearly better
    (:func:`fill_residual`, raised by :data:`REGION_COST` a region, at most
    :data:`FILL_GAIN` of the first's): drawings, logos and gradients. On
    photos texture dominates both residuals and the Ward merge's more
    object-like regions stay (the bundled samples keep theirs).

    A flat-colour graphic (a drawing, a logo, a screenshot: :func:`flat_regions`)
    takes its patches of one colour as regions instead, when no ``n_regions``
    is asked for and they score no worse than both merges (the same fill
    residual and cost a region).

    Last, the borders are smoothed where they follow no edge (:func:`smooth_borders`)
    and, when no ``n_regions`` is asked for, neighbours whose shared border steps by
    less than :data:`WEAK_BORDER` are joined (:func:`join_weak_borders`): the count
    may then fall below ``counts`` (a photo with no strong edge is one region).
    Merged superpixels of a photo often meet inside a texture of slowly changing
    colour, where a border buys nothing the detail layer would not draw and costs its
    outline, control grid and lattice of features.

    Deterministic for a given ``seed`` (SLIC itself is deterministic; the seed
    only breaks exact cost ties).

    Parameters
    ----------
    rgb : ndarray (H, W, 3)
        uint8, or float in ``[0, 1]``.
    n_regions : int, optional
        Number of regions to merge down to (before the clean-up).
    seed : int
        Breaks exact ties of the merge cost.
    counts : (int, int)
        The region counts chosen from without ``n_regions`` (:data:`AUTO_COUNTS`;
        :data:`FEW_COUNTS` for a coarser candidate).

    Returns
    -------
    labels : ndarray (H, W) int32, values ``0..n-1``
    """
    rgb = _check_rgb(rgb)
    H, W = rgb.shape[:2]
    if n_regions is not None and n_regions < 1:
        raise TpsvError("--regions must be at least 1")
    flat = flat_regions(rgb) if n_regions is None else None
    lab = lab_image(rgb, clip=True)
    sp, n = _superpixels(rgb, lab)
    if n <= 1:
        return np.zeros((H, W), np.int32) if flat is None else flat

    def merged_and_scored(boundary: bool):
        labels = _merged(sp, n, lab, seed, n_regions, boundary=boundary, counts=counts)
        return labels, fill_residual(lab, labels) * (1.0 + REGION_COST * (int(labels.max()) + 1))

    # the two merges are independent: side by side on two host threads (their numpy passes over the
    # pixels release the interpreter; the same labels as one after the other)
    if host_cores() > 1:
        ward_job = pool("segment", 2).submit(merged_and_scored, False)
        steps, steps_score = merged_and_scored(True)
        ward, ward_score = ward_job.result()
    else:
        (ward, ward_score), (steps, steps_score) = merged_and_scored(False), merged_and_scored(True)
    if flat is not None:
        # a flat graphic's patches when they explain it as well for their number (small anti-aliased
        # text cut into many tiny regions does not: its letters came back with dark blobs at 4x)
        flat_score = fill_residual(lab, flat) * (1.0 + REGION_COST * (int(flat.max()) + 1))
        if flat_score <= min(ward_score, steps_score):
            return flat
    labels = smooth_borders(steps if steps_score <= FILL_GAIN * ward_score else ward, lab)
    return labels if n_regions is not None else join_weak_borders(labels, lab)


#: Regions of a photo whose shared border steps by less than this (Lab units, the median over its
#: pixel pairs of :func:`wide_steps`) are joined after the merges (:func:`join_weak_borders`): such a
#: border is no edge the texture cannot draw, and a region costs its outline, its control grid and
#: its own lattice of features.
WEAK_BORDER = 25.0
#: :func:`wide_steps`: the Gaussian (px) the picture is smoothed by, and how far (px) beyond either
#: pixel of a pair it is read: a soft edge (a cat's pupil, a few pixels a side) shows its whole
#: step, a texture's grain is averaged away.
WIDE_SIGMA = 1.0
WIDE_REACH = 2


def wide_steps(labels: np.ndarray, lab: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every pair of 4-neighbour pixels of different labels: the two labels and the step across it.

    The step is the Lab distance between the picture smoothed by :data:`WIDE_SIGMA` px at
    :data:`WIDE_REACH` px beyond either pixel, along the pair's axis (clipped at the picture's
    edge).

    Returns
    -------
    a, b : ndarray (n,) int64
        Labels of the first (left or upper) and the second pixel.
    step : ndarray (n,) float32
    """
    smooth = cv2.GaussianBlur(np.asarray(lab, np.float32), (0, 0), WIDE_SIGMA)
    h, w = labels.shape
    out = [], [], []
    for first, second, axis in ((labels[:, :-1], labels[:, 1:], 1), (labels[:-1, :], labels[1:, :], 0)):
        y, x = np.nonzero(first != second)
        if axis:
            near, far = smooth[y, np.maximum(x - WIDE_REACH, 0)], smooth[y, np.minimum(x + 1 + WIDE_REACH, w - 1)]
        else:
            near, far = smooth[np.maximum(y - WIDE_REACH, 0), x], smooth[np.minimum(y + 1 + WIDE_REACH, h - 1), x]
        for k, v in enumerate((first[y, x].astype(np.int64), second[y, x].astype(np.int64),
                               np.sqrt(((near - far) ** 2).sum(axis=1)))):
            out[k].append(v)
    return tuple(np.concatenate(v) for v in out)


def join_weak_borders(labels: np.ndarray, lab: np.ndarray, limit: float | None = None) -> np.ndarray:
    """``labels`` with the neighbours joined whose shared border is no edge: the weakest border
    first, while one's median step (:func:`wide_steps`, over at least 8 pixel pairs) is below
    ``limit`` (default :data:`WEAK_BORDER`).

    Each border's median is read again over the joined regions' pixel pairs (the border a join
    leaves with a third region is the two borders together): joins made at once on the first
    medians would chain two regions an edge divides through a third both meet softly.

    Parameters
    ----------
    labels : ndarray (H, W) int
        Regions ``0..n-1``.
    lab : ndarray (H, W, 3)
        The picture in CIE Lab.
    limit : float, optional

    Returns
    -------
    ndarray (H, W) int32
        Regions ``0..m-1``, ``m <= n``, in raster order of their first pixel.
    """
    limit = WEAK_BORDER if limit is None else float(limit)
    labels = np.asarray(labels, np.int32)
    n = int(labels.max()) + 1
    a, b, step = wide_steps(labels, lab)
    root = np.arange(n)
    while True:
        ra, rb = root[a], root[b]
        cut = ra != rb
        pairs, count, median = _border_medians(np.minimum(ra, rb)[cut] * n + np.maximum(ra, rb)[cut], step[cut])
        median = np.where(count >= 8, median, np.inf)
        if not median.size or median.min() >= limit:
            break
        k = int(pairs[np.argmin(median)])
        root[root == k % n] = k // n
    if (root == np.arange(n)).all():
        return labels
    return _renumber(labels, root)[0]


#: Widths (px, the standard deviation of a Gaussian) :func:`smooth_borders` tries in turn.
SMOOTH_SIGMAS = (4.0, 2.0)
#: Pictures of more pixels keep their borders as merged: measured up to a megapixel (retina at
#: 1024 x 1024 +0.18 dB BD-PSNR, hubble at 1000 x 872 +0.07), not beyond.
SMOOTH_PIXELS = 1 << 20
#: A border whose step across (Lab units, the mean over a neighbourhood of the smoothing's width)
#: is at least this follows an edge, and :func:`smooth_borders` leaves it where it is. The edge
#: table's shapes have steps of 24-69 along 94-100 % of their borders; the samples' automatic
#: borders a median of 5 (chelsea's fur) to 19 (astronaut).
EDGE_BORDER_STEP = 20.0


def border_steps(labels: np.ndarray, lab: np.ndarray, sigma: float) -> np.ndarray:
    """At each border pixel of ``labels`` (one with a 4-neighbour in another region), the mean over a
    Gaussian neighbourhood of ``sigma`` px of the border pixels' steps (each the largest Lab
    difference to a neighbour across the border).

    Returns
    -------
    ndarray (H, W) float32
        0 away from borders.
    """
    step = np.zeros(labels.shape, np.float32)
    border = np.zeros(labels.shape, bool)
    for a, b in ((np.s_[:, 1:], np.s_[:, :-1]), (np.s_[1:, :], np.s_[:-1, :])):
        cut = labels[a] != labels[b]
        d = np.where(cut, np.sqrt(((lab[a] - lab[b]) ** 2).sum(axis=2)), 0.0).astype(np.float32)
        for side in (a, b):
            np.maximum(step[side], d, out=step[side])
            border[side] |= cut
    num = cv2.GaussianBlur(step, (0, 0), sigma)
    den = cv2.GaussianBlur(border.astype(np.float32), (0, 0), sigma)
    return np.where(border, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)


def smooth_borders(labels: np.ndarray, lab: np.ndarray, sigmas=SMOOTH_SIGMAS) -> np.ndarray:
    """``labels`` with the borders that follow no edge smoothed: each pixel takes the region whose
    indicator, blurred by a Gaussian of ``sigma`` px, is largest there, except near a border whose
    step across is an edge (:data:`EDGE_BORDER_STEP`, :func:`border_steps`), which stays.

    Merged superpixels meet along borders that wander with the texture (a cat's fur, a sky's
    noise) where the image has no edge. Every wiggle is outline the file stores (chelsea's five
    automatic regions held 2600 bytes of outlines at quality 75, its label map's five 1102) and
    a border the renderer draws; the texture corrects the few pixels a smoother border gives the
    other region (docs/DESIGN.md, "Automatic regions").

    The first of ``sigmas`` that keeps every region, in one piece (:func:`split_connected`), is
    taken; a thin region a wide blur would cut or swallow takes a narrower one, or none (a line
    one pixel wide along a flat area). Pictures of more than :data:`SMOOTH_PIXELS` pixels are
    returned as they are.

    Parameters
    ----------
    labels : ndarray (H, W) int
        Regions ``0..n-1``, each one 4-connected piece.
    lab : ndarray (H, W, 3)
        The image in CIE Lab.
    sigmas : sequence of float

    Returns
    -------
    ndarray (H, W) int32
    """
    labels = np.asarray(labels)
    n = int(labels.max()) + 1
    if n < 2 or labels.size > SMOOTH_PIXELS:
        return labels
    masks = [(labels == k).astype(np.float32) for k in range(n)]
    for sigma in sigmas:
        step = border_steps(labels, lab, sigma)
        reach = 2 * int(np.ceil(2 * sigma)) + 1
        keep = cv2.dilate((step >= EDGE_BORDER_STEP).astype(np.uint8), np.ones((reach, reach), np.uint8)) > 0
        out = np.zeros(labels.shape, np.int32)
        best = cv2.GaussianBlur(masks[0], (0, 0), sigma)
        for k in range(1, n):
            b = cv2.GaussianBlur(masks[k], (0, 0), sigma)
            more = b > best
            out[more] = k
            np.maximum(best, b, out=best)
        out[keep] = labels[keep]
        out = split_connected(out, min_size=default_min_size(labels.shape), sliver_width=1.5)
        if int(out.max()) + 1 == n:
            return out
    return labels


# --------------------------------------------------------------------------- strokes


def stroke_labels(strokes_rgb: np.ndarray) -> tuple[np.ndarray, list[tuple[int, int, int]]]:
    """Marker map from a stroke image: -1 unstroked, else index of the colour.

    Colours are sorted by their (R, G, B) tuple; label ``k`` is the ``k``-th.
    """
    s = np.asarray(strokes_rgb)
    if s.ndim == 2:
        s = np.repeat(s[:, :, None], 3, axis=2)
    if s.ndim != 3 or s.shape[2] not in (3, 4):
        raise TpsvError(f"stroke image must be RGB, got shape {s.shape}")
    if s.shape[2] == 4:
        s = np.where(s[:, :, 3:4] > 0, s[:, :, :3], 0)
    if s.dtype != np.uint8:
        s = np.clip(np.rint(np.asarray(s, np.float64) * (255.0 if s.max() <= 1.0 else 1.0)), 0, 255).astype(np.uint8)
    code = (s[..., 0].astype(np.int64) << 16) | (s[..., 1].astype(np.int64) << 8) | s[..., 2].astype(np.int64)
    stroked = code != 0
    if not stroked.any():
        raise TpsvError("stroke image has no strokes (every pixel is black)")
    colours, inv = np.unique(code[stroked], return_inverse=True)
    if colours.size < 2:
        raise TpsvError("stroke image has only one stroke colour; draw at least two (one per region)")
    if colours.size > 1000:
        raise TpsvError(
            f"stroke image has {colours.size} stroke colours; draw strokes in flat colours without anti-aliasing"
        )
    markers = np.full(code.shape, -1, np.int32)
    markers[stroked] = inv.astype(np.int32)
    cols = [(int(c >> 16) & 255, int(c >> 8) & 255, int(c) & 255) for c in colours]
    return markers, cols


def segment_strokes(rgb: np.ndarray, strokes_rgb: np.ndarray, max_side: int = 256, min_size: int | None = None) -> np.ndarray:
    """Label map from user strokes: each distinct non-black stroke colour is one label.

    Labels of the random walker are the stroke colours sorted by (R, G, B)
    (label 0 = smallest colour tuple). The random walker
    (``skimage.segmentation.random_walker``, mode ``bf``: one sparse direct
    factorisation, much faster here than its conjugate-gradient modes without
    pyamg) runs on the image downscaled to at most ``max_side``
    pixels a side; its per-label probabilities are upscaled bilinearly and
    the most probable label taken. Every stroke pixel then gets its own
    label, pixel for pixel. Finally :func:`split_connected` makes each region
    connected and merges tiny pieces, but never merges away a component that
    holds stroke pixels. So the returned map's values are region numbers
    (``0..n-1``, raster order); a stroke colour drawn in two separate places
    yields two regions.

    Raises
    ------
    TpsvError
        No stroke, a single stroke colour, or strokes of another size.
    """
    rgb = _check_rgb(rgb)
    H, W = rgb.shape[:2]
    s = np.asarray(strokes_rgb)
    if s.shape[:2] != (H, W):
        raise TpsvError(f"stroke image is {s.shape[1]}x{s.shape[0]} but the image is {W}x{H}")
    markers, cols = stroke_labels(s)
    k = len(cols)
    f = min(1.0, max_side / float(max(H, W)))
    h, w = max(2, int(round(H * f))), max(2, int(round(W * f)))
    small = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA) if (h, w) != (H, W) else rgb
    mk = np.zeros((h, w), np.int32)
    rr, cc = np.nonzero(markers >= 0)
    mk[(rr * h) // H, (cc * w) // W] = markers[rr, cc] + 1
    present = np.unique(mk[mk > 0])
    if present.size < 2:
        prob = np.zeros((k, h, w), np.float32)
        prob[present - 1] = 1.0
    else:
        # random_walker needs labels 1..m without gaps
        remap = np.zeros(k + 1, np.int32)
        remap[present] = np.arange(1, present.size + 1)
        p = random_walker(small, remap[mk], beta=130, mode="bf", channel_axis=2, return_full_prob=True)
        prob = np.zeros((k, h, w), np.float32)
        prob[present - 1] = p.astype(np.float32)
    if (h, w) != (H, W):
        prob = np.stack([cv2.resize(p, (W, H), interpolation=cv2.INTER_LINEAR) for p in prob])
    labels = np.argmax(prob, axis=0).astype(np.int32)
    stroked = markers >= 0
    labels[stroked] = markers[stroked]
    return split_connected(labels, min_size=min_size, keep=stroked)


# --------------------------------------------------------------------------- preview


def palette(n: int) -> np.ndarray:
    """``n`` distinct RGB colours (uint8), golden-ratio hues."""
    out = np.zeros((max(n, 1), 3), np.uint8)
    for k in range(n):
        hue = (k * 0.6180339887498949) % 1.0
        sat = 0.65 + 0.35 * ((k // 7) % 2)
        val = 0.95 - 0.25 * ((k // 3) % 2)
        out[k] = np.round(np.array(colorsys.hsv_to_rgb(hue, sat, val)) * 255)
    return out[:n]


def overlay_regions(rgb: np.ndarray, labels: np.ndarray, alpha: float = 0.45) -> np.ndarray:
    """Region colours blended over the photo, boundaries in white: RGB uint8 (H, W, 3)."""
    rgb = _check_rgb(rgb)
    labels = np.asarray(labels)
    if labels.shape != rgb.shape[:2]:
        raise TpsvError("label map and image differ in size")
    _, inv = np.unique(labels, return_inverse=True)
    inv = inv.reshape(labels.shape)
    pal = palette(int(inv.max()) + 1).astype(np.float32) / 255.0
    out = (1 - alpha) * rgb + alpha * pal[inv]
    b = find_boundaries(inv, mode="inner")
    out[b] = 1.0
    return np.clip(np.rint(out * 255), 0, 255).astype(np.uint8)
