import pytest
import torch

from iplanner_torch.errors import ConfigError, ShapeError
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import check_shape, default_device, resolve_device, torch_threads


def test_check_shape_accepts_matching_and_named_dims() -> None:
    check_shape("x", torch.zeros(4, 15, 90), ("B", 15, 90))
    check_shape("x", torch.zeros(2, 3, 4, 3), ("...", 4, 3))


@pytest.mark.parametrize(
    ("shape", "expected"),
    [((15, 90), ("B", 15, 90)), ((4, 14, 90), ("B", 15, 90)), ((3,), ("...", 4, 3))],
)
def test_check_shape_rejects_with_expected_and_got(shape, expected) -> None:
    with pytest.raises(ShapeError, match=r"expected x .* got"):
        check_shape("x", torch.zeros(shape), expected)


def test_check_shape_rejects_non_tensor() -> None:
    with pytest.raises(ShapeError, match="torch.Tensor"):
        check_shape("x", [1, 2, 3], ("B",))  # type: ignore[arg-type]


def test_forecast_mixture_mean_and_shape_checks() -> None:
    b, a, f, k = 2, 3, 4, 10
    w = torch.softmax(torch.randn(b, a), dim=-1)
    mean = torch.randn(b, a, f, k, 3)
    fc = Forecast(
        weights=w,
        mean=mean,
        var=0.5 + torch.rand(b, a, f, k, 3),
        dt=1 / 15,
        joint_names=tuple(f"j{i}" for i in range(k)),
        action_names=("a", "b", "c"),
    )
    expected = (w[:, :, None, None, None] * mean).sum(1)
    torch.testing.assert_close(fc.expected_mean(), expected)
    cov = fc.joint_cov()
    assert cov.shape == (b, a, f, k, 3, 3)
    for i in range(3):  # the per-axis variances on the diagonal, nothing off it
        torch.testing.assert_close(cov[..., i, i], fc.var[..., i])
        for j in range(3):
            if j != i:
                assert bool((cov[..., i, j] == 0).all())
    assert fc.select(1).batch_size == 1
    torch.testing.assert_close(fc.times[-1], torch.tensor(f / 15))
    with pytest.raises(ShapeError, match="expected mean"):
        Forecast(
            weights=w,
            mean=mean[:, :2],
            var=torch.ones(b, 2, f, k, 3),
            dt=1 / 15,
            joint_names=tuple(f"j{i}" for i in range(k)),
            action_names=("a", "b", "c"),
        )


def test_resolve_device_names_usable_devices_only() -> None:
    assert resolve_device("auto") == default_device()
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(torch.device("cpu")) == torch.device("cpu")
    for bad in ("tpu9", "", 3.5):
        with pytest.raises(ConfigError, match="unknown device"):
            resolve_device(bad)  # type: ignore[arg-type]
    # torch knows these types, but they hold no numbers or are untested here
    for other in ("meta", "mps", "xpu", torch.device("meta")):
        with pytest.raises(ConfigError, match="not one this project runs on"):
            resolve_device(other)
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="CUDA is not available"):
            resolve_device("cuda")
    else:
        assert resolve_device("cuda:0").type == "cuda"
        with pytest.raises(ConfigError, match="CUDA device"):
            resolve_device(f"cuda:{torch.cuda.device_count()}")


def test_torch_threads_sets_the_count_in_the_block_and_restores_it() -> None:
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(3)
        with torch_threads(1):
            assert torch.get_num_threads() == 1
        assert torch.get_num_threads() == 3
        with torch_threads(None):  # torch's count as it is
            assert torch.get_num_threads() == 3
        with pytest.raises(RuntimeError), torch_threads(2):
            assert torch.get_num_threads() == 2
            raise RuntimeError("inside")
        assert torch.get_num_threads() == 3  # restored on an error too
    finally:
        torch.set_num_threads(before)
