import pytest
import torch

from iplanner_torch.errors import ShapeError
from iplanner_torch.prediction.forecast import Forecast
from iplanner_torch.types import check_shape


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
        var=torch.ones(b, a, f, k, 3),
        dt=1 / 15,
        joint_names=tuple(f"j{i}" for i in range(k)),
        action_names=("a", "b", "c"),
    )
    expected = (w[:, :, None, None, None] * mean).sum(1)
    torch.testing.assert_close(fc.expected_mean(), expected)
    assert fc.joint_cov().shape == (b, a, f, k, 3, 3)
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
