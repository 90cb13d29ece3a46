"""The console commands (Hydra apps); the only place Hydra is used.

Importing this package (every command does, before torch loads) bounds how long OpenMP's
waiting threads spin: see :func:`bounded_omp_spin`.
"""

from __future__ import annotations

import os

#: OpenMP (libgomp, torch's CPU backend) spin iterations a waiting thread burns before it
#: sleeps, when the environment sets neither ``GOMP_SPINCOUNT`` nor ``OMP_WAIT_POLICY``.
OMP_SPIN_COUNT = "1000"
#: set when :func:`bounded_omp_spin` set ``GOMP_SPINCOUNT`` (not the user)
SPIN_SET_MARK = "IPLANNER_TORCH_SET_GOMP_SPINCOUNT"


def bounded_omp_spin() -> bool:
    """Set ``GOMP_SPINCOUNT`` to :data:`OMP_SPIN_COUNT` unless the environment sets it or
    ``OMP_WAIT_POLICY``; libgomp reads it when torch loads, so this runs before.

    With libgomp's default (about 300,000 spins, a few ms) a training's two threads spin for
    cores that another busy process holds. On the 2-core machine the main job's two
    trainings took 70 s and 67 s with a one-thread Python loop running beside it, and 36 s
    and 35 s with 1,000 spins; alone they took 20 s and 17 s, and 20 s and 19 s
    (``experiments/bench/README.md``; ``python scripts/bench.py --only sweep`` measures one
    training). The setting changes how threads wait, not what they compute: the predictors
    came out equal tensor by tensor.

    Returns:
        Whether it was set.
    """
    if "GOMP_SPINCOUNT" in os.environ or "OMP_WAIT_POLICY" in os.environ:
        return False
    os.environ["GOMP_SPINCOUNT"] = OMP_SPIN_COUNT
    os.environ[SPIN_SET_MARK] = "1"
    return True


bounded_omp_spin()


def experiment_config(*overrides: str):  # noqa: ANN201 - the ExperimentCfg, imported late
    """The ``ExperimentCfg`` that ``iplanner-experiment <overrides>`` runs: see
    :func:`iplanner_torch.cli.experiment.experiment_config`."""
    from iplanner_torch.cli.experiment import experiment_config as compose_experiment

    return compose_experiment(*overrides)
