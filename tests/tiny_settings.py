"""Predictor settings small enough to train in about a second on a few generated reaches,
shared by the training and command-line tests (``tests/conftest.py`` puts this folder on
``sys.path``)."""

from __future__ import annotations

from typing import Any

from iplanner_torch.prediction.predictor import PredictorCfg
from iplanner_torch.prediction.svgp import SVGPCfg


def tiny_predictor_cfg(**svgp: Any) -> PredictorCfg:
    """A predictor with 16 inducing points, 2 epochs of at most 12 steps, an RBF classifier
    and 6 import vectors; ``svgp`` overrides fields of its :class:`SVGPCfg`."""
    return PredictorCfg(
        svgp=SVGPCfg(**{"num_inducing": 16, "epochs": 2, "max_steps": 12, **svgp}),
        classifier_kernel="rbf",
        ivm_max_import=6,
        ivm_candidates=8,
        min_group_size=10,
    )
