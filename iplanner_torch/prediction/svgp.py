"""Sparse variational GP regression with the noisy-input correction (paper eq. GPRlearning, 6.1).

One :class:`SVGPRegressor` is trained per (progress state, current action). Its inputs are the
flattened observed windows (normalised per dimension) and its outputs are all ``C = n_f x K x 3``
future coordinates (the output channels of eq. GPRlearning), standardised per channel. The
predictor feeds it positions relative to the current pose, so one model generalises across
where the person sits (ARCHITECTURE 4.10).

Model (normalised units; ``y_c`` is channel c divided by its training standard deviation):

    y_c(x_i) = g_c(x_i) + eps_ic,   g_c ~ GP(0, s k_l) i.i.d. over c,   eps_ic ~ N(0, lam_i),
    lam_i = floor + e_i.

All C channels share the kernel (outputscale s, lengthscale l), the M inducing inputs Z and the
observation noise ``lam_i``, so the optimal variational posterior ``q(v_c) = N(m_c, S)``
(whitened, ``u_c = L v_c`` with ``K_ZZ = L L^T``) has *one* covariance
``S = (I + Phi Lam^-1 Phi^T)^-1`` for every channel and means ``m_c = S Phi Lam^-1 y_c``
(``Phi = L^-1 K_ZX``): one M x M matrix and an M x C mean matrix are stored
(:class:`SharedCovarianceVariationalDistribution`, used by GPyTorch's ``VariationalStrategy``).

Training maximises Titsias's collapsed bound (the ELBO at that optimal q; exact for a Gaussian
likelihood with diagonal, per-point noise) with Adam over the hyperparameters: outputscale,
lengthscale(s), the noise floor and (rbf/matern) the inducing inputs; q is then set in closed
form from all N points. Each step costs ``O(N M D_in + N M^2 + M N C)``, independent of C in
its M^2 terms. A step may use a random subset of ``batch_size`` points (the bound on the subset
scaled to N), q always uses every point.

Noisy-input corrections (the per-point term ``e_i``, normalised output units, shared by all
channels):

* ``none``: ``e_i = 0``;
* ``simple`` (paper sec. 6.1): the paper's term ``sigma^2 (1 + ||v||^2)`` [m^2] (``sigma`` the
  sensor noise [m], ``v`` the joint velocity limit [m/s], units as printed) divided by the mean
  output variance ``mean_c std_c^2``: the term of a channel of average spread, so a channel gets
  ``sigma^2 (1 + ||v||^2) std_c^2 / mean_c(std_c^2)`` in metres (the same on average);
* ``nigp`` (McHutchon and Rasmussen 2011): fit, then
  ``e_i = sigma^2 mean_c ||A^T d g_c / d x (x_i)||^2`` with the gradient of the posterior mean
  with respect to the raw inputs (closed form for rbf, autograd for matern; the time-series
  kernels give none, so they refuse nigp), refit; repeated ``nigp_iterations`` times. ``A``
  (D_in, D_src) maps the noisy source values to the raw inputs (the input noise covariance is
  ``sigma^2 A A^T``): the predictor's training gives the Jacobian of its window features and
  GP inputs with respect to the observed joint positions (velocities and accelerations are
  finite differences of the same noisy positions); without one ``A = I``, every input
  column noisy with ``sigma^2`` on its own. Averaging over channels keeps one S; in
  normalised output units the channels' gradients are of comparable size.

Calibration (``calibrate_floor``): windows of one demonstration are strongly correlated, so a
floor fitted on the training windows alone is overconfident on new demonstrations; when
validation windows (other demonstrations) are given, the floor is raised to the maximiser of
their likelihood and q recomputed (:meth:`SVGPRegressor.calibrate`); it is never lowered.

Prediction uses tensors cached from the trained model (:meth:`SVGPRegressor.refresh_cache`,
:class:`SVGPBank` for several regressors at once): with ``k = k(x, Z)`` and ``w = L^-1 k``,
``mean_c = w^T m_c`` (one (B, M) x (M, C) matmul) and
``var = s - w^T (I - S) w + floor + e_test`` (shared by all channels), scaled back by
``std_c^2``. The test input is as noisy as the training inputs, so the input-noise term
inflates the predictive variance too: ``e_test`` is the simple term, the mean of the training
``e_i`` for nigp, and 0 for none.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from typing import Any, Literal

import gpytorch
import torch
from gpytorch.distributions import MultivariateNormal
from gpytorch.models import ApproximateGP
from gpytorch.variational import VariationalStrategy, _VariationalDistribution
from linear_operator.operators import DenseLinearOperator
from torch import nn

from iplanner_torch import checks
from iplanner_torch.errors import CheckpointError, ConfigError, ShapeError
from iplanner_torch.seeds import SVGP_MINIBATCHES, derive_seed
from iplanner_torch.types import check_finite, check_shape, torch_threads

KernelName = Literal["rbf", "matern", "gak", "dtw"]
NoisyInput = Literal["none", "simple", "nigp"]

#: The :class:`SVGPCfg` fields each ``noisy_input`` mode does not read: ``input_noise_sigma``
#: feeds ``simple`` and ``nigp``, ``velocity_limit`` ``simple`` alone, and ``nigp_iterations``
#: and ``nigp_refit_steps`` ``nigp`` alone.
UNREAD_BY_NOISY_INPUT: dict[str, tuple[str, ...]] = {
    "none": ("input_noise_sigma", "velocity_limit", "nigp_iterations", "nigp_refit_steps"),
    "simple": ("nigp_iterations", "nigp_refit_steps"),
    "nigp": ("velocity_limit",),
}

#: version of :meth:`SVGPRegressor.to_checkpoint`'s layout
CHECKPOINT_FORMAT = 2

#: most inducing inputs of one GP (the paper's 100): each output channel keeps an M x M
#: covariance root, so a count beyond this (a typo's extra zeros, on a training set that
#: large) would exhaust the memory midway through training; it is refused when the settings
#: are made
MAX_INDUCING = 8192


@dataclass(frozen=True, kw_only=True)
class SVGPCfg:
    """Hyperparameters of one sparse variational GP (eq. GPRlearning) and its training."""

    # M, the number of inducing inputs (paper sec. 7: 100); fewer are used when N < M.
    num_inducing: int = 100
    # kernel on the input windows: rbf/matern on flattened normalised features, gak/dtw on
    # windows (gak is PSD and preferred; dtw = exp(-DTW/gamma) is not PSD in general).
    kernel: KernelName = "rbf"
    # one lengthscale per input dimension (rbf/matern only).
    ard: bool = False
    # noisy-input correction: none, the paper's simplified form, or per-point NIGP.
    noisy_input: NoisyInput = "simple"
    # sensor noise sigma of the input positions [m].
    input_noise_sigma: float = 0.01
    # joint velocity limit ||v|| of the simplified correction [m/s].
    velocity_limit: float = 1.5
    # fit -> gradient -> refit rounds of the NIGP correction.
    nigp_iterations: int = 2
    # optimiser steps of each NIGP refit (warm started from the previous round).
    nigp_refit_steps: int = 30
    # Adam learning rate (hyperparameters and inducing inputs).
    lr: float = 0.05
    # passes over the training set per fit (the number of steps is also capped by max_steps).
    epochs: int = 30
    # maximum optimiser steps per fit.
    max_steps: int = 150
    # points per optimiser step: a random subset of the training set when N is larger.
    batch_size: int = 1024
    # learn the inducing inputs (rbf/matern; time-series kernels keep training windows).
    learn_inducing: bool = True
    # initial observation-noise floor in normalised output units (variance).
    noise_floor_init: float = 1e-2
    # lower bound of the noise floor (variance, normalised units).
    noise_floor_min: float = 1e-6
    # raise the noise floor to the maximiser of the likelihood of validation windows (other
    # demonstrations) when they are given: windows of one demonstration are correlated, so the
    # floor fitted on the training windows alone is overconfident on new demonstrations.
    calibrate_floor: bool = True
    # validation windows needed for that calibration.
    calibrate_min_windows: int = 10
    # DTW kernel gamma / GAK sigma; None picks the median heuristic on the training windows.
    series_bandwidth: float | None = None
    # Sakoe-Chiba band of the time-series kernels (frames); None = unconstrained.
    series_band: int | None = None
    # seed of inducing-point selection and minibatch order.
    seed: int = 0

    def __post_init__(self) -> None:
        # every number is checked for its range and, for floats, for NaN and infinities
        # (``nan <= 0`` is False): a bad value fails here, before a training folder is touched
        if checks.integer("num_inducing", self.num_inducing, minimum=1) > MAX_INDUCING:
            raise ConfigError(
                f"expected num_inducing <= {MAX_INDUCING} (MAX_INDUCING), got {self.num_inducing}"
            )
        if self.kernel not in ("rbf", "matern", "gak", "dtw"):
            raise ConfigError(f"kernel must be one of rbf, matern, gak, dtw, got {self.kernel!r}")
        if self.noisy_input not in ("none", "simple", "nigp"):
            raise ConfigError(
                f"noisy_input must be one of none, simple, nigp, got {self.noisy_input!r}"
            )
        if self.noisy_input == "nigp" and self.kernel in ("gak", "dtw"):
            raise ConfigError(
                f"noisy_input nigp needs the gradient of the posterior mean, which kernel "
                f"{self.kernel} does not give: use kernel rbf or matern, or noisy_input simple"
            )
        checks.non_negative("input_noise_sigma", self.input_noise_sigma)
        checks.non_negative("velocity_limit", self.velocity_limit)
        checks.integer("nigp_iterations", self.nigp_iterations, minimum=1)
        checks.integer("nigp_refit_steps", self.nigp_refit_steps, minimum=0)
        checks.positive("lr", self.lr)
        checks.integer("epochs", self.epochs, minimum=0)
        checks.integer("max_steps", self.max_steps, minimum=0)
        checks.integer("batch_size", self.batch_size, minimum=2)
        checks.positive("noise_floor_init", self.noise_floor_init)
        checks.non_negative("noise_floor_min", self.noise_floor_min)
        if not self.noise_floor_init > self.noise_floor_min:
            raise ConfigError(
                f"need noise_floor_init > noise_floor_min >= 0, got {self.noise_floor_init}, "
                f"{self.noise_floor_min}"
            )
        checks.integer("calibrate_min_windows", self.calibrate_min_windows, minimum=1)
        checks.optional(checks.positive, "series_bandwidth", self.series_bandwidth)
        checks.optional(checks.integer, "series_band", self.series_band, minimum=0)
        checks.seed(self.seed)

    @property
    def simple_extra_var(self) -> float:
        """The paper's input-noise term ``sigma^2 (1 + ||v||^2)`` [m^2]."""
        return self.input_noise_sigma**2 * (1.0 + self.velocity_limit**2)

    def steps_for(self, n: int, max_epochs: int | None = None) -> int:
        """Optimiser steps of a first fit on ``n`` points (``max_epochs`` caps ``epochs``)."""
        epochs = self.epochs if max_epochs is None else min(self.epochs, max_epochs)
        return min(epochs * math.ceil(n / min(self.batch_size, max(n, 1))), self.max_steps)


class SeriesKernel(gpytorch.kernels.Kernel):
    """A GPyTorch kernel over flattened windows that wraps a time-series kernel.

    Inputs ``(..., n * T * D)`` are reshaped to windows ``(n, T, D)`` and passed to
    ``series_kernel(x1 (B1, T, D), x2 (B2, T, D)) -> (B1, B2)`` (e.g. the global alignment
    kernel of :mod:`iplanner_torch.prediction.dtw`).
    """

    has_lengthscale = False

    def __init__(
        self,
        series_kernel: Callable[[torch.Tensor, torch.Tensor], torch.Tensor],
        window: tuple[int, int],
        **kwargs: Any,
    ) -> None:
        super().__init__(**kwargs)
        self.series_kernel = series_kernel
        self.window = tuple(window)

    def forward(
        self, x1: torch.Tensor, x2: torch.Tensor, diag: bool = False, **params: Any
    ) -> torch.Tensor:
        t, d = self.window
        batch = x1.shape[:-2]
        a = x1.reshape(-1, x1.shape[-2], t, d)  # (batches, N1, T, D)
        b = x2.reshape(-1, x2.shape[-2], t, d)  # (batches, N2, T, D)
        if diag:
            out = torch.stack([self.series_kernel.diag(ai) for ai in a])  # (batches, N1)
            return out.reshape(*batch, x1.shape[-2])
        out = torch.stack([self.series_kernel(ai, bi) for ai, bi in zip(a, b)])
        return out.reshape(*batch, x1.shape[-2], x2.shape[-2])


class SharedCovarianceVariationalDistribution(_VariationalDistribution):
    """``q(v_c) = N(m_c, S)`` for C channels with one shared ``S = R R^T`` (whitened).

    The tensors are buffers, not gradient parameters: they are set in closed form by
    :meth:`SVGPRegressor.finalise` (the exact ELBO optimum for a Gaussian likelihood).
    """

    def __init__(self, num_inducing_points: int, num_channels: int) -> None:
        super().__init__(num_inducing_points, batch_shape=torch.Size([num_channels]))
        # (C, M) whitened means m_c
        self.register_buffer("variational_mean", torch.zeros(num_channels, num_inducing_points))
        # (M, M) a square root R of the shared covariance S = R R^T
        self.register_buffer("covar_root", torch.eye(num_inducing_points))

    @property
    def device(self) -> torch.device:
        return self.variational_mean.device

    @property
    def dtype(self) -> torch.dtype:
        return self.variational_mean.dtype

    @property
    def covariance(self) -> torch.Tensor:
        """(M, M) the shared S."""
        return self.covar_root @ self.covar_root.mT

    def forward(self) -> MultivariateNormal:
        c, m = self.variational_mean.shape
        cov = self.covariance.expand(c, m, m)  # (C, M, M)
        return MultivariateNormal(self.variational_mean, DenseLinearOperator(cov))

    def initialize_variational_distribution(self, prior_dist: MultivariateNormal) -> None:
        with torch.no_grad():
            self.variational_mean.zero_()
            self.covar_root.copy_(torch.eye(self.num_inducing_points, dtype=self.dtype))


class ChannelSVGPModel(ApproximateGP):
    """The variational GP: shared kernel, inducing inputs and q covariance over C channels."""

    def __init__(
        self,
        inducing: torch.Tensor,
        num_channels: int,
        covar_module: gpytorch.kernels.Kernel,
        learn_inducing: bool,
    ) -> None:
        """Build the model.

        Args:
            inducing: (M, D_in) initial inducing inputs (normalised input units).
            num_channels: C, the number of output channels.
            covar_module: the shared kernel.
            learn_inducing: whether Z is a trained parameter.
        """
        vd = SharedCovarianceVariationalDistribution(inducing.shape[0], num_channels)
        strategy = VariationalStrategy(self, inducing, vd, learn_inducing_locations=learn_inducing)
        super().__init__(strategy)
        self.mean_module = gpytorch.means.ZeroMean()
        self.covar_module = covar_module

    def forward(self, x: torch.Tensor) -> MultivariateNormal:
        """Prior at ``x`` (N, D_in)."""
        # evaluated eagerly: a lazy kernel tensor would be repeated (and re-evaluated) once per
        # output channel when combined with the batched variational distribution
        cov = DenseLinearOperator(self.covar_module(x).to_dense())
        return MultivariateNormal(self.mean_module(x), cov)


class NoiseFloor(nn.Module):
    """The learned observation-noise floor (variance, normalised units), ``> floor_min``."""

    def __init__(self, floor_init: float, floor_min: float) -> None:
        super().__init__()
        self.floor_min = float(floor_min)
        init = math.log(math.expm1(floor_init - floor_min))
        self.raw_floor = nn.Parameter(torch.tensor(init))

    @property
    def floor(self) -> torch.Tensor:
        """() the noise floor."""
        return nn.functional.softplus(self.raw_floor) + self.floor_min


def _median_sq_dist(x: torch.Tensor, n: int, generator: torch.Generator) -> float:
    idx = torch.randperm(x.shape[0], generator=generator)[:n].to(x.device)
    d2 = torch.cdist(x[idx], x[idx]).pow(2)
    vals = d2[~torch.eye(len(idx), dtype=torch.bool, device=x.device)]
    return float(vals.median()) if vals.numel() else 1.0


def _chol(a: torch.Tensor, jitter: float) -> torch.Tensor:
    """Cholesky factor of ``a + jitter I``, raising the jitter tenfold on failure."""
    eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device)
    for _ in range(6):
        l_a, info = torch.linalg.cholesky_ex(a + jitter * eye)
        if not bool(info.any()):
            return l_a
        jitter = jitter * 10
    return torch.linalg.cholesky(a + jitter * eye)


class SVGPRegressor(nn.Module):
    """A multi-output sparse variational GP on flattened windows (see the module docstring).

    Build with :meth:`from_data` (chooses Z, the normalisation and the kernel bandwidth), train
    with :meth:`fit` (or :class:`~iplanner_torch.prediction.training.SVGPModule`), predict with
    :meth:`predict`. Save with :meth:`to_checkpoint`, restore with :meth:`from_checkpoint`.
    """

    def __init__(
        self,
        cfg: SVGPCfg,
        *,
        input_dim: int,
        num_channels: int,
        num_inducing: int,
        window: tuple[int, int] | None = None,
        bandwidth: float = 1.0,
    ) -> None:
        """Build an untrained regressor (see :meth:`from_data` for the usual entry).

        Args:
            cfg: hyperparameters.
            input_dim: D_in, flattened input size (``n_p * D`` for windows).
            num_channels: C, the number of output channels.
            num_inducing: M actually used (``<= N``).
            window: (n_p, D) window shape, required by the time-series kernels.
            bandwidth: initial lengthscale (rbf/matern) or series kernel bandwidth (gak/dtw).
        """
        super().__init__()
        self.cfg = cfg
        self.input_dim = int(input_dim)
        self.num_channels = int(num_channels)
        self.window = None if window is None else (int(window[0]), int(window[1]))
        self.bandwidth = float(bandwidth)
        if cfg.kernel in ("gak", "dtw") and (
            self.window is None or self.window[0] * self.window[1] != self.input_dim
        ):
            raise ConfigError(
                f"kernel {cfg.kernel!r} needs window (n_p, D) with n_p * D = {self.input_dim}, "
                f"got {self.window}"
            )
        covar = gpytorch.kernels.ScaleKernel(self._make_base_kernel())
        z0 = torch.zeros(num_inducing, self.input_dim)
        learn_z = cfg.learn_inducing and cfg.kernel in ("rbf", "matern")
        self.model = ChannelSVGPModel(z0, self.num_channels, covar, learn_z)
        self.likelihood = NoiseFloor(cfg.noise_floor_init, cfg.noise_floor_min)
        self.register_buffer("x_mean", torch.zeros(self.input_dim))
        self.register_buffer("x_std", torch.ones(self.input_dim))
        self.register_buffer("y_mean", torch.zeros(self.num_channels))
        self.register_buffer("y_std", torch.ones(self.num_channels))
        # () input-noise variance e_test added at prediction (normalised output units)
        self.register_buffer("test_extra_noise", torch.zeros(()))
        # cached fast-path tensors (rebuilt by refresh_cache, not saved)
        self._cache: dict[str, torch.Tensor] | None = None

    # ----------------------------------------------------------------------------- building
    def _make_base_kernel(self) -> gpytorch.kernels.Kernel:
        cfg = self.cfg
        if cfg.kernel in ("rbf", "matern"):
            ard = self.input_dim if cfg.ard else None
            k = (
                gpytorch.kernels.RBFKernel(ard_num_dims=ard)
                if cfg.kernel == "rbf"
                else gpytorch.kernels.MaternKernel(nu=2.5, ard_num_dims=ard)
            )
            k.lengthscale = torch.full_like(k.lengthscale, self.bandwidth)
            return k
        from iplanner_torch.prediction import dtw

        if cfg.kernel == "gak":
            series = dtw.GlobalAlignmentKernel(self.bandwidth, band=cfg.series_band)
        else:
            series = dtw.DTWKernel(self.bandwidth, band=cfg.series_band)
        return SeriesKernel(series, self.window)

    @classmethod
    def from_data(
        cls,
        cfg: SVGPCfg,
        x: torch.Tensor,
        y: torch.Tensor,
        *,
        window: tuple[int, int] | None = None,
    ) -> SVGPRegressor:
        """A regressor initialised from training data (normalisation, Z, bandwidth).

        Args:
            cfg: hyperparameters.
            x: (N, D_in) inputs (flattened windows, any units).
            y: (N, C) outputs (e.g. future positions relative to the current pose [m]).
            window: (n_p, D) window shape (needed by gak/dtw).

        Returns:
            The initialised, untrained regressor on ``x``'s device and dtype.

        Raises:
            ShapeError: when shapes disagree, N == 0, or x and y are not of one floating
                dtype.
            DataError: when x or y hold NaN or inf (one NaN input was gpytorch's error on a
                constraint; an infinite output made every prediction NaN).
        """
        check_shape("x", x, ("N", "D_in"))
        check_shape("y", y, (x.shape[0], "C"))
        if not x.is_floating_point() or y.dtype != x.dtype:
            raise ShapeError(f"expected x and y of one floating dtype, got {x.dtype}, {y.dtype}")
        if x.shape[0] == 0:
            raise ShapeError("expected x (N, D_in) with N >= 1, got N = 0")
        check_finite("x", x, ("window", "input"))
        check_finite("y", y, ("window", "output"))
        g = torch.Generator().manual_seed(cfg.seed)
        m = min(cfg.num_inducing, x.shape[0])
        x_mean, x_std = x.mean(0), x.std(0, unbiased=False).clamp_min(1e-6)
        y_mean, y_std = y.mean(0), y.std(0, unbiased=False).clamp_min(1e-4)
        xn = (x - x_mean) / x_std
        if cfg.kernel in ("rbf", "matern"):
            bw = math.sqrt(max(_median_sq_dist(xn, 256, g), 1e-6))
        elif cfg.series_bandwidth is not None:
            bw = cfg.series_bandwidth
        else:
            bw = cls._series_median(cfg, xn, window, g)
        reg = cls(
            cfg,
            input_dim=x.shape[1],
            num_channels=y.shape[1],
            num_inducing=m,
            window=window,
            bandwidth=bw,
        ).to(device=x.device, dtype=x.dtype)
        reg.x_mean.copy_(x_mean)
        reg.x_std.copy_(x_std)
        reg.y_mean.copy_(y_mean)
        reg.y_std.copy_(y_std)
        idx = torch.randperm(x.shape[0], generator=g)[:m].to(x.device)
        reg.set_inducing(xn[idx])
        return reg

    @staticmethod
    def _series_median(
        cfg: SVGPCfg, xn: torch.Tensor, window: tuple[int, int] | None, g: torch.Generator
    ) -> float:
        if window is None:
            raise ConfigError(f"kernel {cfg.kernel!r} needs window (n_p, D)")
        from iplanner_torch.prediction import dtw

        w = xn.reshape(xn.shape[0], *window)  # (N, n_p, D)
        seed = int(torch.randint(0, 2**31 - 1, (1,), generator=g))
        med = float(dtw.median_dtw(w, 64, seed))
        if cfg.kernel == "gak":
            return dtw.gak_sigma(med, window[0])
        return max(med, 1e-6)

    @property
    def num_inducing(self) -> int:
        """M."""
        return int(self.model.variational_strategy.inducing_points.shape[0])

    @property
    def variational(self) -> SharedCovarianceVariationalDistribution:
        """The shared-covariance q (means (C, M), covariance root (M, M))."""
        return self.model.variational_strategy._variational_distribution

    @property
    def jitter(self) -> float:
        """Jitter added to K_ZZ (the same as GPyTorch's variational strategy)."""
        return float(self.model.variational_strategy.jitter_val)

    def set_inducing(self, z: torch.Tensor) -> None:
        """Set the inducing inputs. ``z``: (M, D_in) in normalised input units."""
        check_shape("z", z, (self.num_inducing, self.input_dim))
        with torch.no_grad():
            self.model.variational_strategy.inducing_points.copy_(z)
        self._cache = None

    # ------------------------------------------------------------------------- normalisation
    def normalise_x(self, x: torch.Tensor) -> torch.Tensor:
        """(N, D_in) raw inputs -> normalised inputs."""
        return (x - self.x_mean) / self.x_std

    def normalise_y(self, y: torch.Tensor) -> torch.Tensor:
        """(N, C) raw outputs -> normalised outputs."""
        return (y - self.y_mean) / self.y_std

    def extra_noise_simple(self) -> torch.Tensor:
        """() the paper's input-noise term in normalised units (over the mean output variance)."""
        return self.cfg.simple_extra_var / self.y_std.pow(2).mean()

    # ------------------------------------------------------------------------------ training
    def _kernel_terms(self, xn: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``L`` (M, M), ``Phi = L^-1 K_ZX`` (M, N) and ``diag K_XX`` (N,) at normalised x."""
        z = self.model.variational_strategy.inducing_points
        kern = self.model.covar_module
        l_zz = _chol(kern(z).to_dense(), self.jitter)
        kzx = torch.cat(
            [kern(z, xn[s : s + 4096]).to_dense() for s in range(0, xn.shape[0], 4096)], -1
        )  # (M, N)
        phi = torch.linalg.solve_triangular(l_zz, kzx, upper=False)  # (M, N)
        if self.cfg.kernel in ("rbf", "matern"):
            kdiag = kern.outputscale.expand(xn.shape[0])
        else:
            kdiag = kern(xn, diag=True)
        return l_zz, phi, kdiag

    def elbo_loss(
        self, xn: torch.Tensor, yn: torch.Tensor, extra: torch.Tensor | None, num_data: int
    ) -> torch.Tensor:
        """Negative collapsed ELBO (Titsias 2009) per datum and channel, normalised units.

        ``log N(y_c | 0, Q + Lam) - tr(Lam^-1 (K - Q)) / 2`` summed over channels, with
        ``Q = K_XZ K_ZZ^-1 K_ZX`` and ``Lam = diag(floor + e_i)``, divided by ``B * C``: per
        datum, so that a batch's loss estimates the whole data's on the same scale (it does
        not depend on ``num_data``).

        Args:
            xn: (B, D_in) normalised inputs.
            yn: (B, C) normalised outputs.
            extra: (B,) extra observation noise ``e_i`` (normalised units), or None.
            num_data: N, the size of the full training set (unused: the loss is per datum).

        Returns:
            () the loss.
        """
        b, c = yn.shape
        _, phi, kdiag = self._kernel_terms(xn)
        lam = self.likelihood.floor.expand(b)
        if extra is not None:
            lam = lam + extra.reshape(b)
        isd = lam.rsqrt()  # (B,)
        psi = phi * isd  # (M, B)
        eye = torch.eye(phi.shape[0], dtype=phi.dtype, device=phi.device)
        l_b = _chol(eye + psi @ psi.T, 1e-8)
        yt = yn * isd.unsqueeze(-1)  # (B, C)
        cc = torch.linalg.solve_triangular(l_b, psi @ yt, upper=False)  # (M, C)
        logdet = lam.log().sum() + 2.0 * l_b.diagonal().log().sum()
        quad = yt.pow(2).sum() - cc.pow(2).sum()
        trace = ((kdiag - phi.pow(2).sum(0)).clamp_min(0.0) / lam).sum()
        bound = -0.5 * (c * b * math.log(2 * math.pi) + c * logdet + quad + c * trace)
        return -bound / (b * c)

    def extra_train_noise(
        self, x: torch.Tensor, noise_map: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(N,) extra observation noise ``e_i`` (normalised units) at raw x (N, D_in).

        ``simple`` gives the constant paper term; ``nigp`` uses the current posterior mean's
        gradient (call after a first fit) and ``noise_map`` ``A`` (D_in, D_src), the inputs'
        Jacobian with respect to the values the noise ``input_noise_sigma`` is on (None: the
        identity, see the module docstring); ``none`` gives zeros.

        Raises:
            ShapeError: when ``noise_map`` is not (D_in, D_src).
        """
        n = x.shape[0]
        if self.cfg.noisy_input == "none":
            return torch.zeros(n, dtype=x.dtype, device=x.device)
        if self.cfg.noisy_input == "simple":
            return self.extra_noise_simple().to(x).expand(n).clone()
        grad_sq = self.mean_grad_sq(x, noise_map=noise_map)
        return self.cfg.input_noise_sigma**2 * grad_sq / self.num_channels

    @torch.no_grad()
    def mean_grad_sq(
        self, x: torch.Tensor, chunk: int = 512, *, noise_map: torch.Tensor | None = None
    ) -> torch.Tensor:
        """(N,) ``sum_c ||A^T d g_c / d x||^2`` of the normalised posterior means at raw x
        (N, D_in); ``A`` is ``noise_map`` (D_in, D_src), the identity when None.

        Closed form for rbf: with ``k_j`` the kernel to inducing input ``j``, ``W`` (M, C) the
        mean weights, ``P = W W^T``, ``F = diag(1 / (l^2 std_x))`` and ``Q = F A A^T F``, the
        sum is ``sum_jl k_j k_l P_jl (x_n - z_j)^T Q (x_n - z_l)`` (normalised ``x_n``, in
        float64); autograd otherwise.

        Raises:
            ShapeError: when ``noise_map`` is not (D_in, D_src).
        """
        if noise_map is not None:
            check_shape("noise_map", noise_map, (x.shape[-1], "D_src"))
        self.refresh_cache()
        c = self._cache
        if self.cfg.kernel != "rbf":
            return self._mean_grad_sq_autograd(x, chunk, noise_map)
        dt = torch.float64
        ls = self.model.covar_module.base_kernel.lengthscale.detach().to(dt).reshape(-1)
        z = c["z"].to(dt)  # (M, D_in)
        w = c["w"].to(dt)  # (M, C)
        p = w @ w.T  # (M, M)
        if noise_map is None:
            lam_d = 1.0 / (ls.pow(4) * self.x_std.to(dt).pow(2))  # (D_in,) F^2
            pq = p * ((z * lam_d) @ z.T)  # (M, M)
        else:
            f = 1.0 / (ls.pow(2) * self.x_std.to(dt))  # (D_in,)
            a_map = noise_map.to(device=z.device, dtype=dt)  # (D_in, D_src)
            v = (z * f) @ a_map  # (M, D_src)
            pq = p * (v @ v.T)  # (M, M)
        out = []
        for s in range(0, x.shape[0], chunk):
            xn = self.normalise_x(x[s : s + chunk]).to(dt)  # (b, D_in)
            k = self.model.covar_module(xn, z).to_dense()  # (b, M)
            if noise_map is None:
                a = (xn * lam_d * xn).sum(-1)  # (b,)
                bm = (xn * lam_d) @ z.T  # (b, M)
            else:
                u = (xn * f) @ a_map  # (b, D_src)
                a = u.pow(2).sum(-1)  # (b,)
                bm = u @ v.T  # (b, M)
            kp = k @ p  # (b, M)
            t = a * (kp * k).sum(-1) - 2 * (((k * bm) @ p) * k).sum(-1) + ((k @ pq) * k).sum(-1)
            out.append(t.clamp_min(0.0))
        return torch.cat(out).to(x.dtype)

    def _mean_grad_sq_autograd(
        self, x: torch.Tensor, chunk: int, noise_map: torch.Tensor | None
    ) -> torch.Tensor:
        a_map = None if noise_map is None else noise_map.to(x)  # (D_in, D_src)
        out = []
        for s in range(0, x.shape[0], chunk):
            xb = x[s : s + chunk].detach().clone().requires_grad_(True)
            total = torch.zeros(xb.shape[0], dtype=x.dtype, device=x.device)
            with torch.enable_grad():
                mean = self._mean_normalised(xb)  # (b, C)
                for ch in range(self.num_channels):
                    (g,) = torch.autograd.grad(mean[:, ch].sum(), xb, retain_graph=True)
                    if a_map is not None:
                        g = g @ a_map  # (b, D_src)
                    total = total + g.pow(2).sum(-1)
            out.append(total.detach())
        return torch.cat(out)

    def trainable_parameters(self) -> list[nn.Parameter]:
        """Parameters given to Adam: kernel hyperparameters, Z (when learned), noise floor."""
        return [p for p in self.parameters() if p.requires_grad]

    def fit(
        self,
        x: torch.Tensor,
        y: torch.Tensor,
        *,
        progress: bool = False,
        noise_map: torch.Tensor | None = None,
    ) -> list[float]:
        """Train on (x, y) with Adam on the collapsed bound, set q; NIGP refits as configured.

        Args:
            x: (N, D_in) raw inputs.
            y: (N, C) raw outputs.
            progress: show a tqdm bar.
            noise_map: (D_in, D_src) for nigp, as :meth:`extra_train_noise` takes it.

        Returns:
            The loss (negative ELBO per datum and channel) of every step.

        Raises:
            ShapeError: when ``x`` or ``y`` is not of the shapes above, or of the regressor's
                dtype and device.
            DataError: when they hold NaN or inf (the fit would learn NaN).
        """
        check_shape("x", x, ("N", self.input_dim))
        check_shape("y", y, (x.shape[0], self.num_channels))
        self._check_dtype(x)
        self._check_dtype(y, "y")
        check_finite("x", x, ("window", "input"))
        check_finite("y", y, ("window", "output"))
        rounds = self.cfg.nigp_iterations + 1 if self.cfg.noisy_input == "nigp" else 1
        losses: list[float] = []
        extra = (
            torch.zeros(x.shape[0], dtype=x.dtype, device=x.device)
            if self.cfg.noisy_input == "nigp"
            else self.extra_train_noise(x)
        )
        for r in range(rounds):
            if r > 0:
                extra = self.extra_train_noise(x, noise_map)
            steps = self.cfg.steps_for(x.shape[0]) if r == 0 else self.cfg.nigp_refit_steps
            losses += self.train_steps(x, y, extra, steps=steps, progress=progress, round_index=r)
            self.finalise(x, y, extra)
        return losses

    def batch_indices(
        self, n: int, steps: int, device: torch.device, round_index: int = 0
    ) -> list[torch.Tensor]:
        """Seeded point subsets of every step (all points when ``n <= batch_size``).

        Each training round (the noisy-input refits are rounds 1, 2, ...) draws its own
        minibatches, from a stream of ``cfg.seed`` apart from the one that chose the
        inducing points (:func:`~iplanner_torch.seeds.derive_seed`).
        """
        bs = min(self.cfg.batch_size, n)
        if bs >= n:
            return [torch.arange(n, device=device)] * steps
        g = torch.Generator().manual_seed(
            derive_seed(self.cfg.seed, SVGP_MINIBATCHES, round_index)
        )
        return [torch.randperm(n, generator=g)[:bs].to(device) for _ in range(steps)]

    def train_steps(
        self,
        x: torch.Tensor,
        y: torch.Tensor,
        extra: torch.Tensor,
        *,
        steps: int,
        progress: bool = False,
        round_index: int = 0,
    ) -> list[float]:
        """Adam on the collapsed bound for ``steps`` steps (q is not touched); the
        minibatches are those of training round ``round_index`` (:meth:`batch_indices`)."""
        if steps == 0:
            return []
        n = x.shape[0]
        xn, yn = self.normalise_x(x), self.normalise_y(y)
        opt = torch.optim.Adam(self.trainable_parameters(), lr=self.cfg.lr)
        self.train()
        losses = []
        batches = self.batch_indices(n, steps, x.device, round_index)
        it: Any = batches
        if progress:
            from tqdm import tqdm

            it = tqdm(batches, desc="svgp", leave=False)
        for idx in it:
            opt.zero_grad(set_to_none=True)
            loss = self.elbo_loss(xn[idx], yn[idx], extra[idx], n)
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        self.eval()
        self._cache = None
        return losses

    @torch.no_grad()
    def finalise(self, x: torch.Tensor, y: torch.Tensor, extra: torch.Tensor) -> None:
        """Set q to the closed-form ELBO optimum on the full set; set the test noise term.

        ``S = (I + Phi Lam^-1 Phi^T)^-1``, ``m_c = S Phi Lam^-1 y_c`` (whitened).

        Args:
            x: (N, D_in) raw inputs.
            y: (N, C) raw outputs.
            extra: (N,) extra observation noise ``e_i`` (normalised units).
        """
        xn, yn = self.normalise_x(x), self.normalise_y(y)
        _, phi, _ = self._kernel_terms(xn)
        lam = self.likelihood.floor + extra.reshape(-1)  # (N,)
        m = phi.shape[0]
        eye = torch.eye(m, dtype=phi.dtype, device=phi.device)
        l_b = _chol(eye + (phi / lam) @ phi.T, 1e-8)  # B = I + Phi Lam^-1 Phi^T = L_B L_B^T
        rhs = phi @ (yn / lam.unsqueeze(-1))  # (M, C)
        mean = torch.cholesky_solve(rhs, l_b)  # (M, C)
        root = torch.linalg.solve_triangular(l_b.T, eye, upper=True)  # S = B^-1 = R R^T
        vd = self.variational
        vd.variational_mean.copy_(mean.T)
        vd.covar_root.copy_(root)
        self.model.variational_strategy.variational_params_initialized.fill_(1)
        if self.cfg.noisy_input == "none":
            self.test_extra_noise.zero_()
        else:
            self.test_extra_noise.copy_(extra.mean())
        self._cache = None

    @torch.no_grad()
    def calibrate(
        self,
        x_val: torch.Tensor,
        y_val: torch.Tensor,
        x: torch.Tensor,
        y: torch.Tensor,
        extra: torch.Tensor,
        rounds: int = 2,
    ) -> float:
        """Raise the noise floor to the validation-likelihood maximiser, then reset q.

        With ``r_i`` the mean over channels of the squared normalised validation residuals and
        ``b_i = var_f(x_i) + e_test``, the floor ``f`` maximises
        ``sum_i -(log(b_i + f) + r_i / (b_i + f)) / 2`` (bisection on its derivative). q is
        then recomputed from the training points with the new floor, and the next round
        (``rounds`` in all, since q depends on the floor) maximises again with it. A round
        only raises the floor: where the maximiser lies below the current floor (the ELBO's,
        or an earlier round's) the floor is kept and the rounds end, so the result may sit a
        little above the last round's maximiser (wider, the safe side).

        Args:
            x_val: (N_v, D_in) raw validation inputs (other demonstrations than training).
            y_val: (N_v, C) raw validation outputs.
            x: (N, D_in) raw training inputs.
            y: (N, C) raw training outputs.
            extra: (N,) training extra noise ``e_i`` (normalised units).
            rounds: calibrate -> refit q rounds.

        Returns:
            The final noise floor (normalised units).
        """
        check_shape("x_val", x_val, ("N_v", self.input_dim))
        check_shape("y_val", y_val, (x_val.shape[0], self.num_channels))
        for _ in range(rounds):
            mean, var = self.predict(x_val)
            c = self._cache
            base = var[:, 0] / self.y_std[0] ** 2 - c["floor"]  # (N_v,) var_f + e_test
            r2 = ((y_val - mean) / self.y_std).pow(2).mean(-1)  # (N_v,)
            floor = float(c["floor"])

            def slope(f: float, base: torch.Tensor = base, r2: torch.Tensor = r2) -> float:
                t = base + f
                return float((1.0 / t - r2 / t.pow(2)).sum())

            if slope(floor) >= 0:  # the training floor is already wide enough
                break
            lo, hi = floor, max(2 * floor, 1e-6)
            while slope(hi) < 0 and hi < 1e6:
                lo, hi = hi, 2 * hi
            for _ in range(50):
                mid = 0.5 * (lo + hi)
                lo, hi = (mid, hi) if slope(mid) < 0 else (lo, mid)
            new = 0.5 * (lo + hi)
            raw = math.log(math.expm1(max(new - self.likelihood.floor_min, 1e-12)))
            self.likelihood.raw_floor.fill_(raw)
            self.finalise(x, y, extra)
        return float(self.likelihood.floor.detach())

    # ---------------------------------------------------------------------------- prediction
    @torch.no_grad()
    def refresh_cache(self, threads: int | None = None) -> None:
        """Precompute the fast-path tensors from the current parameters.

        ``z`` (M, D_in), ``t = L^-T`` (M, M) so that ``w = k t`` is ``L^-1 k``, the whitened
        means ``mw`` (M, C), ``p = I - S`` (M, M), the mean weights ``w = L^-T mw`` (M, C),
        ``outputscale`` and ``noise = floor + e_test``; computed in float64, stored in the
        model's dtype.

        Args:
            threads: torch CPU threads to compute them on (restored after); None: torch's
                setting. The count splits the Cholesky factor's and the solve's sums, so it
                fixes their last bits, and every later forecast reads them:
                :meth:`HumanMotionPredictor.prepare` passes 1.

        Raises:
            ConfigError: when ``threads`` is not None or an integer >= 1.
        """
        if threads is not None:
            checks.integer("threads", threads, minimum=1)
        with torch_threads(threads):
            self._refresh_cache()

    def _refresh_cache(self) -> None:
        dt = torch.float64
        vs = self.model.variational_strategy
        z = vs.inducing_points.detach()
        kzz = self.model.covar_module(z).to_dense().to(dt)
        l_zz = _chol(kzz, self.jitter)
        m = z.shape[0]
        eye = torch.eye(m, dtype=dt, device=z.device)
        linv = torch.linalg.solve_triangular(l_zz, eye, upper=False)  # (M, M)
        vd = self.variational
        mw = vd.variational_mean.detach().to(dt).T  # (M, C)
        s_cov = vd.covariance.detach().to(dt)
        out_dt = z.dtype
        self._cache = {
            "z": z,
            "t": linv.T.to(out_dt).contiguous(),
            "mw": mw.to(out_dt).contiguous(),
            "p": (eye - s_cov).to(out_dt).contiguous(),
            "w": (linv.T @ mw).to(out_dt).contiguous(),
            "outputscale": self.model.covar_module.outputscale.detach().to(out_dt),
            "noise": (self.likelihood.floor.detach() + self.test_extra_noise).to(out_dt),
            "floor": self.likelihood.floor.detach().to(out_dt),
        }

    def _mean_normalised(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C) posterior mean of the normalised outputs at raw x (B, D_in), differentiable."""
        c = self._cache
        k = self.model.covar_module(self.normalise_x(x), c["z"]).to_dense()  # (B, M)
        return k @ c["w"]

    def _check_dtype(self, t: torch.Tensor, name: str = "x") -> None:
        """ShapeError unless ``t`` has the regressor's dtype and device (its
        normalisation's)."""
        if t.dtype != self.x_mean.dtype:
            raise ShapeError(
                f"expected {name} {self.x_mean.dtype} (the regressor's), got {t.dtype}"
            )
        if t.device != self.x_mean.device:
            raise ShapeError(
                f"expected {name} on {self.x_mean.device} (the regressor's), got {t.device}"
            )

    def predict(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Predictive mean and variance of the outputs (fast path, cached tensors).

        Args:
            x: (B, D_in) raw inputs.

        Returns:
            mean: (B, C) [output units]; var: (B, C) [output units^2], including the noise floor
            and the input-noise term (see the module docstring). A NaN input gives NaN.

        Raises:
            ShapeError: when ``x`` is not (B, D_in) of the regressor's dtype and device.
        """
        check_shape("x", x, ("B", self.input_dim))
        self._check_dtype(x)
        if self._cache is None:
            self.refresh_cache()
        c = self._cache
        with torch.no_grad():
            xn = self.normalise_x(x)
            k = self.model.covar_module(xn, c["z"]).to_dense()  # (B, M)
            kss = (
                c["outputscale"].expand(x.shape[0])
                if self.cfg.kernel in ("rbf", "matern")
                else self.model.covar_module(xn, diag=True)
            )
            w = k @ c["t"]  # (B, M) = (L^-1 k)^T
            mean = w @ c["mw"]  # (B, C)
            var_f = (kss - ((w @ c["p"]) * w).sum(-1)).clamp_min(0.0)  # (B,)
            var = (var_f + c["noise"]).unsqueeze(-1) * self.y_std.pow(2)  # (B, C)
            return mean * self.y_std + self.y_mean, var

    def predict_gpytorch(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reference prediction through GPyTorch's own variational strategy (slow).

        Args:
            x: (B, D_in) raw inputs.

        Returns:
            Same as :meth:`predict`.

        Raises:
            ShapeError: as :meth:`predict`.
        """
        check_shape("x", x, ("B", self.input_dim))
        self._check_dtype(x)
        self.eval()
        with torch.no_grad(), gpytorch.settings.fast_pred_var(False):
            out = self.model(self.normalise_x(x))
            mean, var = out.mean.T, out.variance.T  # (B, C)
            noise = self.likelihood.floor + self.test_extra_noise
            var = (var + noise) * self.y_std.pow(2)
            return mean * self.y_std + self.y_mean, var

    # ------------------------------------------------------------------------------ storing
    def to_checkpoint(self) -> dict[str, Any]:
        """Everything needed to rebuild the regressor (config, sizes, tensors)."""
        return {
            "format": CHECKPOINT_FORMAT,
            "cfg": asdict(self.cfg),
            "input_dim": self.input_dim,
            "num_channels": self.num_channels,
            "num_inducing": self.num_inducing,
            "window": self.window,
            "bandwidth": self.bandwidth,
            "state_dict": {k: v.detach().cpu() for k, v in self.state_dict().items()},
        }

    @classmethod
    def from_checkpoint(
        cls, d: dict[str, Any], map_location: torch.device | str | None = None
    ) -> SVGPRegressor:
        """Rebuild a regressor saved with :meth:`to_checkpoint`.

        Raises:
            CheckpointError: for a checkpoint of another layout (an older version).
        """
        if d.get("format") != CHECKPOINT_FORMAT:
            raise CheckpointError(
                f"GP checkpoint format {d.get('format')} is not {CHECKPOINT_FORMAT}: retrain "
                "the predictor with this version"
            )
        reg = cls(
            SVGPCfg(**d["cfg"]),
            input_dim=d["input_dim"],
            num_channels=d["num_channels"],
            num_inducing=d["num_inducing"],
            window=d["window"],
            bandwidth=d["bandwidth"],
        )
        sd = d["state_dict"]
        reg.to(sd["x_mean"].dtype)
        reg.load_state_dict(sd)
        reg.eval()
        if map_location is not None:
            reg.to(map_location)
        return reg


class SVGPBank:
    """G trained rbf/matern regressors of equal D_in and C, evaluated together.

    Every regressor's fast-path tensors are stacked (inducing inputs zero-padded to the largest
    M, with zero weights, so padding changes nothing) and one batched matmul chain predicts all
    of them: the online forecast of every action's GP in a few tensor operations.

    Args:
        regs: the regressors (the same object may appear several times).

    Raises:
        ConfigError: for time-series kernels or mismatched sizes.
    """

    def __init__(self, regs: Sequence[SVGPRegressor]) -> None:
        if not regs:
            raise ConfigError("an SVGPBank needs at least one regressor")
        kinds = {r.cfg.kernel for r in regs}
        if not kinds <= {"rbf", "matern"} or len(kinds) != 1:
            raise ConfigError(f"SVGPBank needs one of rbf or matern for all GPs, got {kinds}")
        d_in, c = regs[0].input_dim, regs[0].num_channels
        if any(r.input_dim != d_in or r.num_channels != c for r in regs):
            raise ConfigError("SVGPBank needs regressors of equal input_dim and num_channels")
        self.kernel = kinds.pop()
        m = max(r.num_inducing for r in regs)
        g = len(regs)
        ref = regs[0].x_mean
        z = torch.zeros(g, m, d_in, dtype=ref.dtype, device=ref.device)
        t = torch.zeros(g, m, m, dtype=ref.dtype, device=ref.device)
        p = torch.zeros_like(t)
        mw = torch.zeros(g, m, c, dtype=ref.dtype, device=ref.device)
        scale = torch.empty(g, d_in, dtype=ref.dtype, device=ref.device)
        shift = torch.empty_like(scale)
        os_, noise = torch.empty(g, dtype=ref.dtype), torch.empty(g, dtype=ref.dtype)
        for i, r in enumerate(regs):
            if r._cache is None:
                r.refresh_cache()
            cc = r._cache
            mi = r.num_inducing
            ls = r.model.covar_module.base_kernel.lengthscale.detach().reshape(-1)  # (1|D_in,)
            z[i, :mi] = cc["z"] / ls
            t[i, :mi, :mi] = cc["t"]
            p[i, :mi, :mi] = cc["p"]
            mw[i, :mi] = cc["mw"]
            scale[i] = 1.0 / (r.x_std * ls)
            shift[i] = r.x_mean * scale[i]
            os_[i], noise[i] = cc["outputscale"], cc["noise"]
        self.z, self.t, self.p, self.mw = z, t, p, mw
        self.z2 = z.pow(2).sum(-1)  # (G, M)
        self.scale, self.shift = scale, shift  # (G, D_in): x_scaled = x * scale - shift
        self.outputscale = os_.to(ref.device).view(g, 1)
        self.noise = noise.to(ref.device).view(g, 1)
        self.y_mean = torch.stack([r.y_mean for r in regs])  # (G, C)
        self.y_std = torch.stack([r.y_std for r in regs])  # (G, C)
        self.num_gps = g

    @torch.no_grad()
    def predict(self, x: torch.Tensor, chunk: int = 256) -> tuple[torch.Tensor, torch.Tensor]:
        """Every regressor's predictive mean and variance at the same inputs.

        Args:
            x: (B, D_in) raw inputs.
            chunk: windows per batched pass (bounds the (G, chunk, D_in) temporary).

        Returns:
            mean: (B, G, C) [output units]; var: (B, G, C) [output units^2].

        Raises:
            ShapeError: when ``x`` is not (B, D_in) of the bank's dtype and device.
            ConfigError: when ``chunk`` is not an integer >= 1.
        """
        check_shape("x", x, ("B", self.z.shape[-1]))
        if x.dtype != self.z.dtype or x.device != self.z.device:
            raise ShapeError(
                f"expected x {self.z.dtype} on {self.z.device} (the bank's), got {x.dtype} on "
                f"{x.device}"
            )
        checks.integer("chunk", chunk, minimum=1)
        if x.shape[0] == 0:
            g, c = self.mw.shape[0], self.mw.shape[-1]
            empty = x.new_zeros(0, g, c)
            return empty, empty.clone()
        means, vars_ = [], []
        for s in range(0, x.shape[0], chunk):
            xs = x[s : s + chunk].unsqueeze(0) * self.scale.unsqueeze(1) - self.shift.unsqueeze(
                1
            )  # (G, b, D_in)
            d2 = torch.baddbmm(
                xs.pow(2).sum(-1, keepdim=True) + self.z2.unsqueeze(1),
                xs,
                self.z.mT,
                alpha=-2.0,
            ).clamp_min_(0.0)  # (G, b, M)
            if self.kernel == "rbf":
                k = torch.exp(-0.5 * d2)
            else:
                r5 = (5.0 * d2).sqrt()
                k = (1.0 + r5 + r5.pow(2) / 3.0) * torch.exp(-r5)
            k = k * self.outputscale.unsqueeze(-1)  # (G, b, M)
            w = torch.bmm(k, self.t)  # (G, b, M)
            mean = torch.bmm(w, self.mw)  # (G, b, C)
            var_f = (self.outputscale - (torch.bmm(w, self.p) * w).sum(-1)).clamp_min(0.0)
            var = (var_f + self.noise).unsqueeze(-1) * self.y_std.pow(2).unsqueeze(1)
            mean = mean * self.y_std.unsqueeze(1) + self.y_mean.unsqueeze(1)
            means.append(mean.transpose(0, 1))  # (b, G, C)
            vars_.append(var.transpose(0, 1))
        return torch.cat(means), torch.cat(vars_)
