"""Fixtures of the prediction tests."""

from __future__ import annotations

import pytest
import torch

from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
from iplanner_torch.data.windows import WindowCfg, build_windows
from iplanner_torch.prediction.predictor import PredictorCfg
from iplanner_torch.prediction.svgp import SVGPCfg
from iplanner_torch.prediction.training import TrainerCfg, train_predictor

#: the joints of the small predictor of :func:`trained`
TRAINED_JOINTS = ("torso", "left_hand", "right_hand")


@pytest.fixture
def one_thread():
    """One intra-op thread: these small problems run fastest (and fairest) that way, and
    shared CPUs are not oversubscribed."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory):
    """(checkpoint path, windows) of a small predictor trained on 2 reaching targets x 5
    reaches (joints :data:`TRAINED_JOINTS`, 6 past and 8 future frames), once per module, on
    one thread."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    rc = ReachingCfg(n_targets=2, reaches_per_target=5)
    demos = [d for t in range(2) for r in range(5) for d in reaching_demonstrations(rc, t, r)]
    wc = WindowCfg(n_prev=6, n_future=8, stride=2, joints=TRAINED_JOINTS)
    windows = build_windows(demos, wc)
    cfg = PredictorCfg(
        svgp=SVGPCfg(num_inducing=20, epochs=3, max_steps=20),
        classifier_kernel="rbf",
        ivm_max_import=8,
        ivm_candidates=16,
        min_group_size=10,
    )
    path = train_predictor(
        windows,
        predictor_cfg=cfg,
        trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
        out_dir=tmp_path_factory.mktemp("pred"),
        progress=False,
    )
    yield path, windows
    torch.set_num_threads(threads)
