"""One transfer for many arrays (tpsv.gpu.transfer): the same arrays, the same renders."""

import numpy as np
import pytest

wp = pytest.importorskip("warp")

from tpsv.gpu import transfer  # noqa: E402
from tpsv.rendering.raster import render  # noqa: E402


@pytest.mark.parametrize("pack_bytes", [0, 32, transfer.PACK_BYTES])
def test_upload_gives_each_array_its_values_shape_and_type(pack_bytes):
    rng = np.random.default_rng(3)
    # (host array, device type, the device array's shape, its scalars' numpy type)
    items = [
        (rng.normal(size=(5, 2)), wp.vec2d, (5,), np.float64),
        (np.arange(7, dtype=np.int64), wp.int32, (7,), np.int32),  # cast
        (rng.normal(size=12).astype(np.float32), wp.vec4f, (3,), np.float32),  # flat scalars -> 3 vectors
        (np.zeros((0, 3)), wp.vec3f, (0,), np.float32),
        (rng.integers(0, 9, size=(3, 4)), wp.int32, (3, 4), np.int32),  # 2-D
        (np.array([1, 2, 3], np.uint16), wp.uint16, (3,), np.uint16),  # 6 bytes: the next starts aligned
        (rng.normal(size=(2, 4)), wp.vec4d, (2,), np.float64),
    ]
    out = transfer.upload("cpu", *[(a, t) for a, t, _, _ in items], pack_bytes=pack_bytes)
    assert len(out) == len(items)
    for (a, dtype, shape, scalar), d in zip(items, out):
        assert d.dtype == dtype and d.shape == shape
        got = d.numpy()
        np.testing.assert_array_equal(got, np.asarray(a).astype(scalar).reshape(got.shape))
        assert not d.size or d.ptr % transfer.ALIGN == 0


def test_packed_views_outlive_their_names():
    out = transfer.upload("cpu", (np.arange(1000.0), wp.float64), (np.arange(10), wp.int32))
    del out[0]
    import gc

    gc.collect()
    np.testing.assert_array_equal(out[0].numpy(), np.arange(10))


@pytest.fixture(scope="module")
def detailed_model(small_rgb, small_labels):
    """A small photo with two regions, curved outlines and a detail layer: every upload of a render."""
    from tpsv.encode.rate import encode_quality

    model = encode_quality(small_rgb, small_labels).model
    assert model.detail is not None and model.curves
    return model


def test_a_render_through_packed_uploads_is_the_same(detailed_model, monkeypatch):
    packed = render(detailed_model, scale=2.5)
    monkeypatch.setattr(transfer.upload, "__defaults__", (0,))  # every array on its own
    np.testing.assert_array_equal(render(detailed_model, scale=2.5), packed)
