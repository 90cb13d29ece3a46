"""Import Vector Machine action classifier (paper sec. 4.1, eq. IVMclassifier).

``p(c = a_j | F_prev, p) = exp(f_j(F_prev)) / sum_k exp(f_k(F_prev))`` with, per progress state
``p``, the kernel expansion ``f_c(x) = b_c + sum_{s in S} a_{s c} k(x, x_s)`` over a small set S
of *import vectors* chosen greedily among the training windows (Zhu and Hastie 2005, "Kernel
logistic regression and the import vector machine").

Training minimises the regularised negative log-likelihood

    H(b, a) = -sum_i log p(y_i | x_i) + lam / 2 sum_c a_c^T (K_SS + s I) a_c

(the negative log-likelihood summed over the N points, where Zhu and Hastie average it: this
``lam`` is theirs times N), where ``s >= 0`` is the smallest shift that makes the training
Gram positive semi-definite (``s = 0`` up to jitter for positive definite kernels; the DTW
kernel is not one, and without the shift H would be unbounded below). Because the
eigenvalues of a principal submatrix interlace those of the whole Gram, ``K_SS + s I`` is PSD
for every S.

Optimiser. Newton steps use Boehning's bound on the softmax Hessian,
``diag(p) - p p^T <= (I - 1 1^T / C) / 2``, so each step solves one fixed ``(m+1) x (m+1)``
system ``(Phi^T Phi / 2 + lam Pen) delta = grad`` for all classes at once (coefficients keep
sum-to-zero rows) and never increases H (a majorise-minimise step). Hence the recorded loss is
non-increasing: adding an import vector with coefficient 0 leaves H unchanged and every later
step only lowers it. The bound is loose, so the steps shrink with ``lam``: the final refit
(``10 newton_steps`` steps) reaches H's minimum on S to about 1e-5 relative at the
predictors' ``lam = 0.03``, but can stop well above it at this class's default ``1e-3``.

Greedy selection. Each import step draws ``candidates`` random not-yet-imported training
windows (all of them when ``candidates`` is None). Each candidate is scored by
``newton_steps`` warm-started Newton steps on the parameters that its import introduces or
couples to directly, its new coefficients and the biases, with the coefficients of the vectors
already in S held fixed (vectorised over all candidates). The candidate with the smallest H is
imported and then the whole model (all coefficients) is refitted by ``newton_steps`` steps. The
loop stops when the relative decrease of H over the last step is below ``tol`` or
``|S| = max_import``; a final refit of up to ``10 newton_steps`` steps follows.

Classes missing from the training labels get the fixed logit ``-inf``: their probability is
exactly 0. A state whose windows show one class only has no import vectors and gives that class
probability 1.
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Callable, Sequence
from typing import Any

import torch
from torch import Tensor

from iplanner_torch import checks
from iplanner_torch.errors import CheckpointError, ConfigError, DataError, ShapeError
from iplanner_torch.prediction.dtw import KernelLike, kernel_from_state
from iplanner_torch.types import check_finite, check_shape, resolve_device

__all__ = ["ActionClassifier", "IVMClassifier", "feature_columns"]

_JITTER = 1e-8


def _check_windows(name: str, x: Tensor) -> None:
    check_shape(name, x, ("N", "T", "D"))
    if not x.is_floating_point():
        raise ShapeError(f"expected {name} floating point, got {x.dtype}")


def _check_labels(name: str, y: Tensor, n: int, high: int) -> None:
    check_shape(name, y, (n,))
    if y.dtype != torch.int64:
        raise ShapeError(f"expected {name} int64, got {y.dtype}")
    if n and (int(y.min()) < 0 or int(y.max()) >= high):
        raise DataError(f"expected {name} in [0, {high}), got [{int(y.min())}, {int(y.max())}]")


class IVMClassifier:
    """Multi-class kernel logistic regression on a greedily grown basis (eq. IVMclassifier).

    Args:
        kernel: callable ``(x1 (B1, T, D), x2 (B2, T, D)) -> (B1, B2)``, e.g.
            :class:`~iplanner_torch.prediction.dtw.DTWKernel`; an attribute
            ``positive_definite = True`` skips the eigenvalue shift (see the module docstring).
        num_classes: C, the number of classes (labels are 0..C-1), an integer >= 1.
        lam: regularisation weight (> 0, finite).
        max_import: the largest number of import vectors, an integer >= 0.
        tol: stop when the relative decrease of H in one import step is below this (>= 0,
            finite).
        candidates: random candidates scored per import step, an integer >= 1; None scores
            all.
        newton_steps: Newton (bound) steps per candidate and per refit, an integer >= 1.
        seed: seed of the candidate sampler, an integer in [0, 2^32 - 1].

    Raises:
        ConfigError: when ``kernel`` is not callable (None), or a setting is not of the type
            and range above (a float ``2.5`` or a string ``"2"`` for an integer, NaN or inf
            included).

    Attributes (after ``fit``):
        loss_history_: H after the bias-only start, after each import, and after the final
            refit (non-increasing).
        import_index_: (M,) indices of the import vectors in the training set, in import order.
    """

    def __init__(
        self,
        kernel: Callable[[Tensor, Tensor], Tensor],
        *,
        num_classes: int,
        lam: float = 1e-3,
        max_import: int = 60,
        tol: float = 1e-3,
        candidates: int | None = 200,
        newton_steps: int = 3,
        seed: int = 0,
    ) -> None:
        if not callable(kernel):
            raise ConfigError(
                "expected kernel a callable (x1 (B1, T, D), x2 (B2, T, D)) -> (B1, B2), e.g. "
                f"iplanner_torch.prediction.dtw.DTWKernel, got {kernel!r}"
            )
        self.kernel = kernel
        self.num_classes = checks.integer("num_classes", num_classes, minimum=1)
        self.lam = checks.positive("lam", lam)  # NaN and inf refused too
        self.max_import = checks.integer("max_import", max_import, minimum=0)
        self.tol = checks.non_negative("tol", tol)
        self.candidates = checks.optional(checks.integer, "candidates", candidates, minimum=1)
        self.newton_steps = checks.integer("newton_steps", newton_steps, minimum=1)
        self.seed = checks.seed(seed)
        self.classes_: Tensor | None = None
        self.import_vectors_: Tensor | None = None
        self.import_index_: Tensor | None = None
        self.weights_: Tensor | None = None
        self.loss_history_: list[float] = []

    # ------------------------------------------------------------------ training

    def fit(self, x: Tensor, y: Tensor) -> IVMClassifier:
        """Fit on windows ``x`` with labels ``y``.

        Args:
            x: (N, T, D) windows (features per frame).
            y: (N,) int64 class labels in [0, num_classes).

        Returns:
            self.

        Raises:
            ShapeError: on wrong shapes or dtypes.
            DataError: on labels out of range or an empty training set.
        """
        _check_windows("x", x)
        n = x.shape[0]
        _check_labels("y", y, n, self.num_classes)
        if n == 0:
            raise DataError("expected at least one training window, got N = 0")
        classes, yc = torch.unique(y.cpu(), return_inverse=True)
        self.classes_ = classes
        c = len(classes)
        dev = x.device
        self.import_index_ = torch.zeros(0, dtype=torch.int64)
        self.import_vectors_ = x[:0].detach().clone()
        if c == 1:
            self.weights_ = torch.zeros(1, 1, dtype=torch.float64)
            self.loss_history_ = [0.0]
            return self
        yc = yc.to(dev)
        onehot = torch.nn.functional.one_hot(yc, c).double()  # (N, C')
        kmat = self.kernel(x, x).double()  # (N, N)
        kmat = 0.5 * (kmat + kmat.T)
        shift = _JITTER * float(kmat.diagonal().abs().mean().clamp(min=1e-12))
        if not getattr(self.kernel, "positive_definite", False):
            lam_min = float(torch.linalg.eigvalsh(kmat.cpu())[0])
            shift += max(0.0, -lam_min) * (1.0 + 1e-6)

        # bias-only start: the exact optimum, log class frequencies with zero-mean rows
        freq = onehot.mean(0)
        bias = freq.log() - freq.log().mean()
        sel: list[int] = []
        w = bias.view(1, c).clone()  # (m+1, C'): row 0 the bias, then one row per import
        phi = torch.ones(n, 1, dtype=torch.float64, device=dev)  # (N, m+1)
        pen = torch.zeros(1, 1, dtype=torch.float64, device=dev)  # (m+1, m+1)
        loss = self._loss(phi @ w, onehot, w, pen)
        history = [loss]
        gen = torch.Generator().manual_seed(self.seed)
        remaining = torch.ones(n, dtype=torch.bool)
        limit = min(self.max_import, n)
        while len(sel) < limit:
            pool = remaining.nonzero().squeeze(1)
            if self.candidates is not None and len(pool) > self.candidates:
                pool = pool[torch.randperm(len(pool), generator=gen)[: self.candidates]]
            best, b_new, v_new = self._score_candidates(
                kmat, phi, w, pen, onehot, pool.to(dev), sel, shift
            )
            j = int(pool[best])
            sel.append(j)
            remaining[j] = False
            kj = kmat[:, j : j + 1]  # (N, 1)
            phi = torch.cat([phi, kj], 1)
            pen = self._penalty(kmat, sel, shift, dev)
            # start from the candidate's own fit (H already below the last value), refit all
            w0 = torch.cat([w, w.new_zeros(1, c)], 0)  # H(w0) = the last recorded H
            w = torch.cat([b_new.view(1, c), w[1:], v_new.view(1, c)], 0).double()
            if self._loss(phi @ w, onehot, w, pen) > history[-1]:  # float32 scoring rounding
                w = w0
            w = self._refit(phi, w, pen, onehot, self.newton_steps)
            history.append(self._loss(phi @ w, onehot, w, pen))
            rel = (history[-2] - history[-1]) / max(abs(history[-2]), 1e-300)
            if rel < self.tol:
                break
        w = self._refit(phi, w, pen, onehot, 10 * self.newton_steps)
        history.append(self._loss(phi @ w, onehot, w, pen))
        idx = torch.tensor(sel, dtype=torch.int64)
        self.import_index_ = idx
        self.import_vectors_ = x[idx.to(dev)].detach().clone()
        self.weights_ = w.cpu()
        self.loss_history_ = history
        return self

    @staticmethod
    def _penalty(kmat: Tensor, sel: list[int], shift: float, dev: torch.device) -> Tensor:
        m = len(sel)
        idx = torch.tensor(sel, device=dev)
        pen = torch.zeros(m + 1, m + 1, dtype=torch.float64, device=dev)
        pen[1:, 1:] = kmat[idx][:, idx] + shift * torch.eye(m, dtype=torch.float64, device=dev)
        return pen

    def _loss(self, logits: Tensor, onehot: Tensor, w: Tensor, pen: Tensor) -> float:
        nll = -(torch.log_softmax(logits, -1) * onehot).sum()
        return float(nll + 0.5 * self.lam * (w * (pen @ w)).sum())

    def _refit(self, phi: Tensor, w: Tensor, pen: Tensor, onehot: Tensor, steps: int) -> Tensor:
        """Bound-Newton steps on all coefficients (never increase H)."""
        m1 = phi.shape[1]
        bound = 0.5 * phi.T @ phi + self.lam * pen  # (m+1, m+1)
        bound = bound + _JITTER * bound.diagonal().mean() * torch.eye(
            m1, dtype=bound.dtype, device=bound.device
        )
        chol = torch.linalg.cholesky(bound)
        for _ in range(steps):
            r = torch.softmax(phi @ w, -1) - onehot  # (N, C')
            grad = phi.T @ r + self.lam * (pen @ w)  # (m+1, C')
            w = w - torch.cholesky_solve(grad, chol)
        return w

    def _score_candidates(
        self,
        kmat: Tensor,
        phi: Tensor,
        w: Tensor,
        pen: Tensor,
        onehot: Tensor,
        pool: Tensor,
        sel: list[int],
        shift: float,
    ) -> tuple[int, Tensor, Tensor]:
        """The candidate (index into ``pool``) that lowers H most, with its bias and coefficients.

        Per candidate l the parameters (bias b, new coefficients v) take ``newton_steps``
        bound-Newton steps from (current bias, 0), the other coefficients fixed; the 2 x 2 bound
        ``[[N, sum k], [sum k, sum k^2]] / 2 + lam [[0, 0], [0, k_ll + s]]`` is shared by classes.
        """
        n, c = onehot.shape
        lam = self.lam
        # large problems are scored in float32 (twice the speed); the refit is float64
        dt = torch.float32 if n * len(pool) * c > 2**20 else torch.float64
        kl = kmat[:, pool].to(dt)  # (N, L)
        base = (phi[:, 1:] @ w[1:]).to(dt)  # (N, C') logits of the fixed part, without bias
        onehot = onehot.to(dt)
        w = w.to(dt)
        bias = w[0].expand(len(pool), c).clone()  # (L, C')
        v = torch.zeros_like(bias)  # (L, C')
        if sel:
            k_sl = kmat[torch.tensor(sel, device=kmat.device)][:, pool].to(dt)  # (m, L)
            cross = k_sl.T @ w[1:]  # (L, C') coupling of v with the fixed coefficients
        else:
            cross = torch.zeros_like(bias)
        k_ll = (kmat[pool, pool] + shift).to(dt)  # (L,)
        s1 = kl.sum(0)  # (L,)
        s2 = (kl * kl).sum(0)  # (L,)
        a11 = torch.full_like(s1, 0.5 * n) * (1 + _JITTER)
        a12 = 0.5 * s1
        a22 = 0.5 * s2 + lam * k_ll
        a22 = a22 * (1 + _JITTER) + 1e-30
        det = a11 * a22 - a12 * a12  # (L,)
        # class-major layout (C', L, N): softmax reductions run over the outer dimension
        klt = kl.T.contiguous()  # (L, N)
        base_c = base.T.unsqueeze(1)  # (C', 1, N)
        y_c = onehot.T.unsqueeze(1)  # (C', 1, N)
        b_c = bias.T.contiguous()  # (C', L)
        v_c = v.T.contiguous()  # (C', L)
        cross_c = cross.T  # (C', L)

        def logits() -> Tensor:  # (C', L, N)
            return torch.addcmul(base_c + b_c.unsqueeze(-1), klt, v_c.unsqueeze(-1))

        for _ in range(self.newton_steps):
            e = logits()
            e.sub_(e.amax(0)).exp_()
            e.div_(e.sum(0)).sub_(y_c)  # residual p - y
            g_b = e.sum(-1)  # (C', L)
            g_v = torch.einsum("cln,ln->cl", e, klt) + lam * (cross_c + k_ll * v_c)  # (C', L)
            b_c = b_c - (a22 * g_b - a12 * g_v) / det
            v_c = v_c - (a11 * g_v - a12 * g_b) / det
        e = logits()
        mx = e.amax(0)  # (L, N)
        lse = mx + (e - mx).exp_().sum(0).log_()  # (L, N)
        nll = (lse - (e * y_c).sum(0)).sum(-1)  # (L,)
        pen_new = (v_c * (2.0 * cross_c + k_ll * v_c)).sum(0)  # (L,)
        score = nll + 0.5 * lam * pen_new  # H minus the constant penalty of the fixed part
        best = int(torch.argmin(score))
        return best, b_c[:, best], v_c[:, best]

    # ------------------------------------------------------------------ inference

    def to(self, device: torch.device | str) -> IVMClassifier:
        """Move the fitted tensors (import vectors, coefficients, classes) to ``device``.

        Predictions then run where the windows are without copies per call; the coefficients
        stay float64.

        Raises:
            ConfigError: for a device that :func:`~iplanner_torch.types.resolve_device`
                refuses (an unknown name, CUDA where there is none, ``meta``, which holds no
                numbers, or another device type), before anything is moved.
        """
        device = resolve_device(device)
        for name in ("import_vectors_", "weights_", "classes_"):
            val = getattr(self, name)
            if val is not None:
                setattr(self, name, val.to(device))
        return self

    def _require_fit(self) -> None:
        if self.weights_ is None or self.classes_ is None:
            raise CheckpointError("IVMClassifier is not fitted: call fit() or from_state_dict()")

    def decision_function(self, x: Tensor) -> Tensor:
        """Class logits ``f_c(x)``.

        Args:
            x: (B, T, D) windows.

        Returns:
            (B, C) logits, float64 on x's device; ``-inf`` for classes absent from training.

        Raises:
            ShapeError: on wrong shapes: another D than the training windows', or another T
                for a kernel of windows of equal length (``equal_lengths``, the RBF kernel).
            DataError: when a window holds NaN or inf (from the kernel).
            CheckpointError: before fit.
        """
        self._require_fit()
        _check_windows("x", x)
        assert self.weights_ is not None and self.classes_ is not None
        assert self.import_vectors_ is not None
        _, t, d = self.import_vectors_.shape
        same_t = getattr(self.kernel, "equal_lengths", False)
        if x.shape[-1] != d or (same_t and x.shape[1] != t):
            # before the kernel, which would name its import vectors (its x2) as the culprit
            raise ShapeError(
                f"expected x (B, {t if same_t else 'T'}, {d}) as the classifier was trained on, "
                f"got {tuple(x.shape)}"
            )
        b, dev = x.shape[0], x.device
        out = torch.full((b, self.num_classes), -math.inf, dtype=torch.float64, device=dev)
        w = self.weights_.to(dev)
        cols = self.classes_.to(dev)
        if len(cols) == 1:
            out[:, cols] = 0.0
            return out
        assert self.import_vectors_ is not None
        logits = w[0].expand(b, -1).clone()  # (B, C')
        if len(self.import_vectors_):
            kx = self.kernel(x, self.import_vectors_.to(dev, x.dtype)).double()  # (B, M)
            logits = logits + kx @ w[1:]
        out[:, cols] = logits
        return out

    def predict_proba(self, x: Tensor) -> Tensor:
        """``p(c | x)`` (eq. IVMclassifier).

        Args:
            x: (B, T, D) windows.

        Returns:
            (B, C) probabilities in x's dtype; rows sum to 1, absent classes exactly 0.

        Raises:
            ShapeError, DataError, CheckpointError: as :meth:`decision_function`.
        """
        return torch.softmax(self.decision_function(x), -1).to(x.dtype)

    def predict(self, x: Tensor) -> Tensor:
        """(B, T, D) windows -> (B,) int64 most probable class."""
        return self.decision_function(x).argmax(-1)

    # ------------------------------------------------------------------ persistence

    def state_dict(self) -> dict[str, Any]:
        """Everything needed to predict: import vectors, coefficients, kernel, classes."""
        self._require_fit()
        assert self.import_vectors_ is not None
        return {
            "format": "ivm/1",
            "num_classes": self.num_classes,
            "classes": self.classes_.cpu().clone(),
            "import_vectors": self.import_vectors_.detach().cpu().clone(),
            "import_index": self.import_index_.clone() if self.import_index_ is not None else None,
            "weights": self.weights_.cpu().clone(),
            "kernel_name": getattr(self.kernel, "name", type(self.kernel).__name__),
            "kernel_hparams": dict(getattr(self.kernel, "hparams", {})),
            "hparams": {
                "lam": self.lam,
                "max_import": self.max_import,
                "tol": self.tol,
                "candidates": self.candidates,
                "newton_steps": self.newton_steps,
                "seed": self.seed,
            },
            "loss_history": list(self.loss_history_),
        }

    @classmethod
    def from_state_dict(
        cls, d: dict[str, Any], kernel: Callable[[Tensor, Tensor], Tensor] | None = None
    ) -> IVMClassifier:
        """Rebuild a fitted classifier.

        Args:
            d: a dict from :meth:`state_dict`.
            kernel: the kernel to use; None rebuilds one of the kernels of
                :mod:`~iplanner_torch.prediction.dtw` from the stored name and parameters.

        Raises:
            CheckpointError: on something other than a dict, a dict of another format, missing
                entries (named), tensors that are None or of inconsistent shapes, or settings or
                kernel parameters that the classifier or kernel refuses.
        """
        if not isinstance(d, dict):
            raise CheckpointError(
                f"expected an IVM state dict (format ivm/1), got a {type(d).__name__}"
            )
        if d.get("format") != "ivm/1":
            raise CheckpointError(
                f"expected an IVM state dict (format ivm/1), got {d.get('format')!r}"
            )
        required = ["num_classes", "classes", "import_vectors", "weights", "hparams"]
        if kernel is None:
            required += ["kernel_name", "kernel_hparams"]
        missing = [k for k in required if k not in d]
        if missing:
            raise CheckpointError(f"incomplete IVM state dict: missing {missing}")
        tensors = {k: d[k] for k in ("classes", "import_vectors", "weights")}
        for name, t in tensors.items():
            if not isinstance(t, Tensor):
                raise CheckpointError(
                    f"IVM state dict entry {name!r} is not a tensor, got {type(t).__name__}"
                )
        classes, vectors, weights = tensors.values()
        fits = classes.dim() == 1 and vectors.dim() == 3
        if not fits or tuple(weights.shape) != (vectors.shape[0] + 1, classes.shape[0]):
            raise CheckpointError(
                "IVM state dict tensors do not fit together: expected classes (C'), "
                "import_vectors (M, T, D) and weights (M + 1, C'), got "
                f"{tuple(classes.shape)}, {tuple(vectors.shape)}, {tuple(weights.shape)}"
            )
        index = d.get("import_index")
        if index is not None and not isinstance(index, Tensor):
            raise CheckpointError(
                f"IVM state dict entry 'import_index' is not a tensor or None, got "
                f"{type(index).__name__}"
            )
        hparams = d["hparams"]
        known = set(inspect.signature(cls).parameters) - {"kernel", "num_classes"}
        if not isinstance(hparams, dict) or set(hparams) - known:
            raise CheckpointError(
                f"expected the IVM state dict's hparams a dict of {sorted(known)}, got {hparams!r}"
            )
        try:
            if kernel is None:
                kernel = kernel_from_state(d["kernel_name"], d["kernel_hparams"])
            obj = cls(kernel, num_classes=d["num_classes"], **hparams)
        except ConfigError as err:
            raise CheckpointError(f"invalid IVM state dict: {err}") from err
        obj.classes_ = classes.clone()
        obj.import_vectors_ = vectors.clone()
        obj.import_index_ = index
        obj.weights_ = weights.clone()
        obj.loss_history_ = list(d.get("loss_history") or [])
        return obj


class _SingleAction:
    """A progress state whose windows show one action: probability 1 for it."""

    def __init__(self, action: int, num_actions: int) -> None:
        self.action = int(action)
        self.num_actions = int(num_actions)

    def to(self, device: torch.device | str) -> _SingleAction:
        """Nothing to move: kept for a uniform interface."""
        return self

    def predict_proba(self, x: Tensor) -> Tensor:
        out = torch.zeros(x.shape[0], self.num_actions, dtype=x.dtype, device=x.device)
        out[:, self.action] = 1.0
        return out

    def state_dict(self) -> dict[str, Any]:
        return {"format": "single/1", "action": self.action, "num_actions": self.num_actions}


def _call_factory(factory: Callable[..., KernelLike], x: Tensor) -> KernelLike:
    """Call a kernel factory with the state's windows if it takes an argument."""
    try:
        n_params = len(inspect.signature(factory).parameters)
    except (TypeError, ValueError):
        n_params = 1
    return factory(x) if n_params >= 1 else factory()


_GLOBAL = -1  # key of the classifier trained on all windows

#: Joints and feature kinds that separate reaches early (see :func:`feature_columns`).
HAND_JOINTS: tuple[str, ...] = ("left_hand", "right_hand")
HAND_KINDS: tuple[str, ...] = ("position", "velocity")


def feature_columns(
    joint_names: Sequence[str],
    feature_kinds: Sequence[str],
    joints: Sequence[str] = HAND_JOINTS,
    kinds: Sequence[str] = HAND_KINDS,
) -> list[int]:
    """Columns of the window features ``(N, T, D)`` that hold ``joints`` x ``kinds``.

    The layout is the one of :func:`iplanner_torch.data.windows.compute_features`: one block of
    ``3 K`` columns per feature kind, each joint-major (x, y, z per joint). On the synthetic
    reaching set the hands' positions and velocities alone classify better than all 90 columns
    (the other joints and the accelerations add mostly tracker noise to the DTW distances).

    Args:
        joint_names: the K joint names of the windows.
        feature_kinds: the feature kinds of the windows, in order.
        joints: joints to keep.
        kinds: feature kinds to keep.

    Returns:
        Column indices, kind-major then joint, then x, y, z.

    Raises:
        ConfigError: for a joint or kind that the windows do not have.
    """
    names, fk = list(joint_names), list(feature_kinds)
    missing = [j for j in joints if j not in names] + [k for k in kinds if k not in fk]
    if missing:
        raise ConfigError(f"windows have no joints or feature kinds {missing}")
    k = len(names)
    return [
        3 * k * fk.index(kind) + 3 * names.index(j) + a
        for kind in kinds
        for j in joints
        for a in range(3)
    ]


class ActionClassifier:
    """One IVM per progress state: ``p(c | F_prev, p)`` (eq. IVMclassifier is per p).

    Fallback for a progress state not seen in training (bitmask ``p``): among the seen states
    ``q`` that are a subset or a superset of ``p`` (``q & p == q`` or ``q & p == p``), take the
    one with the smallest Hamming distance ``popcount(p ^ q)``; ties go to subsets (progress
    already made) and then to the smaller ``q``. When no seen state is related, the classifier
    trained on all windows is used (when ``fit_global`` was False: uniform over the actions).

    Args:
        feature_index: columns of the windows' last dimension the classifier uses (e.g. from
            :func:`feature_columns`); None uses all. Applied in ``fit`` and ``predict_proba``,
            so callers always pass the full windows.

    Attributes (after ``fit``):
        models_: dict progress bitmask -> IVMClassifier or single-action model; key -1 is the
            global classifier.
        num_features: D of the training windows (all columns, before ``feature_index``);
            None for a checkpoint of an older version that does not tell.
    """

    def __init__(self, *, feature_index: Sequence[int] | None = None) -> None:
        self.num_actions = 0
        self.num_features: int | None = None
        self.models_: dict[int, IVMClassifier | _SingleAction] = {}
        self.feature_index: list[int] | None = None
        if feature_index is not None:
            self.feature_index = [int(i) for i in feature_index]
            if not self.feature_index or min(self.feature_index) < 0:
                raise ConfigError(
                    f"expected feature_index None or non-negative columns, got {feature_index}"
                )

    def _select(self, x: Tensor) -> Tensor:
        """(N, T, D) windows -> (N, T, D') the classifier's columns."""
        if self.feature_index is None:
            return x
        if max(self.feature_index) >= x.shape[2]:
            raise ShapeError(
                f"expected windows with more than {max(self.feature_index)} features, got "
                f"{tuple(x.shape)}"
            )
        return x[..., self.feature_index]

    def to(self, device: torch.device | str) -> ActionClassifier:
        """Move every per-state model to ``device`` (predictions then run there).

        Raises:
            ConfigError: for a device that :func:`~iplanner_torch.types.resolve_device`
                refuses (an unknown name, CUDA where there is none, ``meta``, which holds no
                numbers, or another device type), before anything is moved.
        """
        device = resolve_device(device)
        for model in self.models_.values():
            model.to(device)
        return self

    def fit(
        self,
        x: Tensor,
        progress: Tensor,
        current: Tensor,
        *,
        num_actions: int,
        kernel_factory: Callable[..., KernelLike],
        ivm_kwargs: dict[str, Any] | None = None,
        fit_global: bool = True,
    ) -> ActionClassifier:
        """Fit one classifier per progress state.

        Args:
            x: (N, T, D) windows F_prev.
            progress: (N,) int64 progress bitmasks.
            current: (N,) int64 current action of each window, in [0, num_actions).
            num_actions: A.
            kernel_factory: builds the kernel of one state; called with that state's windows
                (M, T, D) (e.g. to set ``gamma`` by :func:`~iplanner_torch.prediction.dtw.
                median_dtw`) or with no argument if it takes none.
            ivm_kwargs: keyword arguments of :class:`IVMClassifier` other than ``num_classes``.
            fit_global: also fit the classifier on all windows used by the fallback.

        Returns:
            self.

        Raises:
            ShapeError: on wrong shapes; DataError: on labels out of range or N = 0.
        """
        _check_windows("x", x)
        n = x.shape[0]
        check_shape("progress", progress, (n,))
        if progress.dtype != torch.int64:
            raise ShapeError(f"expected progress int64, got {progress.dtype}")
        _check_labels("current", current, n, num_actions)
        if n == 0:
            raise DataError("expected at least one training window, got N = 0")
        num_features = int(x.shape[2])
        x = self._select(x)
        self.num_features = num_features
        kwargs = dict(ivm_kwargs or {})
        kwargs.pop("num_classes", None)
        self.num_actions = int(num_actions)
        self.models_ = {}
        prog = progress.cpu()
        for p in torch.unique(prog).tolist():
            idx = (prog == p).nonzero().squeeze(1).to(x.device)
            self.models_[int(p)] = self._fit_one(x[idx], current[idx], kernel_factory, kwargs)
        if fit_global:
            self.models_[_GLOBAL] = self._fit_one(x, current, kernel_factory, kwargs)
        return self

    def _fit_one(
        self, x: Tensor, y: Tensor, factory: Callable[..., KernelLike], kwargs: dict[str, Any]
    ) -> IVMClassifier | _SingleAction:
        labels = torch.unique(y)
        if len(labels) == 1:
            return _SingleAction(int(labels[0]), self.num_actions)
        kernel = _call_factory(factory, x)
        return IVMClassifier(kernel, num_classes=self.num_actions, **kwargs).fit(x, y)

    def resolve(self, progress: int) -> int:
        """The key of the model used for a progress state (see the class docstring)."""
        p = int(progress)
        if p in self.models_:
            return p
        related = [q for q in self.models_ if q != _GLOBAL and ((q & p) == q or (q & p) == p)]
        if related:
            return min(related, key=lambda q: (bin(p ^ q).count("1"), (q & p) != q, q))
        return _GLOBAL

    def predict_proba(self, x: Tensor, progress: Tensor) -> Tensor:
        """``p(c | F_prev, p)`` for a batch of windows with their progress states.

        Args:
            x: (B, T, D) windows with the D of the training windows, finite (in the columns
                of ``feature_index``).
            progress: (B,) progress bitmasks of an integer dtype (int64).

        Returns:
            (B, A) probabilities in x's dtype, rows sum to 1.

        Raises:
            ShapeError: on wrong shapes (another D than the training windows'), a ``progress``
                of a floating, complex or bool dtype (a float would be truncated), or as the
                per-state :meth:`IVMClassifier.predict_proba`.
            DataError: when a window holds NaN or inf (naming window and frame), whichever
                model its state uses (single-action states included).
            CheckpointError: before fit.
        """
        if not self.models_:
            raise CheckpointError(
                "ActionClassifier is not fitted: call fit() or from_state_dict()"
            )
        _check_windows("x", x)
        b = x.shape[0]
        check_shape("progress", progress, (b,))
        if progress.is_floating_point() or progress.is_complex() or progress.dtype == torch.bool:
            raise ShapeError(
                f"expected progress (B,) bitmasks of an integer dtype (int64), got "
                f"{progress.dtype}"
            )
        full = x
        x = self._select(x)
        if self.num_features is not None and full.shape[2] != self.num_features:
            raise ShapeError(
                f"expected x (B, T, {self.num_features}) as the classifier was trained on, got "
                f"{tuple(full.shape)}"
            )
        # the bitmasks and a finiteness flag of the windows in one transfer (one host sync);
        # x.sum() is NaN or inf when an entry is (or when the sum overflows: check_finite tells)
        finite = torch.isfinite(x.sum()).to(device=progress.device, dtype=torch.int64)
        prog = torch.cat([progress.to(torch.int64), finite.view(1)]).cpu()  # (B + 1,)
        if not bool(prog[-1]):
            check_finite("x", x, ("window", "frame"), hint="impute lost frames first")
        out = torch.empty(b, self.num_actions, dtype=x.dtype, device=x.device)
        groups: dict[int, list[int]] = {}
        for i, p in enumerate(prog[:-1].tolist()):
            groups.setdefault(self.resolve(p), []).append(i)
        for key, rows in groups.items():
            idx = torch.tensor(rows, device=x.device)
            model = self.models_.get(key)
            if model is None:  # no related state and no global classifier: uniform
                out[idx] = 1.0 / self.num_actions
            else:
                out[idx] = model.predict_proba(x[idx])
        return out

    def state_dict(self) -> dict[str, Any]:
        """Per-state model dicts, keyed by progress bitmask (-1: global)."""
        return {
            "format": "action_classifier/1",
            "num_actions": self.num_actions,
            "num_features": self.num_features,
            "feature_index": self.feature_index,
            "models": {k: m.state_dict() for k, m in self.models_.items()},
        }

    @classmethod
    def from_state_dict(
        cls, d: dict[str, Any], kernel: Callable[[Tensor, Tensor], Tensor] | None = None
    ) -> ActionClassifier:
        """Rebuild; ``kernel`` (shared by all states) as in :meth:`IVMClassifier.from_state_dict`.

        Raises:
            CheckpointError: on something other than a dict, a dict of another format, missing
                entries (named), or per-state models that do not load (as
                :meth:`IVMClassifier.from_state_dict`).
        """
        if not isinstance(d, dict):
            raise CheckpointError(
                f"expected an action classifier state dict, got a {type(d).__name__}"
            )
        if d.get("format") != "action_classifier/1":
            raise CheckpointError(
                f"expected an action classifier state dict, got format {d.get('format')!r}"
            )
        missing = [k for k in ("num_actions", "models") if k not in d]
        if missing:
            raise CheckpointError(f"incomplete action classifier state dict: missing {missing}")
        if not isinstance(d["models"], dict):
            raise CheckpointError(
                f"expected the action classifier's models a dict, got {type(d['models']).__name__}"
            )
        try:
            try:
                obj = cls(feature_index=d.get("feature_index"))
            except (TypeError, ValueError) as err:  # not a sequence of integers
                raise ConfigError(f"expected feature_index None or columns, got {err}") from err
            obj.num_actions = checks.integer("num_actions", d["num_actions"], minimum=1)
            obj.num_features = checks.optional(
                checks.integer, "num_features", d.get("num_features"), minimum=1
            )
            for k, md in d["models"].items():
                key = checks.integer("model key (progress bitmask)", k, minimum=_GLOBAL)
                if isinstance(md, dict) and md.get("format") == "single/1":
                    gone = [f for f in ("action", "num_actions") if f not in md]
                    if gone:
                        raise CheckpointError(
                            f"incomplete single-action model {key}: missing {gone}"
                        )
                    a_n = checks.integer("num_actions", md["num_actions"], minimum=1)
                    action = checks.integer("action", md["action"], minimum=0)
                    if action >= a_n:
                        raise ConfigError(f"expected action in [0, {a_n}), got {action}")
                    obj.models_[key] = _SingleAction(action, a_n)
                else:
                    obj.models_[key] = IVMClassifier.from_state_dict(md, kernel)
        except ConfigError as err:
            raise CheckpointError(f"invalid action classifier state dict: {err}") from err
        if obj.num_features is None and obj.feature_index is None:  # an older checkpoint
            dims = {
                int(m.import_vectors_.shape[-1])
                for m in obj.models_.values()
                if isinstance(m, IVMClassifier) and m.import_vectors_ is not None
            }
            obj.num_features = dims.pop() if len(dims) == 1 else None
        return obj
