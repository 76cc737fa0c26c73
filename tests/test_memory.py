"""Peak memory of the encoder (issue 12): per-pixel work in bands, stages that free what they are done with."""

import tracemalloc

import cv2
import numpy as np
import pytest

from tpsv import metrics, threads
from tpsv.color import srgb_to_lab
from tpsv.encode import detail
from tpsv.encode.features import lab_gradient
from tpsv.encode.rate import encode_quality
from tpsv.geometry.bands import lab_image, row_bands
from tpsv.model import DETAIL_GAIN, DETAIL_YCC, DETAIL_ZERO

#: Bound on the peak of numpy's traced allocations of ``encode_quality`` per input pixel. Measured
#: 184 B/px on the 256 x 256 photo below (437 B/px before issue 12: float64 copies of the whole image
#: in the segmentation and the features, every lattice's cell map held at once).
PEAK_BYTES_PER_PIXEL = 250


def photo(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A synthetic photo: gradients, a disc, a darker corner and a little noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    img = np.stack([0.2 + 0.6 * x, 0.3 + 0.4 * y, 0.5 + 0.3 * np.sin(6 * x * y)], -1)
    img[(x - 0.35) ** 2 + (y - 0.4) ** 2 < 0.05] = [0.85, 0.25, 0.2]
    img[(x > 0.6) & (y > 0.55)] *= 0.4
    img += rng.normal(0, 0.02, img.shape)
    return np.clip(img, 0, 1).astype(np.float32)


def test_encode_quality_peak_per_pixel():
    encode_quality(photo(32, 32))  # Warp's kernels and lazy imports are loaded once, not per image
    rgb = photo(256, 256)
    tracemalloc.start()
    try:
        result = encode_quality(rgb)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert result.psnr > 30
    per_pixel = peak / (256 * 256)
    assert per_pixel < PEAK_BYTES_PER_PIXEL, f"peak {per_pixel:.0f} bytes per pixel"


def test_the_fit_design_is_built_within_twice_its_size(monkeypatch):
    """The colour fit's design matrix (``fit.build_design``) of a dense 256 x 256 model: the build's
    peak (numpy's traced allocations, one host thread so that the temporaries of concurrent
    batches do not vary) is less than twice what it keeps. It was 3.7 times: per-entry index and
    frame arrays of all points at once, the cardinal matrices in float64 beside their float32
    copy, and batches of 2 000 000 entries x slots."""
    from tpsv import tps
    from tpsv.encode import fit
    from tpsv.rendering.magnify import dense_model

    monkeypatch.setattr(threads, "host_cores", lambda: 1)  # the fit on one host thread
    rgb = photo(256, 256)
    model, _ = dense_model(rgb)
    ks = tps.group_kernels(model)
    target = fit.fit_target(rgb, *fit.pixel_maps(model), 1)
    tracemalloc.start()
    try:
        design, nnz = fit.build_design(ks, target.region, target.st)
        held, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert nnz > 30 * 256 * 256  # dense: every pixel in a few kernels of 32 features
    assert held >= sum(b.data.nbytes for b in design.blocks)
    assert peak < 2 * held, f"peak {peak / held:.2f} times the design"


def traced_fits(model, target, budgets) -> tuple[list, list]:
    """Peaks of numpy's traced allocations and ``(colours, report)`` of fits with each ``group_pixels``."""
    from tpsv.encode import fit

    peaks, fits = [], []
    for most in budgets:
        tracemalloc.start()
        try:
            fitted, report = fit.fit_colors(model, target=target, group_pixels=most)
            peaks.append(tracemalloc.get_traced_memory()[1])
        finally:
            tracemalloc.stop()
        fits.append((fitted.features.lab, report))
    return peaks, fits


def test_the_fit_in_groups_of_regions_holds_less_and_fits_alike(monkeypatch):
    """A dense model of four regions fitted a group of regions at a time (``group_pixels``): the fit's
    peak (numpy's traced allocations, one host thread) falls with the largest group (measured 39 ->
    24 MB; the table of every kernel's cardinal matrix, 10 MB here, is allocated whole, though only
    the group's rows are written), and the colours are the one-group fit's to float rounding (the
    groups sum a pixel's kernels in another order)."""
    from tpsv.encode import fit
    from tpsv.rendering.magnify import dense_model

    monkeypatch.setattr(threads, "host_cores", lambda: 1)  # the fit on one host thread
    rgb = photo(192, 192)
    labels = np.zeros((192, 192), np.int32)
    labels[:, 96:] = 1
    labels[96:] += 2
    model, _ = dense_model(rgb, labels)
    target = fit.fit_target(rgb, *fit.pixel_maps(model), 1)
    peaks, fits = traced_fits(model, target, (fit.GROUP_PIXELS, 96 * 96))
    (one, r1), (four, r4) = fits
    assert peaks[1] < 0.7 * peaks[0], peaks
    assert np.abs(one.astype(np.float64) - four).max() < 0.01
    assert r4.iterations == r1.iterations and r4.nnz == r1.nnz
    assert abs(r4.mse - r1.mse) < 1e-6 * r1.mse
    # a picture past GROUP_PIXELS keeps no whole target: each group's is made from the image when fitted,
    # the same values
    index, st = fit.pixel_maps(model)
    source = fit.TargetSource(rgb, index, st, 1)
    assert np.array_equal(source.region, target.region)
    part = source.part([1, 2])
    both = np.isin(target.region, [1, 2])
    assert all(np.array_equal(getattr(part, f), getattr(target, f)[both]) for f in ("rows", "region", "st", "lab", "W"))
    again, r = fit.fit_colors(model, target=source, group_pixels=96 * 96)
    assert np.array_equal(again.features.lab, four) and r.mse == r4.mse


def test_a_region_past_the_budget_is_fitted_in_strips_that_hold_less_and_fit_alike(monkeypatch):
    """One region of a dense model fitted in strips of its kernel columns (``group_pixels`` below its
    pixels): the fit's peak (numpy's traced allocations, one host thread) falls with the strip (a
    margin of kernel columns each side fitted and dropped; measured 41 -> 28 MB, the table of every
    kernel's cardinal matrix allocated whole), and the colours are the whole region's
    fit's but for the conjugate gradients' step lengths, which are the strip's own."""
    from tpsv import tps
    from tpsv.encode import fit
    from tpsv.rendering.magnify import dense_model

    monkeypatch.setattr(threads, "host_cores", lambda: 1)  # the fit on one host thread
    rgb = photo(192, 192)
    model, _ = dense_model(rgb)
    ks = tps.group_kernels(model)
    index, st = fit.pixel_maps(model)
    target = fit.fit_target(rgb, index, st, 1)
    most = 192 * 192 // 4
    strips = fit.region_strips(ks, 0, target.st, most)
    assert len(strips) >= 4
    peaks, fits = traced_fits(model, target, (fit.GROUP_PIXELS, most))
    (whole, r1), (cut, r2) = fits
    assert peaks[1] < 0.75 * peaks[0], peaks
    diff = np.abs(whole.astype(np.float64) - cut)
    assert diff.mean() < 0.05 and diff.max() < 3.0, (diff.mean(), diff.max())  # measured 0.018, 1.36 (Lab)
    assert abs(r2.mse - r1.mse) < 0.25 * r1.mse
    # from a TargetSource (each strip's pixels made from the image when fitted): the same colours
    again, _ = fit.fit_colors(model, target=fit.TargetSource(rgb, index, st, 1), group_pixels=most)
    assert np.array_equal(again.features.lab, cut)


def test_region_strips_partition_the_region():
    """Strips' cores cut the region's kernel columns into consecutive runs; each feature of the region is
    kept by exactly one strip and fitted by it; a strip's window holds the pixels its wide columns'
    kernels cover (their cells and the overlap)."""
    from tpsv import tps
    from tpsv.encode import fit
    from tpsv.rendering.magnify import dense_model

    rgb = photo(160, 96)
    model, _ = dense_model(rgb)
    ks = tps.group_kernels(model)
    target = fit.fit_target(rgb, *fit.pixel_maps(model), 1)
    strips = fit.region_strips(ks, 0, target.st, target.rows.size // 3, margin=2)
    gx, gy, _ = ks.grid[0]
    assert strips and all(s.axis == (0 if gx >= gy else 1) for s in strips)
    assert strips[0].core_columns[0] == 0 and strips[-1].core_columns[1] == strips[0].n
    assert all(a.core_columns[1] == b.core_columns[0] for a, b in zip(strips, strips[1:]))
    freg = np.asarray(model.features.region)
    kept = np.zeros(len(freg), int)
    for s in strips:
        keep, free = s.features(ks, freg)
        assert not (keep & ~free).any()
        kept += keep
        e0, e1 = s.wide_columns
        assert e0 == max(s.core_columns[0] - 2, 0) and e1 == min(s.core_columns[1] + 2, s.n)
        cover = s.window.holds(target.st)
        v = target.st[:, s.axis].astype(np.float64) * s.n
        assert cover[(v >= e0 - ks.overlap + 1e-6) & (v < e1 + ks.overlap - 1e-6)].all()
    assert (kept == 1).all()
    assert fit.region_strips(ks, 0, target.st, 10 * target.rows.size) == []


def test_region_groups():
    from tpsv.encode.fit import region_groups

    groups = region_groups(np.array([5, 0, 3, 9, 2, 2, 0]), 8)
    assert [g.tolist() for g in groups] == [[0, 2], [3], [4, 5]]  # 9 > 8 pixels: a group alone
    assert [g.tolist() for g in region_groups(np.array([5, 0, 3]), 100)] == [[0, 2]]
    assert [g.tolist() for g in region_groups(np.zeros(3, np.int64), 8)] == [[]]


def test_row_bands_cover_the_rows():
    for h, w, px in ((7, 3, 5), (100, 1000, 1), (1, 1, 1 << 16), (300, 17, 1 << 10)):
        bands = list(row_bands(h, w, px))
        assert bands[0][0] == 0 and bands[-1][1] == h
        assert all(a < b for a, b in bands) and all(b == a2 for (_, b), (a2, _) in zip(bands, bands[1:]))


def sobel_max(img: np.ndarray) -> tuple:
    """The gradient of :func:`tpsv.encode.features.lab_gradient` worked out on the whole image at once."""
    gx = cv2.Sobel(img, cv2.CV_32F, 1, 0, ksize=3, borderType=cv2.BORDER_REPLICATE)
    gy = cv2.Sobel(img, cv2.CV_32F, 0, 1, ksize=3, borderType=cv2.BORDER_REPLICATE)
    m2 = gx * gx + gy * gy
    ch = np.argmax(m2, axis=-1)[..., None]
    return (np.take_along_axis(gx, ch, -1)[..., 0], np.take_along_axis(gy, ch, -1)[..., 0],
            np.sqrt(np.take_along_axis(m2, ch, -1)[..., 0]))


@pytest.mark.parametrize("shape", [(1, 5), (2, 3), (3, 4), (301, 257)])
def test_banded_lab_and_gradient_equal_whole_image(shape):
    rng = np.random.default_rng(1)
    rgb = rng.random(shape + (3,)).astype(np.float32)
    assert np.array_equal(lab_image(rgb), srgb_to_lab(rgb))
    assert np.array_equal(lab_image(rgb * 1.4 - 0.2, clip=True), srgb_to_lab(np.clip(rgb * 1.4 - 0.2, 0, 1)))
    lab = srgb_to_lab(rgb)
    want = sobel_max(lab * np.float32(2.55))
    for got in (lab_gradient(lab, scale=2.55), lab_gradient(lab * np.float32(2.55))):
        for g, w in zip(got, want):
            assert np.array_equal(g, w)


def test_mse_and_texels_equal_whole_image():
    rng = np.random.default_rng(2)
    a = rng.random((400, 300, 3)).astype(np.float32) * 1.2 - 0.1
    b = rng.random((400, 300, 3))
    qa = np.round(np.clip(a.astype(np.float64), 0, 1) * 255.0) / 255.0
    qb = np.round(np.clip(b, 0, 1) * 255.0) / 255.0
    assert metrics.mse(a, b) == pytest.approx(float(np.mean((qa - qb) ** 2)), rel=1e-12)
    # bands summed on the host's threads: exact, so the same on any number of them
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(threads, "host_cores", lambda: 1)
        one = metrics.mse(a, b)
    assert metrics.mse(a, b) == one
    u = (rng.random((40, 30, 3)) * 255).astype(np.uint8)
    assert metrics.mse(u, u.astype(np.float32) / 255) == 0.0
    rendered = rng.random((400, 300, 3)).astype(np.float32)
    res = (a.astype(np.float64) - rendered.astype(np.float64)) @ DETAIL_YCC.T
    texels = np.clip(np.rint(DETAIL_ZERO + DETAIL_GAIN * res), 0, 1023).astype(np.uint16)
    assert np.array_equal(detail.residual_texels(a, rendered), texels)
    ycc = (texels.astype(np.float64) - DETAIL_ZERO) / DETAIL_GAIN
    assert np.array_equal(detail.texel_rgb(texels), (ycc @ np.linalg.inv(DETAIL_YCC).T).astype(np.float32))
    assert np.array_equal(detail.with_texels(rendered, texels),
                          np.clip(rendered + detail.texel_rgb(texels), 0.0, 1.0))
