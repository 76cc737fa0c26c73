"""Anti-aliased border coverage on a Warp device (tpsv.gpu.coverage) against the host's (tpsv.rendering.borders)."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from tpsv.geometry.regions import build_regions
from tpsv.gpu import pieces as gpieces
from tpsv.gpu.coverage import APART_CELL, MAX_CELLS, DeviceBorders, border_mix
from tpsv.gpu.pieces import DevicePieces, apart_host, one_of_each
from tpsv.model import Features, Model, Params
from tpsv.rendering import borders as hborders
from tpsv.rendering.borders import BorderMix, Borders, outline_pieces
from tpsv.rendering.pixelmap import region_index


def blob_model(w=48, h=36, n=6, seed=0, blur=None) -> Model:
    """Regions traced from smooth random blobs (curved borders, junctions of three); ``blur``: sigma of each pair."""
    rng = np.random.default_rng(seed)
    noise = cv2.GaussianBlur(rng.random((h, w, n)).astype(np.float32), (0, 0), 4.0)
    labels = np.argmax(noise.reshape(h, w, n), axis=-1)
    regions, _ = build_regions(labels)
    F = len(regions) * 4
    lab = rng.random((F, 3)) * (100, 60, 60) - (0, 30, 30)
    features = Features(np.repeat(np.arange(len(regions)), 4).astype(np.int32), rng.random((F, 2)),
                        lab.astype(np.float32), np.zeros(F, np.uint8), np.full(F, -1, np.int32))
    m = Model(w, h, regions, features, Params(kernel_size=8))
    if blur is not None:
        # every pair of regions that touch, some sharp, the others of widths up to ``blur``
        idx = region_index(m, w, h)
        pairs = set()
        for a, b in ((idx[:, :-1], idx[:, 1:]), (idx[:-1], idx[1:])):
            d = a != b
            pairs |= {(min(p, q), max(p, q)) for p, q in zip(a[d].tolist(), b[d].tolist())}
        rows = [[p, q, blur * rng.uniform(0.3, 1.0)] for p, q in sorted(pairs) if rng.random() < 0.8]
        m.blur = np.array(rows, np.float64).reshape(-1, 3)
    return m


def exact_host(monkeypatch):
    """Make the host measure each pixel to its nearest border piece, not the nearest of a few."""
    monkeypatch.setattr(Borders, "exact", True)
    feet = Borders._feet
    monkeypatch.setattr(Borders, "_feet", lambda self, p, k: feet(self, p, max(k, 64)))


def tied(borders, pixels, W: int, index: np.ndarray, excl: np.ndarray | None = None) -> np.ndarray:
    """Whether each pixel's centre is equally near two pieces with different feet (either may give the region across).

    The pieces that count are those the rule measures to (``Borders._nearest_border``:
    with another region just beyond, or within 0.75 px of a pixel beside another region; within
    the region's limit; else all). With ``excl`` (a region per pixel), those of the second border:
    with another region than the pixel's and ``excl`` just beyond.
    """
    p = np.column_stack([pixels % W + 0.5, pixels // W + 0.5])
    w = p[:, None, :] - borders.a[None]
    t = np.clip((w * borders.d).sum(-1) / np.maximum((borders.d ** 2).sum(-1), 1e-300), 0.0, 1.0)
    foot = borders.a[None] + t[..., None] * borders.d[None]
    dist = np.hypot(*np.moveaxis(p[:, None, :] - foot, -1, 0))
    mine = index.reshape(-1)[pixels]
    ext = np.pad(index, ((0, 0), (1, 1)), mode="edge")
    r = Borders._beyond(ext, 0, p[:, None, :], foot, dist, 0)
    within = dist < borders.limit[mine][:, None]
    if excl is None:
        pad = np.pad(index, 1, mode="edge")
        y, x = pixels // W, pixels % W
        beside = np.zeros(len(pixels), bool)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                nb = pad[1 + y + dy, 1 + x + dx]
                beside |= (nb != mine) & (nb >= 0)
        ok = (((dist <= 0.75) & beside[:, None]) | ((r != mine[:, None]) & (r >= 0))) & within
    else:
        ok = (r != mine[:, None]) & (r != excl[:, None]) & (r >= 0) & within
    dist = np.where(ok.any(axis=1, keepdims=True), np.where(ok, dist, np.inf), dist)
    near = dist <= dist.min(axis=1, keepdims=True) + 1e-12
    spread = [np.ptp(f[k], axis=0).max() if k.sum() > 1 else 0.0 for f, k in zip(foot, near)]
    return np.array(spread) > 1e-9


def differences(host, dev, borders=None, index=None) -> dict:
    """How two border mixes differ: pixels in one only, and, over the pixels in both, the regions across
    (``other``: either differs) and the shares (``alpha``: the larger difference of the two) and xy.

    With ``borders``, pixels whose centre is as near two outlines (:func:`tied`; either
    gives the region across, and its direction the shares) count as ``ties``, not as differences.
    """
    assert np.all(np.diff(dev.pixels) > 0), "device pixels are not in increasing order"
    o = np.argsort(host.pixels)
    hp, ho, hxy = host.pixels[o], host.other[o], host.xy[o]
    common, ih, jd = np.intersect1d(hp, dev.pixels, return_indices=True)
    one = np.setxor1d(hp, dev.pixels)
    same = ho[ih] == dev.other[jd]
    same2 = host.other2[o][ih] == dev.other2[jd]
    da = np.maximum(np.abs(host.alpha[o][ih] - dev.alpha[jd]), np.abs(host.alpha2[o][ih] - dev.alpha2[jd]))
    tie_one = tie_other = np.zeros(0, bool)
    excused = np.zeros(len(common), bool)
    if borders is not None:
        W = index.shape[1]
        tie_one, tie_other = tied(borders, one, W, index), tied(borders, common[~same], W, index)
        odd = np.flatnonzero(same & (~same2 | (da > 1e-6)))
        excused[odd] = tied(borders, common[odd], W, index) | tied(borders, common[odd], W, index, ho[ih][odd])
    differ2 = same & ~same2 & ~excused
    da = da[same & same2 & ~excused]
    return {
        "n": len(np.union1d(hp, dev.pixels)),
        "one_side": int(len(one) - tie_one.sum()),
        "other": int((~same).sum() - tie_other.sum() + differ2.sum()),
        "ties": int(tie_one.sum() + tie_other.sum() + excused.sum()),
        "alpha": float(da.max(initial=0.0)),
        "alpha_over": int((da > 1e-4).sum()),
        "xy": float(np.abs(hxy[ih] - dev.xy[jd]).max(initial=0.0)),
    }


CASES = [(seed, blur, scale) for seed, blur in ((0, None), (1, 0.6), (2, 1.2)) for scale in (1.0, 3.7, 8.0)]


@pytest.mark.parametrize("seed, blur, scale", CASES)
def test_equals_the_host_measuring_to_the_nearest_piece(seed, blur, scale, monkeypatch):
    """With the host's distance the true one, the two agree on every pixel."""
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    idx = region_index(m, W, H)
    exact_host(monkeypatch)
    b = Borders(m, W, H)
    host = b.mix(idx)
    dev = DeviceBorders(m, W, H).mix(idx)
    assert len(host.pixels) > 0
    diff = differences(host, dev, b, idx)
    assert diff["one_side"] == 0 and diff["other"] == 0, diff
    # (a second border's share depends on the angle to the first, which the device may round with FMA)
    assert diff["alpha"] <= 1e-5 and diff["xy"] <= 1e-9, diff
    assert blur is None or (host.other2 >= 0).any()


@pytest.mark.parametrize("seed, blur, scale", [(1, 0.6, 3.7), (2, 1.2, 8.0)])
def test_the_host_as_it_is_differs_only_where_its_nearest_piece_is_not(seed, blur, scale):
    """The host measures pixels off the 8-neighbours to the nearest border of 4 pieces: a few come out too far.

    (Compared where neither has a second border: its share turns on the direction to the first,
    which a piece a little too far changes more.)
    """
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    idx = region_index(m, W, H)
    b = Borders(m, W, H)
    host = b.mix(idx)
    dev = DeviceBorders(m, W, H).mix(idx)
    two = np.union1d(host.pixels[host.other2 >= 0], dev.pixels[dev.other2 >= 0])
    host, dev = (BorderMix(*(v[~np.isin(mix.pixels, two)] for v in (mix.pixels, mix.other, mix.alpha, mix.xy)))
                 for mix in (host, dev))
    diff = differences(host, dev, b, idx)
    assert diff["one_side"] + diff["other"] <= 0.002 * diff["n"], diff
    assert diff["alpha_over"] <= 0.01 * diff["n"] and diff["alpha"] < 0.05, diff
    assert diff["xy"] <= 1e-9, diff


def test_sharp_borders_equal_the_host_as_it_is():
    """Sharp borders mix only 8-neighbours of another region, measured to 8 pieces: the host finds the nearest."""
    for seed, scale in ((3, 1.0), (4, 5.3)):
        m = blob_model(seed=seed)
        W, H = round(m.width * scale), round(m.height * scale)
        idx = region_index(m, W, H)
        b = Borders(m, W, H)
        diff = differences(b.mix(idx), DeviceBorders(m, W, H).mix(idx), b, idx)
        assert diff["one_side"] == 0 and diff["other"] == 0 and diff["alpha"] <= 1e-6, diff


@pytest.mark.parametrize("blur", [None, 1.2])
def test_bands_are_the_frame(blur):
    """A band's border pixels are the frame's: with host halo rows (as ``_bands`` has them) or rows of a frame map."""
    from tpsv.gpu import warp

    wp = warp()
    m = blob_model(seed=5, blur=blur)
    W, H = round(m.width * 4.0), round(m.height * 4.0)
    idx = region_index(m, W, H)
    db = DeviceBorders(m, W, H)
    frame = db.mix(idx)
    frame_d = wp.array(idx, dtype=wp.int32)
    hr = db.halo
    got = []
    for y0 in range(0, H, 37):
        y1 = min(y0 + 37, H)
        halo = (idx[max(0, y0 - hr):y0] if y0 > 0 else None, idx[y1:min(H, y1 + hr)] if y1 < H else None)
        band = db.mix(idx[y0:y1], y0, halo)
        # the same band as a row range of the frame's map on the device
        rows = db.mix_device(frame_d, 0, band=(y0, y1)).numpy()
        for f in ("pixels", "other", "alpha", "xy", "other2", "alpha2"):
            assert np.array_equal(getattr(band, f), getattr(rows, f)), f
        got.append((band.pixels + y0 * W, band.other, band.alpha, band.xy, band.other2, band.alpha2))
    for f, v in zip(("pixels", "other", "alpha", "xy", "other2", "alpha2"), zip(*got)):
        assert np.array_equal(np.concatenate(v), getattr(frame, f)), f
    assert blur is None or (frame.other2 >= 0).any()


def test_pixels_of_no_region_and_threads(monkeypatch, every_band):
    """Pixels of no region (-1) never mix nor are mixed into; any split over host threads gives the same result."""
    m = blob_model(seed=6, blur=0.8)
    W, H = round(m.width * 3.0), round(m.height * 3.0)
    idx = region_index(m, W, H)
    idx[20:50, 30:70] = -1
    idx[:, :3] = -1
    exact_host(monkeypatch)
    b = Borders(m, W, H)
    host = b.mix(idx)
    db = DeviceBorders(m, W, H)
    one, two = db.mix(idx, threads=1), db.mix(idx, threads=2)
    for f in ("pixels", "other", "alpha", "xy"):
        assert np.array_equal(getattr(one, f), getattr(two, f))
    diff = differences(host, one, b, idx)
    assert diff["one_side"] == 0 and diff["other"] == 0 and diff["alpha"] <= 1e-6, diff
    assert (idx.reshape(-1)[one.pixels] >= 0).all() and (one.other >= 0).all()


def test_device_result_and_no_borders():
    """The device-side result downloads to the host one; a model of one region has no border pixels."""
    from tpsv.gpu import warp

    wp = warp()
    m = blob_model(seed=7, blur=0.5)
    W, H = 90, 70
    idx = region_index(m, W, H)
    db = DeviceBorders(m, W, H)
    d = db.mix_device(wp.array(idx, dtype=wp.int32))
    assert isinstance(d.pixels, wp.array) and d.xy.dtype == wp.vec2d and d.n == len(db.mix(idx).pixels)
    assert np.array_equal(d.numpy().alpha, border_mix(m, idx).alpha)
    assert np.array_equal(d.numpy().pixels, border_mix(m, wp.array(idx, dtype=wp.int32)).pixels)
    one = blob_model(n=1)
    assert len(one.regions) == 1
    idx1 = region_index(one, 50, 40)
    assert DeviceBorders(one, 50, 40).mix(idx1).pixels.size == 0
    assert db.mix_device(wp.array(idx, dtype=wp.int32), 0, band=(10, 10)).n == 0
    with pytest.raises(ValueError):
        db.mix_device(wp.array(idx, dtype=wp.int32), 0, band=(10, 80))


def test_outlines_folded_over_a_small_canvas_go_to_the_host_search():
    # a long zig-zag hole in a 12x10 canvas: thousands of outline pieces per output pixel
    m = blob_model(w=12, h=10, n=2, seed=3)
    zig = np.array([[2.0 + 8.0 * (i % 2), 2.0 + 6.0 * i / 3999] for i in range(4000)])
    m.regions[0].outline = [m.regions[0].outline[0], np.vstack([zig, zig[::-1][1:-1] + [0.01, 0.0]])]
    W, H = 12, 10
    db = DeviceBorders(m, W, H)
    assert db.n_pieces > 16 * W * H and db.grid is None
    index = region_index(m, W, H)
    host = Borders(m, W, H).mix(index)
    dev = db.mix(index)
    assert np.array_equal(host.pixels, dev.pixels) and np.array_equal(host.other, dev.other)
    assert np.array_equal(host.alpha, dev.alpha)
    # bands through the same path
    top = db.mix(index[:5], 0, (None, index[5:]))
    low = db.mix(index[5:], 5, (index[:5], None))
    assert np.array_equal(np.concatenate([top.pixels, low.pixels + 5 * W]), host.pixels)


# --------------------------------------------------------------------------- the preparation on the device


def host_grid(m, W, H, cell, gw, gh):
    """The pieces, grid and distance bound as the host prepared them: one copy of each, sorted by cell (stably)."""
    a, d = one_of_each(*outline_pieces(m, W, H))
    mid = a + 0.5 * d
    c = (np.clip(np.floor(mid[:, 1] / cell), 0, gh - 1).astype(np.int64) * gw
         + np.clip(np.floor(mid[:, 0] / cell), 0, gw - 1).astype(np.int64))
    order = np.argsort(c, kind="stable")
    start = np.concatenate([[0], np.cumsum(np.bincount(c, minlength=gw * gh))]).astype(np.int32)
    return a[order], d[order], start


@pytest.mark.parametrize("seed, blur, scale", CASES)
def test_pieces_and_grid_are_the_hosts(seed, blur, scale):
    """The device cuts the host's pieces to the bit, in its order, and sorts one copy of each as the host did."""
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    a, d = outline_pieces(m, W, H)
    p = DevicePieces(m, W, H, "cpu")
    assert p.n == len(a) and not p.host_counted
    assert np.array_equal(p.a.numpy(), a) and np.array_equal(p.d.numpy(), d)
    db = DeviceBorders(m, W, H)
    g = db.grid
    ha, hd, hstart = host_grid(m, W, H, g.cell, g.gw, g.gh)
    ga, gd = db.pieces()
    start = g.start.numpy()
    assert np.array_equal(ga, ha) and np.array_equal(gd, hd) and np.array_equal(start, hstart)
    # shared borders kept once
    assert db.n_pieces == len(ha) < len(a)
    # each cell's run of pieces has its midpoints in that cell
    mid = ga + 0.5 * gd
    cells = np.repeat(np.arange(g.gw * g.gh), np.diff(start))
    assert np.array_equal(np.clip(np.floor(mid[:, 0] / g.cell), 0, g.gw - 1), cells % g.gw)
    assert np.array_equal(np.clip(np.floor(mid[:, 1] / g.cell), 0, g.gh - 1), cells // g.gw)
    assert g.slack >= 0.5 * np.hypot(*hd.T).max()


@pytest.mark.parametrize("W, host_counted", [(37, True), (185, False)])
def test_lengths_near_whole_pixels_are_counted_by_the_host(W, host_counted):
    """An edge (6, 8) long at scale 3.7 is 37.00000000000001 px (38 pieces): the host counts it, to be sure."""
    m = blob_model(w=10, h=10, n=2, seed=3)
    m.regions[0].outline = [m.regions[0].outline[0], np.array([[1.0, 1.0], [7.0, 9.0], [1.0, 9.0]])]
    p = DevicePieces(m, W, W, "cpu")
    a, d = outline_pieces(m, W, W)
    # (at scale 18.5 the length is exactly 185: no doubt)
    assert p.host_counted == host_counted
    assert np.array_equal(p.a.numpy(), a) and np.array_equal(p.d.numpy(), d)


def test_more_than_max_pieces_makes_longer_ones(monkeypatch):
    """Past MAX_PIECES the host's step (from numpy's sum of lengths) cuts the outlines, as the host does."""
    monkeypatch.setattr(gpieces, "MAX_PIECES", 300)
    monkeypatch.setattr(hborders, "MAX_PIECES", 300)
    m = blob_model(seed=1, blur=0.6)
    W, H = round(m.width * 3.7), round(m.height * 3.7)
    a, d = outline_pieces(m, W, H)
    assert 300 < len(a) < 600 and np.hypot(*d.T).max() > 1.5
    p = DevicePieces(m, W, H, "cpu")
    assert p.host_counted and np.array_equal(p.a.numpy(), a) and np.array_equal(p.d.numpy(), d)
    db = DeviceBorders(m, W, H)
    g = db.grid
    ga, gd = db.pieces()
    ha, hd, hstart = host_grid(m, W, H, g.cell, g.gw, g.gh)
    assert np.array_equal(ga, ha) and np.array_equal(gd, hd) and np.array_equal(g.start.numpy(), hstart)


@pytest.mark.parametrize("seed, blur, scale", [(1, 0.6, 1.0), (2, 1.2, 3.7), (6, 0.8, 8.0)])
def test_distance_bound_is_the_hosts_up_to_the_reach(seed, blur, scale):
    """The device's distance transform is OpenCV's (to float32 rounding) below the reach, a lower bound above."""
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    db = DeviceBorders(m, W, H)
    g = db.grid
    assert g.blurred
    a, d = db.pieces()
    acell, aw, ah, ref = apart_host(a + 0.5 * d, g.slack, W, H, MAX_CELLS, APART_CELL)
    assert (acell, aw) == (g.acell, g.aw)
    got = g.apart.numpy().reshape(ah, aw).astype(np.float64)
    tol = 1e-6 * np.maximum(ref, 1.0)
    near = ref < db.reach_px
    assert near.mean() > 0.1 and np.all(np.abs(got - ref)[near] <= tol[near])
    assert np.all(got <= ref + tol) and np.all(got >= np.minimum(ref, db.reach_px) - tol)


@pytest.mark.parametrize("seed, blur, scale", [(0, None, 3.7), (2, 1.2, 1.0), (6, 0.8, 8.0)])
def test_mix_is_the_one_of_the_host_prepared_grid(seed, blur, scale):
    """Borders mixed over the device's grid are those mixed over the grid the host prepared, bit for bit."""
    from tpsv.gpu import warp

    wp = warp()
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    idx = region_index(m, W, H)
    db = DeviceBorders(m, W, H)
    g = db.grid
    dev = db.mix(idx)
    # the same object over the host's pieces, cells and (blurred) distance bound
    a, d, start = host_grid(m, W, H, g.cell, g.gw, g.gh)
    g.a, g.d, g.start = (wp.array(v, dtype=t) for v, t in ((a, wp.vec2d), (d, wp.vec2d), (start, wp.int32)))
    if g.blurred:
        g.apart = wp.array(apart_host(a + 0.5 * d, g.slack, W, H, MAX_CELLS, APART_CELL)[3].ravel(), dtype=wp.float32)
    host = db.mix(idx)
    assert len(dev.pixels) > 100
    for f in ("pixels", "other", "alpha", "xy"):
        assert np.array_equal(getattr(dev, f), getattr(host, f)), f


@pytest.mark.parametrize("seed, blur, scale", [(1, 0.6, 1.0), (2, 1.2, 8.0)])
def test_region_limits_are_where_coverage_reaches_one(seed, blur, scale):
    """Each region's limit is past where its widest border's coverage reaches 1 - 1e-4, by at most a pixel,
    within the reach."""
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    db = DeviceBorders(m, W, H)
    g = db.grid
    keys, sigma = g.keys.numpy(), g.sigma.numpy()
    widest = np.zeros(g.n_regions)
    np.maximum.at(widest, keys // g.n_regions, sigma)
    np.maximum.at(widest, keys % g.n_regions, sigma)
    limit = g.limit.numpy()
    assert np.all(limit <= db.reach_px) and (widest > 0).any()
    inside = limit < db.reach_px
    assert np.all(Borders._coverage(limit - 1e-6, widest)[inside] >= 1.0 - 1e-4)
    assert np.all(Borders._coverage(limit - 1.0, widest)[inside] < 1.0 - 1e-4)
    assert np.all(g.limit2.numpy() <= limit)


@pytest.mark.parametrize("seed, blur, scale", [(1, 0.6, 1.0), (2, 1.2, 3.7), (6, 0.8, 8.0)])
def test_distance_bound_by_window_is_meijsters(seed, blur, scale, monkeypatch):
    """A GPU's bound a thread a cell (gpu.pieces._window) is the row pass's, value for value (both kernels
    launched here on the CPU device)."""
    m = blob_model(seed=seed, blur=blur)
    W, H = round(m.width * scale), round(m.height * scale)
    cell = 4
    gw, gh = -(-W // cell), -(-H // cell)
    pieces = DevicePieces(m, W, H, "cpu")
    ga, gd, start = pieces.grid(cell, gw, gh)
    reach = 0.5 + 3.0 * blur * scale
    args = (ga, gd, start, 0.5 * pieces.longest, reach, W, H, MAX_CELLS, APART_CELL, "cpu")
    rows = gpieces.apart(*args, window=False)[3].numpy()
    monkeypatch.setattr(gpieces, "WINDOW", 1 << 30)  # (the window whatever the reach)
    window = gpieces.apart(*args, window=True)[3].numpy()
    assert np.array_equal(window, rows) and (rows < reach).mean() > 0.05


def test_a_nearer_distance_bound_changes_no_pixel(monkeypatch):
    """Outlines dense beside the bound's grid get exact distances over fewer cells: still a lower bound, same mix."""
    m = blob_model(seed=2, blur=1.2)
    W, H = round(m.width * 3.7), round(m.height * 3.7)
    idx = region_index(m, W, H)
    full = DeviceBorders(m, W, H)
    monkeypatch.setattr(gpieces, "FAR", 2)
    near = DeviceBorders(m, W, H)
    a, d = near.pieces()
    ref = apart_host(a + 0.5 * d, near.grid.slack, W, H, MAX_CELLS, APART_CELL)[3].ravel()
    got = near.grid.apart.numpy()
    # (capped a few cells out, short of the reach)
    assert got.max() < near.reach_px <= full.grid.apart.numpy().max() and np.all(got <= ref + 1e-5)
    one, two = full.mix(idx), near.mix(idx)
    for f in ("pixels", "other", "alpha", "xy"):
        assert np.array_equal(getattr(one, f), getattr(two, f)), f
