"""Batched DTW and window kernels against plain dynamic-programming references."""

from __future__ import annotations

import math
import re
from collections.abc import Callable

import numpy as np
import pytest
import torch

from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.prediction.dtw import (
    DTWKernel,
    GlobalAlignmentKernel,
    RBFKernel,
    dtw_distance,
    dtw_paired,
    gak_log,
    gak_log_paired,
    kernel_from_state,
    median_dtw,
)

pytestmark = pytest.mark.usefixtures("one_thread")


def _in_band(i: int, j: int, t1: int, t2: int, band: int | None) -> bool:
    if band is None or t1 == 1 or t2 == 1:
        return True
    r = (t1 - 1) / (t2 - 1)
    return abs(i - j * r) <= max(band, max(1.0, r) / 2) + 1e-9


def dtw_reference(x: np.ndarray, y: np.ndarray, band: int | None, squared: bool) -> float:
    """Textbook O(T T2) dynamic programme, one pair at a time."""
    t1, t2 = len(x), len(y)
    r = np.full((t1 + 1, t2 + 1), np.inf)
    r[0, 0] = 0.0
    for i in range(t1):
        for j in range(t2):
            if not _in_band(i, j, t1, t2, band):
                continue
            c = float(((x[i] - y[j]) ** 2).sum())
            c = c if squared else math.sqrt(c)
            r[i + 1, j + 1] = c + min(r[i, j + 1], r[i + 1, j], r[i, j])
    return math.sqrt(r[t1, t2]) if squared else float(r[t1, t2])


def gak_reference(x: np.ndarray, y: np.ndarray, sigma: float) -> float:
    """Cuturi's recursion in plain probabilities (no logs)."""
    t1, t2 = len(x), len(y)
    m = np.zeros((t1 + 1, t2 + 1))
    m[0, 0] = 1.0
    for i in range(t1):
        for j in range(t2):
            d2 = float(((x[i] - y[j]) ** 2).sum()) / (2 * sigma**2)
            kappa = math.exp(-d2) / (2.0 - math.exp(-d2))
            m[i + 1, j + 1] = kappa * (m[i, j + 1] + m[i + 1, j] + m[i, j])
    return float(m[t1, t2])


@pytest.mark.parametrize("dtype,atol", [(torch.float32, 1e-5), (torch.float64, 1e-10)])
@pytest.mark.parametrize("band", [None, 0, 2])
@pytest.mark.parametrize("squared", [False, True])
def test_dtw_matches_reference(dtype: torch.dtype, atol: float, band: int | None, squared: bool):
    g = torch.Generator().manual_seed(1)
    for t1, t2 in [(7, 5), (4, 9), (6, 6), (1, 3), (10, 2)]:
        x = torch.randn(3, t1, 4, generator=g).to(dtype)
        y = torch.randn(4, t2, 4, generator=g).to(dtype)
        got = dtw_distance(x, y, band=band, squared=squared, max_cells=60)
        want = torch.tensor(
            [
                [dtw_reference(a.double().numpy(), b.double().numpy(), band, squared) for b in y]
                for a in x
            ],
            dtype=torch.float64,
        )
        assert got.dtype == dtype and got.shape == (3, 4)
        torch.testing.assert_close(got.double(), want, atol=atol, rtol=0)


def test_symmetry_batch_and_paired():
    g = torch.Generator().manual_seed(2)
    x = torch.randn(9, 6, 3, generator=g, dtype=torch.float64)
    gram = dtw_distance(x, x, max_cells=100)  # several tiles, upper triangle mirrored
    torch.testing.assert_close(gram, gram.T, atol=0, rtol=0)
    torch.testing.assert_close(gram.diagonal(), torch.zeros(9, dtype=torch.float64))
    full = dtw_distance(x, x.clone(), band=1)  # not the same object: every tile computed
    torch.testing.assert_close(full, full.T, atol=1e-12, rtol=0)
    stacked = torch.cat([dtw_distance(x[i : i + 1], x, band=1) for i in range(9)])
    torch.testing.assert_close(full, stacked, atol=1e-12, rtol=0)
    y = torch.randn(9, 4, 3, generator=g, dtype=torch.float64)
    torch.testing.assert_close(dtw_paired(x, y), dtw_distance(x, y).diagonal(), atol=1e-12, rtol=0)


def test_band_limits_against_closed_forms():
    """Band references that do not restate the band rule: band 0 on equal lengths allows the
    lock-step alignment only (DTW: the sum of frame distances; GAK: the product of the
    local kernels); a band as wide as the windows is no band; a band never shortens DTW."""
    g = torch.Generator().manual_seed(6)
    x = torch.randn(4, 6, 3, generator=g, dtype=torch.float64)
    y = torch.randn(4, 6, 3, generator=g, dtype=torch.float64)
    z = torch.randn(5, 8, 3, generator=g, dtype=torch.float64)
    sigma = 1.3
    lock_dtw = (x[:, None] - y[None]).norm(dim=-1).sum(-1)  # (4, 4)
    d2 = (x[:, None] - y[None]).square().sum(-1) / (2 * sigma**2)
    lock_gak = (torch.exp(-d2) / (2.0 - torch.exp(-d2))).log().sum(-1)
    torch.testing.assert_close(dtw_distance(x, y, band=0), lock_dtw, atol=1e-12, rtol=0)
    torch.testing.assert_close(dtw_paired(x, y, band=0), lock_dtw.diagonal(), atol=1e-12, rtol=0)
    torch.testing.assert_close(gak_log(x, y, sigma=sigma, band=0), lock_gak, atol=1e-12, rtol=0)
    torch.testing.assert_close(
        gak_log_paired(x, y, sigma=sigma, band=0), lock_gak.diagonal(), atol=1e-12, rtol=0
    )
    for a, b in ((x, y), (x, z), (z, x)):
        free, wide = dtw_distance(a, b), dtw_distance(a, b, band=8)
        torch.testing.assert_close(wide, free, atol=1e-12, rtol=0)
        torch.testing.assert_close(
            gak_log(a, b, sigma=sigma, band=8), gak_log(a, b, sigma=sigma), atol=1e-12, rtol=0
        )
        for band in (0, 1, 2):
            assert bool((dtw_distance(a, b, band=band) >= free - 1e-12).all())
    # the paired functions agree with the Gram's diagonal under a band, on unequal lengths
    zz = z[:4]
    for band in (0, 1, 2):
        torch.testing.assert_close(
            dtw_paired(x, zz, band=band),
            dtw_distance(x, zz, band=band).diagonal(),
            atol=1e-12,
            rtol=0,
        )
        torch.testing.assert_close(
            gak_log_paired(x, zz, sigma=sigma, band=band),
            gak_log(x, zz, sigma=sigma, band=band).diagonal(),
            atol=1e-12,
            rtol=0,
        )


@pytest.mark.slow  # tslearn compiles its numba code on first use (~30 s)
def test_matches_tslearn_squared_variant():
    tslearn = pytest.importorskip("tslearn.metrics")
    g = torch.Generator().manual_seed(3)
    x = torch.randn(5, 8, 3, generator=g, dtype=torch.float64)
    y = torch.randn(4, 6, 3, generator=g, dtype=torch.float64)
    want = torch.from_numpy(tslearn.cdist_dtw(x.numpy(), y.numpy()))
    torch.testing.assert_close(dtw_distance(x, y, squared=True), want, atol=1e-10, rtol=0)


def test_nearly_equal_frames_are_exact_in_float32():
    g = torch.Generator().manual_seed(4)
    x = 50.0 + torch.randn(4, 10, 30, generator=g)  # large offset: cancellation territory
    y = x + 1e-3 * torch.randn(4, 10, 30, generator=g)
    want = [
        dtw_reference(a.double().numpy(), b.double().numpy(), None, False) for a, b in zip(x, y)
    ]
    got = dtw_distance(x, y).diagonal().double()
    torch.testing.assert_close(got, torch.tensor(want, dtype=torch.float64), atol=1e-5, rtol=1e-4)


def test_gak_matches_reference_and_is_psd():
    g = torch.Generator().manual_seed(5)
    x = torch.randn(12, 7, 2, generator=g, dtype=torch.float64)
    y = torch.randn(3, 5, 2, generator=g, dtype=torch.float64)
    sigma = 1.5
    want = torch.tensor(
        [[math.log(gak_reference(a.numpy(), b.numpy(), sigma)) for b in y] for a in x],
        dtype=torch.float64,
    )
    torch.testing.assert_close(gak_log(x, y, sigma=sigma, max_cells=40), want, atol=1e-10, rtol=0)
    for kernel in (GlobalAlignmentKernel(sigma), GlobalAlignmentKernel(sigma, normalize=False)):
        gram = kernel(x, x)
        torch.testing.assert_close(gram, gram.T, atol=1e-12, rtol=1e-12)
        torch.testing.assert_close(kernel.diag(x), gram.diagonal(), atol=1e-10, rtol=1e-10)
        assert float(torch.linalg.eigvalsh(gram)[0]) > -1e-6
    x32 = torch.randn(40, 10, 3, generator=g)
    gram32 = GlobalAlignmentKernel(2.0)(x32, x32).double()
    assert float(torch.linalg.eigvalsh(gram32)[0]) > -1e-6


@pytest.mark.parametrize(
    "kernel", [DTWKernel(3.0), DTWKernel(2.0, band=1), GlobalAlignmentKernel(1.0), RBFKernel(4.0)]
)
def test_kernel_contract(kernel):
    g = torch.Generator().manual_seed(6)
    x = torch.randn(6, 5, 3, generator=g, dtype=torch.float64)
    z = torch.randn(4, 5, 3, generator=g, dtype=torch.float64)
    gram = kernel(x, x)
    torch.testing.assert_close(gram, gram.T, atol=1e-12, rtol=1e-12)
    torch.testing.assert_close(kernel.diag(x), gram.diagonal(), atol=1e-10, rtol=0)
    cross = kernel(x, z)
    stacked = torch.cat([kernel(x[i : i + 1], z) for i in range(6)])
    torch.testing.assert_close(cross, stacked, atol=1e-12, rtol=0)
    assert ((cross > 0) & (cross <= 1 + 1e-12)).all()
    rebuilt = kernel_from_state(kernel.name, kernel.hparams)
    torch.testing.assert_close(rebuilt(x, z), cross, atol=0, rtol=0)


def test_dtw_kernel_value_and_median():
    g = torch.Generator().manual_seed(7)
    x = torch.randn(8, 5, 2, generator=g, dtype=torch.float64)
    d = dtw_distance(x, x)
    torch.testing.assert_close(DTWKernel(2.5)(x, x), torch.exp(-d / 2.5))
    # pairs of distinct windows drawn uniformly: about the median of the 56 off-diagonal
    # distances (between their 40th and 60th percentiles with 4000 pairs)
    med = median_dtw(x, n_pairs=4000, seed=0)
    off = d[~torch.eye(8, dtype=torch.bool)].double()
    assert float(off.quantile(0.4)) <= med <= float(off.quantile(0.6))
    assert med == median_dtw(x, n_pairs=4000, seed=0)
    # two windows: every pair is the same pair; identical windows: the documented 1.0
    assert median_dtw(x[:2], n_pairs=7, seed=3) == pytest.approx(float(d[0, 1]), rel=1e-12)
    assert median_dtw(x[:1].expand(3, 5, 2), n_pairs=9) == 1.0


def test_errors():
    x = torch.randn(2, 5, 3)
    with pytest.raises(ShapeError, match=r"expected y \(B2, T2, 3\)"):
        dtw_distance(x, torch.randn(2, 5, 4))
    with pytest.raises(ShapeError, match=r"expected x \(B1, T, D\), got \(5, 3\)"):
        dtw_distance(torch.randn(5, 3), x)
    with pytest.raises(ShapeError, match="same dtype"):
        dtw_distance(x, x.double())
    with pytest.raises(ConfigError, match="band"):
        dtw_distance(x, x, band=-1)
    with pytest.raises(ConfigError, match="gamma > 0"):
        DTWKernel(0.0)
    with pytest.raises(ConfigError, match="unknown kernel"):
        kernel_from_state("nope", {})
    with pytest.raises(ShapeError, match="B >= 2"):
        median_dtw(x[:1])
    with pytest.raises(ConfigError, match="n_pairs an integer >= 1, got 0"):
        median_dtw(x, n_pairs=0)


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_windows_are_named_not_spread(bad: float):
    """One NaN/inf frame would make every distance NaN (the frames are centred on a mean over
    all windows), and the median rule would quietly fall back to 1: it raises instead, naming
    the window and frame; the finite windows are unaffected."""
    g = torch.Generator().manual_seed(3)
    x = torch.rand(4, 10, 6, generator=g)
    y = torch.rand(3, 10, 6, generator=g)
    finite = dtw_distance(x, y)
    x_bad = x.clone()
    x_bad[2, 7, 1] = bad
    where = "window 2, frame 7"
    with pytest.raises(DataError, match=f"x is NaN/Inf at {where}: impute lost frames first"):
        dtw_distance(x_bad, y)
    with pytest.raises(DataError, match=f"y is NaN/Inf at {where}"):
        dtw_distance(y, x_bad)
    with pytest.raises(DataError, match=f"x is NaN/Inf at {where}"):
        dtw_distance(x_bad, x_bad)
    with pytest.raises(DataError, match=f"y is NaN/Inf at {where}"):
        dtw_paired(x, x_bad)
    with pytest.raises(DataError, match=f"x is NaN/Inf at {where}"):
        gak_log(x_bad, y, sigma=1.0)
    with pytest.raises(DataError, match=f"y is NaN/Inf at {where}"):
        gak_log_paired(x, x_bad, sigma=1.0)
    with pytest.raises(DataError, match=f"x is NaN/Inf at {where}"):
        median_dtw(x_bad, n_pairs=50)
    for kernel in (DTWKernel(1.0), GlobalAlignmentKernel(1.0), RBFKernel(1.0)):
        with pytest.raises(DataError, match=f"is NaN/Inf at {where}"):
            kernel(y, x_bad)
    torch.testing.assert_close(dtw_distance(x, y), finite, atol=0, rtol=0)


@pytest.mark.gpu
def test_cuda_parity():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    g = torch.Generator().manual_seed(8)
    x = torch.randn(30, 12, 9, generator=g)
    y = torch.randn(20, 10, 9, generator=g)
    for band in (None, 2):
        cpu = dtw_distance(x, y, band=band)
        gpu = dtw_distance(x.cuda(), y.cuda(), band=band)
        assert gpu.device.type == "cuda"
        torch.testing.assert_close(gpu.cpu(), cpu, atol=1e-4, rtol=1e-5)
    k = GlobalAlignmentKernel(2.0)
    torch.testing.assert_close(k(x.cuda(), y.cuda()).cpu(), k(x, y), atol=1e-5, rtol=1e-4)
    torch.testing.assert_close(
        DTWKernel(3.0)(x.cuda(), x.cuda()).cpu(), DTWKernel(3.0)(x, x), atol=1e-5, rtol=1e-5
    )


@pytest.mark.parametrize("band", [None, 1])
@pytest.mark.parametrize("squared", [False, True])
def test_gram_with_uneven_tiles_matches_reference(band: int | None, squared: bool):
    """13 windows in tiles of 4 (last tile 1): every tile shape and both triangles checked."""
    g = torch.Generator().manual_seed(9)
    x = torch.randn(13, 6, 3, generator=g, dtype=torch.float64)
    y = torch.randn(5, 4, 3, generator=g, dtype=torch.float64)
    for a, b in ((x, x), (x, y)):
        got = dtw_distance(a, b, band=band, squared=squared, max_cells=4 * 4 * a.shape[1] ** 2)
        want = torch.tensor(
            [[dtw_reference(u.numpy(), v.numpy(), band, squared) for v in b] for u in a],
            dtype=torch.float64,
        )
        torch.testing.assert_close(got, want, atol=1e-10, rtol=0)


def _every_public_call(x: torch.Tensor, y: torch.Tensor) -> list[Callable[[], object]]:
    """Each public function and kernel of dtw.py on windows x (B, T, D), y (B, T, D)."""
    return [
        lambda: dtw_distance(x, y),
        lambda: dtw_paired(x, y),
        lambda: gak_log(x, y, sigma=1.0),
        lambda: gak_log_paired(x, y, sigma=1.0),
        lambda: median_dtw(x, n_pairs=5),
        lambda: DTWKernel(1.0)(x, y),
        lambda: GlobalAlignmentKernel(1.0)(x, y),
        lambda: RBFKernel(1.0)(x, y),
    ]


@pytest.mark.parametrize("dtype", [torch.float16, torch.bfloat16])
def test_half_precision_is_refused_by_every_public_function(dtype: torch.dtype):
    """float16 squared distances overflow (dtw_distance returned NaN for features of a few
    hundred units) and cdist refuses half precision on the CPU (a raw NotImplementedError):
    a ShapeError naming the dtype instead, as in collision.gaussian."""
    g = torch.Generator().manual_seed(10)
    x = (200 * torch.randn(2, 6, 3, generator=g)).to(dtype)
    y = (200 * torch.randn(2, 6, 3, generator=g)).to(dtype)
    for call in _every_public_call(x, y):
        with pytest.raises(ShapeError, match=f"got {dtype}: half precision"):
            call()
    # float32 gives the finite distances the float64 reference gives
    want = dtw_distance(x.double(), y.double())
    torch.testing.assert_close(
        dtw_distance(x.float(), y.float()).double(), want, rtol=1e-5, atol=0
    )


def test_features_whose_squared_distances_overflow_are_refused_by_every_public_function():
    """float32 windows of 30 features around 1e19 gave inf or NaN distances and kernels (the
    squared frame norms overflow): a DataError saying to standardise the features instead.
    The same values in float64 are fine, and squared DTW, whose path sums overflow earlier, is
    refused from about 1e18 while the plain distance of those windows is computed."""
    g = torch.Generator().manual_seed(11)
    base = torch.randn(3, 15, 30, generator=g, dtype=torch.float64)
    x, y = (1e19 * base).float(), (1e19 * base.flip(0)).float()
    for call in _every_public_call(x, y):
        with pytest.raises(
            DataError, match="feature values too large for torch.float32.*standardise"
        ):
            call()
    assert torch.isfinite(dtw_distance(x.double(), y.double())).all()
    x, y = (1e18 * base).float(), (1e18 * base.flip(0)).float()
    assert torch.isfinite(dtw_distance(x, y)).all()
    for call in (lambda: dtw_distance(x, y, squared=True), lambda: dtw_paired(x, y, squared=True)):
        with pytest.raises(DataError, match="their sums along a warping path would overflow"):
            call()


def test_empty_batches_give_empty_results_for_every_kernel():
    """RBFKernel()(x[:0], y) used to fail in max() of an empty tensor; the DTW kernels gave
    empty results already."""
    x = torch.randn(3, 5, 2, dtype=torch.float64)
    for kernel in (DTWKernel(3.0), GlobalAlignmentKernel(1.0), RBFKernel(4.0)):
        assert kernel(x[:0], x).shape == (0, 3)
        assert kernel(x, x[:0]).shape == (3, 0)
        assert kernel(x[:0], x[:0]).shape == (0, 0)


def test_windows_without_features_are_refused():
    """D = 0 used to fail in a reshape (DTW) or give kernel values of 1 (RBF)."""
    x = torch.zeros(2, 4, 0)
    match = r"one feature \(T, T2, D >= 1\), got x \(2, 4, 0\)"
    for call in (
        lambda: dtw_distance(x, x),
        lambda: dtw_paired(x, x),
        lambda: gak_log(x, x, sigma=1.0),
        lambda: DTWKernel(1.0)(x, x),
    ):
        with pytest.raises(ShapeError, match=match):
            call()
    with pytest.raises(ShapeError, match=r"one feature .*got x1 \(2, 4, 0\), x2 \(2, 4, 0\)"):
        RBFKernel(1.0)(x, x)


@pytest.mark.parametrize("band", ["a", math.nan, math.inf, True])
def test_band_that_is_not_an_integer_is_a_config_error(band: object):
    """A string or NaN used to raise a raw ValueError, inf an OverflowError; True passed as 1."""
    x = torch.randn(2, 4, 3)
    match = f"expected band None or an integer >= 0, got {band!r}"
    for call in (
        lambda: dtw_distance(x, x, band=band),
        lambda: dtw_paired(x, x, band=band),
        lambda: gak_log(x, x, sigma=1.0, band=band),
        lambda: median_dtw(x, n_pairs=3, band=band),
        lambda: DTWKernel(1.0, band=band),
        lambda: GlobalAlignmentKernel(1.0, band=band),
    ):
        with pytest.raises(ConfigError, match=re.escape(match)):
            call()
    # an integral float is an integer band, as before
    torch.testing.assert_close(dtw_distance(x, x, band=2.0), dtw_distance(x, x, band=2))


@pytest.mark.parametrize("max_cells", ["a", 0, 2.5])
def test_max_cells_must_be_a_positive_integer(max_cells: object):
    x = torch.randn(2, 4, 3)
    match = f"expected max_cells an integer >= 1, got {max_cells!r}"
    for call in (
        lambda: dtw_distance(x, x, max_cells=max_cells),
        lambda: dtw_paired(x, x, max_cells=max_cells),
        lambda: gak_log(x, x, sigma=1.0, max_cells=max_cells),
        lambda: gak_log_paired(x, x, sigma=1.0, max_cells=max_cells),
        lambda: DTWKernel(1.0, max_cells=max_cells),
        lambda: GlobalAlignmentKernel(1.0, max_cells=max_cells),
    ):
        with pytest.raises(ConfigError, match=re.escape(match)):
            call()


@pytest.mark.parametrize("value", ["a", math.inf])
def test_bandwidths_must_be_finite_positive_numbers(value: object):
    """sigma="a" used to raise a raw TypeError; an infinite bandwidth made every kernel 1."""
    x = torch.randn(2, 4, 3)
    for name, call in (
        ("sigma", lambda: gak_log(x, x, sigma=value)),
        ("sigma", lambda: gak_log_paired(x, x, sigma=value)),
        ("sigma", lambda: GlobalAlignmentKernel(value)),
        ("gamma", lambda: DTWKernel(value)),
        ("lengthscale", lambda: RBFKernel(value)),
    ):
        with pytest.raises(ConfigError, match=re.escape(f"expected {name} > 0 and finite")):
            call()
    with pytest.raises(ConfigError, match="expected seed an integer >= 0, got 'a'"):
        median_dtw(x, n_pairs=3, seed="a")


def test_kernel_from_state_names_missing_arguments():
    """kernel_from_state("dtw", {}) used to raise a raw TypeError."""
    with pytest.raises(ConfigError, match=r"kernel 'dtw' needs the arguments \['gamma'\]"):
        kernel_from_state("dtw", {})
    with pytest.raises(ConfigError, match="hparams of kernel 'rbf' a dict, got NoneType"):
        kernel_from_state("rbf", None)  # type: ignore[arg-type]


@pytest.mark.parametrize("seed", [2**70, -1])
def test_median_dtw_refuses_a_seed_out_of_range(seed: int) -> None:
    """2**70 raised a bare ValueError ("Overflow when unpacking long long") from the torch
    generator; seeds are checked as everywhere else, as integers in [0, 2^32 - 1]."""
    x = torch.randn(3, 4, 2, generator=torch.Generator().manual_seed(0))
    with pytest.raises(ConfigError, match="expected seed an integer"):
        median_dtw(x, seed=seed)


def test_windows_that_require_grad_are_detached() -> None:
    """Windows that required grad raised a bare RuntimeError ("functions with out=...
    arguments don't support automatic differentiation") from every DTW and GAK entry point;
    they are detached, with the values of the detached windows."""
    g = torch.Generator().manual_seed(8)
    x = torch.randn(3, 5, 2, generator=g, dtype=torch.float64)
    y = torch.randn(3, 4, 2, generator=g, dtype=torch.float64)
    xg = x.clone().requires_grad_(True)
    for fn in (dtw_distance, dtw_paired):
        got = fn(xg, y)
        assert not got.requires_grad
        torch.testing.assert_close(got, fn(x, y), rtol=0, atol=0)
    for fn in (gak_log, gak_log_paired):
        torch.testing.assert_close(fn(xg, y, sigma=1.0), fn(x, y, sigma=1.0), rtol=0, atol=0)
    assert median_dtw(xg) == median_dtw(x)


def test_a_bandwidth_beyond_the_square_root_of_float_range_is_its_limit() -> None:
    """sigma or lengthscale above about 1.3e154 raised a bare OverflowError from squaring it in
    Python. Its limit is a local kernel of 1: the GAK then counts the alignment paths (the
    central Delannoy number, 321 for 5 frames), and the RBF kernel is 1."""
    x = torch.randn(3, 5, 2, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    for sigma in (1e200, 1e300):
        assert torch.allclose(
            gak_log(x, x, sigma=sigma), torch.full((3, 3), math.log(321.0)).double()
        )
        assert torch.allclose(
            gak_log_paired(x, x, sigma=sigma), torch.full((3,), math.log(321.0)).double()
        )
        assert torch.equal(GlobalAlignmentKernel(sigma=sigma)(x, x), torch.ones(3, 3).double())
        assert torch.equal(RBFKernel(lengthscale=sigma)(x, x), torch.ones(3, 3).double())
