"""Quality and size figures: PSNR, SSIM, bpp and the paper's efficiency w = 1 / (E * C)."""

from __future__ import annotations

import numpy as np

from .threads import map_ordered


def _as_float(img: np.ndarray) -> np.ndarray:
    img = np.asarray(img)
    if img.dtype == np.uint8:
        return img.astype(np.float64) / 255.0
    return img.astype(np.float64)


#: Values per band of :func:`mse` (its float64 temporaries are of a band, not of the image).
MSE_BAND = 1 << 18


def _levels(img: np.ndarray) -> np.ndarray:
    """8-bit levels ``round(255 clip(x, 0, 1))`` of an image, as float64 (uint8: its values)."""
    if img.dtype == np.uint8:
        return img.astype(np.float64)
    return np.round(np.clip(img.astype(np.float64), 0, 1) * 255.0)


def mse(a: np.ndarray, b: np.ndarray) -> float:
    """Mean squared error of RGB in ``[0, 1]`` over the whole image (the paper's E).

    Both images are quantised to 8 bits first, as a saved PNG would be. The
    squared level differences are summed exactly (whole numbers in float64),
    band by band of rows on the host's threads, so no float64 copy of the
    image is made.
    """
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        raise ValueError(f"shape mismatch {a.shape} vs {b.shape}")
    if a.size == 0:
        return float("nan")
    rows = max(1, MSE_BAND // max(a[:1].size, 1)) if a.ndim else 1
    a2, b2 = (a, b) if a.ndim else (a.reshape(1), b.reshape(1))

    def band(r: int) -> float:
        d = (_levels(a2[r:r + rows]) - _levels(b2[r:r + rows])).ravel()
        return float(np.dot(d, d))

    # whole numbers below 2^53: exact in any order, so the bands go to the host's threads
    total = sum(map_ordered("mse", band, range(0, a2.shape[0], rows)))
    return total / (255.0 * 255.0 * a.size)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR in dB of 8-bit RGB over the whole image (inf for identical images)."""
    return psnr_of_mse(mse(a, b))


def psnr_of_mse(err: float) -> float:
    """PSNR in dB of a mean squared error of values in ``[0, 1]`` (inf for 0)."""
    return float("inf") if err == 0 else float(10.0 * np.log10(1.0 / err))


def ssim(a: np.ndarray, b: np.ndarray) -> float:
    """Mean SSIM over the RGB channels (scikit-image, data range 1)."""
    from skimage.metrics import structural_similarity

    return float(structural_similarity(_as_float(a), _as_float(b), channel_axis=2, data_range=1.0))


def bpp(nbytes: int, width: int, height: int) -> float:
    """Bits per pixel of a file of ``nbytes`` for a ``width x height`` image."""
    return 8.0 * nbytes / (width * height)


def efficiency(err: float, nbytes: int, width: int, height: int) -> float:
    """The paper's w = 1 / (E * C), with C = file bytes / (W * H * 3)."""
    c = nbytes / (width * height * 3.0)
    return float("inf") if err == 0 else 1.0 / (err * c)


#: GMSD's stability constant for intensities in [0, 255] (Xue et al. 2014).
GMSD_C = 170.0


def _gmsd_luma(img: np.ndarray) -> np.ndarray:
    """Grey level in [0, 255]: 0.299 R + 0.587 G + 0.114 B of sRGB (a 2-D input is taken as grey)."""
    x = _as_float(img) * 255.0
    if x.ndim == 3:
        x = x[..., 0] * 0.299 + x[..., 1] * 0.587 + x[..., 2] * 0.114
    elif x.ndim != 2:
        raise ValueError(f"expected an (H, W) or (H, W, 3) image, got shape {x.shape}")
    return x


def _gmsd_gradient_magnitude(y: np.ndarray) -> np.ndarray:
    """2x2 average + downsample by 2, then Prewitt (/3) gradient magnitude, zero
    padding at the borders (MATLAB ``conv2(..., 'same')`` of the reference code)."""
    p = np.pad(y, ((0, 1), (0, 1)))
    ave = (p[:-1, :-1] + p[1:, :-1] + p[:-1, 1:] + p[1:, 1:]) / 4.0
    d = np.pad(ave[::2, ::2], 1)
    # Prewitt: the column (row) of three on one side minus the other side, / 3
    cols = d[:-2] + d[1:-1] + d[2:]
    rows = d[:, :-2] + d[:, 1:-1] + d[:, 2:]
    gx = (cols[:, :-2] - cols[:, 2:]) / 3.0
    gy = (rows[:-2] - rows[2:]) / 3.0
    return np.hypot(gx, gy)


def gmsd(a: np.ndarray, b: np.ndarray, c: float = GMSD_C) -> float:
    """Gradient magnitude similarity deviation of two images (0 = identical; lower is better).

    Follows Xue, Zhang, Mou and Bovik, "Gradient Magnitude Similarity
    Deviation: A Highly Efficient Perceptual Image Quality Index", IEEE Trans.
    Image Processing 23(2), 2014, and its reference implementation: the grey
    level Y = 0.299 R + 0.587 G + 0.114 B in [0, 255] is filtered by a 2x2
    average and downsampled by 2; Prewitt gradients (the 3x3 kernels divided
    by 3, zero padding) give magnitudes m1, m2; the similarity map is
    GMS = (2 m1 m2 + c) / (m1^2 + m2^2 + c) and GMSD is its standard deviation
    (the paper's 1/N form; the reference code's ``std2`` divides by N - 1).

    Parameters
    ----------
    a, b : ndarray (H, W, 3) or (H, W)
        Images of one shape: uint8, or float in [0, 1] (not clipped).
    c : float
        Stability constant for intensities in [0, 255] (the paper's T = 170).

    Returns
    -------
    float
        GMSD; symmetric in ``a`` and ``b``.

    Raises
    ------
    ValueError
        The shapes differ or are not images.
    """
    ya, yb = _gmsd_luma(a), _gmsd_luma(b)
    if ya.shape != yb.shape:
        raise ValueError(f"shape mismatch {np.shape(a)} vs {np.shape(b)}")
    m1, m2 = _gmsd_gradient_magnitude(ya), _gmsd_gradient_magnitude(yb)
    gms = (2.0 * m1 * m2 + c) / (m1 * m1 + m2 * m2 + c)
    return float(np.std(gms))
