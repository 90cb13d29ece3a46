"""Sparse variational GP regression with the noisy-input correction (paper eq. GPRlearning, 6.1).

One :class:`SVGPRegressor` is trained per (progress state, current action). Its inputs are the
flattened, normalised observed windows ``F_prev`` and its outputs are all ``n_f x K x 3`` future
coordinates (the output channels of eq. GPRlearning). The predictor feeds it positions relative
to the current pose, so one model generalises across where the person sits (ARCHITECTURE 4.10).

Design (chosen for speed and memory, see the module's tests for the checks):

* All C channels share the kernel hyperparameters and the M inducing inputs Z; each channel has
  its own variational distribution ``q(v_c) = N(m_c, S_c)`` (a ``CholeskyVariationalDistribution``
  with ``batch_shape=[C]``, whitened: ``u_c = L v_c`` with ``K_ZZ = L L^T``). The kernel matrix
  and its Cholesky factor are thus computed once per batch for all channels.
* Hyperparameters, Z and the noise floor are trained with Adam on the minibatch ELBO
  (``gpytorch.mlls.VariationalELBO``); q is not a gradient variable by default (``train_q``):
  every ``q_refresh_every`` steps and after training it is set to its closed-form optimum for
  the full training set (the exact maximiser of the ELBO in q for a Gaussian likelihood; a
  variational-EM scheme, several times faster per step and converging in far fewer steps):
  ``S = (I + Phi Lam^-1 Phi^T)^-1``, ``m = S Phi Lam^-1 y`` with ``Phi = L^-1 K_ZX``.
  When the observation noise does not depend on the channel (``none``/``simple``) all channels
  share one ``S``, which is stored once.
* The observation noise is ``floor + extra_{i,c}``: a learned floor (one scalar, in normalised
  output units) plus a fixed per-point, per-channel term from the noisy-input correction:

  - ``none``: ``extra = 0``;
  - ``simple`` (paper sec. 6.1): ``extra = sigma^2 (1 + ||v||^2)`` with ``sigma`` the sensor noise
    [m] and ``v`` the joint velocity limit [m/s] (the paper's formula, its units taken as printed);
  - ``nigp`` (McHutchon and Rasmussen 2011): fit, take the gradient of the posterior mean at
    each training input by autograd, set ``extra_{i,c} = sigma_x^2 ||d m_c / d x (x_i)||^2``
    (in raw input units, i.e. gradients w.r.t. the un-normalised features), refit; repeated
    ``nigp_iterations`` times.

* Prediction (the fast path used online) uses cached tensors, without GPyTorch objects:
  ``mean_c = K_*Z alpha_c`` with ``alpha_c = L^-T m_c`` and
  ``var_c = k_** - ||L^-1 k_Z*||^2 + ||Q_c^T k_Z*||^2`` with ``Q_c = L^-T R_c``
  (``S_c = R_c R_c^T``), which equals
  ``k_** - k_*Z (K_ZZ^-1 - K_ZZ^-1 Sigma_u K_ZZ^-1) k_Z*``. The returned predictive
  variance of an output is ``var_c + floor + extra_test_c``: the test input is as noisy as the
  training inputs, so the input-noise term inflates it too; ``extra_test_c`` is
  ``sigma^2 (1 + ||v||^2)`` for ``simple``, the mean over the training points of the NIGP term
  for ``nigp``, and 0 for ``none``.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Literal

import gpytorch
import torch
from gpytorch.distributions import MultivariateNormal
from gpytorch.likelihoods import Likelihood
from gpytorch.models import ApproximateGP
from gpytorch.variational import CholeskyVariationalDistribution, VariationalStrategy
from linear_operator.operators import DenseLinearOperator
from torch import nn

from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.types import check_shape

KernelName = Literal["rbf", "matern", "gak", "dtw"]
NoisyInput = Literal["none", "simple", "nigp"]


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
    # Adam learning rate.
    lr: float = 0.02
    # passes over the training set per fit (the number of steps is also capped by max_steps).
    epochs: int = 30
    # maximum optimiser steps per fit (keeps large groups affordable).
    max_steps: int = 60
    # minibatch size of the ELBO.
    batch_size: int = 128
    # every this many steps q is reset to its closed-form optimum (0 = only at the end).
    q_refresh_every: int = 10
    # also train q by Adam between refreshes (slower; q's closed form is exact anyway).
    train_q: bool = False
    # learn the inducing inputs (rbf/matern; time-series kernels keep training windows).
    learn_inducing: bool = True
    # initial observation-noise floor in normalised output units (variance).
    noise_floor_init: float = 1e-2
    # lower bound of the noise floor (variance, normalised units).
    noise_floor_min: float = 1e-6
    # DTW kernel gamma / GAK sigma; None picks the median heuristic on the training windows.
    series_bandwidth: float | None = None
    # Sakoe-Chiba band of the time-series kernels (frames); None = unconstrained.
    series_band: int | None = None
    # seed of inducing-point selection and minibatch order.
    seed: int = 0

    def __post_init__(self) -> None:
        if self.num_inducing < 1:
            raise ConfigError(f"num_inducing must be >= 1, got {self.num_inducing}")
        if self.kernel not in ("rbf", "matern", "gak", "dtw"):
            raise ConfigError(f"kernel must be one of rbf, matern, gak, dtw, got {self.kernel!r}")
        if self.noisy_input not in ("none", "simple", "nigp"):
            raise ConfigError(
                f"noisy_input must be one of none, simple, nigp, got {self.noisy_input!r}"
            )
        if self.input_noise_sigma < 0:
            raise ConfigError(f"input_noise_sigma must be >= 0, got {self.input_noise_sigma}")
        if self.velocity_limit < 0:
            raise ConfigError(f"velocity_limit must be >= 0, got {self.velocity_limit}")
        if self.nigp_iterations < 1:
            raise ConfigError(f"nigp_iterations must be >= 1, got {self.nigp_iterations}")
        if self.lr <= 0:
            raise ConfigError(f"lr must be > 0, got {self.lr}")
        if self.epochs < 0 or self.max_steps < 0:
            raise ConfigError(
                f"epochs and max_steps must be >= 0, got {self.epochs}, {self.max_steps}"
            )
        if self.batch_size < 1:
            raise ConfigError(f"batch_size must be >= 1, got {self.batch_size}")
        if self.q_refresh_every < 0:
            raise ConfigError(f"q_refresh_every must be >= 0, got {self.q_refresh_every}")
        if not self.noise_floor_init > self.noise_floor_min >= 0:
            raise ConfigError(
                f"need noise_floor_init > noise_floor_min >= 0, got {self.noise_floor_init}, "
                f"{self.noise_floor_min}"
            )
        if self.series_bandwidth is not None and self.series_bandwidth <= 0:
            raise ConfigError(f"series_bandwidth must be > 0, got {self.series_bandwidth}")

    @property
    def simple_extra_var(self) -> float:
        """The paper's input-noise term ``sigma^2 (1 + ||v||^2)`` [m^2]."""
        return self.input_noise_sigma**2 * (1.0 + self.velocity_limit**2)


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


class ChannelSVGPModel(ApproximateGP):
    """The variational GP: shared kernel and inducing inputs, one q(v_c) per output channel."""

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
        vd = CholeskyVariationalDistribution(
            inducing.shape[0], batch_shape=torch.Size([num_channels])
        )
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


class PointNoiseGaussianLikelihood(Likelihood):
    """Gaussian likelihood with noise ``floor + extra_{i,c}`` (learned floor, fixed extra).

    ``extra_noise`` is passed per call: (C, N) or (1, N) variances in normalised output units.
    """

    def __init__(self, floor_init: float, floor_min: float) -> None:
        super().__init__()
        self.floor_min = float(floor_min)
        init = math.log(math.expm1(floor_init - floor_min))
        self.raw_floor = nn.Parameter(torch.tensor(init))

    @property
    def floor(self) -> torch.Tensor:
        """() the learned noise floor (variance, normalised units)."""
        return nn.functional.softplus(self.raw_floor) + self.floor_min

    def _noise(self, like: torch.Tensor, extra_noise: torch.Tensor | None) -> torch.Tensor:
        noise = self.floor.to(like)
        return noise if extra_noise is None else noise + extra_noise

    def expected_log_prob(
        self,
        target: torch.Tensor,
        input: MultivariateNormal,
        *args: Any,
        extra_noise: torch.Tensor | None = None,
        **kwargs: Any,
    ) -> torch.Tensor:
        """(C, N) E_q[log N(y | f, noise)] for targets (C, N)."""
        mean, var = input.mean, input.variance
        noise = self._noise(mean, extra_noise)
        return -0.5 * (torch.log(2 * math.pi * noise) + ((target - mean) ** 2 + var) / noise)

    def forward(
        self,
        function_samples: torch.Tensor,
        *args: Any,
        extra_noise: torch.Tensor | None = None,
        **kwargs: Any,
    ) -> torch.distributions.Normal:
        """p(y | f) for latent samples (..., C, N)."""
        noise = self._noise(function_samples, extra_noise)
        return torch.distributions.Normal(
            function_samples, noise.sqrt().expand_as(function_samples)
        )

    def marginal(
        self,
        function_dist: MultivariateNormal,
        *args: Any,
        extra_noise: torch.Tensor | None = None,
        **kwargs: Any,
    ) -> MultivariateNormal:
        """p(y) with the observation noise added to the diagonal (independent outputs)."""
        mean, var = function_dist.mean, function_dist.variance
        noise = self._noise(mean, extra_noise)
        return MultivariateNormal(mean, torch.diag_embed(var + noise))


def _median_sq_dist(x: torch.Tensor, n: int, generator: torch.Generator) -> float:
    idx = torch.randperm(x.shape[0], generator=generator)[:n].to(x.device)
    d2 = torch.cdist(x[idx], x[idx]).pow(2)
    vals = d2[~torch.eye(len(idx), dtype=torch.bool, device=x.device)]
    return float(vals.median()) if vals.numel() else 1.0


class SVGPRegressor(nn.Module):
    """A multi-output sparse variational GP on flattened windows, with input normalisation.

    Build with :meth:`from_data` (chooses Z, the normalisation and the kernel bandwidth), train
    with :meth:`fit`, predict with :meth:`predict`. Save with :meth:`to_checkpoint`, restore
    with :meth:`from_checkpoint`.
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
        base = self._make_base_kernel()
        covar = gpytorch.kernels.ScaleKernel(base)
        z0 = torch.zeros(num_inducing, self.input_dim)
        learn_z = cfg.learn_inducing and cfg.kernel in ("rbf", "matern")
        self.model = ChannelSVGPModel(z0, self.num_channels, covar, learn_z)
        self.likelihood = PointNoiseGaussianLikelihood(cfg.noise_floor_init, cfg.noise_floor_min)
        self.register_buffer("x_mean", torch.zeros(self.input_dim))
        self.register_buffer("x_std", torch.ones(self.input_dim))
        self.register_buffer("y_mean", torch.zeros(self.num_channels))
        self.register_buffer("y_std", torch.ones(self.num_channels))
        # (C,) input-noise variance added at prediction [output units^2]
        self.register_buffer("extra_test_var", torch.zeros(self.num_channels))
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
            ShapeError: when shapes disagree or N == 0.
        """
        check_shape("x", x, ("N", "D_in"))
        check_shape("y", y, (x.shape[0], "C"))
        if x.shape[0] == 0:
            raise ShapeError("expected x (N, D_in) with N >= 1, got N = 0")
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
            # GAK sigma of the order of the typical per-frame distance (Cuturi 2011)
            return max(math.sqrt(med / window[0]), 1e-3)
        return max(med, 1e-6)

    def set_inducing(self, z: torch.Tensor) -> None:
        """Set the inducing inputs. ``z``: (M, D_in) in normalised input units."""
        check_shape(
            "z", z, (self.model.variational_strategy.inducing_points.shape[0], self.input_dim)
        )
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
        """(C,) the paper's input-noise term in normalised output units."""
        return self.cfg.simple_extra_var / self.y_std**2

    # ------------------------------------------------------------------------------ training
    def elbo_loss(
        self, xn: torch.Tensor, yn: torch.Tensor, extra: torch.Tensor | None, num_data: int
    ) -> torch.Tensor:
        """Negative ELBO per datum and channel on a minibatch (normalised units).

        Args:
            xn: (B, D_in) normalised inputs.
            yn: (B, C) normalised outputs.
            extra: (B, C) or (B, 1) extra observation noise (normalised units), or None.
            num_data: N, the size of the full training set.

        Returns:
            () the loss, mean over channels of ``-ELBO_c``.
        """
        mll = gpytorch.mlls.VariationalELBO(self.likelihood, self.model, num_data=num_data)
        out = self.model(xn)
        kw = {} if extra is None else {"extra_noise": extra.T}
        return -mll(out, yn.T, **kw).mean()

    def extra_train_noise(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C) or (N, 1) extra observation noise (normalised units) at raw x (N, D_in).

        ``simple`` gives the constant paper term; ``nigp`` uses the current posterior mean's
        gradient (call after a first fit); ``none`` gives zeros.
        """
        n = x.shape[0]
        if self.cfg.noisy_input == "none":
            return torch.zeros(n, 1, dtype=x.dtype, device=x.device)
        if self.cfg.noisy_input == "simple":
            return self.extra_noise_simple().to(x).expand(n, -1).clone()
        return self.nigp_extra_noise(x) / self.y_std**2

    def nigp_extra_noise(self, x: torch.Tensor, chunk: int = 256) -> torch.Tensor:
        """(N, C) NIGP term ``sigma_x^2 ||d mean_c / d x||^2`` [output units^2] at raw x (N, D_in).

        The gradient is taken by autograd of the cached posterior mean with respect to the raw
        (un-normalised) inputs.
        """
        self.refresh_cache()
        out = []
        for s in range(0, x.shape[0], chunk):
            xb = x[s : s + chunk].detach().clone().requires_grad_(True)
            rows = []
            with torch.enable_grad():
                mean = self._mean_raw(xb)  # (b, C)
                for c in range(self.num_channels):
                    (g,) = torch.autograd.grad(mean[:, c].sum(), xb, retain_graph=True)
                    rows.append(g.pow(2).sum(-1))
            out.append(torch.stack(rows, -1))
        return self.cfg.input_noise_sigma**2 * torch.cat(out).detach()

    def fit(self, x: torch.Tensor, y: torch.Tensor, *, progress: bool = False) -> list[float]:
        """Train on (x, y) with Adam, then set q to its optimum; NIGP refits as configured.

        Args:
            x: (N, D_in) raw inputs.
            y: (N, C) raw outputs.
            progress: show a tqdm bar.

        Returns:
            The loss (negative ELBO per datum and channel) of every step.
        """
        check_shape("x", x, ("N", self.input_dim))
        check_shape("y", y, (x.shape[0], self.num_channels))
        rounds = self.cfg.nigp_iterations + 1 if self.cfg.noisy_input == "nigp" else 1
        losses: list[float] = []
        extra = (
            torch.zeros(x.shape[0], 1, dtype=x.dtype, device=x.device)
            if self.cfg.noisy_input == "nigp"
            else self.extra_train_noise(x)
        )
        for r in range(rounds):
            if r > 0:
                extra = self.extra_train_noise(x)
            losses += self.train_steps(x, y, extra, progress=progress)
            self.finalise(x, y, extra)
        return losses

    def freeze_q(self, frozen: bool) -> None:
        """Stop (or restart) gradients to the variational parameters of q."""
        for p in self.model.variational_strategy._variational_distribution.parameters():
            p.requires_grad_(not frozen)

    def trainable_parameters(self) -> list[nn.Parameter]:
        """Parameters given to Adam: hyperparameters, Z, noise floor (and q if ``train_q``)."""
        vd = self.model.variational_strategy._variational_distribution
        skip = set() if self.cfg.train_q else {id(p) for p in vd.parameters()}
        return [p for p in self.parameters() if id(p) not in skip]

    def train_steps(
        self, x: torch.Tensor, y: torch.Tensor, extra: torch.Tensor, *, progress: bool = False
    ) -> list[float]:
        """Adam on the minibatch ELBO for ``min(epochs * ceil(N / batch), max_steps)`` steps."""
        n = x.shape[0]
        xn, yn = self.normalise_x(x), self.normalise_y(y)
        bs = min(self.cfg.batch_size, n)
        steps = min(self.cfg.epochs * math.ceil(n / bs), self.cfg.max_steps)
        if steps == 0:
            return []
        g = torch.Generator().manual_seed(self.cfg.seed)
        opt = torch.optim.Adam(self.trainable_parameters(), lr=self.cfg.lr)
        self.freeze_q(not self.cfg.train_q)
        self.train()
        losses = []
        it = range(steps)
        if progress:
            from tqdm import tqdm

            it = tqdm(it, desc="svgp", leave=False)
        perm = torch.randperm(n, generator=g)
        pos = 0
        every = self.cfg.q_refresh_every
        for step in it:
            if every and step % every == 0:
                self.finalise(x, y, extra)
            if pos + bs > n:
                perm, pos = torch.randperm(n, generator=g), 0
            idx = perm[pos : pos + bs].to(x.device)
            pos += bs
            opt.zero_grad(set_to_none=True)
            loss = self.elbo_loss(xn[idx], yn[idx], extra[idx], n)
            loss.backward()
            opt.step()
            losses.append(float(loss.detach()))
        self.freeze_q(False)
        self.eval()
        self._cache = None
        return losses

    @torch.no_grad()
    def finalise(self, x: torch.Tensor, y: torch.Tensor, extra: torch.Tensor) -> None:
        """Set q(v_c) to the closed-form ELBO optimum on the full set; set ``extra_test_var``.

        Args:
            x: (N, D_in) raw inputs.
            y: (N, C) raw outputs.
            extra: (N, C) or (N, 1) extra observation noise (normalised units).
        """
        xn, yn = self.normalise_x(x), self.normalise_y(y)
        z = self.model.variational_strategy.inducing_points
        kern = self.model.covar_module
        kzz = kern(z).to_dense()
        m = z.shape[0]
        # same jitter as GPyTorch's strategy and the fast path, so q matches their L exactly
        l_zz = self._chol(kzz, self.model.variational_strategy.jitter_val)
        kzx = torch.cat(
            [kern(z, xn[s : s + 2048]).to_dense() for s in range(0, xn.shape[0], 2048)], -1
        )  # (M, N)
        phi = torch.linalg.solve_triangular(l_zz, kzx, upper=False)  # (M, N)
        lam = self.likelihood.floor + extra.T  # (C|1, N)
        eye = torch.eye(m, dtype=x.dtype, device=x.device)
        w = 1.0 / lam  # (C|1, N)
        prec = torch.cat(
            [eye + (phi * w[s : s + 32].unsqueeze(1)) @ phi.T for s in range(0, w.shape[0], 32)]
        )  # (C|1, M, M)
        l_p = self._chol(prec, 1e-8)
        rhs = (phi.unsqueeze(0) * (yn.T / lam).unsqueeze(1)).sum(-1)  # (C, M)
        mean = torch.cholesky_solve(rhs.unsqueeze(-1), l_p).squeeze(-1)  # (C, M)
        # S = P^-1 = L_p^-T L_p^-1: its Cholesky factor via the flipped factorisation
        s_cov = torch.cholesky_inverse(l_p)  # (C|1, M, M)
        r = self._chol(s_cov, 1e-10)
        vd = self.model.variational_strategy._variational_distribution
        vd.variational_mean.copy_(mean)
        vd.chol_variational_covar.copy_(r.expand(self.num_channels, m, m))
        self.model.variational_strategy.variational_params_initialized.fill_(1)
        self._shared_cov = r.shape[0] == 1
        if self.cfg.noisy_input == "simple":
            self.extra_test_var.fill_(self.cfg.simple_extra_var)
        elif self.cfg.noisy_input == "nigp":
            self.extra_test_var.copy_((extra * self.y_std**2).mean(0).expand(self.num_channels))
        else:
            self.extra_test_var.zero_()
        self._cache = None

    @staticmethod
    def _chol(a: torch.Tensor, jitter: float = 1e-6) -> torch.Tensor:
        eye = torch.eye(a.shape[-1], dtype=a.dtype, device=a.device)
        for _ in range(6):
            l, info = torch.linalg.cholesky_ex(a + jitter * eye)
            if not bool(info.any()):
                return l
            jitter = jitter * 10
        return torch.linalg.cholesky(a + jitter * eye)

    # ---------------------------------------------------------------------------- prediction
    @torch.no_grad()
    def refresh_cache(self) -> None:
        """Precompute ``L``, ``alpha`` and ``Q`` from the current parameters (fast path)."""
        vs = self.model.variational_strategy
        z = vs.inducing_points.detach()
        kern = self.model.covar_module
        kzz = kern(z).to_dense()
        l_zz = self._chol(kzz, vs.jitter_val)
        vd = vs._variational_distribution
        mvec = vd.variational_mean.detach()  # (C, M)
        r = vd.chol_variational_covar.detach().tril()  # (C, M, M)
        if getattr(self, "_shared_cov", False) or bool((r == r[:1]).all()):
            r = r[:1]
        alpha = torch.linalg.solve_triangular(l_zz.mT, mvec.unsqueeze(-1), upper=True)
        q = torch.linalg.solve_triangular(l_zz.mT, r, upper=True)  # (C|1, M, M)
        self._cache = {
            "z": z,
            "l": l_zz,
            "alpha": alpha.squeeze(-1).T.contiguous(),
            "q": q,
            "outputscale": kern.outputscale.detach(),
        }

    def _kernel_cross(self, xn: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return self.model.covar_module(xn, z).to_dense()

    def _mean_raw(self, x: torch.Tensor) -> torch.Tensor:
        """(B, C) posterior mean [output units] at raw x (B, D_in), differentiable in x."""
        c = self._cache
        k = self._kernel_cross(self.normalise_x(x), c["z"])  # (B, M)
        return (k @ c["alpha"]) * self.y_std + self.y_mean

    def predict(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Predictive mean and variance of the outputs (fast path, cached tensors).

        Args:
            x: (B, D_in) raw inputs.

        Returns:
            mean: (B, C) [output units]; var: (B, C) [output units^2], including the noise floor
            and the input-noise term (see the module docstring).
        """
        check_shape("x", x, ("B", self.input_dim))
        if self._cache is None:
            self.refresh_cache()
        c = self._cache
        with torch.no_grad():
            xn = self.normalise_x(x)
            k = self._kernel_cross(xn, c["z"])  # (B, M)
            mean = k @ c["alpha"]  # (B, C)
            kss = (
                c["outputscale"].expand(x.shape[0])
                if self.cfg.kernel in ("rbf", "matern")
                else self.model.covar_module(xn, diag=True)
            )
            v = torch.linalg.solve_triangular(c["l"], k.T, upper=False)  # (M, B)
            qk = torch.einsum("cmk,bm->cbk", c["q"], k)  # (C|1, B, M)
            var_f = (kss - v.pow(2).sum(0)).unsqueeze(0) + qk.pow(2).sum(-1)  # (C|1, B)
            var_f = var_f.clamp_min(0.0).T  # (B, C|1)
            var = (var_f + self.likelihood.floor) * self.y_std**2 + self.extra_test_var
            return mean * self.y_std + self.y_mean, var.expand(-1, self.num_channels)

    def predict_gpytorch(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Reference prediction through GPyTorch's own variational strategy (slow).

        Args:
            x: (B, D_in) raw inputs.

        Returns:
            Same as :meth:`predict`.
        """
        self.eval()
        with torch.no_grad(), gpytorch.settings.fast_pred_var(False):
            out = self.model(self.normalise_x(x))
            mean, var = out.mean.T, out.variance.T  # (B, C)
        var = (var + self.likelihood.floor) * self.y_std**2 + self.extra_test_var
        return mean * self.y_std + self.y_mean, var

    # ------------------------------------------------------------------------------ storing
    def to_checkpoint(self) -> dict[str, Any]:
        """Everything needed to rebuild the regressor (config, sizes, tensors)."""
        return {
            "cfg": asdict(self.cfg),
            "input_dim": self.input_dim,
            "num_channels": self.num_channels,
            "num_inducing": int(self.model.variational_strategy.inducing_points.shape[0]),
            "window": self.window,
            "bandwidth": self.bandwidth,
            "shared_cov": bool(getattr(self, "_shared_cov", False)),
            "state_dict": {k: v.detach().cpu() for k, v in self.state_dict().items()},
        }

    @classmethod
    def from_checkpoint(
        cls, d: dict[str, Any], map_location: torch.device | str | None = None
    ) -> SVGPRegressor:
        """Rebuild a regressor saved with :meth:`to_checkpoint`."""
        reg = cls(
            SVGPCfg(**d["cfg"]),
            input_dim=d["input_dim"],
            num_channels=d["num_channels"],
            num_inducing=d["num_inducing"],
            window=d["window"],
            bandwidth=d["bandwidth"],
        )
        reg.load_state_dict(d["state_dict"])
        reg._shared_cov = d.get("shared_cov", False)
        reg.eval()
        if map_location is not None:
            reg.to(map_location)
        return reg
