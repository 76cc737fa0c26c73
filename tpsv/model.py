"""The hybrid vector image: plain dataclasses of numpy arrays.

Coordinates
-----------
Pixel space is continuous: the pixel in row ``r`` and column ``c`` covers
``[c, c+1] x [r, r+1]`` and its centre is ``(x, y) = (c + 0.5, r + 0.5)``.
Rendering at scale ``k`` samples output pixel ``(X, Y)`` at
``((X + 0.5) / k, (Y + 0.5) / k)`` in this space, so outlines, control points
and features never need rescaling.

Each region's Hermite patch has ``M x N`` control points. The patch parameter
``s`` runs over ``[0, M-1]`` and ``t`` over ``[0, N-1]``; cell ``(floor(s),
floor(t))`` is one bicubic Hermite sub-patch. Features are stored in the
normalised parameters ``S = s / (M-1)`` and ``T = t / (N-1)``, both in
``[0, 1]``, so they ride along when the patch is deformed.

Colours are CIE Lab (D65): ``L`` in ``[0, 100]``, ``a`` and ``b`` in
``[-128, 127]``.

TPS kernels (sub-patch grouping, packing, coefficients) are not part of the
model: they are derived from it at load time.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

#: Feature kinds.
GRADATION = 0
CURVILINEAR = 1

#: Detail modes of a region (``Detail.mode``).
DETAIL_OFF = 0
DETAIL_FULL = 1
DETAIL_LUMA = 2
#: Texel value of a zero residual, and texel steps per unit of sRGB (2 per 8-bit level).
DETAIL_ZERO = 512
DETAIL_GAIN = 510.0
#: sRGB residual -> (Y, Cb, Cr) residual of the detail texture (ITU-R BT.601, full range).
DETAIL_YCC = np.array([[0.299, 0.587, 0.114], [-0.168736, -0.331264, 0.5], [0.5, -0.418688, -0.081312]])


@dataclass
class Patch:
    """A bicubic Hermite patch.

    Attributes
    ----------
    ctrl : ndarray, shape (M, N, 4, 2), float64
        Control vectors per control point ``(i, j)`` (``i`` along ``s``, ``j``
        along ``t``), in pixel coordinates: ``[..., 0, :]`` position,
        ``[..., 1, :]`` derivative along ``s``, ``[..., 2, :]`` derivative along
        ``t``, ``[..., 3, :]`` twist (mixed ``st`` derivative). ``M, N >= 2``.
    """

    ctrl: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """``(M, N)``: control points along ``s`` and along ``t``."""
        return int(self.ctrl.shape[0]), int(self.ctrl.shape[1])


@dataclass
class Region:
    """One connected object region.

    Attributes
    ----------
    label : int
        The label-map value the region came from (several regions may share a
        label when it was not connected).
    outline : list of ndarray, each shape (k, 2), float64
        Closed polygons in pixel coordinates (the last vertex is not repeated).
        The first is the outer boundary, counter-clockwise in image
        coordinates; the others are holes. Membership at any output size is
        rasterised from these, never from a label raster.
    patch : Patch
        The region's Hermite patch; its surface covers every pixel of the
        region.
    transparent : bool
        The region is a hole in the picture (the fully transparent part of an
        RGBA input): it renders with alpha 0, and a border with it is the
        other region's anti-aliased edge in the alpha channel.
    """

    label: int
    outline: list[np.ndarray]
    patch: Patch
    transparent: bool = False


@dataclass
class Features:
    """Colour features of all regions, sorted by region.

    Attributes
    ----------
    region : ndarray, shape (F,), int32
        Index into ``Model.regions``.
    st : ndarray, shape (F, 2), float64
        Normalised patch parameters ``(S, T)`` in ``[0, 1]``.
    lab : ndarray, shape (F, 3), float32
        CIE Lab colour.
    kind : ndarray, shape (F,), uint8
        ``GRADATION`` (0) or ``CURVILINEAR`` (1).
    pair : ndarray, shape (F,), int32
        Index of the other half of a curvilinear pair (which may lie in another
        region), or -1.
    """

    region: np.ndarray
    st: np.ndarray
    lab: np.ndarray
    kind: np.ndarray
    pair: np.ndarray

    #: dtype and per-feature shape of every array (a subclass adding arrays extends it).
    _COLUMNS: ClassVar[dict] = {
        "region": (np.int32, ()),
        "st": (np.float64, (2,)),
        "lab": (np.float32, (3,)),
        "kind": (np.uint8, ()),
        "pair": (np.int32, ()),
    }

    def __len__(self) -> int:
        return int(self.region.shape[0])

    @classmethod
    def empty(cls):
        """No features."""
        return cls(**{name: np.zeros((0,) + shape, dtype) for name, (dtype, shape) in cls._COLUMNS.items()})

    @classmethod
    def _cast(cls, pick) -> dict:
        """Every array except ``pair`` (whose indices need remapping): ``pick(name)`` cast to its dtype."""
        return {name: pick(name).astype(dtype) for name, (dtype, _) in cls._COLUMNS.items() if name != "pair"}

    def subset(self, index: np.ndarray):
        """Features at ``index`` (bool mask or integer array, in that order), pairs remapped.

        A pair whose partner is dropped becomes -1.
        """
        idx = np.arange(len(self))[index]
        remap = np.full(len(self) + 1, -1, np.int32)
        remap[idx] = np.arange(idx.size, dtype=np.int32)
        pair = self.pair[idx]
        pair = np.where(pair >= 0, remap[pair], -1).astype(np.int32)
        return type(self)(**self._cast(lambda name: getattr(self, name)[idx]), pair=pair)

    @classmethod
    def concat(cls, parts: list):
        """The features of ``parts`` one after the other, later parts' pair indices shifted.

        Parameters
        ----------
        parts : list of Features (of this class)

        Returns
        -------
        Features
            Not sorted by region.
        """
        parts = [p for p in parts if len(p)]
        if not parts:
            return cls.empty()
        pairs, off = [], 0
        for p in parts:
            pairs.append(np.where(p.pair >= 0, p.pair + off, -1))
            off += len(p)
        columns = cls._cast(lambda name: np.concatenate([getattr(p, name) for p in parts]))
        return cls(**columns, pair=np.concatenate(pairs).astype(np.int32))


@dataclass
class Params:
    """Parameters a model was made with (stored in the file).

    The defaults are the default feature scheme's, ``"tpsv"``: a ``Params()``
    has no ``extra["scheme"]`` and ``tpsv.encode.vectorize.scheme_of`` reads
    it as ``"tpsv"``. ``tpsv.encode.vectorize.scheme_params("paper")`` derives
    the paper's plain scheme (K = 64, ``overlap = 0.5``, the finest
    quantisation) from them.

    Attributes
    ----------
    t_canny : float
        Canny high threshold on the Sobel gradient magnitude of 2.55 * Lab
        (the scale of ``cv2.Canny`` on 8-bit images; low = high / 2).
    t_super : float
        Superpixel threshold on a cell's RMS colour deviation,
        sqrt(trace of the Lab covariance) in 2.55 * Lab units (0-255 scale).
    kernel_size : int
        Features per TPS kernel after packing (K).
    overlap : float
        Extension of each sub-patch beyond its cell, as a fraction of the cell
        size on each side (0 < overlap <= 0.5).
    smoothing : float
        TPS smoothing term lambda added to the kernel diagonal (0: exact
        interpolation).
    st_steps : int
        Precision of the stored feature positions: about ``1 / st_steps`` px
        across a patch as wide as the image (``docs/FORMAT.md``, S and T).
    l_step, ab_step : int
        Quantisation steps of the stored colours: ``L`` in units of
        ``l_step * 100 / 255``, ``a`` and ``b`` in units of ``ab_step``
        (1, 1: the finest the format stores).
    extra : dict
        Free key-value pairs (bool, int, float, str), stored as they are.
        ``extra["scheme"] = "paper"`` marks a model made with the paper's
        plain scheme (``tpsv.encode.vectorize``).
    """

    t_canny: float = 40.0
    t_super: float = 40.0
    kernel_size: int = 32
    overlap: float = 0.25
    smoothing: float = 0.0
    st_steps: int = 2
    l_step: int = 8
    ab_step: int = 8
    extra: dict = field(default_factory=dict)


@dataclass(eq=False)
class Detail:
    """The texture detail layer: what the vector image misses, per region in its ``(S, T)``.

    The residual (photo minus vector render, sRGB, turned into Y, Cb, Cr so
    that a recoloured region can keep just its luma) is one 10-bit texture,
    ``texels``, laid out as the picture was when it was vectorised: a region
    finds its texels through its rest frame, the affine map ``(S, T) ->
    origin + S * ds + T * dt`` (texture pixels, centres at half-integers),
    which is its patch at vectorisation time. The texels therefore follow
    ``(S, T)``: they move with ``deform`` (which changes the patch, not the
    frame), and ``crossmap`` gives a region another region's frame.
    docs/FORMAT.md ("Detail") and docs/DESIGN.md ("Detail layer").

    Attributes
    ----------
    payload : tuple of bytes
        The texture as stored, kept so that writing the model again gives
        the same bytes: one monochrome 10-bit AVIF file of the three planes
        Y, Cb, Cr one below the other (``w x 3h``), or the planes one by one,
        each in bands of rows, an AVIF file a band
        (``tpsv.codec.detail.plane_bands``; one ``bytes`` object is taken as
        the single file).
    texels : ndarray, shape (h, w, 3), uint16
        Decoded texture, (Y, Cb, Cr) of the residual, each
        ``(texel - DETAIL_ZERO) / DETAIL_GAIN`` (:data:`DETAIL_YCC`).
    frame : ndarray, shape (R, 3, 2), float64
        Per region: origin, ``d/dS`` and ``d/dT`` of its texture position.
    mode : ndarray, shape (R,), uint8
        Per region: :data:`DETAIL_OFF`, :data:`DETAIL_FULL` or
        :data:`DETAIL_LUMA` (only the residual's Y: a recoloured region
        keeps its texture, not the old colours).
    quality : int
        The quality the texture was coded at (1-100; informative).
    """

    payload: tuple
    texels: np.ndarray
    frame: np.ndarray
    mode: np.ndarray
    quality: int = 0

    def __eq__(self, other) -> bool:
        if not isinstance(other, Detail):
            return NotImplemented
        return (self.payload == other.payload and self.quality == other.quality
                and np.array_equal(self.texels, other.texels) and np.array_equal(self.frame, other.frame)
                and np.array_equal(self.mode, other.mode))


@dataclass
class BlurMap:
    """Edge width along region borders point by point, where it changes along a border.

    A border between two regions may be a sharp edge in one stretch and cross a
    flat area in the next (a label map cuts a region in two there); one width
    per pair of regions cannot suit both. ``sigma[i, j]`` is the edge width
    (source px) at the centre ``((j + 0.5) cell, (i + 0.5) cell)`` of cell
    ``(i, j)``, and a border point's width is the bilinear sample of ``sigma``
    there (the grid's edges clamped): continuous along every border, the same
    for both regions of a shared one. Only cells a border passes through are
    stored (docs/FORMAT.md); the cells within two of them hold their
    neighbours' means, the rest 0 (``geometry.edgewidth.fill_map``).

    Attributes
    ----------
    cell : int
        Cell side, source px.
    sigma : ndarray, shape (gh, gw), float32
        ``ceil(height / cell) x ceil(width / cell)``.
    """

    cell: int
    sigma: np.ndarray

    def __eq__(self, other) -> bool:
        if not isinstance(other, BlurMap):
            return NotImplemented
        return self.cell == other.cell and np.array_equal(self.sigma, other.sigma)


@dataclass
class Model:
    """A hybrid vector image.

    Attributes
    ----------
    width, height : int
        Size in pixels of the image the model was made from.
    regions : list of Region
    features : Features
    params : Params
    encoding : dict
        Owned by ``tpsv.codec``: how the file this model was decoded from was
        quantised where the format leaves a choice (``st_bits``), so that
        encoding the model again gives the same file. Empty for a new model;
        not part of the image (ignored by ``==``).
    blur : ndarray, shape (n, 3), float64
        Edge width of region borders: rows ``(a, b, sigma)``, regions ``a < b``
        sorted, ``sigma`` the standard deviation (source px) of the Gaussian
        that blurs the step between them (a defocused edge stays soft at any
        scale). Borders not listed are sharp.
    detail : Detail or None
        The texture detail layer (None: the pure vector image).
    blur_map : BlurMap or None
        Edge width point by point along the borders; where there is one it
        replaces ``blur`` in the renderer (``blur`` still lists a width per
        pair; ``deform`` carries the map's widths along with the borders it
        moves).
    curves : bool
        Outlines are drawn as smooth curves through their vertices
        (``tpsv.geometry.curves``: centripetal Catmull-Rom, broken at corners,
        junctions and the frame); otherwise as polygons.
    """

    width: int
    height: int
    regions: list[Region]
    features: Features
    params: Params = field(default_factory=Params)
    encoding: dict = field(default_factory=dict, compare=False, repr=False)
    blur: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)), repr=False)
    detail: Detail | None = field(default=None, repr=False)
    curves: bool = False
    blur_map: BlurMap | None = field(default=None, repr=False)
