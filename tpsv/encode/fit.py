"""Least-squares feature colours (the render is linear in them).

A render at scale 1 is, per Lab channel, ``img(x) = sum_k beta_k(x) f_k(x)``
where ``f_k`` is kernel ``k``'s TPS through its features' colours and
``beta_k`` the blend weights (``tpsv.tps.blend``). A TPS is linear in the values it
interpolates: ``f_k(x) = b_k(x)^T Z_k h_k`` with ``b_k(x) = [phi(|x - p_i|)
..., 1, u, v]`` in the kernel's local frame and ``Z_k = M_k^{-1} [I; 0]`` the
first ``K`` columns of the inverse of the kernel's symmetric system of Eq. (4)
(its cardinal functions). So the whole render is ``img = A h`` with a sparse
``A`` (pixels x features) and the colours ``h`` can be *fitted* to the image
instead of sampled from it.

What is minimised (one Gauss-Newton step on the sRGB error)
-----------------------------------------------------------
The error the user sees is in 8-bit sRGB while the model is in Lab, so the
residual of pixel ``x`` is linearised at the image colour: ``J_x (A_x h -
lab_x)`` with ``J_x`` the 3 x 3 Jacobian of Lab -> sRGB at ``lab_x``
(:func:`tpsv.color.lab_to_srgb_jacobian`, analytic). The fit minimises ``sum_x |J_x
(A_x h - lab_x)|^2 + mu |h - h0|^2`` (``h0`` the starting colours; the small
``mu`` keeps features that no pixel sees where they are) by conjugate
gradients with a Jacobi preconditioner, started at ``h0``. The result is
clipped to the Lab ranges the file stores.

Region separation: pixels come from the renderer's own maps at scale 1
(outline rasterisation and the Warp inverse patch map), and each pixel is
fitted through the kernels of its own region only, so ``A`` never links a
pixel to another region's features and the normal matrix is block diagonal
by region. The conjugate gradients run per region (step lengths per region),
so a feature's fitted colour depends on its own region's pixels only, bit for
bit, however few iterations run. Degenerate kernels (affine fallback) are
linear in ``h`` too and are fitted the same way.

The range clamp of the rasteriser (``clamp=True``) is not linear; the fit
ignores it. Measured on the samples: at the settings the search chooses the
fitted model renders within 0.1 dB with and without the clamp (fitted edge
colours spread each kernel's range, so the clamp cuts little); on sparse
lattices with many edge pairs the clamp still helps by up to 0.6 dB, so it
stays on.

Iterations: from cell-mean colours 3 iterations reach within 0.1 dB of 30
(within 0.25 dB with many edge pairs, which converge slower); colours sampled
at single pixels need more.

Cost: ``A`` holds ``K`` numbers per (pixel, covering kernel): about
``(1 + 2 overlap)^2 K`` per pixel, built kernel by kernel as dense blocks
(batched over kernels of similar pixel counts, a few host threads) with the
kernels' cardinal matrices from one batched solve. A :class:`FitTarget` may
hold every ``sub``-th pixel per axis only (the search fits on every second:
4 times cheaper, within 0.1-1 dB of the full fit, least good with dense edge
pairs); beyond :data:`MAX_NNZ` stored numbers the pixels are subsampled so.
The design (4-byte numbers) is the fit's largest array, 285 bytes per pixel
of a `--no-detail` model on 2 px lattices; its build adds a few bytes per
entry and one batch of kernels per thread, and the conjugate gradients a few
arrays of a colour per pixel. On a pixel lattice of 2 (the detail layer's
base, the search) the fit is a quarter of that. Fitting on every pixel
cannot be made cheaper by subsampling: on every second pixel the 2 px
lattices of `--no-detail` qualities 85-100 lose 2.5-3.3 dB. Past
:data:`GROUP_PIXELS` fitted pixels the design is built and solved a group
of regions at a time (:func:`region_groups`: the normal matrix is block
diagonal by region, so each group's conjugate gradients are the whole fit's
for its regions, to the rounding of the order in which a pixel's kernels
are summed), and its target is made from the image when the group is
fitted (:class:`TargetSource`, :func:`target_for_fit`); the peak then
follows the largest group, not the picture. A region of more fitted pixels
than that is fitted in strips of its kernel grid's columns
(:func:`region_strips`), one after another: each moves its own features and
those of a margin of :data:`STRIP_MARGIN` columns each side, from the
pixels their kernels cover, and keeps its own. The strips' conjugate
gradients take their own step lengths, so the colours are not the whole
region's to rounding, but as good: at `--no-detail --quality 95` in strips
of 30 000 pixels chelsea renders at 34.0036 dB against 34.0048 whole (31855
bytes against 31826), rocket at 31.9864 against 31.9890 (28269 against
28278). Margins of 1, 2, 3 and 5 columns gave the same PSNR to 0.003 dB;
the margins' pixels are fitted twice, so they are kept narrow.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from .. import tps
from ..color import lab_to_srgb_jacobian, srgb_to_lab
from ..rendering.pixelmap import pixel_map
from ..threads import map_ordered

#: Largest number of stored coefficients of ``A`` (float32); beyond, pixels are subsampled.
MAX_NNZ = 40_000_000
#: Fitted pixels of one group of regions: the design is built and solved a group at a time, so the
#: fit's peak follows the largest group (its design and conjugate gradients hold about 400 bytes a
#: fitted pixel), not the whole picture. A region of more pixels is fitted in strips (:func:`region_strips`).
GROUP_PIXELS = 1 << 20
#: Kernel columns on each side of a strip of a region past :data:`GROUP_PIXELS` whose features are
#: fitted with the strip's own and then dropped: they let the strip's border features reach the values
#: the whole region's fit would give them (see :func:`region_strips`).
STRIP_MARGIN = 1


@dataclass
class FitReport:
    """How a fit went."""

    iterations: int
    seconds: float
    nnz: int
    residual0: float
    residual: float
    subsample: int
    mse: float = float("nan")
    kernels: object = None  # the tps.KernelSet the fit used (positions as the model's)


# --------------------------------------------------------------------------- helpers


def pixel_maps(model, device: str = "cpu") -> tuple[np.ndarray, np.ndarray]:
    """The pixel maps at scale 1, as rendered (:func:`tpsv.rendering.pixelmap.pixel_map`, draw order included).

    Parameters
    ----------
    model : Model
    device : str
        Warp device for the inverse patch map.

    Returns
    -------
    index : ndarray (H, W) int32
        Region of every pixel.
    st : ndarray (H, W, 2) float32
        ``(S, T)`` of every pixel in its region's patch.
    """
    pm = pixel_map(model, device=device)
    return pm.index, pm.st


@dataclass
class FitTarget:
    """What a fit compares with: the image at a lattice of pixels (computed once per image).

    Attributes
    ----------
    rows : ndarray (n,) int64
        Flat pixel indices fitted (every ``sub``-th pixel in x and y, inside a region).
    region : ndarray (n,) int32
    st : ndarray (n, 2) float32
        ``(S, T)`` of each pixel in its region's patch (the pixel map's own float32 values).
    lab : ndarray (n, 3) float32
        Image colour (Lab, as :func:`tpsv.color.srgb_to_lab` gives it; the fit reads both in float64).
    W : ndarray (n, 3, 3) float64
        ``J^T J`` with ``J`` the Jacobian of Lab -> sRGB at the image colour.
    sub : int
    """

    rows: np.ndarray
    region: np.ndarray
    st: np.ndarray
    lab: np.ndarray
    W: np.ndarray
    sub: int


def _fitted(index: np.ndarray, sub: int, skip=None, regions=None, window=None, st=None
            ) -> tuple[np.ndarray, np.ndarray]:
    """Flat index and region of every fitted pixel: every ``sub``-th one in a region, less ``skip``
    (and, with ``regions``, in one of those; with ``window``, an :class:`Window`, inside it by
    ``st``, the pixel map of (S, T))."""
    h, w = index.shape
    ys, xs = np.mgrid[0:h:sub, 0:w:sub]
    rows = (ys * w + xs).ravel()
    del ys, xs
    reg = np.asarray(index).ravel()[rows]
    keep = reg >= 0
    if skip is not None and len(skip):
        keep &= ~np.isin(rows, np.asarray(skip))
    if regions is not None:
        keep &= np.isin(reg, regions)
    rows, reg = rows[keep], reg[keep]
    if window is not None:
        inside = window.holds(np.asarray(st).reshape(-1, 2)[rows])
        rows, reg = rows[inside], reg[inside]
    return rows, reg


def fit_target(rgb: np.ndarray, index: np.ndarray, st: np.ndarray, sub: int = 1, skip=None,
               replace=None, regions=None, window=None) -> FitTarget:
    """A :class:`FitTarget` from the image and the pixel maps at scale 1 (``pixel_maps``).

    ``skip``: flat pixel indices left out of the fit. ``replace``: ``(pixels,
    colours)``, flat indices and the sRGB colours fitted there instead of the
    image's. Both are for the pixels a border crosses, whose colour the
    renderer mixes from both sides (``tpsv.rendering.borders``): fitted to the
    image there, a region's TPS would reach for its neighbour's colour and
    bleed it into its own fill; left out, nothing holds the TPS up to its
    outline, and a magnified render shows whatever it does there.
    ``regions``: only the pixels of these regions, and with ``window`` (a
    strip of a region's (S, T) square) only those inside it (each pixel's
    values are the same as in the whole target).
    """
    rgb = np.asarray(rgb)
    if rgb.dtype == np.uint8:
        rgb = rgb.astype(np.float32) / 255.0
    rows, reg = _fitted(index, sub, skip, regions, window, st)
    colours = np.asarray(rgb, np.float32)[..., :3].reshape(-1, 3)[rows]
    if replace is not None and len(replace[0]):
        at = np.searchsorted(rows, np.asarray(replace[0]))
        ok = at < len(rows)
        ok[ok] = rows[at[ok]] == np.asarray(replace[0])[ok]
        colours[at[ok]] = np.asarray(replace[1], np.float32)[ok]
    lab = srgb_to_lab(colours[None])[0]
    J = lab_to_srgb_jacobian(lab.astype(np.float64))
    W = np.einsum("nij,nik->njk", J, J)
    # (Lab and (S, T) kept in float32, as they come: the fit's float64 arithmetic reads the same values)
    return FitTarget(
        rows=rows, region=reg.astype(np.int32), st=np.asarray(st, np.float32).reshape(-1, 2)[rows],
        lab=np.asarray(lab, np.float32), W=W, sub=int(sub),
    )


@dataclass
class TargetSource:
    """The :class:`FitTarget` of a picture past :data:`GROUP_PIXELS` fitted pixels, made a group of
    regions at a time by :func:`fit_colors` (so the whole target, 104 bytes a pixel, is never held):
    :func:`fit_target`'s arguments, and the region of every fitted pixel to make the groups from."""

    rgb: np.ndarray
    index: np.ndarray
    st: np.ndarray
    sub: int
    skip: object = None
    replace: object = None
    region: np.ndarray | None = None

    def __post_init__(self):
        if self.region is None:
            self.region = _fitted(self.index, self.sub, self.skip)[1].astype(np.int32)

    def part(self, regions, window=None) -> FitTarget:
        """The target of the pixels of ``regions`` (inside ``window``, a :class:`Window`)."""
        return fit_target(self.rgb, self.index, self.st, self.sub, self.skip, self.replace, regions, window)


def target_for_fit(rgb: np.ndarray, index: np.ndarray, st: np.ndarray, sub: int = 1, skip=None, replace=None):
    """:func:`fit_target`, or past :data:`GROUP_PIXELS` fitted pixels a :class:`TargetSource` that
    :func:`fit_colors` makes a group at a time (either can be kept and fitted to again)."""
    h, w = index.shape
    if -(-h // sub) * -(-w // sub) <= GROUP_PIXELS:
        return fit_target(rgb, index, st, sub, skip, replace)
    return TargetSource(rgb, index, st, int(sub), skip, replace)


def _phi_into(d2: np.ndarray, out: np.ndarray) -> None:
    """``out = phi(r) = 0.5 r^2 log r^2`` from ``d2 = r^2`` (0 at 0); ``d2`` is overwritten."""
    tiny = np.finfo(d2.dtype).tiny
    lg = np.log(np.maximum(d2, tiny))
    np.multiply(d2, lg, out=d2)
    np.multiply(d2, 0.5, out=out)


def _cardinal_chunk(Pk: np.ndarray, mk: np.ndarray, lamk: np.ndarray, K: int) -> np.ndarray:
    """``M^{-1} [I; 0]`` for a batch of non-degenerate kernels (local points, active mask, lambda)."""
    nk = Pk.shape[0]
    px, py = Pk[..., 0], Pk[..., 1]
    d2 = (px[:, :, None] - px[:, None, :]) ** 2
    d2 += (py[:, :, None] - py[:, None, :]) ** 2
    M = np.empty((nk, K + 3, K + 3))
    _phi_into(d2, M[:, :K, :K])
    M[:, :K, :K] *= mk[:, :, None]
    M[:, :K, :K] *= mk[:, None, :]
    ii = np.arange(K)
    M[:, ii, ii] = np.where(mk, lamk[:, None], 1.0)
    M[:, :K, K] = mk
    M[:, :K, K + 1] = px * mk
    M[:, :K, K + 2] = py * mk
    M[:, K:, :K] = M[:, :K, K:].transpose(0, 2, 1)
    M[:, K:, K:] = 0.0
    E = np.zeros((nk, K + 3, K))
    E[:, ii, ii] = mk
    try:
        Zk = np.linalg.solve(M, E)
    except np.linalg.LinAlgError:  # a singular kernel (should not happen): least squares for each
        Zk = np.stack([np.linalg.lstsq(m, e, rcond=None)[0] for m, e in zip(M, E)])
    Zk[~np.isfinite(Zk)] = 0.0
    return Zk


def cardinal_matrices(ks: tps.KernelSet, dtype=np.float64, wanted: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Per kernel: local points (n_k, K, 2) and ``Z`` (n_k, K + 3, K) of ``dtype`` (zero for the kernels
    that ``wanted``, a mask, leaves out: a fit of some regions solves only theirs).

    ``Z[k] @ h`` gives kernel ``k``'s coefficients ``[w_1..w_K, b0, b_u, b_v]``
    in its local frame for slot values ``h`` (inactive slots: zero rows and
    columns). Positions are rounded to float32 like the device solver's.
    ``Z`` is worked out in float64 either way (``dtype=np.float32``: rounded
    as it is stored, so a large set of kernels is never held in float64).
    """
    n, K = ks.n_kernels, ks.kernel_size
    mask = ks.index >= 0
    idx = np.maximum(ks.index, 0)
    st = ks.st[idx]  # (n, K, 2)
    fr = ks.frame
    P = np.stack([(st[..., 0] - fr[:, None, 0]) * fr[:, None, 2], (st[..., 1] - fr[:, None, 1]) * fr[:, None, 3]], -1)
    P = np.where(mask[..., None], P.astype(np.float32).astype(np.float64), 0.0)
    Z = np.zeros((n, K + 3, K), dtype)
    if n == 0:
        return P, Z
    lam = tps.kernel_lambda(ks)
    ok = ~ks.degenerate
    if wanted is not None:
        ok &= wanted
    if ok.any():
        sel = np.nonzero(ok)[0]
        chunks = [sel[i:i + 128] for i in range(0, sel.size, 128)]  # a few MB of temporaries a thread

        def work(c):
            Z[c] = _cardinal_chunk(P[c], mask[c], lam[c], K)

        _pool_map(work, chunks)
    for k in np.nonzero(ks.degenerate if wanted is None else ks.degenerate & wanted)[0]:
        # affine fallback of tpsv.gpu.solve._affine_fallback: linear along anchors 0 -> 1, constant across
        m = int(ks.count[k])
        if m == 0:
            continue
        p = P[k, :m]
        cen = p.mean(0)
        dvec = np.array([1.0, 0.0])
        if m >= 2:
            e = p[1] - p[0]
            ln = float(np.hypot(*e))
            if ln > 0:
                dvec = e / ln
        t = (p - cen) @ dvec
        stt = float(t @ t)
        zk = np.zeros((3, m))
        zk[0] = 1.0 / m
        if stt > 0:
            zk[0] -= t * float(cen @ dvec) / stt
            zk[1] = t * dvec[0] / stt
            zk[2] = t * dvec[1] / stt
        Z[k, K:, :m] = zk
    return P, Z


# --------------------------------------------------------------------------- design matrix


def _pool_map(fn, items) -> list:
    """``[fn(x) for x in items]`` on up to 8 host threads of the fit's pool (:func:`tpsv.threads.map_ordered`;
    numpy releases the GIL in the heavy calls); ``fn`` must not call ``_pool_map`` itself."""
    return map_ordered("fit", fn, items)


@dataclass
class _Block:
    """Kernels of similar pixel counts, padded to one dense batch."""

    kernels: np.ndarray  # (b,) kernel ids
    rows: np.ndarray  # (b, me) int32 fitted pixel of each entry (padding: 0); a view of Design.rows
    data: np.ndarray  # (b, me, K) float32 coefficients (padding: 0)
    start: int = 0  # offset of the block's entries in Design.rows


@dataclass
class Design:
    """The render operator ``A`` (fitted pixels x features), as dense blocks per kernel.

    Each kernel holds, for every fitted pixel it covers, ``K`` coefficients
    (blend weight times the cardinal functions at the pixel) for its slots
    ``index[kernel]``; kernels of similar pixel counts are padded into one batch
    (:class:`_Block`) so that products are a few batched matrix products.
    ``rows`` holds every block's entries' pixels end to end (each block's
    ``rows`` is a view of it), so that a product sums them with one
    ``bincount`` and no copy.
    """

    blocks: list
    index: np.ndarray  # (n_k, K) feature per slot (inactive: 0, with zero data)
    n_pix: int
    n_features: int
    rows: np.ndarray  # (entries,) int32, the blocks' rows end to end

    def forward(self, H: np.ndarray) -> np.ndarray:
        """``A H``: (n_pix, c) for H (F, c)."""
        H32 = np.asarray(H, np.float32)
        G = H32[self.index]  # (n_k, K, c)
        c = H32.shape[1]
        vals = np.empty((self.rows.size, c), np.float32)

        def one(blk):
            b, me = blk.rows.shape
            np.matmul(blk.data, G[blk.kernels], out=vals[blk.start:blk.start + b * me].reshape(b, me, c))

        _pool_map(one, self.blocks)
        out = np.empty((self.n_pix, c))
        for j in range(c):
            out[:, j] = np.bincount(self.rows, vals[:, j], self.n_pix)
        return out

    def _adjoint(self, R: np.ndarray, square: bool) -> np.ndarray:
        R32 = np.asarray(R, np.float32)
        c = R32.shape[1]
        G = np.zeros((self.index.shape[0], self.index.shape[1], c), np.float32)

        def one(blk):
            d = blk.data * blk.data if square else blk.data
            G[blk.kernels] = np.matmul(d.transpose(0, 2, 1), R32[blk.rows])

        _pool_map(one, self.blocks)
        flat = self.index.ravel()
        out = np.empty((self.n_features, c))
        for j in range(c):
            out[:, j] = np.bincount(flat, G[..., j].ravel().astype(np.float64), self.n_features)
        return out

    def adjoint(self, R: np.ndarray) -> np.ndarray:
        """``A^T R`` for R (n_pix, c): (F, c)."""
        return self._adjoint(R, False)

    def column_sq(self, Wd: np.ndarray) -> np.ndarray:
        """``sum_x A[x, j]^2 Wd[x]`` per feature (F, c): the Jacobi diagonal (overlapping slots
        of one feature in two kernels counted apart)."""
        return self._adjoint(Wd, True)


#: Points whose blend weights :func:`build_design` works out at once (bounds its temporaries).
DESIGN_CHUNK = 1 << 16


def _entries(ks: tps.KernelSet, region: np.ndarray, st: np.ndarray) -> tuple:
    """The (point, kernel) pairs of nonzero blend weight, sorted by kernel: ``(pixel int32, kernel
    int32, weight float32)``, worked out :data:`DESIGN_CHUNK` points at a time."""
    parts = []
    for a in range(0, region.shape[0], DESIGN_CHUNK):
        kid, bw = tps.blend_weights(ks, region[a:a + DESIGN_CHUNK], st[a:a + DESIGN_CHUNK])
        use = kid >= 0
        pix = np.broadcast_to(np.arange(a, a + kid.shape[0], dtype=np.int32)[:, None], kid.shape)[use]
        parts.append((pix, kid[use].astype(np.int32), bw[use].astype(np.float32)))
        del kid, bw, use
    if not parts:
        return np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0, np.float32)
    e_pix, e_k, e_w = (np.concatenate(x) for x in zip(*parts))
    del parts
    order = np.argsort(e_k, kind="stable")
    return e_pix[order], e_k[order], e_w[order]


def build_design(ks: tps.KernelSet, region: np.ndarray, st: np.ndarray) -> tuple[Design, int]:
    """The render operator at the given points (region (n,), st (n, 2)).

    Returns the design and its number of stored coefficients (padding excluded).
    Besides the design, the build holds 12 bytes per (point, kernel) pair and
    one batch of kernels at a time per thread.
    """
    n = region.shape[0]
    F = ks.st.shape[0]
    K = ks.kernel_size
    st = np.asarray(st, np.float64)
    e_pix, e_k, e_w = _entries(ks, region, st)
    bounds = np.searchsorted(e_k, np.arange(ks.n_kernels + 1))
    del e_k
    ne = e_pix.size
    counts = np.diff(bounds)
    P, Zc = cardinal_matrices(ks, np.float32, counts > 0)  # Zc: (n_k, K + 3, K), the kernels with points
    P32 = P.astype(np.float32)
    del P
    # kernels in groups of similar entry counts, each group one padded batch
    order_k = np.argsort(counts, kind="stable")
    order_k = order_k[counts[order_k] > 0]
    # padded entries x slots per batch: each thread's temporaries are a few times this in floats
    # (2 000 000 made them 25 MB a thread, as much as the design of a 256 x 256 picture)
    budget = 500_000
    groups = []
    i = 0
    nk = order_k.size
    while i < nk:
        j = i + 1
        top = int(counts[order_k[i]])
        while j < nk and (j - i + 1) * int(counts[order_k[j]]) * (K + 3) <= budget and counts[order_k[j]] <= 1.25 * top + 8:
            j += 1
        groups.append(order_k[i:j])
        i = j
    sizes = [len(g) * int(counts[g].max()) for g in groups]
    starts = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    rows = np.empty(int(starts[-1]), np.int32)

    def batch(gi):
        ks_ = groups[gi]
        me = int(counts[ks_].max())
        pos = bounds[ks_][:, None] + np.arange(me)[None, :]  # (b, me)
        valid = np.arange(me)[None, :] < counts[ks_][:, None]
        pos = np.where(valid, pos, bounds[ks_][:, None])
        pix = e_pix[pos]
        fr = ks.frame[ks_][:, None, :]
        q = st[pix]
        ub = ((q[..., 0] - fr[..., 0]) * fr[..., 2]).astype(np.float32)  # (b, me), the kernel's local frame
        vb = ((q[..., 1] - fr[..., 1]) * fr[..., 3]).astype(np.float32)
        del q
        pk = P32[ks_]  # (b, K, 2)
        d2 = (ub[:, :, None] - pk[:, None, :, 0]) ** 2
        d2 += (vb[:, :, None] - pk[:, None, :, 1]) ** 2
        B = np.empty((len(ks_), me, K + 3), np.float32)
        _phi_into(d2, B[:, :, :K])
        del d2
        B[:, :, K] = 1.0
        B[:, :, K + 1] = ub
        B[:, :, K + 2] = vb
        out = np.matmul(B, Zc[ks_])  # (b, me, K)
        out *= np.where(valid, e_w[pos], 0.0)[:, :, None]
        view = rows[starts[gi]:starts[gi + 1]].reshape(pix.shape)
        view[...] = pix
        return _Block(kernels=ks_, rows=view, data=out, start=int(starts[gi]))

    blocks = _pool_map(batch, range(len(groups)))
    index = np.where(ks.index >= 0, ks.index, 0).astype(np.int64)
    return Design(blocks=blocks, index=index, n_pix=n, n_features=F, rows=rows), ne * K


def fit_colors(
    model,
    rgb: np.ndarray | None = None,
    *,
    target: FitTarget | None = None,
    iterations: int = 6,
    mu: float = 1e-6,
    tol: float = 1e-3,
    device: str = "cpu",
    maps: tuple[np.ndarray, np.ndarray] | None = None,
    kernels: tps.KernelSet | None = None,
    max_nnz: int = MAX_NNZ,
    group_pixels: int | None = None,
):
    """Feature colours fitted by least squares to ``rgb`` (see the module doc).

    Parameters
    ----------
    model : Model
        Positions are kept; colours are the starting point.
    rgb : ndarray (H, W, 3) float in [0, 1], the model's size (or give ``target``).
    target : FitTarget or TargetSource, optional
        The image at the fitted pixels, when the caller has it (it depends on
        the image and the regions only, so a search computes it once); a
        :class:`TargetSource` is made a group of regions at a time.
    iterations : int
        Conjugate-gradient iterations at most (6 reach within 0.05 dB of 30 on
        the samples: the start, the sampled colours, is close).
    mu : float
        Weight of ``|h - h0|^2`` relative to the per-pixel sRGB error.
    tol : float
        Stop when the preconditioned residual norm falls below ``tol`` times its start.
    maps : (index, st), optional
        The pixel maps of :func:`pixel_maps`, when the caller has them.
    kernels : KernelSet, optional
        ``tps.group_kernels(model)`` when the caller has it.
    group_pixels : int, optional
        Fitted pixels of one group of regions, at most (default
        :data:`GROUP_PIXELS`): the design is built and solved one group at a
        time (:func:`region_groups`), a region of more pixels in strips
        (:func:`region_strips`).

    Returns
    -------
    (Model, FitReport)
        A new model with fitted ``features.lab`` (float32, clipped to the
        stored Lab ranges; features fitted to neutral grey pixels alone,
        :data:`NEUTRAL_AB`, are grey); features merged away by the grouping
        (duplicates) take their representative's colour. ``FitReport.mse`` estimates the
        sRGB mean squared error at the fitted pixels (linearised, no range
        clamp, no 8-bit rounding).
    """
    t0 = time.perf_counter()
    group_pixels = GROUP_PIXELS if group_pixels is None else int(group_pixels)
    F = len(model.features)
    if F == 0:
        return model, FitReport(0, 0.0, 0, 0.0, 0.0, 1, float("nan"), None)
    ks = kernels if kernels is not None else tps.group_kernels(model)
    if target is None:
        target = _target_for(model, rgb, ks, device, maps, max_nnz)
    # pixels of regions without kernels are left out (the fill colour is no feature's)
    sel = ks.grid[np.maximum(target.region, 0), 0] > 0
    n_fit = int(np.count_nonzero(sel))
    h0 = ks.lab.astype(np.float64).copy()
    mu_n = float(mu) * max(n_fit, 1) / max(F, 1)
    freg = np.asarray(model.features.region, np.int64)
    used = np.zeros(F, bool)
    used[ks.index[ks.index >= 0]] = True
    X = h0.copy()
    it, nnz, err, norms = 0, 0, 0.0, []
    counts = np.bincount(target.region[sel], minlength=ks.grid.shape[0])
    source = isinstance(target, TargetSource)
    groups = region_groups(counts, group_pixels)
    for g in groups:
        strips = [None]
        if len(g) == 1 and counts[g[0]] > group_pixels:
            strips = region_strips(ks, int(g[0]), _region_st(target, sel, int(g[0])), group_pixels) or [None]
        for strip in strips:
            window = None if strip is None else strip.window
            part = target
            if source:
                # the group's pixels alone, made now (regions without kernels are in no group)
                part, pick = target.part(g, window), (lambda a: a)
            elif len(groups) == 1 and strip is None:
                # (a copy of the target's per-pixel arrays only where some pixels are left out: they are
                # the largest arrays of the fit after its design)
                pick = (lambda a: a) if sel.all() else (lambda a, sel=np.nonzero(sel)[0]: a[sel])
            else:
                at = sel & np.isin(target.region, g)
                if window is not None:
                    at &= window.holds(target.st)
                pick = (lambda a, at=np.nonzero(at)[0]: a[at])
            st_t = pick(part.st)
            des, n = build_design(ks, pick(part.region), st_t)
            lab_t = pick(part.lab)
            normal = _Normal(des, pick(part.W), mu_n)
            Minv = normal.jacobi()
            if strip is None:
                # the other groups' features have no pixel here: no residual, they stay as they are
                x0, mine, counted = h0, np.isin(freg, g), slice(None)
            else:
                # only the strip's features move (a zero preconditioner keeps the others where they are:
                # fitted by the strips before, or still h0)
                mine, free = strip.features(ks, freg)
                Minv[~free] = 0.0
                x0, counted = X, strip.core.holds(st_t)
            Xg, it_g, r0, r1 = _region_cg(normal, normal.rhs(lab_t, h0), Minv, x0, freg, iterations, tol)
            X[mine] = Xg[mine]
            if np.abs(lab_t[:, 1:]).max(initial=0.0) <= NEUTRAL_AB:
                # grey pixels stay grey: the sRGB metric's cross terms would pay a, b to cancel part of
                # the L error, a false tint (a grey photo came back with lilac rims at 4x)
                X[mine, 1:] = 0.0
            X[~used] = h0[~used]
            X[:, 0] = np.clip(X[:, 0], 0.0, 100.0)
            X[:, 1:] = np.clip(X[:, 1:], -128.0, 127.0)
            # (a strip's error counts its core pixels, the later strips' features still unfitted)
            res = des.forward(X) - lab_t
            err += float((res * normal.wmul(res))[counted].sum())
            # (strips count their margins' coefficients and residuals again: the report's nnz and norms are
            # what the fit worked through)
            it, nnz = max(it, it_g), nnz + n
            norms.append((r0, r1))
            del des, normal, res, lab_t, Xg, part, st_t
    mse = err / (3.0 * max(n_fit, 1))
    # features the grouping merged away (duplicates) take their representative's colour
    lab = tps.Duplicates.of_features(model.features).spread(X.astype(np.float32))
    out = replace(model, features=replace(model.features, lab=lab))
    # the groups' preconditioned residual norms, as one (their regions' sums of squares add up)
    res0, res1 = norms[0] if len(norms) == 1 else np.sqrt(np.square(norms).sum(axis=0)).tolist()
    return out, FitReport(it, time.perf_counter() - t0, int(nnz), res0, res1, target.sub, mse, ks)


def region_groups(pixels: np.ndarray, most: int) -> list[np.ndarray]:
    """Regions in groups of consecutive ids holding at most ``most`` fitted pixels each (a region of more
    is a group alone); regions without pixels are in none.

    Parameters
    ----------
    pixels : ndarray (R,) int
        Fitted pixels of each region.
    most : int

    Returns
    -------
    list of ndarray of int
        At least one group (empty when no region has a pixel).
    """
    groups, cur, size = [], [], 0
    for r in np.flatnonzero(pixels):
        c = int(pixels[r])
        if cur and size + c > most:
            groups.append(np.array(cur))
            cur, size = [], 0
        cur.append(int(r))
        size += c
    if cur:
        groups.append(np.array(cur))
    return groups or [np.zeros(0, np.int64)]


#: Largest |a|, |b| (Lab) of pixels taken as neutral grey: features fitted to such pixels alone get a = b = 0
#: (:func:`fit_colors`; an exact grey sRGB pixel reads about 1e-5).
NEUTRAL_AB = 0.5


@dataclass(frozen=True)
class Window:
    """A strip of a region's (S, T) square: the points with ``lo <= st[:, axis] < hi``."""

    axis: int
    lo: float
    hi: float

    def holds(self, st: np.ndarray) -> np.ndarray:
        v = np.asarray(st)[:, self.axis]
        return (v >= self.lo) & (v < self.hi)


def _columns(v: np.ndarray, n: int) -> np.ndarray:
    """Kernel column of each coordinate ``v`` of a region's square cut into ``n`` columns."""
    return np.clip(np.floor(np.asarray(v, np.float64) * n), 0, n - 1).astype(np.int64)


@dataclass(frozen=True)
class Strip:
    """Columns ``core_columns`` of a region's kernel grid (along ``axis``, ``n`` of them) whose
    features one fit keeps, fitted with those of the columns ``wide_columns`` (the core and a margin
    each side) from the pixels their kernels cover (``window``)."""

    region: int
    axis: int
    n: int
    core_columns: tuple
    wide_columns: tuple
    window: Window

    @property
    def core(self) -> Window:
        """The pixels of the core columns (each pixel in one strip's core)."""
        c0, c1 = self.core_columns
        return Window(self.axis, -np.inf if c0 == 0 else c0 / self.n, np.inf if c1 == self.n else c1 / self.n)

    def features(self, ks: tps.KernelSet, freg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Masks over the features: those the strip keeps (its region's, in the core columns) and
        those it fits (in a kernel of the wide columns, and the kept ones)."""
        gx, gy, first = (int(v) for v in ks.grid[self.region])
        e0, e1 = self.wide_columns
        ix, iy = np.meshgrid(np.arange(gx), np.arange(gy))
        along = ix if self.axis == 0 else iy
        kernels = (first + iy * gx + ix)[(along >= e0) & (along < e1)]
        slots = ks.index[kernels]
        keep = freg == self.region
        col = _columns(ks.st[keep, self.axis], self.n)
        keep[keep] = (col >= self.core_columns[0]) & (col < self.core_columns[1])
        free = keep.copy()
        free[slots[slots >= 0]] = True
        return keep, free


def region_strips(ks: tps.KernelSet, region: int, st: np.ndarray, most: int, margin: int | None = None) -> list:
    """A region's fit cut into strips of its kernel grid's columns, each core about ``most`` fitted pixels.

    Past :data:`GROUP_PIXELS` a region alone would still be fitted whole; so
    the strips are fitted one after another (:func:`fit_colors`), each
    moving the features of its columns and of ``margin`` columns each side,
    from the pixels their kernels cover, with every other feature held where
    it is (fitted by an earlier strip, or its start). Only the core columns'
    features are kept: the margin's stand in for the neighbours' features,
    which the whole fit would move at the same time. The strips run along
    the grid's longer side.

    Parameters
    ----------
    ks : KernelSet
    region : int
    st : ndarray (n, 2)
        ``(S, T)`` of the region's fitted pixels.
    most : int
        Fitted pixels of a strip's core, at most about (its margins come on top).
    margin : int, optional
        Kernel columns each side (default :data:`STRIP_MARGIN`).

    Returns
    -------
    list of Strip
        Empty when the region is not cut (one strip would hold it all).
    """
    margin = STRIP_MARGIN if margin is None else int(margin)
    gx, gy, _ = (int(v) for v in ks.grid[region])
    axis = 0 if gx >= gy else 1
    n = gx if axis == 0 else gy
    counts = np.bincount(_columns(st[:, axis], n), minlength=n)
    total = int(counts.sum())
    # (cores of at most ``most`` pixels: a strip holds its margins' pixels too, but each strip more
    # fits another two margins' pixels again)
    pieces = min(int(np.ceil(total / max(most, 1))), n)
    if pieces <= 1:
        return []
    cuts = np.searchsorted(np.cumsum(counts), total * np.arange(1, pieces) / pieces) + 1
    bounds = [0, *np.unique(np.clip(cuts, 1, n - 1)).tolist(), n]
    ov = ks.overlap
    out = []
    for c0, c1 in zip(bounds[:-1], bounds[1:]):
        e0, e1 = max(c0 - margin, 0), min(c1 + margin, n)
        window = Window(axis, -np.inf if e0 == 0 else (e0 - ov) / n, np.inf if e1 == n else (e1 + ov) / n)
        out.append(Strip(region, axis, n, (c0, c1), (e0, e1), window))
    return out


def _region_st(target, sel: np.ndarray, region: int) -> np.ndarray:
    """``(S, T)`` of a region's fitted pixels, from a :class:`FitTarget` or a :class:`TargetSource`."""
    if isinstance(target, TargetSource):
        rows, _ = _fitted(target.index, target.sub, target.skip, [region])
        return np.asarray(target.st).reshape(-1, 2)[rows]
    return target.st[sel & (target.region == region)]


def _target_for(model, rgb: np.ndarray, ks: tps.KernelSet, device: str, maps, max_nnz: int) -> FitTarget:
    """The :class:`FitTarget` of ``rgb``: every pixel, or every ``sub``-th where ``A`` would pass ``max_nnz``."""
    index, st = maps if maps is not None else pixel_maps(model, device)
    per_px = (1.0 + 2.0 * ks.overlap) ** 2 * ks.kernel_size
    sub = 1
    while (model.height // sub) * (model.width // sub) * per_px > max_nnz:
        sub += 1
    return fit_target(rgb, index, st, sub)


@dataclass
class _Normal:
    """The fit's normal equations ``(A^T W A + mu I) h = A^T W lab + mu h0`` (``W``: per-pixel 3 x 3)."""

    des: Design
    W: np.ndarray  # (n, 3, 3) J^T J per fitted pixel
    mu: float

    def wmul(self, Y: np.ndarray) -> np.ndarray:
        """``W Y`` per pixel for Y (n, 3)."""
        W = self.W
        out = W[:, :, 0] * Y[:, 0:1]  # summed in place, in the same order: one temporary, not three
        out += W[:, :, 1] * Y[:, 1:2]
        out += W[:, :, 2] * Y[:, 2:3]
        return out

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.des.adjoint(self.wmul(self.des.forward(X))) + self.mu * X

    def rhs(self, lab: np.ndarray, h0: np.ndarray) -> np.ndarray:
        """``A^T W lab + mu h0``."""
        return self.des.adjoint(self.wmul(lab)) + self.mu * h0

    def jacobi(self) -> np.ndarray:
        """Inverse diagonal of the normal matrix (overlaps of duplicate columns ignored)."""
        Wd = np.ascontiguousarray(self.W[:, [0, 1, 2], [0, 1, 2]], np.float32)
        diag = self.des.column_sq(Wd) + self.mu
        return 1.0 / np.maximum(diag, 1e-12)


def _region_cg(normal, rhs: np.ndarray, Minv: np.ndarray, x0: np.ndarray, region: np.ndarray,
               iterations: int, tol: float) -> tuple[np.ndarray, int, float, float]:
    """Jacobi-preconditioned conjugate gradients with step lengths per region.

    ``A`` has no entry linking a pixel to another region's features, so the
    normal matrix is block diagonal and per-region step lengths keep every
    region's iterates independent of the others' (a feature's fitted colour
    never depends on another region). A region stops when its preconditioned
    residual falls below ``tol`` times its start.

    Returns
    -------
    X : ndarray (F, 3)
    iterations : int
        Iterations run.
    res0, res : float
        Preconditioned residual norm at the start and at the end.
    """
    R_n = int(region.max()) + 1 if region.size else 0

    def rdot(a, b):
        return np.bincount(region, (a * b).sum(axis=1), R_n)

    X = x0.copy()
    R = rhs - normal(X)
    Zr = Minv * R
    Pd = Zr.copy()
    rz = rdot(R, Zr)
    rz0 = rz.copy()
    res0 = float(np.sqrt(max(rz.sum(), 0.0)))
    active = rz > 0
    it = 0
    for it in range(1, iterations + 1):
        if not active.any():
            it -= 1
            break
        Q = normal(Pd)
        pq = rdot(Pd, Q)
        active &= pq > 0
        alpha = np.where(active, rz / np.where(active, pq, 1.0), 0.0)
        X += alpha[region][:, None] * Pd
        R -= alpha[region][:, None] * Q
        Zr = Minv * R
        rz_new = rdot(R, Zr)
        beta = np.where(active, rz_new / np.where(rz > 0, rz, 1.0), 0.0)
        active &= rz_new > (tol**2) * rz0
        Pd = Zr + beta[region][:, None] * Pd
        rz = np.where(active, rz_new, rz)
    return X, it, res0, float(np.sqrt(max(float(np.sum(rz)), 0.0)))
