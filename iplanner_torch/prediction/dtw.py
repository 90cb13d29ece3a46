"""Batched dynamic time warping and time-series kernels on tensors (paper sec. 4.1).

The paper classifies and regresses windows ``F_prev`` with a "DTW kernel" (Mueller 2007). This
module computes DTW for every pair of two batches of windows at once:

* the local cost of frames ``x_i`` and ``y_j`` is the Euclidean distance ``||x_i - y_j||``
  (computed for all pairs of a tile by one matrix product);
* ``DTW(x, y)`` is the smallest sum of local costs along a warping path from ``(0, 0)`` to
  ``(T - 1, T2 - 1)`` with steps ``(1, 0)``, ``(0, 1)`` and ``(1, 1)``;
* the dynamic programme runs as an anti-diagonal wavefront: cells with the same ``i + j`` do not
  depend on each other, so the only Python loop runs over the ``T + T2 - 1`` anti-diagonals, each
  step updating all pairs of the tile in one vectorised operation;
* a Gram tile of ``b1 x b2`` pairs gets its local costs from one matrix product
  ``(T b1, D) x (D, T2 b2)`` whose output already is the layout ``(T, b1, T2, b2)``: every
  anti-diagonal and its three predecessor sets are strided views of that buffer (built once per
  tile shape, :class:`_GridPlan`), row 0 and column 0 are cumulative sums, and the accumulated
  costs overwrite the local ones in place: no copy or permutation of the cost cells;
* on CPU tiles hold about ``2**18`` cells (2 MB in float64) so the wavefront runs in cache; on
  other devices and always at most ``max_cells`` cells, so memory stays bounded; a Gram of a
  batch with itself computes only the upper triangle of tiles;
* paired DTW (``x[b]`` against ``y[b]``) uses a padded cell-major layout
  ``((T + 1) (T2 + 1), P)`` with the same in-place wavefront.

Sakoe-Chiba band, for unequal lengths: cell ``(i, j)`` is admissible iff
``|i - j r| <= w`` with the slope ``r = (T - 1) / (T2 - 1)`` (the line through both corner cells)
and the half-width ``w = max(band, max(1, r) / 2)``. The lower limit on ``w`` is the smallest one
for which the admissible cells always contain a monotone path from corner to corner; for equal
lengths ``band=0`` gives the Euclidean (lock-step) distance. With unequal lengths the band is
measured along the first sequence's axis, so ``dtw(x, y)`` and ``dtw(y, x).T`` can differ.

Kernels (classes with ``__call__(x1, x2) -> (B1, B2)`` and ``diag(x) -> (B,)``):

* :class:`DTWKernel`: ``exp(-DTW / gamma)``. It is *not* positive definite in general (DTW is not
  a metric of negative type); kernel logistic regression tolerates that, a GP needs jitter.
* :class:`GlobalAlignmentKernel`: Cuturi's global alignment kernel (2011), the sum over all
  alignments of the product of local Gaussian-like kernels; positive definite. Computed in log
  space on the same wavefront with log-sum-exp.
* :class:`RBFKernel`: Gaussian kernel on the flattened windows, the cheap alternative.

Inputs: windows are float32 or float64 (:data:`DTYPES`), both of one dtype and on one device,
with T >= 1 frames and D >= 1 features, finite, and small enough that squared frame distances
fit the dtype: summed over D features they overflow once feature values reach about 1e19 in
float32 (1e154 in float64; earlier the more features), the path sums of squared DTW
(``squared=True``) about 5x earlier;
such windows are refused with :class:`~iplanner_torch.errors.DataError` (standardise the
features) rather than giving inf or NaN. Half precision (float16, bfloat16) is refused
rather than computed, as in :mod:`iplanner_torch.collision.gaussian`: float16 squared frame
distances overflow beyond 256 feature units (NaN distances), a DTW sum of up to T + T2 - 1
costs overflows its largest value 65504 even where each distance does not, bfloat16 keeps
fewer than 3 significant digits, and ``cdist`` does not take half precision on the CPU.
Computing in float32 and rounding back would still overflow the float16 result, so callers
convert (``x.float()``) and get float32 distances. Empty batches (B = 0) give empty results.
Settings (``band``, ``max_cells``, ``sigma``, ``gamma``, ``lengthscale``) are checked when
given, with :class:`~iplanner_torch.errors.ConfigError`.

DTW and GAK are not differentiable here (the wavefront runs in place): windows that require
grad are detached, and the results carry no gradient. :class:`RBFKernel` is differentiable.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable
from typing import Any, Literal, Protocol

import torch
from torch import Tensor

from iplanner_torch import checks
from iplanner_torch.errors import ConfigError, DataError, ShapeError
from iplanner_torch.types import check_finite, check_shape

__all__ = [
    "DTWKernel",
    "GlobalAlignmentKernel",
    "KernelLike",
    "RBFKernel",
    "dtw_distance",
    "dtw_paired",
    "gak_log",
    "gak_log_paired",
    "kernel_from_state",
    "gak_sigma",
    "median_dtw",
]

#: Default largest number of cost cells (pairs x T x T2) held by one tile.
DEFAULT_MAX_CELLS = 2**23

#: The dtypes windows may have (half precision overflows: see the module docstring).
DTYPES = (torch.float32, torch.float64)

# Entries whose squared distance is below this fraction of ||a||^2 + ||b||^2 (after centring)
# are recomputed from explicit differences: the matrix-product form loses them to cancellation.
_EXACT_FRACTION = 1e-3

_Mode = Literal["min", "logsumexp"]


class KernelLike(Protocol):
    """What the classifiers expect of a kernel on windows."""

    def __call__(self, x1: Tensor, x2: Tensor) -> Tensor:
        """(B1, T, D), (B2, T2, D) -> (B1, B2)."""
        ...

    def diag(self, x: Tensor) -> Tensor:
        """(B, T, D) -> (B,) the kernel of each window with itself."""
        ...


# --------------------------------------------------------------------------------------------
# the wavefront on a padded, cell-major layout


class _Layout:
    """Anti-diagonal bookkeeping for one (T, T2, band, device).

    Cells live in a padded cell-major tensor ``(T + 1) (T2 + 1)`` x ``P`` whose flat index of
    cell ``(i, j)`` is ``(i + 1) (T2 + 1) + j + 1`` (row and column 0 are the pads ``i = -1``,
    ``j = -1``). Along an anti-diagonal ``i + j = k`` that index grows by ``T2`` per row, so each
    anti-diagonal and its three predecessor sets are strided views: the programme runs in place.
    """

    def __init__(self, t1: int, t2: int, band: int | None, device: torch.device) -> None:
        self.t1, self.t2, self.n_diag = t1, t2, t1 + t2 - 1
        self.n_cells = (t1 + 1) * (t2 + 1)
        i = torch.arange(t1).view(-1, 1)  # (T, 1)
        j = torch.arange(t2).view(1, -1)  # (1, T2)
        valid = torch.ones(t1, t2, dtype=torch.bool)  # (T, T2)
        if band is not None and t1 > 1 and t2 > 1:
            r = (t1 - 1) / (t2 - 1)
            w = max(float(band), max(1.0, r) / 2.0)
            valid = (i.double() - j.double() * r).abs() <= w + 1e-9
        # padded mask of cells that must hold the neutral value: pads and cells outside the band
        neutral = torch.ones(t1 + 1, t2 + 1, dtype=torch.bool)
        neutral[1:, 1:] = ~valid
        neutral[0, 0] = False  # the start M[-1, -1] (0 for DTW, log 1 for GAK)
        self.neutral = neutral.view(-1, 1).to(device)  # ((T+1)(T2+1), 1)
        self.pads_only = band is None or bool(valid.all())
        # admissible rows [lo, hi] of each anti-diagonal (an interval: the band is convex)
        self.rows: list[tuple[int, int]] = []
        for k in range(self.n_diag):
            ii = torch.arange(max(0, k - t2 + 1), min(k, t1 - 1) + 1)
            ok = ii[valid[ii, k - ii]]
            self.rows.append((int(ok[0]), int(ok[-1])) if len(ok) else (1, 0))


_LAYOUT_CACHE: dict[tuple[int, int, int | None, str], _Layout] = {}


def _layout(t1: int, t2: int, band: int | None, device: torch.device) -> _Layout:
    key = (t1, t2, band, str(device))
    if key not in _LAYOUT_CACHE:
        if len(_LAYOUT_CACHE) > 64:
            _LAYOUT_CACHE.clear()
        _LAYOUT_CACHE[key] = _Layout(t1, t2, band, device)
    return _LAYOUT_CACHE[key]


def _prepare(cells: Tensor, lay: _Layout, kind: str) -> None:
    """Set pads (and cells outside the band) to the neutral value and the start to 0."""
    fill = _fill(kind)
    view = cells.view(lay.t1 + 1, lay.t2 + 1, -1)  # (T+1, T2+1, P)
    if lay.pads_only:
        view[0].fill_(fill)
        view[:, 0].fill_(fill)
    else:
        cells.masked_fill_(lay.neutral, fill)
    view[0, 0].fill_(0.0)


def _wavefront(cells: Tensor, lay: _Layout, mode: _Mode) -> Tensor:
    """Run the DP in place, anti-diagonal by anti-diagonal.

    Args:
        cells: ((T+1)(T2+1), P) local terms in the padded layout of :class:`_Layout`, prepared
            by :func:`_prepare`; overwritten with the accumulated values.
        lay: the layout.
        mode: ``min`` (DTW: cost + min of predecessors) or ``logsumexp`` (log GAK: log local
            kernel + log-sum-exp of predecessors).

    Returns:
        (P,) the accumulated value of the last cell (T-1, T2-1).
    """
    t2 = lay.t2
    w = t2 + 1
    tmp = torch.empty_like(cells[: lay.t1])  # (T, P), enough for any anti-diagonal
    for k in range(lay.n_diag):
        lo, hi = lay.rows[k]
        if hi < lo:
            continue
        n = hi - lo + 1
        f0 = lo * t2 + t2 + k + 2  # flat index of cell (lo, k - lo)
        span = (n - 1) * t2 + 1
        cur = cells[f0 : f0 + span : t2]  # (n, P)
        up = cells[f0 - w : f0 - w + span : t2]  # (i-1, j)
        left = cells[f0 - 1 : f0 - 1 + span : t2]  # (i, j-1)
        diag = cells[f0 - w - 1 : f0 - w - 1 + span : t2]  # (i-1, j-1)
        t = tmp[:n]
        if mode == "min":
            torch.minimum(up, left, out=t)
            torch.minimum(t, diag, out=t)
        else:
            torch.logaddexp(up, left, out=t)
            torch.logaddexp(t, diag, out=t)
        cur.add_(t)
    return cells[lay.n_cells - 1]


# --------------------------------------------------------------------------------------------
# squared frame distances


def _sqdist_rows(xf: Tensor, yf: Tensor, names: str) -> Tensor:
    """(n, D), (m, D) -> (n, m) squared Euclidean distances, accurate near zero; n, m >= 1.

    Raises:
        DataError: when the distances would overflow (see :func:`_check_scale`).
    """
    mean = torch.cat([xf, yf]).mean(0, keepdim=True)  # distances are translation invariant
    xc, yc = xf - mean, yf - mean
    xn = (xc * xc).sum(-1)  # (n,)
    yn = (yc * yc).sum(-1)  # (m,)
    scale = float(xn.max() + yn.max())
    _check_scale(names, scale, xf.dtype, "dtw", 1, 1)
    sq = torch.mm(xc, yc.T).mul_(-2.0)  # (n, m)
    sq.add_(xn[:, None]).add_(yn[None, :])
    # cancellation makes the product form inexact for nearly equal frames: recompute those
    small = sq < _EXACT_FRACTION * scale
    if bool(small.any()):
        r, c = small.nonzero(as_tuple=True)
        sq[r, c] = (xc[r] - yc[c]).pow(2).sum(-1)
    return sq.clamp_(min=0.0)


def _check_scale(
    names: str, scale: float, dtype: torch.dtype, kind: str, t1: int, t2: int
) -> None:
    """DataError when squared frame distances could overflow ``dtype``.

    ``scale = max ||a||^2 + max ||b||^2`` over the centred frames bounds every squared frame
    distance (and every intermediate of its matrix-product form) by ``2 scale``; for ``dtw_sq``
    a warping path sums at most ``T + T2 - 1`` of them. One comparison of a Python float, once
    per call (or chunk of paired windows).
    """
    bound = 2.0 * scale * (t1 + t2 - 1 if kind == "dtw_sq" else 1)
    if not bound <= torch.finfo(dtype).max:  # also refuses NaN and inf (an overflowed scale)
        what = "their sums along a warping path" if kind == "dtw_sq" else "frame distances"
        raise DataError(
            f"{names}: feature values too large for {dtype}: squared frame norms (centred) "
            f"reach {scale:.3g}, so {what} would overflow to inf or NaN (largest "
            f"{torch.finfo(dtype).max:.3g}); standardise the features (zero mean, unit "
            "variance per feature) or use float64"
        )


def _local_terms(sq: Tensor, kind: str, sigma: float | None) -> Tensor:
    """Map squared frame distances to the DP's local terms, in place."""
    if kind == "dtw":
        return sq.sqrt_()
    if kind == "dtw_sq":
        return sq
    # GAK: log kappa = -(d^2 / (2 sigma^2) + log(2 - exp(-d^2 / (2 sigma^2))))
    assert sigma is not None
    # -d^2 / (2 sigma^2); sigma * sigma, unlike sigma**2, gives inf (a limit of 0) instead of
    # raising OverflowError above 1.3e154, and the same value below
    u = sq.mul_(-0.5 / (sigma * sigma))
    return u.sub_(torch.log(2.0 - torch.exp(u)))


def _fill(kind: str) -> float:
    return -math.inf if kind == "gak" else math.inf


def _mode(kind: str) -> _Mode:
    return "logsumexp" if kind == "gak" else "min"


def _finish(v: Tensor, kind: str) -> Tensor:
    return v.sqrt_() if kind == "dtw_sq" else v


class _GridPlan:
    """Wavefront views on one Gram tile laid out as ``(T, b1, T2, b2)``, for a fixed shape.

    The tile's local terms come from one matrix product ``(T b1, D) x (D, T2 b2)``, whose
    output *is* the layout ``(T, b1, T2, b2)``: cell ``(i, j)`` of pair ``(a, b)`` sits at
    ``i s_i + a s_a + j s_j + b`` with ``s_i = b1 T2 b2``, ``s_a = T2 b2``, ``s_j = b2``. Along an
    anti-diagonal ``i + j = k`` the offset grows by ``s_i - s_j`` per row, so every anti-diagonal
    and its three predecessor sets are strided ``(n, b1, b2)`` views of the same buffer, built
    once per tile shape and reused by every tile of that shape. Row 0 and column 0 have one
    predecessor each and are cumulative sums; the interior starts at ``k = 2``.
    """

    def __init__(
        self,
        t1: int,
        t2: int,
        b1: int,
        b2: int,
        band: int | None,
        dtype: torch.dtype,
        device: torch.device,
    ) -> None:
        self.t1, self.t2, self.b1, self.b2 = t1, t2, b1, b2
        self.buf = torch.empty(t1 * b1, t2 * b2, dtype=dtype, device=device)  # (T*b1, T2*b2)
        self.grid = self.buf.view(t1, b1, t2, b2)
        lay = _layout(t1, t2, band, torch.device("cpu"))
        self.outside: Tensor | None = None
        if not lay.pads_only:  # cells outside the band: (T, 1, T2, 1) mask
            self.outside = lay.neutral.view(t1 + 1, t2 + 1)[1:, 1:].reshape(t1, 1, t2, 1)
            self.outside = self.outside.to(device)
        s_i, s_a, s_j = b1 * t2 * b2, t2 * b2, b2
        step = (s_i - s_j, s_a, 1)
        self.tmp = torch.empty(min(t1, t2), b1, b2, dtype=dtype, device=device)
        self.steps: list[tuple[Tensor, Tensor, Tensor, Tensor, Tensor]] = []
        buf = self.buf
        for k in range(2, t1 + t2 - 1):
            lo, hi = lay.rows[k]
            lo, hi = max(lo, 1, k - t2 + 1), min(hi, k - 1, t1 - 1)
            if hi < lo:
                continue
            size = (hi - lo + 1, b1, b2)
            f0 = lo * s_i + (k - lo) * s_j  # cell (lo, k - lo)
            self.steps.append(
                (
                    buf.as_strided(size, step, f0),  # (i, j)
                    buf.as_strided(size, step, f0 - s_i),  # (i-1, j)
                    buf.as_strided(size, step, f0 - s_j),  # (i, j-1)
                    buf.as_strided(size, step, f0 - s_i - s_j),  # (i-1, j-1)
                    self.tmp[: size[0]],
                )
            )

    def run(self, mode: _Mode) -> Tensor:
        """Accumulate the local terms held in ``buf`` in place; (b1, b2) value of the last cell."""
        g = self.grid
        row0 = g[0]  # (b1, T2, b2)
        row0.copy_(row0.cumsum(1))
        col0 = g[:, :, 0]  # (T, b1, b2)
        col0.copy_(col0.cumsum(0))
        if mode == "min":
            for cur, up, left, diag, t in self.steps:
                torch.minimum(up, left, out=t)
                torch.minimum(t, diag, out=t)
                cur.add_(t)
        else:
            for cur, up, left, diag, t in self.steps:
                torch.logaddexp(up, left, out=t)
                torch.logaddexp(t, diag, out=t)
                cur.add_(t)
        return g[self.t1 - 1, :, self.t2 - 1]

    def fill(
        self,
        xc: Tensor,
        yc: Tensor,
        xn: Tensor,
        yn: Tensor,
        kind: str,
        sigma: float | None,
        scale: float,
    ) -> None:
        """Write the tile's local terms into ``buf``.

        Args:
            xc: (T*b1, D) centred frames, time-major. yc: (T2*b2, D).
            xn: (T*b1,) their squared norms. yn: (T2*b2,).
            kind: ``dtw``, ``dtw_sq`` or ``gak``. sigma: the GAK bandwidth.
            scale: ``||a||^2 + ||b||^2`` bound below which entries are recomputed exactly.
        """
        sq = torch.addmm(xn[:, None], xc, yc.T, alpha=-2.0, out=self.buf)  # (T*b1, T2*b2)
        sq.add_(yn[None, :])
        small = sq < _EXACT_FRACTION * scale
        if bool(small.any()):
            r, c = small.nonzero(as_tuple=True)
            sq[r, c] = (xc[r] - yc[c]).pow(2).sum(-1)
        sq.clamp_(min=0.0)
        _local_terms(sq, kind, sigma)
        if self.outside is not None:
            self.grid.masked_fill_(self.outside, _fill(kind))


def _paired(
    x: Tensor, y: Tensor, band: int | None, kind: str, sigma: float | None
) -> Tensor:  # (P, T, D), (P, T2, D) -> (P,), P >= 1
    p, t1, _ = x.shape
    t2 = y.shape[1]
    lay = _layout(t1, t2, band, x.device)
    mean = torch.cat([x, y], 1).mean(1, keepdim=True)  # (P, 1, D)
    xc, yc = x - mean, y - mean  # (P, T, D), (P, T2, D)
    norms = torch.stack([torch.linalg.vector_norm(c, dim=-1).amax() for c in (xc, yc)])  # (2,)
    nx, ny = norms.tolist()  # largest centred frame norms: their squares cannot overflow here
    _check_scale("x and y", nx * nx + ny * ny, x.dtype, kind, t1, t2)
    d = torch.cdist(xc, yc, compute_mode="donot_use_mm_for_euclid_dist")
    terms = _local_terms(d.pow_(2), kind, sigma)  # (P, T, T2)
    cells = x.new_empty(lay.n_cells, p)  # ((T+1)(T2+1), P)
    cells.view(t1 + 1, t2 + 1, p)[1:, 1:].copy_(terms.permute(1, 2, 0))
    _prepare(cells, lay, kind)
    return _finish(_wavefront(cells, lay, _mode(kind)), kind)


def _check_finite(name: str, x: Tensor) -> None:
    """Raise :class:`DataError` naming the first window and frame of ``x`` (B, T, D) that holds
    NaN or inf: one such frame would spoil every distance (the frames are centred on a mean
    over all windows)."""
    check_finite(name, x, ("window", "frame"), hint="impute lost frames first")


def _check_pair(x: Tensor, y: Tensor, names: tuple[str, str] = ("x", "y")) -> None:
    """Shapes (B1, T, D) and (B2, T2, D) with T, T2, D >= 1, one dtype of :data:`DTYPES`, one
    device, finite values (ShapeError, DataError)."""
    nx, ny = names
    check_shape(nx, x, ("B1", "T", "D"))
    check_shape(ny, y, ("B2", "T2", x.shape[2]))
    if x.shape[1] < 1 or y.shape[1] < 1 or x.shape[2] < 1:
        raise ShapeError(
            f"expected at least one frame and one feature (T, T2, D >= 1), got {nx} "
            f"{tuple(x.shape)}, {ny} {tuple(y.shape)}"
        )
    if x.dtype != y.dtype or x.device != y.device:
        raise ShapeError(
            f"expected {nx} and {ny} with the same dtype and device, got {x.dtype}/{x.device} "
            f"and {y.dtype}/{y.device}"
        )
    if x.dtype not in DTYPES:
        half = x.is_floating_point()  # float16 overflows squared distances beyond 256
        why = (
            ": half precision overflows or rounds off frame distances, use x.float()"
            if half
            else ""
        )
        raise ShapeError(
            f"expected floating point windows of dtype torch.float32 or torch.float64, got "
            f"{x.dtype}{why}"
        )
    _check_finite(nx, x)
    if y is not x:
        _check_finite(ny, y)


def _check_band(band: object) -> None:
    """ConfigError unless ``band`` is None or an integer >= 0 (an integral float counts)."""
    ok = band is None or (
        checks.is_real(band)
        and math.isfinite(float(band))  # type: ignore[arg-type]
        and float(band) == int(band)  # type: ignore[arg-type, call-overload]
        and float(band) >= 0  # type: ignore[arg-type]
    )
    if not ok:
        raise ConfigError(f"expected band None or an integer >= 0, got {band!r}")


def _check_max_cells(max_cells: object) -> int:
    """``max_cells`` as an int; ConfigError unless it is an integer >= 1."""
    return checks.integer("max_cells", max_cells, minimum=1)


#: Cost cells per Gram tile on CPU: about 2 MB in float64, so a tile stays in cache.
_CACHE_CELLS = 2**18


def _gram(
    x: Tensor,
    y: Tensor,
    band: int | None,
    kind: str,
    sigma: float | None,
    max_cells: int,
    symmetric: bool,
) -> Tensor:
    x, y = x.detach(), y.detach()  # in-place wavefront: no autograd (module docstring)
    b1, t1, _ = x.shape
    b2, t2, _ = y.shape
    out = torch.empty(b1, b2, dtype=x.dtype, device=x.device)
    if b1 == 0 or b2 == 0:
        return out
    cells = min(max_cells, _CACHE_CELLS) if x.device.type == "cpu" else max_cells
    pairs = max(1, cells // (t1 * t2))
    side = max(1, int(math.sqrt(pairs)))
    r1 = min(b1, side)
    r2 = min(b2, max(1, pairs // r1))
    if symmetric:
        r1 = r2 = min(r1, r2)
    # centre once (distances are translation invariant) and lay frames out time-major per tile
    mean = torch.cat([x.reshape(-1, x.shape[2]), y.reshape(-1, y.shape[2])]).mean(0)  # (D,)
    xc_all, yc_all = x - mean, y - mean  # (B1, T, D), (B2, T2, D)
    xn_all, yn_all = (xc_all * xc_all).sum(-1), (yc_all * yc_all).sum(-1)  # (B1, T), (B2, T2)
    scale = float(xn_all.max() + yn_all.max())
    _check_scale("x and y", scale, x.dtype, kind, t1, t2)
    mode = _mode(kind)
    plans: dict[tuple[int, int], _GridPlan] = {}

    def frames(xc: Tensor, xn: Tensor, s: int, e: int) -> tuple[Tensor, Tensor]:
        return xc[s:e].transpose(0, 1).reshape(-1, xc.shape[2]), xn[s:e].T.reshape(-1)

    for s1 in range(0, b1, r1):
        e1 = min(b1, s1 + r1)
        xs, xns = frames(xc_all, xn_all, s1, e1)  # (T*b1, D), (T*b1,)
        for s2 in range(s1 if symmetric else 0, b2, r2):
            e2 = min(b2, s2 + r2)
            ys, yns = frames(yc_all, yn_all, s2, e2)  # (T2*b2, D), (T2*b2,)
            key = (e1 - s1, e2 - s2)
            if key not in plans:
                plans[key] = _GridPlan(t1, t2, *key, band, x.dtype, x.device)
            plan = plans[key]
            plan.fill(xs, ys, xns, yns, kind, sigma, scale)
            block = _finish(plan.run(mode), kind)  # (b1, b2)
            out[s1:e1, s2:e2] = block
            if symmetric and s2 != s1:
                out[s2:e2, s1:e1] = block.T
    if symmetric:
        out = 0.5 * (out + out.T)  # the diagonal tiles are symmetric only up to rounding
    return out


def _chunked_paired(
    x: Tensor, y: Tensor, band: int | None, kind: str, sigma: float | None, max_cells: int
) -> Tensor:
    x, y = x.detach(), y.detach()  # in-place wavefront: no autograd (module docstring)
    t1, t2 = x.shape[1], y.shape[1]
    per_pair = t1 * t2
    step = max(1, max_cells // per_pair)
    outs = [
        _paired(x[s : s + step], y[s : s + step], band, kind, sigma)
        for s in range(0, len(x), step)
    ]
    return torch.cat(outs) if outs else x.new_zeros(0)


# --------------------------------------------------------------------------------------------
# public functions


def dtw_distance(
    x: Tensor,
    y: Tensor,
    *,
    band: int | None = None,
    squared: bool = False,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> Tensor:
    """DTW between every window of ``x`` and every window of ``y``.

    Args:
        x: (B1, T, D) windows, any units (features of frames).
        y: (B2, T2, D) windows, same units and D as ``x``; T2 may differ from T.
        band: Sakoe-Chiba half-width in frames of ``x`` (see the module docstring for unequal
            lengths); None for no band.
        squared: False: sum of Euclidean local costs ``||x_i - y_j||`` along the optimal path.
            True: ``sqrt`` of the smallest sum of *squared* local costs ``||x_i - y_j||^2``
            (the definition of ``tslearn.metrics.dtw``).
        max_cells: the largest number of cost cells (pairs x T x T2) one tile holds, an integer
            >= 1; peak memory is about 3 x 4 bytes x ``max_cells`` in float32.

    Returns:
        (B1, B2) DTW distances, same units as the features, dtype and device of ``x``. When
        ``y is x`` only the upper triangle of tiles is computed and the result is symmetric.

    Raises:
        ShapeError: on wrong ranks, T, T2 or D = 0, different D, dtypes or devices, or a dtype
            other than float32 and float64 (half precision included: see the module docstring).
        ConfigError: on a band that is not None or an integer >= 0 (NaN, inf, a string), or a
            ``max_cells`` that is not an integer >= 1.
        DataError: when a window of ``x`` or ``y`` holds NaN or inf (naming window and frame),
            or features so large that squared frame distances (with ``squared``, their sums
            along a path) overflow the dtype (see the module docstring).
    """
    _check_pair(x, y)
    _check_band(band)
    max_cells = _check_max_cells(max_cells)
    kind = "dtw_sq" if squared else "dtw"
    return _gram(x, y, band, kind, None, max_cells, symmetric=y is x)


def dtw_paired(
    x: Tensor,
    y: Tensor,
    *,
    band: int | None = None,
    squared: bool = False,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> Tensor:
    """DTW between ``x[b]`` and ``y[b]`` for each b (no cross pairs).

    Args:
        x: (B, T, D) windows.
        y: (B, T2, D) windows.
        band: as in :func:`dtw_distance`.
        squared: as in :func:`dtw_distance`.
        max_cells: as in :func:`dtw_distance`.

    Returns:
        (B,) DTW distances.

    Raises:
        ShapeError: as :func:`dtw_distance`, or on different batch sizes.
        ConfigError: as :func:`dtw_distance`.
        DataError: as :func:`dtw_distance`.
    """
    _check_pair(x, y)
    _check_band(band)
    max_cells = _check_max_cells(max_cells)
    if x.shape[0] != y.shape[0]:
        raise ShapeError(f"expected y with batch {x.shape[0]}, got {tuple(y.shape)}")
    return _chunked_paired(x, y, band, "dtw_sq" if squared else "dtw", None, max_cells)


def gak_log(
    x: Tensor,
    y: Tensor,
    *,
    sigma: float,
    band: int | None = None,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> Tensor:
    """Log of Cuturi's global alignment kernel between every window of ``x`` and ``y``.

    ``k(x, y) = sum over alignments pi of prod_{(i, j) in pi} kappa(x_i, y_j)`` with
    ``kappa = exp(-phi)``, ``phi(a, b) = ||a - b||^2 / (2 sigma^2) + log(2 - exp(-||a - b||^2 /
    (2 sigma^2)))``; recursion ``M[i, j] = kappa(x_i, y_j) (M[i-1, j] + M[i, j-1] + M[i-1, j-1])``
    with ``M[-1, -1] = 1``, here in log space.

    Args:
        x: (B1, T, D) windows.
        y: (B2, T2, D) windows.
        sigma: bandwidth of the local kernel, in feature units.
        band: as in :func:`dtw_distance` (restricts the alignments).
        max_cells: as in :func:`dtw_distance`.

    Returns:
        (B1, B2) ``log k(x, y)``.

    Raises:
        ShapeError: as :func:`dtw_distance`.
        ConfigError: on a ``sigma`` that is not a finite number > 0, or as
            :func:`dtw_distance` (band, max_cells).
        DataError: as :func:`dtw_distance`.
    """
    _check_pair(x, y)
    _check_band(band)
    max_cells = _check_max_cells(max_cells)
    sigma = checks.positive("sigma", sigma)
    return _gram(x, y, band, "gak", sigma, max_cells, symmetric=y is x)


def gak_log_paired(
    x: Tensor,
    y: Tensor,
    *,
    sigma: float,
    band: int | None = None,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> Tensor:
    """``log k(x[b], y[b])`` of the global alignment kernel for each b.

    Args:
        x: (B, T, D) windows.
        y: (B, T2, D) windows.
        sigma: as in :func:`gak_log`.
        band: as in :func:`dtw_distance`.
        max_cells: as in :func:`dtw_distance`.

    Returns:
        (B,) log kernel values.

    Raises:
        ShapeError: as :func:`dtw_distance`, or on different batch sizes.
        ConfigError: as :func:`gak_log`.
        DataError: as :func:`dtw_distance`.
    """
    _check_pair(x, y)
    _check_band(band)
    max_cells = _check_max_cells(max_cells)
    sigma = checks.positive("sigma", sigma)
    if x.shape[0] != y.shape[0]:
        raise ShapeError(f"expected y with batch {x.shape[0]}, got {tuple(y.shape)}")
    return _chunked_paired(x, y, band, "gak", sigma, max_cells)


def gak_sigma(median_distance: float, length: int) -> float:
    """Bandwidth of the global alignment kernel from the median DTW distance (Cuturi 2011).

    Cuturi's rule, ``sigma = median frame distance * sqrt(median length)``, with the median
    frame distance taken as ``median_distance / length`` (DTW sums the aligned frames'
    distances): ``sigma = median_distance / sqrt(length)``. The square root of the length
    keeps the local kernel from vanishing over a whole alignment; a sigma of the order of a
    single frame's distance (``median_distance / length``) made the kernel so peaked that an
    IVM on noisy sine windows (``tests/prediction/test_ivm.py``) classified 92 % of them, 87 %
    with ``sqrt(median_distance / length)``, against 100 % with this rule.

    Args:
        median_distance: :func:`median_dtw` of the windows, in feature units.
        length: T, the windows' number of frames, >= 1.

    Returns:
        sigma (at least 1e-3).

    Raises:
        ConfigError: when ``median_distance`` is not a finite number >= 0 or ``length`` not
            an integer >= 1.
    """
    checks.non_negative("median_distance", median_distance)
    checks.integer("length", length, minimum=1)
    return max(float(median_distance) / math.sqrt(length), 1e-3)


def median_dtw(x: Tensor, n_pairs: int = 500, seed: int = 0, *, band: int | None = None) -> float:
    """Median DTW distance over random pairs of distinct windows (the ``gamma`` heuristic).

    Args:
        x: (B, T, D) windows, B >= 2, float32 or float64, finite.
        n_pairs: number of random pairs, >= 1.
        seed: seed of the pair sampler, an integer in [0, 2^32 - 1].
        band: as in :func:`dtw_distance`.

    Returns:
        The median distance (a positive float; 1.0 if all sampled pairs coincide).

    Raises:
        ShapeError: when fewer than two windows are given, or as :func:`dtw_distance`.
        ConfigError: when ``n_pairs < 1``, ``seed`` is not an integer in [0, 2^32 - 1], or as
            :func:`dtw_distance` (band).
        DataError: when a window holds NaN or inf (naming window and frame), or as
            :func:`dtw_distance` (features so large that distances overflow).
    """
    check_shape("x", x, ("B", "T", "D"))
    if x.shape[0] < 2:
        raise ShapeError(f"expected x (B >= 2, T, D), got {tuple(x.shape)}")
    checks.integer("n_pairs", n_pairs, minimum=1)
    seed = checks.seed(seed)
    _check_band(band)
    _check_pair(x, x)  # shapes, dtype, finite values
    g = torch.Generator().manual_seed(seed)
    i = torch.randint(0, x.shape[0], (n_pairs,), generator=g)
    j = (i + torch.randint(1, x.shape[0], (n_pairs,), generator=g)) % x.shape[0]
    d = dtw_paired(x[i.to(x.device)], x[j.to(x.device)], band=band)
    med = float(d.median())
    return med if med > 0 else 1.0


# --------------------------------------------------------------------------------------------
# kernels


class DTWKernel:
    """``k(x, y) = exp(-DTW(x, y) / gamma)`` on windows.

    Not positive definite in general (DTW is not of negative type): fine for the IVM (regularised
    kernel logistic regression), a GP needs jitter. ``diag`` is exactly 1 since DTW(x, x) = 0.

    Args:
        gamma: length scale in the units of DTW distances (> 0, finite); :func:`median_dtw`
            is a common choice.
        band: Sakoe-Chiba half-width, as in :func:`dtw_distance`.
        max_cells: tile size, as in :func:`dtw_distance`.

    Raises:
        ConfigError: on a ``gamma`` that is not a finite number > 0, or a band or
            ``max_cells`` that :func:`dtw_distance` refuses.
    """

    name = "dtw"
    positive_definite = False
    #: windows of different lengths T may be compared
    equal_lengths = False

    def __init__(
        self, gamma: float, band: int | None = None, *, max_cells: int = DEFAULT_MAX_CELLS
    ) -> None:
        self.gamma = checks.positive("gamma", gamma)
        _check_band(band)
        self.band = band
        self.max_cells = _check_max_cells(max_cells)

    @property
    def hparams(self) -> dict[str, Any]:
        """Keyword arguments that rebuild this kernel."""
        return {"gamma": self.gamma, "band": self.band}

    def __call__(self, x1: Tensor, x2: Tensor) -> Tensor:
        """(B1, T, D), (B2, T2, D) -> (B1, B2) kernel values in (0, 1].

        Raises:
            ShapeError, DataError: as :func:`dtw_distance` (naming ``x1`` as ``x``).
        """
        d = dtw_distance(x1, x2, band=self.band, max_cells=self.max_cells)
        return torch.exp(-d / self.gamma)

    def diag(self, x: Tensor) -> Tensor:
        """(B, T, D) -> (B,) ones."""
        check_shape("x", x, ("B", "T", "D"))
        return torch.ones(x.shape[0], dtype=x.dtype, device=x.device)

    def __repr__(self) -> str:
        return f"DTWKernel(gamma={self.gamma:g}, band={self.band})"


class GlobalAlignmentKernel:
    """Cuturi's global alignment kernel (positive definite), see :func:`gak_log`.

    Args:
        sigma: bandwidth of the local kernel in feature units (> 0); Cuturi suggests a multiple
            of the median frame distance times ``sqrt(T)``.
        band: restricts the alignments, as in :func:`dtw_distance`.
        normalize: return ``k(x, y) / sqrt(k(x, x) k(y, y))`` (values in (0, 1], diag 1) instead
            of the raw kernel, whose magnitude grows exponentially with T.
        max_cells: tile size, as in :func:`dtw_distance`.

    Raises:
        ConfigError: on a ``sigma`` that is not a finite number > 0, or a band or
            ``max_cells`` that :func:`dtw_distance` refuses.
    """

    name = "gak"
    positive_definite = True
    #: windows of different lengths T may be compared
    equal_lengths = False

    def __init__(
        self,
        sigma: float,
        band: int | None = None,
        *,
        normalize: bool = True,
        max_cells: int = DEFAULT_MAX_CELLS,
    ) -> None:
        self.sigma = checks.positive("sigma", sigma)
        _check_band(band)
        self.band = band
        self.normalize = bool(normalize)
        self.max_cells = _check_max_cells(max_cells)

    @property
    def hparams(self) -> dict[str, Any]:
        """Keyword arguments that rebuild this kernel."""
        return {"sigma": self.sigma, "band": self.band, "normalize": self.normalize}

    def log_diag(self, x: Tensor) -> Tensor:
        """(B, T, D) -> (B,) ``log k(x_b, x_b)`` of the raw kernel."""
        check_shape("x", x, ("B", "T", "D"))
        return gak_log_paired(x, x, sigma=self.sigma, band=self.band, max_cells=self.max_cells)

    def __call__(self, x1: Tensor, x2: Tensor) -> Tensor:
        """(B1, T, D), (B2, T2, D) -> (B1, B2) kernel values.

        Raises:
            ShapeError, DataError: as :func:`gak_log` (naming ``x1`` as ``x``).
        """
        lk = gak_log(x1, x2, sigma=self.sigma, band=self.band, max_cells=self.max_cells)
        if self.normalize:
            d1 = self.log_diag(x1)
            d2 = d1 if x2 is x1 else self.log_diag(x2)
            lk = lk - 0.5 * (d1[:, None] + d2[None, :])
        return torch.exp(lk)

    def diag(self, x: Tensor) -> Tensor:
        """(B, T, D) -> (B,) ``k(x_b, x_b)`` (ones when normalised)."""
        if self.normalize:
            check_shape("x", x, ("B", "T", "D"))
            return torch.ones(x.shape[0], dtype=x.dtype, device=x.device)
        return torch.exp(self.log_diag(x))

    def __repr__(self) -> str:
        return f"GlobalAlignmentKernel(sigma={self.sigma:g}, band={self.band})"


class RBFKernel:
    """Gaussian kernel on flattened windows: ``exp(-||x - y||^2 / (2 lengthscale^2))``.

    Args:
        lengthscale: in feature units (> 0, finite); windows must have equal T.

    Raises:
        ConfigError: on a ``lengthscale`` that is not a finite number > 0.
    """

    name = "rbf"
    positive_definite = True
    #: both windows of a pair must have the same length T
    equal_lengths = True

    def __init__(self, lengthscale: float) -> None:
        self.lengthscale = checks.positive("lengthscale", lengthscale)

    @property
    def hparams(self) -> dict[str, Any]:
        """Keyword arguments that rebuild this kernel."""
        return {"lengthscale": self.lengthscale}

    def __call__(self, x1: Tensor, x2: Tensor) -> Tensor:
        """(B1, T, D), (B2, T, D) -> (B1, B2) kernel values in (0, 1]; an empty batch gives
        an empty result.

        Raises:
            ShapeError: on wrong shapes (T or D = 0 included), different dtypes or devices, or
                a dtype other than float32 and float64 (as :func:`dtw_distance`).
            DataError: when a window holds NaN or inf (naming window and frame), or features
                so large that the squared distance of flattened windows overflows the dtype.
        """
        check_shape("x1", x1, ("B1", "T", "D"))
        check_shape("x2", x2, ("B2", x1.shape[1], x1.shape[2]))
        _check_pair(x1, x2, ("x1", "x2"))
        if x1.shape[0] == 0 or x2.shape[0] == 0:
            return x1.new_empty(x1.shape[0], x2.shape[0])
        sq = _sqdist_rows(x1.flatten(1), x2.flatten(1), "x1 and x2")  # (B1, B2)
        return torch.exp(-0.5 * sq / (self.lengthscale * self.lengthscale))  # ** 2 may raise

    def diag(self, x: Tensor) -> Tensor:
        """(B, T, D) -> (B,) ones."""
        check_shape("x", x, ("B", "T", "D"))
        return torch.ones(x.shape[0], dtype=x.dtype, device=x.device)

    def __repr__(self) -> str:
        return f"RBFKernel(lengthscale={self.lengthscale:g})"


_KERNELS: dict[str, Callable[..., KernelLike]] = {
    "dtw": DTWKernel,
    "gak": GlobalAlignmentKernel,
    "rbf": RBFKernel,
}


def kernel_from_state(name: str, hparams: dict[str, Any]) -> KernelLike:
    """Rebuild one of this module's kernels from its ``name`` and ``hparams``.

    Raises:
        ConfigError: for an unknown name, ``hparams`` that is not a dict, arguments the
            kernel does not take, required ones that are missing (named), or values the
            kernel refuses. Checkpoint loaders turn it into a
            :class:`~iplanner_torch.errors.CheckpointError`.
    """
    if not isinstance(name, str) or name not in _KERNELS:
        raise ConfigError(f"unknown kernel {name!r}; known: {sorted(_KERNELS)}")
    if not isinstance(hparams, dict):
        raise ConfigError(
            f"expected the hparams of kernel {name!r} a dict, got {type(hparams).__name__}"
        )
    params = inspect.signature(_KERNELS[name]).parameters
    unknown = set(hparams) - set(params)
    if unknown:
        raise ConfigError(f"kernel {name!r} takes no arguments {sorted(unknown)}")
    missing = [p for p, spec in params.items() if spec.default is spec.empty and p not in hparams]
    if missing:
        raise ConfigError(f"kernel {name!r} needs the arguments {missing}, missing from {hparams}")
    return _KERNELS[name](**hparams)
