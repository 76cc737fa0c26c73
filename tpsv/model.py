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

import numpy as np

#: Feature kinds.
GRADATION = 0
CURVILINEAR = 1


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
    """

    label: int
    outline: list[np.ndarray]
    patch: Patch


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

    def __len__(self) -> int:
        return int(self.region.shape[0])

    @classmethod
    def empty(cls) -> "Features":
        return cls(
            region=np.zeros(0, np.int32),
            st=np.zeros((0, 2), np.float64),
            lab=np.zeros((0, 3), np.float32),
            kind=np.zeros(0, np.uint8),
            pair=np.zeros(0, np.int32),
        )

    def subset(self, index: np.ndarray) -> "Features":
        """Features at ``index`` (bool mask or integer array), pairs remapped.

        A pair whose partner is dropped becomes -1.
        """
        idx = np.arange(len(self))[index]
        remap = np.full(len(self) + 1, -1, np.int32)
        remap[idx] = np.arange(idx.size, dtype=np.int32)
        pair = self.pair[idx]
        pair = np.where(pair >= 0, remap[pair], -1).astype(np.int32)
        return Features(
            region=self.region[idx].astype(np.int32),
            st=self.st[idx].astype(np.float64),
            lab=self.lab[idx].astype(np.float32),
            kind=self.kind[idx].astype(np.uint8),
            pair=pair,
        )


@dataclass
class Params:
    """Parameters a model was made with (stored in the file).

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
    kernel_size: int = 64
    overlap: float = 0.5
    smoothing: float = 0.0
    st_steps: int = 16
    l_step: int = 1
    ab_step: int = 1
    extra: dict = field(default_factory=dict)


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
    """

    width: int
    height: int
    regions: list[Region]
    features: Features
    params: Params = field(default_factory=Params)
