"""Colour features in pixel coordinates: curvilinear pairs and gradation features.

Paper section IV-C1 (curvilinear) and IV-C2 (gradation). Everything here is in
*pixel* space (``x`` right, ``y`` down; pixel ``(r, c)`` covers ``[c, c+1] x
[r, r+1]``, centre ``(c + 0.5, r + 0.5)``); the caller maps features into each
region's patch ``(S, T)``.

Gradient and scales
-------------------
One gradient serves both the Canny detector and the histogram of
:mod:`tpsv.encode.search`: the 3x3 Sobel operator (OpenCV's, aperture 3, replicated
border) applied to each channel of ``2.55 * Lab`` (so ``L`` spans 0-255 like
an 8-bit grey image); at every pixel the channel with the largest L2 gradient
magnitude is kept (what OpenCV's colour Canny does with BGR). Magnitudes are on
the scale of ``cv2.Canny`` thresholds for 8-bit images: a step of height ``h``
(0-255 units) gives ``4 h``. ``T_canny`` is the *high* hysteresis threshold and
``T_canny / 2`` the low one (L2 magnitude).

The superpixel variance ``sigma`` of a cell is the RMS colour deviation from the
cell mean, ``sqrt(trace(cov))``, of ``2.55 * Lab`` -- the same 0-255 units as
the gradient, so that ``T_super`` and the gradient histogram's ``sigma`` (from
which the paper derives ``T0_super``) are commensurable.

Curvilinear pairs (IV-C1, read as in SPEC: the pair straddles the edge)
----------------------------------------------------------------------
For a Canny edge pixel with unit gradient direction ``g``, the edge is first
placed to sub-pixel accuracy along ``g`` (parabola through the magnitudes at
``-g, 0, +g``, offset clamped to half a pixel), giving ``e``. Features sit at
``e - 0.5 g`` and ``e + 0.5 g`` (1 px apart, on opposite sides of the edge).
The feature at ``e + s 0.5 g`` takes the colour of the pixel containing
``e + s 1.0 g`` (one pixel step out: the nearest pixel on its side) and the
region of that pixel. If that pixel is in another region than the pixel
containing the feature itself, the feature's own pixel gives colour and region
instead, so a feature always lies in (or on the border of) its region and never
carries another region's colour. A pair across a region border therefore
belongs to two regions. The two halves are stored adjacently (``2k, 2k+1``) and
``pair`` links them.

Gradation features (IV-C2)
--------------------------
Adaptive superpixels as a hierarchy computed once per image. Level 0 is the
paper's initial decomposition: SLIC (``cv2.ximgproc``, Lab, ruler 10) with
cells of ``CELL_PIXELS = 4000`` pixels, i.e. ``N_cell = floor(N_pixel / 4000)``
cells, cut by the region index so that no cell crosses a region border. Every
cell is then split into (up to) 4 children by a SLIC-style k-means in ``(x, y,
Lab)`` restricted to the cell (compactness 10, seeds at the quadrants of the
cell, 3 iterations), recursively, down to cells of ``min_cell`` pixels (32: with
4000-pixel cells that is at most 4 adaptive levels, the level limit). For a
given ``T_super`` the cut through the tree refines a cell when its colour
deviation exceeds ``T_super`` (or, for safety, when it is larger than
``2 * CELL_PIXELS``). The paper's child-count formula (``W^p``, ``W^i``) only
affects convergence speed (as the paper says); a fixed branching of 4 lets the
tree be built once and cut at any ``T_super``, and makes the partition monotone:
a smaller ``T_super`` refines it.

Cell-boundary pixels become features at their pixel centres with their own
colour: a pixel is a boundary pixel when its right or lower neighbour is in
another cell (one side of each cell boundary), or when any 4-neighbour is in
another *region* (both sides of region borders, so each region is sampled along
its own outline), or on the image frame. They are thinned to one per 2x2 block
of pixels per region (``thin``), about every 2nd pixel along a boundary; the
count is monotone in the boundary set, hence in ``T_super``.

Lattice gradation features (the ``tpsv`` scheme's reading of IV-C2)
-------------------------------------------------------------------
:class:`LatticeGradation` places gradation features on a regular lattice of
each region's ``(S, T)`` square, one per cell at its centre with the cell's
mean colour, the spacing chosen per region from :data:`LATTICE_PX` by
``T_super`` (the coarsest whose cells' RMS deviation, averaged over the
region, is at most ``T_super``); cells holding a curvilinear feature are cut
down to :data:`EDGE_PX`. These features are defined in the patch, not at a
pixel (``FeatureSet.st``); their ``xy`` is ``M(S, T)``. With colours fitted
to the image (``tpsv.encode.fit``) a regular spread of features is the better
basis, and lattice positions cost almost nothing to store (measurements in
the class doc and in ``tpsv.encode.vectorize``).

Every region with at least 3 pixels gets at least 3 non-collinear features (the
TPS affine part needs them): a region whose features are fewer or collinear
gets its extreme pixels as extra features; a straight 1-px line gets three
points offset a quarter pixel across the line inside its pixels. Regions of 1 or
2 pixels get their pixel centres.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..geometry.bands import lab_image, row_bands
from ..geometry.patch import patch_pixel_scale
from ..geometry.regions import region_borders, to_patch_space, to_pixel_space
from ..model import CURVILINEAR, GRADATION, Features

#: Lab is scaled by this so that L spans 0-255 (the gradient and variance scale).
LAB_SCALE = 2.55
#: Integer scale of the Sobel derivatives handed to cv2.Canny (int16).
_CANNY_INT = 8.0
#: The largest gradient magnitude Canny sees: both int16 derivatives at their clip.
_CANNY_MAX = float(np.hypot(32767.0, 32767.0))
#: Pixels per initial superpixel (the paper's N_pixel / 4000).
CELL_PIXELS = 4000
#: Gradation features closer than this (pixels) to a curvilinear feature of their region are dropped.
DEDUP_PX = 0.5


@dataclass
class FeatureSet(Features):
    """:class:`tpsv.model.Features` with their pixel positions: the extractor's working form.

    The arrays of :class:`tpsv.model.Features` (``subset`` and ``concat``
    included) plus ``xy``. ``region`` is the value of the region index map;
    ``st`` holds the normalised patch parameters ``(S, T)`` where a feature is
    defined in its patch (lattice gradation features) and NaN where it is
    defined by ``xy`` (the caller maps it into the patch,
    :meth:`in_patch_space`).

    Attributes
    ----------
    xy : ndarray (F, 2) float64
        Pixel-space position ``(x, y)`` (``M(S, T)`` for features defined in
        the patch).
    """

    xy: np.ndarray

    _COLUMNS: ClassVar[dict] = {**Features._COLUMNS, "xy": (np.float64, (2,))}

    @classmethod
    def at_pixels(cls, xy, region, lab, kind, pair) -> "FeatureSet":
        """Features defined by their pixel positions (``st`` all NaN)."""
        return cls(region=region, st=np.full((len(region), 2), np.nan), lab=lab, kind=kind, pair=pair, xy=xy)

    def in_patch_space(self, patches: list) -> Features:
        """The features with ``(S, T)`` everywhere: those defined by ``xy`` mapped into their patch.

        Parameters
        ----------
        patches : list of Patch
            One per region.

        Returns
        -------
        Features
        """
        st = self.st.copy()
        todo = np.isnan(st[:, 0])
        if todo.any():
            st[todo] = to_patch_space(patches, self.xy[todo], self.region[todo])
        return Features(region=self.region.astype(np.int32), st=st, lab=self.lab.astype(np.float32),
                        kind=self.kind.astype(np.uint8), pair=self.pair.astype(np.int32))


def drop_near(grad: FeatureSet, cur: FeatureSet, radius: float, size: tuple[int, int]) -> FeatureSet:
    """``grad`` without its features within ``radius`` px of a feature of ``cur`` in the same region.

    A gradation feature that close to a curvilinear one adds a feature and
    almost no information.

    Parameters
    ----------
    grad, cur : FeatureSet
        Gradation and curvilinear features.
    radius : float
        Pixels (0: keep everything).
    size : (W, H)
        Image size (regions are kept apart by an offset larger than any
        distance inside it).

    Returns
    -------
    FeatureSet
    """
    if not (len(cur) and len(grad) and radius > 0):
        return grad
    span = float(size[0] + size[1] + 10)
    key_c = np.column_stack([cur.xy, cur.region * span])
    key_g = np.column_stack([grad.xy, grad.region * span])
    dist, _ = cKDTree(key_c).query(key_g, k=1, distance_upper_bound=radius + 1e-9)
    return grad.subset(~np.isfinite(dist) | (dist > radius))


# --------------------------------------------------------------------------- inputs


def as_rgb(rgb: np.ndarray) -> np.ndarray:
    """An image as float32 RGB in ``[0, 1]`` (uint8 scaled, floats clipped, alpha dropped).

    Parameters
    ----------
    rgb : ndarray (H, W, 3 or 4), uint8 or float

    Returns
    -------
    ndarray (H, W, 3) float32

    Raises
    ------
    ValueError
        Not an image of at least 3 channels.
    """
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] < 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
    rgb = rgb[..., :3]
    if rgb.dtype == np.uint8:
        return rgb.astype(np.float32) / 255.0
    rgb = rgb.astype(np.float32, copy=False)
    if rgb.size and (rgb.min() < 0.0 or rgb.max() > 1.0):
        return np.clip(rgb, 0.0, 1.0)
    return rgb  # already in range: no copy (a photo is held once)


def as_index(index: np.ndarray | None, shape: tuple[int, int]) -> np.ndarray:
    """A region index map checked against the image shape (None: one region).

    Parameters
    ----------
    index : ndarray (H, W) int, optional
    shape : (H, W)

    Returns
    -------
    ndarray (H, W) int32

    Raises
    ------
    ValueError
        The shape differs from ``shape`` or a value is negative.
    """
    if index is None:
        return np.zeros(shape, np.int32)
    index = np.asarray(index)
    if index.shape != shape:
        raise ValueError(f"index map shape {index.shape} does not match image {shape}")
    if index.size and index.min() < 0:
        raise ValueError("index map has negative values")
    return index.astype(np.int32, copy=False)


def lab_gradient(lab255: np.ndarray, blur_sigma: float = 0.0,
                 scale: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sobel gradient of the strongest channel of a multi-channel image.

    Without a pre-blur it is computed band by band of rows (each band with a
    row of its neighbours on either side, so the values are the whole
    image's): the temporaries stay a few megabytes.

    Parameters
    ----------
    lab255 : ndarray (H, W, C) float32
        Image (here ``2.55 * Lab``, or Lab with ``scale`` 2.55).
    blur_sigma : float
        Gaussian pre-blur (0: none, as ``cv2.Canny``).
    scale : float
        Factor (float32) applied to the image first.

    Returns
    -------
    dx, dy, mag : ndarray (H, W) float32
        Derivatives (3x3 Sobel, unnormalised) of the channel with the largest
        magnitude at each pixel, and that L2 magnitude.
    """
    h, w = lab255.shape[:2]

    def part(img):
        img = np.ascontiguousarray(img, np.float32)
        if scale != 1.0:
            img = img * np.float32(scale)
        if blur_sigma > 0:
            img = cv2.GaussianBlur(img, (0, 0), blur_sigma, borderType=cv2.BORDER_REPLICATE)
        if img.ndim == 2:
            img = img[..., None]
        gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
        gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
        if gx.ndim == 2:
            gx, gy = gx[..., None], gy[..., None]
        m2 = gx * gx + gy * gy
        ch = np.argmax(m2, axis=-1)[..., None]
        return (np.take_along_axis(gx, ch, -1)[..., 0], np.take_along_axis(gy, ch, -1)[..., 0],
                np.sqrt(np.take_along_axis(m2, ch, -1)[..., 0]))

    if blur_sigma > 0:  # the blur's reach is wider than a row: the whole image at once
        return part(lab255)
    dx, dy, mag = (np.empty((h, w), np.float32) for _ in range(3))
    for a, b in row_bands(h, w):
        lo, hi = max(a - 1, 0), min(b + 1, h)  # one row of context: the 3x3 Sobel sees what it sees whole
        for out, got in zip((dx, dy, mag), part(lab255[lo:hi])):
            out[a:b] = got[a - lo:a - lo + b - a]
    return dx, dy, mag


def _bilinear(img: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sample ``img`` at (column, row) positions in index space, clamped."""
    h, w = img.shape
    x = np.clip(x, 0.0, w - 1.0)
    y = np.clip(y, 0.0, h - 1.0)
    x0 = np.minimum(np.floor(x).astype(np.int64), max(w - 2, 0))
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    fx = x - x0
    fy = y - y0
    a = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    b = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return a * (1 - fy) + b * fy


# ----------------------------------------------------------------------- extractor


def _split4(
    lbl: np.ndarray,
    n: int,
    can: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    col: np.ndarray,
    iters: int,
    compactness: float,
) -> np.ndarray:
    """SLIC-style 4-way k-means inside every cell with ``can[cell]``.

    Returns the child (0-3) of every pixel of those cells, in raster order of
    the selected pixels. Seeds start at the quadrants (centroid +- half the
    standard deviation in x and y) with the cell's mean colour; the distance is
    ``d_lab^2 + (m / S)^2 d_xy^2`` with ``S^2`` = cell size / 4.
    """
    sel_idx = np.nonzero(can[lbl])[0]
    pid = np.full(n, -1, np.int64)
    ns = int(can.sum())
    pid[can] = np.arange(ns)
    pc_r = pid[lbl[sel_idx]]
    order = np.argsort(pc_r, kind="stable")
    pc = pc_r[order]
    src = sel_idx[order]
    X = px[src]
    Y = py[src]
    C = col[src]
    cnt = np.bincount(pc, minlength=ns)
    cntp = cnt.astype(np.float64)
    cx = np.bincount(pc, X, ns) / cntp
    cy = np.bincount(pc, Y, ns) / cntp
    sx = np.sqrt(np.maximum(np.bincount(pc, X.astype(np.float64) ** 2, ns) / cntp - cx * cx, 0))
    sy = np.sqrt(np.maximum(np.bincount(pc, Y.astype(np.float64) ** 2, ns) / cntp - cy * cy, 0))
    seeds = np.empty((ns, 4, 5), np.float32)
    mc = [np.bincount(pc, C[:, c], ns) / cntp for c in range(3)]
    for k, (ax, ay) in enumerate(((-1, -1), (1, -1), (-1, 1), (1, 1))):
        seeds[:, k, 0] = cx + 0.5 * ax * sx
        seeds[:, k, 1] = cy + 0.5 * ay * sy
        for c in range(3):
            seeds[:, k, 2 + c] = mc[c]
    wp = (compactness**2 / np.maximum(cntp / 4.0, 1.0)).astype(np.float32)
    wxy = np.repeat(wp, cnt)
    F = np.column_stack([X * wxy, Y * wxy, C]).astype(np.float32)  # (M, 5)
    a = np.zeros(pc.size, np.int64)
    for _ in range(iters):
        # d_k = |s_k|_w^2 - 2 F . s_k (+ per-pixel terms that do not move the argmin)
        const = wp[:, None] * (seeds[:, :, 0] ** 2 + seeds[:, :, 1] ** 2) + (seeds[:, :, 2:] ** 2).sum(-1)
        sp = np.repeat(seeds * np.float32(-2.0), cnt, axis=0)  # (M, 4, 5)
        d = np.repeat(const.astype(np.float32), cnt, axis=0)
        d += np.einsum("mf,mkf->mk", F, sp)
        a = np.argmin(d, axis=1)
        key = pc * 4 + a
        ck = np.bincount(key, minlength=ns * 4).astype(np.float64)
        nz = ck > 0
        flat = seeds.reshape(-1, 5)
        for f, v in enumerate((X, Y, C[:, 0], C[:, 1], C[:, 2])):
            sm = np.bincount(key, v, ns * 4)
            flat[nz, f] = (sm[nz] / ck[nz]).astype(np.float32)
    out = np.empty(pc.size, np.int64)
    out[np.searchsorted(sel_idx, src)] = a
    return out


@dataclass
class _Hierarchy:
    """Nested cell partitions: ``labels[L]`` (N,) per level, with stats per cell."""

    labels: list[np.ndarray]
    size: list[np.ndarray]
    rms: list[np.ndarray]
    split: list[np.ndarray]  # bool per cell: has >= 2 children at the next level


class FeatureExtractor:
    """Threshold-independent precomputation; ``extract`` for any thresholds.

    Lab conversion is computed here; the gradient (and its int16 copy for
    ``cv2.Canny``), the superpixel hierarchy and the per-region pixel lists on
    first use. Each ``extract`` call then costs a Canny pass, a cut through the
    hierarchy and a few vectorised passes over the boundary pixels.

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float in [0, 1] (uint8 accepted)
    index : ndarray (H, W) int
        Region index of every pixel (0..R-1).
    blur_sigma : float
        Gaussian pre-blur of the gradient (0: none, OpenCV Canny's convention).
    step : int
        Curvilinear subsampling: keep the strongest edge pixel per ``step x
        step`` block (1: every edge pixel, the paper's scheme).
    thin : int
        Gradation thinning: one boundary pixel per ``thin x thin`` block per
        region.
    min_cell : int
        Cells smaller than this are not split further (the level limit: with
        4000-pixel base cells and ``min_cell = 32``, at most 4 adaptive levels).
    """

    def __init__(
        self,
        rgb: np.ndarray,
        index: np.ndarray | None = None,
        *,
        blur_sigma: float = 0.0,
        step: int = 1,
        thin: int = 2,
        min_cell: int = 32,
    ) -> None:
        self.rgb = as_rgb(rgb)
        self.h, self.w = self.rgb.shape[:2]
        self.index = as_index(index, (self.h, self.w))
        self.n_regions = int(self.index.max()) + 1 if self.index.size else 0
        self.step = max(1, int(step))
        self.thin = max(1, int(thin))
        self.min_cell = max(2, int(min_cell))
        self.blur_sigma = float(blur_sigma)
        self.lab = lab_image(self.rgb)
        self._grad: tuple | None = None
        self._hier: _Hierarchy | None = None
        self._order: np.ndarray | None = None
        self._bounds: np.ndarray | None = None
        # Region borders (both sides) and the image frame: always boundary pixels.
        rb = region_borders(self.index)
        rb[0, :] = rb[-1, :] = True
        rb[:, 0] = rb[:, -1] = True
        self._fixed_boundary = rb

    def _gradient(self) -> tuple:
        """``(dx, dy, mag, dx16, dy16)``, made on first use (not before the curvilinear features need it)."""
        if self._grad is None:
            dx, dy, mag = lab_gradient(self.lab, self.blur_sigma, scale=LAB_SCALE)
            lim = 32767.0
            dx16 = np.clip(np.rint(dx * _CANNY_INT), -lim, lim).astype(np.int16)
            dy16 = np.clip(np.rint(dy * _CANNY_INT), -lim, lim).astype(np.int16)
            self._grad = (dx, dy, mag, dx16, dy16)
        return self._grad

    @property
    def dx(self) -> np.ndarray:
        """Sobel x derivative (H, W) float32 of the strongest channel of ``2.55 * Lab`` (:func:`lab_gradient`)."""
        return self._gradient()[0]

    @property
    def dy(self) -> np.ndarray:
        """Sobel y derivative (H, W) float32, as :attr:`dx`."""
        return self._gradient()[1]

    @property
    def mag(self) -> np.ndarray:
        """Gradient magnitude (H, W) float32, as :attr:`dx`."""
        return self._gradient()[2]

    @property
    def lab255(self) -> np.ndarray:
        """``2.55 * Lab`` (H, W, 3) float32: the gradient's and the variance's units (made when asked)."""
        return self.lab * np.float32(LAB_SCALE)

    # ------------------------------------------------------------- curvilinear

    def edges(self, t_canny: float) -> np.ndarray:
        """Canny edge mask (bool HxW): high threshold ``t_canny``, low ``t_canny / 2``."""
        hi = float(max(t_canny, 0.0)) * _CANNY_INT
        lo = 0.5 * hi
        if hi > _CANNY_MAX:
            # no gradient Canny reads can pass (the vector base of a quality, t_canny 1e9): nothing
            # to trace, and no gradient to make (1.5 s of a 12-megapixel photo)
            return np.zeros((self.h, self.w), bool)
        dx16, dy16 = self._gradient()[3:]
        e = cv2.Canny(dx16, dy16, lo, hi, L2gradient=True)
        return e > 0

    def curvilinear(self, t_canny: float, step: int | None = None) -> FeatureSet:
        """Curvilinear feature pairs for threshold ``t_canny`` (see module doc)."""
        step = self.step if step is None else max(1, int(step))
        ys, xs = np.nonzero(self.edges(t_canny))
        if ys.size == 0:
            return FeatureSet.empty()
        if step > 1:
            nbx = (self.w + step - 1) // step
            key = (ys // step) * nbx + xs // step
            order = np.lexsort((-self.mag[ys, xs], key))
            first = np.ones(order.size, bool)
            first[1:] = key[order][1:] != key[order][:-1]
            keep = np.sort(order[first])
            ys, xs = ys[keep], xs[keep]
        gx = self.dx[ys, xs].astype(np.float64)
        gy = self.dy[ys, xs].astype(np.float64)
        gn = np.hypot(gx, gy)
        gn[gn == 0] = 1.0
        gx /= gn
        gy /= gn
        # Sub-pixel edge position along g (parabola through -g, 0, +g).
        m0 = self.mag[ys, xs].astype(np.float64)
        mp = _bilinear(self.mag, xs + gx, ys + gy)
        mm = _bilinear(self.mag, xs - gx, ys - gy)
        den = mm - 2.0 * m0 + mp
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.where(den < -1e-9, 0.5 * (mm - mp) / den, 0.0)
        delta = np.clip(delta, -0.5, 0.5)
        ex = xs + 0.5 + delta * gx
        ey = ys + 0.5 + delta * gy

        w, h, ix = self.w, self.h, self.index
        n = ys.size
        xy = np.empty((2 * n, 2), np.float64)
        region = np.empty(2 * n, np.int32)
        lab = np.empty((2 * n, 3), np.float32)
        for k, s in enumerate((-1.0, 1.0)):
            px = np.clip(ex + 0.5 * s * gx, 0.0, float(w))
            py = np.clip(ey + 0.5 * s * gy, 0.0, float(h))
            # Pixel containing the feature, and the colour pixel one step out.
            rc = np.clip(np.floor(px).astype(np.int64), 0, w - 1)
            rr = np.clip(np.floor(py).astype(np.int64), 0, h - 1)
            qc = np.clip(np.floor(ex + s * gx).astype(np.int64), 0, w - 1)
            qr = np.clip(np.floor(ey + s * gy).astype(np.int64), 0, h - 1)
            same = ix[qr, qc] == ix[rr, rc]
            cc = np.where(same, qc, rc)
            cr = np.where(same, qr, rr)
            xy[k::2, 0] = px
            xy[k::2, 1] = py
            region[k::2] = ix[cr, cc]
            lab[k::2] = self.lab[cr, cc]
        pair = np.arange(2 * n, dtype=np.int32) ^ 1
        return FeatureSet.at_pixels(xy, region, lab, np.full(2 * n, CURVILINEAR, np.uint8), pair)

    # --------------------------------------------------------------- gradation

    def _region_pixels(self) -> tuple[np.ndarray, np.ndarray]:
        if self._order is None:
            flat = self.index.ravel()
            self._order = np.argsort(flat, kind="stable")
            self._bounds = np.concatenate(
                [[0], np.cumsum(np.bincount(flat, minlength=self.n_regions))]
            )
        return self._order, self._bounds

    def hierarchy(self) -> _Hierarchy:
        """The superpixel tree (built on first use, reused for every ``T_super``)."""
        if self._hier is None:
            self._hier = self._build_hierarchy()
        return self._hier

    def _build_hierarchy(self, max_levels: int = 16, iters: int = 3, compactness: float = 10.0) -> _Hierarchy:
        h, w = self.h, self.w
        yy, xx = np.mgrid[0:h, 0:w]
        px = (xx.ravel() + 0.5).astype(np.float32)
        py = (yy.ravel() + 0.5).astype(np.float32)
        col = self.lab.reshape(-1, 3).astype(np.float32)  # k-means in Lab units
        col255 = self.lab255.reshape(-1, 3).astype(np.float64)
        lbl = self._base_cells()
        n = int(lbl.max()) + 1 if lbl.size else 1
        labels, sizes, rmss, splits = [], [], [], []
        floor_t = 1.0  # the search never goes below T_super = 1 (see selection)
        for level in range(max_levels + 1):
            stats = cell_stats(lbl, n, col255)
            size, rms = stats["count"], stats["rms"].astype(np.float32)
            can = (size >= self.min_cell) & ((size > 2 * CELL_PIXELS) | (rms > floor_t))
            labels.append(lbl.astype(np.int32))
            sizes.append(size)
            rmss.append(rms)
            if level == max_levels or not can.any():
                splits.append(np.zeros(n, bool))
                break
            a_sel = _split4(lbl, n, can, px, py, col, iters, compactness)
            sel = can[lbl]
            # New labels: code = parent * 4 + child, compacted.
            code = lbl * 4
            code[sel] += a_sel
            used = np.bincount(code, minlength=n * 4) > 0
            remap = np.cumsum(used) - 1
            new = remap[code]
            nn = int(used.sum())
            children = np.bincount(np.nonzero(used)[0] // 4, minlength=n)
            splits.append(children >= 2)
            lbl, n = new, nn
        assert len(labels) == len(splits)
        return _Hierarchy(labels=labels, size=sizes, rms=rmss, split=splits)

    def _base_cells(self) -> np.ndarray:
        """Level 0: superpixels of ~``CELL_PIXELS`` pixels (cv2 SLIC) cut by the regions."""
        h, w = self.h, self.w
        ix = self.index.ravel().astype(np.int64)
        size = int(round(np.sqrt(CELL_PIXELS)))
        if h * w <= 2 * CELL_PIXELS or min(h, w) < 2:
            sp = np.zeros(h * w, np.int64)
        else:
            slic = cv2.ximgproc.createSuperpixelSLIC(
                np.ascontiguousarray(self.lab), cv2.ximgproc.SLIC, size, 10.0
            )
            slic.iterate(10)
            slic.enforceLabelConnectivity(25)
            sp = slic.getLabels().ravel().astype(np.int64)
        code = ix * (int(sp.max()) + 1) + sp
        _, inv = np.unique(code, return_inverse=True)
        return inv.ravel().astype(np.int64)

    def cells(self, t_super: float) -> np.ndarray:
        """Cell id per pixel (HxW int64) of the adaptive partition for ``t_super``."""
        hier = self.hierarchy()
        offs = np.cumsum([0] + [s.size for s in hier.size])
        eff = hier.labels[0].astype(np.int64)
        active = np.ones(eff.size, bool)
        for L in range(len(hier.labels) - 1):
            refine = hier.split[L] & ((hier.size[L] > 2 * CELL_PIXELS) | (hier.rms[L] > t_super))
            r = active & refine[hier.labels[L]]
            if not r.any():
                break
            eff = np.where(r, hier.labels[L + 1].astype(np.int64) + offs[L + 1], eff)
            active = r
        return eff.reshape(self.h, self.w)

    def boundary(self, t_super: float) -> np.ndarray:
        """Cell-boundary pixels (bool HxW) for ``t_super`` (see module doc)."""
        eff = self.cells(t_super)
        b = self._fixed_boundary.copy()
        b[:, :-1] |= eff[:, :-1] != eff[:, 1:]
        b[:-1, :] |= eff[:-1, :] != eff[1:, :]
        return b

    def gradation(self, t_super: float) -> FeatureSet:
        """Gradation features for threshold ``t_super``, every region covered."""
        boundary = self.boundary_features(t_super)
        return FeatureSet.concat([boundary, self.anchors(boundary)])

    def boundary_features(self, t_super: float) -> FeatureSet:
        """Gradation features on the thinned cell-boundary pixels for ``t_super`` (no anchors)."""
        b = self.boundary(t_super)
        ys, xs = np.nonzero(b)
        th = self.thin
        if th > 1:
            nbx = (self.w + th - 1) // th
            nby = (self.h + th - 1) // th
            key = (self.index[ys, xs].astype(np.int64) * nby + ys // th) * nbx + xs // th
            _, first = np.unique(key, return_index=True)
            first = np.sort(first)
            ys, xs = ys[first], xs[first]
        return FeatureSet.at_pixels(
            np.stack([xs + 0.5, ys + 0.5], axis=1).astype(np.float64),
            self.index[ys, xs].astype(np.int32),
            self.lab[ys, xs].astype(np.float32),
            np.full(ys.size, GRADATION, np.uint8),
            np.full(ys.size, -1, np.int32),
        )

    def anchors(self, fs: FeatureSet) -> FeatureSet:
        """Extra features for the regions that ``fs`` leaves without 3 non-collinear ones.

        See the module doc (the TPS affine part needs 3 non-collinear points
        per region).

        Parameters
        ----------
        fs : FeatureSet
            The features chosen so far (all kinds).

        Returns
        -------
        FeatureSet
            Gradation features at pixels of the regions in need, none at a
            position ``fs`` already has.
        """
        R = self.n_regions
        if R == 0:
            return FeatureSet.empty()
        reg = fs.region
        n, det = region_spread(reg, fs.xy, R)
        npix = np.bincount(self.index.ravel(), minlength=R)
        bad = np.nonzero((npix > 0) & ((n < 3) | (det < 1e-4)) & ~((npix <= 2) & (n >= npix)))[0]
        if bad.size == 0:
            return FeatureSet.empty()
        order, bounds = self._region_pixels()
        forder = np.argsort(reg, kind="stable")
        fbounds = np.concatenate([[0], np.cumsum(np.bincount(reg, minlength=R))])
        w = self.w
        pts: list[tuple[float, float, int, int, int]] = []  # x, y, row, col, region
        for r in bad:
            flat = order[bounds[r] : bounds[r + 1]]
            rows, cols = flat // w, flat % w
            have = {(float(a), float(b)) for a, b in fs.xy[forder[fbounds[r] : fbounds[r + 1]]]}
            if flat.size <= 2:
                cand = [(c + 0.5, rr + 0.5, rr, c) for rr, c in zip(rows, cols)]
            else:
                picks = set()
                for s in (cols, rows, cols + rows, cols - rows):
                    picks.add(int(np.argmin(s)))
                    picks.add(int(np.argmax(s)))
                picks.add(flat.size // 2)
                sel = sorted(picks)
                ax = cols[sel] + 0.5
                ay = rows[sel] + 0.5
                ddx, ddy = ax - ax.mean(), ay - ay.mean()
                dt = np.mean(ddx * ddx) * np.mean(ddy * ddy) - np.mean(ddx * ddy) ** 2
                if len(sel) >= 3 and dt > 1e-4:
                    cand = [(cols[i] + 0.5, rows[i] + 0.5, rows[i], cols[i]) for i in sel]
                else:
                    # Straight 1-px line: raster-first and -last pixels are its
                    # ends, the median one is inside; offset across the line.
                    i0, i1, im = 0, flat.size - 1, flat.size // 2
                    lx = float(cols[i1] - cols[i0])
                    ly = float(rows[i1] - rows[i0])
                    ln = np.hypot(lx, ly) or 1.0
                    nx, ny = -ly / ln, lx / ln
                    cand = [
                        (cols[i] + 0.5 + sgn * 0.25 * nx, rows[i] + 0.5 + sgn * 0.25 * ny, rows[i], cols[i])
                        for i, sgn in ((i0, -1.0), (i1, -1.0), (im, 1.0))
                    ]
            for cx, cy, rr, c in cand:
                if (float(cx), float(cy)) not in have:
                    have.add((float(cx), float(cy)))
                    pts.append((float(cx), float(cy), int(rr), int(c), int(r)))
        if not pts:
            return FeatureSet.empty()
        a = np.array(pts, np.float64)
        rr = a[:, 2].astype(np.int64)
        cc = a[:, 3].astype(np.int64)
        return FeatureSet.at_pixels(
            a[:, :2].copy(),
            a[:, 4].astype(np.int32),
            self.lab[rr, cc].astype(np.float32),
            np.full(len(pts), GRADATION, np.uint8),
            np.full(len(pts), -1, np.int32),
        )

    # ------------------------------------------------------------------ merged

    def extract(self, t_canny: float, t_super: float, dedup: float = DEDUP_PX) -> FeatureSet:
        """Curvilinear pairs + gradation features, merged and sorted by region.

        A gradation feature within ``dedup`` pixels of a curvilinear feature of
        the same region is dropped (the region-coverage anchors are kept).
        The result is stably sorted by region (curvilinear first within a
        region), pair indices remapped.
        """
        cur = self.curvilinear(t_canny)
        grad = self.boundary_features(t_super)
        anchors = self.anchors(grad)
        grad = drop_near(grad, cur, dedup, (self.w, self.h))
        allf = FeatureSet.concat([cur, grad, anchors])
        order = np.argsort(allf.region, kind="stable")
        return allf.subset(order)


# ----------------------------------------------------------------------- lattice

#: Lattice spacings (pixels) a region's gradation features may take ("tpsv" scheme).
LATTICE_PX = (4.0, 5.0, 6.0, 7.0, 8.0, 10.0, 12.0, 14.0, 16.0, 20.0, 24.0, 28.0, 32.0, 40.0, 48.0, 64.0)
#: Finer spacings only the pure vector quality ladder takes (``min_spacing``): a feature per
#: 4-12 pixels. On chelsea at colour steps 4/2 the 2 px lattice gives 34.21 dB at 2.27 bpp, the
#: 4 px one 30.70 dB at 0.90 bpp (docs/DESIGN.md, "Detail layer and rate control").
FINE_LATTICE_PX = (2.0, 2.5, 3.0, 3.5)
#: Cells holding a curvilinear feature are subdivided down to this side (pixels).
EDGE_PX = 8.0


class LatticeGradation:
    """Gradation features on a regular lattice of each region's ``(S, T)`` square.

    The ``tpsv`` scheme's reading of the adaptive superpixels of the paper
    (module doc, and docs/DESIGN.md "Compression" for the measurements that
    led here). Each region's parameter square is cut into ``nx x ny`` equal
    cells about ``d`` pixels wide (``nx = max(1, round(sx / d))`` with ``sx``
    the patch's pixel scale, ``tpsv.geometry.patch.patch_pixel_scale``); each cell
    holding a pixel of the region gives one feature at its centre with the
    mean colour of its pixels. The spacing adapts per region to ``T_super``:
    ``d`` is the largest of :data:`LATTICE_PX` at which the cells' RMS colour
    deviation (``2.55 * Lab`` units, as the superpixel variance), averaged over
    the region's pixels, is at most ``T_super`` (and, when asked, whose cells
    give the region 3 non-collinear features: else anchors pad it with more
    features than a finer lattice has); the smallest spacing when none is. A
    smaller ``T_super`` never gives a coarser lattice.

    Cells holding a curvilinear feature are cut into ``k x k`` sub-cells no
    wider than ``edge_px``, so that an edge pair is never isolated among
    distant features (a TPS through a tight pair far from anything else
    overshoots badly).

    Measured and dropped: a quadtree refined cell by cell where the cell's
    deviation (or its deviation from an affine fit, or its band-pass energy)
    exceeds ``T_super``, and the superpixel boundaries of the ``paper``
    scheme. At equal efficiency-optimal settings both gave a lower ``w`` than
    regular lattices on every sample (irregular positions cost more bytes,
    and the colour fit makes a uniform spread of features the better basis);
    one spacing for the whole image instead of one per region was within
    +-13 % (better on chelsea, worse on rocket).

    Parameters
    ----------
    lab : ndarray (H, W, 3) float32
        CIE Lab of the image.
    index : ndarray (H, W) int
        Region of every pixel (``-1``: none).
    st : ndarray (H, W, 2) float
        ``(S, T)`` of every pixel in its region's patch (as rendered at scale 1).
    patches : list of Patch
        One per region (pixel scale and feature positions).
    """

    def __init__(
        self,
        lab: np.ndarray,
        index: np.ndarray,
        st: np.ndarray,
        patches: list,
        *,
        spacings: tuple = FINE_LATTICE_PX + LATTICE_PX,
        edge_px: float = EDGE_PX,
    ) -> None:
        self.h, self.w = index.shape
        self.patches = list(patches)
        R = len(self.patches)
        self.n_regions = R
        self.edge_px = float(edge_px)
        self.scale = np.array([patch_pixel_scale(p) for p in self.patches], np.float64).reshape(R, 2)
        # Per pixel only what the lattices are made of, in the inputs' own precision (float32 from
        # the renderer's map and the Lab image; products are taken in float64, as before): the
        # cells of a spacing are recomputed when asked (:meth:`_cells`), not held.
        flat = np.asarray(index).ravel()
        keep = flat >= 0
        self.pix = None if keep.all() else np.nonzero(keep)[0]  # None: every pixel
        self.reg = (flat if self.pix is None else flat[self.pix]).astype(np.int32, copy=False)
        S = np.asarray(st)
        S = S.reshape(-1, 2) if np.issubdtype(S.dtype, np.floating) else S.astype(np.float64).reshape(-1, 2)
        S = S if self.pix is None else S[self.pix]
        # the renderer's map is finite and in [0, 1] inside the regions: then no copy
        inside = S.size == 0 or (np.isfinite(S).all() and S.min() >= 0.0 and S.max() <= 1.0)
        self.S = S if inside else np.clip(np.nan_to_num(S), 0.0, 1.0)
        col = np.asarray(lab).reshape(-1, 3)
        self.col = col if self.pix is None else col[self.pix]
        self.spacings = tuple(sorted(float(d) for d in spacings))
        # Each spacing's lattice is a pass over every pixel (a 12-megapixel photo: about a second
        # each), and the quality modes ask for one or two of the 16: made when first asked.
        self._lattices: dict[int, dict] = {}
        # No cell's RMS deviation exceeds the diagonal of the colours' bounding box: a T_super
        # above it (with a margin for rounding) passes every lattice without making one.
        span = self.col.max(axis=0).astype(np.float64) - self.col.min(axis=0) if self.col.size else np.zeros(3)
        self._rms_bound = LAB_SCALE * float(np.sqrt(np.sum(np.square(span)))) * (1.0 + 1e-6) + 1e-6

    def lattice(self, j: int) -> dict:
        """The lattice of ``spacings[j]`` (made at first use): its cells, their mean colours and
        ``region_rms`` (R,), the regions' mean RMS colour deviation of their cells."""
        if j not in self._lattices:
            self._lattices[j] = self._lattice(self.spacings[j])
        return self._lattices[j]

    def _grid(self, d: float) -> np.ndarray:
        return np.maximum(1, np.rint(self.scale / d)).astype(np.int64)  # (R, 2) cells along S, T

    def _cells(self, lat: dict, rows: np.ndarray | None = None) -> np.ndarray:
        """Cell of every pixel (or of the pixel ``rows``) in lattice ``lat``: int64, a chunk at a time."""
        n, off = lat["n"], lat["off"]
        count = self.reg.size if rows is None else rows.size
        out = np.empty(count, np.int64)
        for a in range(0, count, 1 << 16):
            at = slice(a, min(a + (1 << 16), count))
            sel = at if rows is None else rows[at]
            reg = self.reg[sel]
            nr = n[reg]
            ij = np.minimum((self.S[sel] * nr).astype(np.int64), nr - 1)
            out[at] = off[reg] + ij[:, 1] * nr[:, 0] + ij[:, 0]
        return out

    def _lattice(self, d: float) -> dict:
        R = self.n_regions
        n = self._grid(d)
        off = np.concatenate([[0], np.cumsum(n[:, 0] * n[:, 1])])
        stats = cell_stats(self._cells(dict(n=n, off=off)), int(off[-1]), self.col, LAB_SCALE**2)
        r_of = np.repeat(np.arange(R, dtype=np.int32), n[:, 0] * n[:, 1])
        w = stats["count"]
        region_rms = np.bincount(r_of, stats["rms"] * w, R) / np.maximum(np.bincount(r_of, w, R), 1.0)
        # per cell only what the features take (their colours are float32 in the end); a
        # region's lattice spans its patch's rectangle, so cells are many more than pixels / d^2
        return dict(d=d, n=n, off=off, used=w > 0, region=r_of, lab=stats["lab"].astype(np.float32),
                    region_rms=region_rms)

    def _stands(self, j: int, regions: np.ndarray) -> np.ndarray:
        """Whether each of ``regions`` gets 3 non-collinear features from its own used cells of
        lattice ``j`` (:meth:`FeatureExtractor.anchors`' rule on their pixel-space centres).

        A region that does not is given up to 9 anchors at its extreme pixels, more features
        than a finer lattice that stands gives it (quality 10 of the pure vector image then
        made larger files than quality 20). Only these regions' pixels are read.
        """
        if j in self._lattices:
            lat = self._lattices[j]
            cells = np.flatnonzero(lat["used"] & np.isin(lat["region"], regions))
        else:
            n = self._grid(self.spacings[j])
            lat = dict(n=n, off=np.concatenate([[0], np.cumsum(n[:, 0] * n[:, 1])]))
            rows = np.flatnonzero(np.isin(self.reg, regions))
            cells = np.unique(self._cells(lat, rows))
            lat["region"] = np.repeat(np.arange(self.n_regions, dtype=np.int32), n[:, 0] * n[:, 1])
        reg = lat["region"][cells].astype(np.int64)
        cnt, det = region_spread(reg, to_pixel_space(self.patches, reg, self._centres(lat, cells)), self.n_regions)
        return ((cnt >= 3) & (det >= 1e-4))[regions]

    @staticmethod
    def _centres(lat: dict, cells: np.ndarray) -> np.ndarray:
        """``(S, T)`` (k, 2) float64 of the centres of lattice ``lat``'s ``cells``."""
        r = lat["region"][cells]
        n = lat["n"][r]
        k = cells - lat["off"][r]
        return np.column_stack([(k % n[:, 0] + 0.5) / n[:, 0], (k // n[:, 0] + 0.5) / n[:, 1]])

    def region_spacing(self, t_super: float, max_spacing: np.ndarray | None = None,
                       standalone: bool = False, min_spacing: float = LATTICE_PX[0]) -> np.ndarray:
        """Index into ``spacings`` per region for ``t_super``: the coarsest lattice whose cells'
        RMS colour deviation is within ``t_super`` and, with ``standalone``, that gives the
        region 3 non-collinear features by itself (:meth:`_stands`; the finest always
        qualifies), no coarser than ``max_spacing`` (pixels per region, optional) where that is
        given and no finer than ``min_spacing`` (pixels); the finest such when none is."""
        R, t_super = self.n_regions, float(t_super)
        spacings = np.asarray(self.spacings)  # ascending
        finest = min(int(np.searchsorted(spacings, float(min_spacing) - 1e-9)), len(spacings) - 1)
        allowed = np.ones((len(spacings), R), bool)
        allowed[:finest] = False
        if max_spacing is not None:
            allowed &= spacings[:, None] <= np.asarray(max_spacing, np.float64)[None, :]
        # the coarsest allowed lattice within t_super, else the finest: from the coarsest down, a
        # lattice made only while a region still waits for it
        pick = np.full(R, finest, np.int64)
        open_ = np.ones(R, bool)
        for j in range(len(self.spacings) - 1, finest - 1, -1):
            ok = open_ & allowed[j]
            if ok.any() and t_super <= self._rms_bound:
                ok &= self.lattice(j)["region_rms"] <= t_super
            if standalone and j > finest and ok.any():
                # a lattice that needs anchors is never taken while a finer one may stand
                asked = np.flatnonzero(ok)
                ok[asked] = self._stands(j, asked)
            pick[ok] = j
            open_ &= ~ok
            if not open_.any():
                break
        return pick

    def _pixel_rows(self, pixels: np.ndarray | None) -> np.ndarray | None:
        if pixels is None or len(pixels) == 0:
            return None
        if self.pix is None:
            pixels = np.asarray(pixels, np.int64)
            return pixels[(pixels >= 0) & (pixels < self.reg.size)]
        pos = np.minimum(np.searchsorted(self.pix, pixels), self.pix.size - 1)
        return pos[self.pix[pos] == pixels]

    def features(self, t_super: float, edge_pixels: np.ndarray | None = None,
                 max_spacing: np.ndarray | None = None, standalone: bool = False,
                 min_spacing: float = LATTICE_PX[0]) -> FeatureSet:
        """Gradation features for ``t_super``; cells holding ``edge_pixels`` (flat indices) are subdivided;
        each region's spacing at most its ``max_spacing`` (pixels, optional); ``standalone`` and
        ``min_spacing``: as :meth:`region_spacing`."""
        st, reg, lab = self._regions(t_super, self._pixel_rows(edge_pixels), max_spacing, standalone, min_spacing)
        xy = to_pixel_space(self.patches, reg, st)  # for de-duplication and anchors
        n = reg.size
        return FeatureSet(
            xy=xy, region=reg.astype(np.int32), lab=lab.astype(np.float32), kind=np.full(n, GRADATION, np.uint8),
            pair=np.full(n, -1, np.int32), st=st.astype(np.float64),
        )

    def _regions(self, t_super, rows, max_spacing=None, standalone=False, min_spacing=LATTICE_PX[0]):
        pick = self.region_spacing(t_super, max_spacing, standalone, min_spacing)
        parts = []
        for j in range(len(self.spacings)):
            regs = np.nonzero(pick == j)[0]
            if regs.size == 0:
                continue
            lat = self.lattice(j)
            mine = np.isin(lat["region"], regs) & lat["used"]
            split = np.zeros(mine.size, bool)
            k = int(np.ceil(lat["d"] / self.edge_px - 1e-9))
            if rows is not None and k > 1:
                has = np.bincount(self._cells(lat, rows), minlength=mine.size) > 0
                split = mine & has
            keep = np.nonzero(mine & ~split)[0]
            parts.append((self._centres(lat, keep), lat["region"][keep], lat["lab"][keep]))
            if split.any():
                parts.append(self._subdivide(lat, np.nonzero(split)[0], k))
        return _join(parts)

    def _subdivide(self, lat, cells, k):
        """Sub-cells (k x k) of the given cells of a lattice, from their pixels."""
        sel = np.nonzero(np.isin(self._cells(lat), cells))[0]
        reg = self.reg[sel].astype(np.int64)
        n = lat["n"][reg] * k
        ij = np.minimum((self.S[sel] * n).astype(np.int64), n - 1)
        key = (reg * (int(n[:, 1].max()) + 1) + ij[:, 1]) * (int(n[:, 0].max()) + 1) + ij[:, 0]
        u, first, inv = np.unique(key, return_index=True, return_inverse=True)
        stats = cell_stats(inv.ravel(), u.size, self.col[sel], LAB_SCALE**2)
        r = reg[first]
        nn = n[first].astype(np.float64)
        st = np.column_stack([(ij[first, 0] + 0.5) / nn[:, 0], (ij[first, 1] + 0.5) / nn[:, 1]])
        return st, r, stats["lab"]


def region_spread(region: np.ndarray, xy: np.ndarray, n_regions: int) -> tuple[np.ndarray, np.ndarray]:
    """Per region, how many points ``xy`` (k, 2) it has and the determinant of their covariance (0:
    collinear): :meth:`FeatureExtractor.anchors` asks 3 points and a determinant of ``1e-4`` of a region.

    Returns
    -------
    count, det : ndarray (n_regions,) float64
    """
    R = n_regions
    n = np.bincount(region, minlength=R).astype(np.float64)
    safe = np.maximum(n, 1.0)
    x, y = xy[:, 0], xy[:, 1]
    mx = np.bincount(region, x, R) / safe
    my = np.bincount(region, y, R) / safe
    dx, dy = x - mx[region], y - my[region]
    cxx = np.bincount(region, dx * dx, R) / safe
    cyy = np.bincount(region, dy * dy, R) / safe
    cxy = np.bincount(region, dx * dy, R) / safe
    return n, cxx * cyy - cxy * cxy


def cell_stats(cell: np.ndarray, n: int, col: np.ndarray, var_scale: float = 1.0) -> dict:
    """Pixel count, mean colour and RMS colour deviation per cell id ``0..n-1``.

    Parameters
    ----------
    cell : ndarray (P,) int
        Cell id of every pixel.
    n : int
        Number of cells.
    col : ndarray (P, 3) float
        Colour of every pixel (float32 is taken in float64, one channel at a time).
    var_scale : float
        Factor of the variance (``LAB_SCALE ** 2`` turns Lab colours into the
        ``2.55 * Lab`` units of ``T_super``).

    Returns
    -------
    dict
        ``count`` (n,), ``lab`` (n, 3) mean colour (``col``'s units), ``rms``
        (n,) ``sqrt(var_scale * trace(cov))``; all float64, 0 for empty cells.
    """
    cnt = np.bincount(cell, minlength=n).astype(np.float64)
    safe = np.maximum(cnt, 1.0)
    lab = np.zeros((n, 3))
    var = np.zeros(n)
    for c in range(3):
        v = col[:, c].astype(np.float64)
        m = np.bincount(cell, v, n) / safe
        lab[:, c] = m
        var += (np.bincount(cell, np.square(v, out=v), n) / safe - m * m) * var_scale
    return dict(count=cnt, lab=lab, rms=np.sqrt(np.maximum(var, 0.0)))


def _join(parts):
    if not parts:
        return np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 3))
    return (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]).astype(np.int64),
            np.concatenate([p[2] for p in parts]))


# ----------------------------------------------------------------- plain functions


def curvilinear_features(
    rgb: np.ndarray, index: np.ndarray | None, t_canny: float, step: int = 1, blur_sigma: float = 0.0
) -> FeatureSet:
    """Curvilinear feature pairs in pixel coordinates (see module doc).

    Parameters
    ----------
    rgb : ndarray (H, W, 3) float32 in [0, 1]
    index : ndarray (H, W) int32
        Region index per pixel.
    t_canny : float
        Canny high threshold on the Sobel magnitude of ``2.55 * Lab`` (the
        scale of ``cv2.Canny`` on 8-bit images); the low one is half of it.
    step : int
        Keep the strongest edge pixel per ``step x step`` block (1: all).
    """
    return FeatureExtractor(rgb, index, blur_sigma=blur_sigma, step=step).curvilinear(t_canny)


def gradation_features(
    rgb: np.ndarray, index: np.ndarray | None, t_super: float, thin: int = 2
) -> FeatureSet:
    """Gradation features from adaptive superpixels (see module doc).

    Parameters
    ----------
    t_super : float
        Cell colour-deviation threshold (RMS of ``2.55 * Lab`` about the cell
        mean): cells above it are split further.
    """
    return FeatureExtractor(rgb, index, thin=thin).gradation(t_super)


def extract_features(
    rgb: np.ndarray, index: np.ndarray | None, t_canny: float, t_super: float
) -> FeatureSet:
    """Both kinds, merged, de-duplicated and sorted by region.

    For repeated calls on one image use :class:`FeatureExtractor`.
    """
    return FeatureExtractor(rgb, index).extract(t_canny, t_super)
