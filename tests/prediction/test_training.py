"""Lightning training of the predictor: checkpoints, logs, resume, K = 1, configs."""

from __future__ import annotations

import dataclasses
import math
import typing
from pathlib import Path

import pandas as pd
import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from tiny_settings import tiny_predictor_cfg

from iplanner_torch.data.reaching import ReachingCfg, reaching_demonstrations
from iplanner_torch.data.windows import WindowCfg, build_windows, split_by_demonstration
from iplanner_torch.errors import CheckpointError, ConfigError, DataError
from iplanner_torch.prediction.predictor import HumanMotionPredictor, PredictorCfg
from iplanner_torch.prediction.svgp import SVGPCfg
from iplanner_torch.prediction.training import TrainerCfg, train_predictor

REPO = Path(__file__).resolve().parents[2]


pytestmark = pytest.mark.usefixtures("one_thread")


def _windows(joints: tuple[str, ...], n_future: int = 8):
    rc = ReachingCfg(n_targets=2, reaches_per_target=5)
    demos = [d for t in range(2) for r in range(5) for d in reaching_demonstrations(rc, t, r)]
    tr, va, _ = split_by_demonstration(demos, (0.7, 0.3, 0.0))
    wc = WindowCfg(n_prev=6, n_future=n_future, stride=2, joints=joints)
    return build_windows(tr, wc), build_windows(va, wc)


def _cfg(noisy_input: str = "simple") -> PredictorCfg:
    return tiny_predictor_cfg(noisy_input=noisy_input, nigp_iterations=1)


def test_writes_checkpoints_logs_and_resumes(tmp_path: Path) -> None:
    tr, va = _windows(("torso", "left_hand", "right_hand"))
    tcfg = TrainerCfg(accelerator="cpu", log_every_n_steps=1)
    path = train_predictor(
        (tr, va), predictor_cfg=_cfg(), trainer_cfg=tcfg, out_dir=tmp_path, progress=False
    )
    assert path == tmp_path / "predictor.ckpt"
    gp_ckpts = sorted(tmp_path.glob("gp_*.ckpt"))
    assert gp_ckpts and (tmp_path / "classifier.ckpt").is_file()
    lightning_ckpt = torch.load(gp_ckpts[0], weights_only=False)
    assert "state_dict" in lightning_ckpt and "svgp" in lightning_ckpt
    assert "pytorch-lightning_version" in lightning_ckpt
    metrics = pd.read_csv(next((tmp_path / "logs").glob("gp_*/version_0/metrics.csv")))
    assert metrics["train/elbo"].notna().any()
    assert {"val/nll", "val/rmse"} <= set(metrics.columns)
    ivm_log = pd.read_csv(tmp_path / "logs" / "classifier" / "version_0" / "metrics.csv")
    assert ivm_log["train/ivm_loss"].notna().sum() >= 1
    assert any((tmp_path / "tb").rglob("events.out.tfevents*"))
    pred = HumanMotionPredictor.load(path)
    fc = pred.predict(va.f_prev[:3], va.progress[:3])
    before = {p: p.stat().st_mtime_ns for p in gp_ckpts}

    def resume() -> Path:
        return train_predictor(
            (tr, va),
            predictor_cfg=_cfg(),
            trainer_cfg=tcfg,
            out_dir=tmp_path,
            progress=False,
            resume=True,
        )

    path2 = resume()
    assert {p: p.stat().st_mtime_ns for p in gp_ckpts} == before
    fc2 = HumanMotionPredictor.load(path2).predict(va.f_prev[:3], va.progress[:3])
    torch.testing.assert_close(fc.mean, fc2.mean)
    # a damaged sub-model checkpoint is named, with the way out, instead of unpickling noise
    for broken in (gp_ckpts[0], tmp_path / "classifier.ckpt"):
        good = broken.read_bytes()
        broken.write_bytes(b"\xef" + good[1:200])
        with pytest.raises(CheckpointError, match="cannot resume from .*train.resume=false") as e:
            resume()
        assert str(broken) in str(e.value)
        broken.write_bytes(good)


def test_resume_never_mixes_in_sub_models_of_other_inputs(tmp_path: Path) -> None:
    """Resuming on other data or settings is refused by the folder's training_inputs.json; a
    sub-model of another shape (a folder without that record) is caught before the predictor
    is written. Either way the folder's predictor.ckpt is left as it was."""
    import shutil
    import warnings

    from iplanner_torch.errors import DataWarning

    joints = ("torso", "left_hand", "right_hand")
    tcfg = TrainerCfg(accelerator="cpu", tensorboard=False)

    def train(windows, out: Path, resume: bool = False) -> Path:
        return train_predictor(
            windows, predictor_cfg=_cfg(), trainer_cfg=tcfg, out_dir=out, progress=False,
            resume=resume,
        )  # fmt: skip

    a, b = _windows(joints), _windows(joints, n_future=5)
    train(a, tmp_path / "a")
    train(b, tmp_path / "b")
    ckpt_a = (tmp_path / "a" / "predictor.ckpt").read_bytes()
    recorded = (tmp_path / "a" / "training_inputs.json").read_text()
    assert '"fingerprint"' in recorded and '"n_future": 8' in recorded
    with pytest.raises(CheckpointError, match=r"trained with other training data \(other "
                       r"demonstrations, or other windows of them\), window settings "
                       r"\(data.windows\) \(n_future 8 -> 5\) than"):  # fmt: skip
        train(b, tmp_path / "a", resume=True)
    with pytest.raises(CheckpointError, match=r"other predictor settings \(svgp.noisy_input "):
        train_predictor(
            a, predictor_cfg=_cfg("nigp"), trainer_cfg=tcfg, out_dir=tmp_path / "a",
            progress=False, resume=True,
        )  # fmt: skip
    assert (tmp_path / "a" / "predictor.ckpt").read_bytes() == ckpt_a
    # a record that is not a JSON object (broken by hand) is refused by name, not resumed past
    broken = tmp_path / "broken"
    shutil.copytree(tmp_path / "a", broken)
    for text, why in (("[]", "expected a JSON object, got list"), ("{", "JSONDecodeError")):
        (broken / "training_inputs.json").write_text(text)
        with pytest.raises(CheckpointError, match=f"cannot resume in .*unreadable \\({why}"):
            train(a, broken, resume=True)
        assert (broken / "predictor.ckpt").read_bytes() == ckpt_a
    # a folder from before the record and the stamps, with one GP of b's (5 future frames)
    # among a's
    mixed = tmp_path / "mixed"
    shutil.copytree(tmp_path / "a", mixed)
    (mixed / "training_inputs.json").unlink()
    gp = sorted((tmp_path / "b").glob("gp_*.ckpt"))[0]
    assert (mixed / gp.name).is_file()
    old_format = torch.load(gp, weights_only=False)
    del old_format["inputs_digest"], old_format["model_digest"]
    torch.save(old_format, mixed / gp.name)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(CheckpointError, match="fails on its own training windows"):
            train(a, mixed, resume=True)
    assert any(issubclass(w.category, DataWarning) for w in caught)
    # the unstamped sub-model is named: it is used without the checks
    assert any(
        issubclass(w.category, DataWarning)
        and f"{gp.name} carries no digests" in str(w.message)
        and "without the checks" in str(w.message)
        for w in caught
    )
    assert (mixed / "predictor.ckpt").read_bytes() == ckpt_a
    # the same folder with its own sub-models resumes to the same predictor
    shutil.copy(tmp_path / "a" / gp.name, mixed / gp.name)
    train(a, mixed, resume=True)
    fc = HumanMotionPredictor.load(mixed / "predictor.ckpt").predict(
        a[1].f_prev[:2], a[1].progress[:2]
    )
    fc_a = HumanMotionPredictor.load(tmp_path / "a" / "predictor.ckpt").predict(
        a[1].f_prev[:2], a[1].progress[:2]
    )
    torch.testing.assert_close(fc.mean, fc_a.mean)


def test_a_predictor_of_other_inputs_is_not_replaced_without_overwrite(tmp_path: Path) -> None:
    """Training into a folder that held a predictor of other joints (or data, or settings)
    replaced it, its sub-models and logs without a word. It is refused now, before anything
    is written, unless ``overwrite``; the same inputs train anew to the same predictor."""
    tcfg = TrainerCfg(accelerator="cpu", tensorboard=False)

    def train(windows, **kw) -> Path:
        return train_predictor(
            windows, predictor_cfg=_cfg(), trainer_cfg=tcfg, out_dir=tmp_path, progress=False,
            **kw,
        )  # fmt: skip

    three = _windows(("torso", "left_hand", "right_hand"))
    one = _windows(("right_hand",))
    train(three)
    kept = {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    with pytest.raises(
        CheckpointError,
        match=r"holds a predictor trained with other training data .*joints \(\['torso', "
        r"'left_hand', 'right_hand'\] -> \['right_hand'\]\).*add train.overwrite=true",
    ):
        train(one)
    assert {p.name: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == kept
    # the same inputs: trained anew, to the same numbers
    fc = HumanMotionPredictor.load(train(three)).predict(
        three[1].f_prev[:2], three[1].progress[:2]
    )
    fc0 = HumanMotionPredictor.load(tmp_path / "predictor.ckpt")
    assert (tmp_path / "predictor.ckpt").read_bytes() == kept["predictor.ckpt"]
    assert fc0.joint_names == ("torso", "left_hand", "right_hand") and fc.mean.shape[-2] == 3
    # a folder whose record is missing cannot be compared: refused too
    (tmp_path / "training_inputs.json").unlink()
    with pytest.raises(CheckpointError, match="without training_inputs.json, so this run"):
        train(three)
    # with overwrite: replaced
    path = train(one, overwrite=True)
    assert HumanMotionPredictor.load(path).joint_names == ("right_hand",)


def test_single_wrist_dataset_with_nigp(tmp_path: Path) -> None:
    tr, va = _windows(("right_hand",))
    path = train_predictor(
        (tr, None),
        predictor_cfg=_cfg("nigp"),
        trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False),
        out_dir=tmp_path,
        progress=False,
    )
    pred = HumanMotionPredictor.load(path, expect_joints=("right_hand",))
    fc = pred.predict(va.f_prev[:4], va.progress[:4])
    assert fc.mean.shape == (4, len(tr.action_names), 8, 1, 3)
    assert bool(torch.isfinite(fc.var).all()) and bool((fc.var > 0).all())
    assert any((tmp_path / "logs").glob("gp_*_r1"))  # the NIGP refit round was logged


def test_errors(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="accelerator"):
        TrainerCfg(accelerator="tpu")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="max_epochs"):
        TrainerCfg(max_epochs=-1)
    with pytest.raises(ConfigError, match="max_steps"):
        TrainerCfg(max_steps=-1)
    assert TrainerCfg(max_steps=7).cap_steps(100) == 7 and TrainerCfg().cap_steps(100) == 100
    with pytest.raises(ConfigError, match="gp_input"):
        PredictorCfg(gp_input="raw")  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="classifier_kernel"):
        PredictorCfg(classifier_kernel="poly")  # type: ignore[arg-type]
    with pytest.raises(DataError, match="expected a WindowSet"):
        train_predictor("nope", predictor_cfg=_cfg(), trainer_cfg=TrainerCfg(), out_dir=tmp_path)


def _numeric_fields() -> list[tuple[type, str]]:
    """(config class, field) for every int or float field (also ``| None``) of the configs."""
    out = []
    for cls in (PredictorCfg, SVGPCfg, TrainerCfg):
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            kinds = set(typing.get_args(hints[f.name])) - {type(None)} or {hints[f.name]}
            if kinds in ({int}, {float}):
                out.append((cls, f.name))
    return out


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
@pytest.mark.parametrize(
    ("cls", "name"), _numeric_fields(), ids=lambda v: getattr(v, "__name__", v)
)
def test_config_numbers_refuse_nan_and_infinities(cls: type, name: str, value: float) -> None:
    """NaN passed range checks written as ``x <= 0`` (False for NaN) and failed only once
    training had touched the output folder (Lightning replacing earlier logs), or in torch
    (``Invalid learning rate: nan``); every number of the three configs is refused when the
    config is built, naming the field (which the CLI turns into ``predictor.ivm_lam: ...``)."""
    with pytest.raises(ConfigError, match=rf"(?<![\w.]){name}(?!\w).* got {value!r}$"):
        cls(**{name: value})


def test_config_seeds_and_bands_are_checked() -> None:
    """Fields that used to have no check: a negative seed (Lightning's seed_everything and
    numpy refuse it, mid-training) or a negative Sakoe-Chiba band."""
    assert len(_numeric_fields()) == 34  # the parametrisation above covers every number
    for cls in (PredictorCfg, SVGPCfg, TrainerCfg):
        with pytest.raises(ConfigError, match="expected seed an integer >= 0, got -1"):
            cls(seed=-1)
    with pytest.raises(ConfigError, match=r"expected seed an integer <= 4294967295 \(2\^32 - 1\)"):
        TrainerCfg(seed=2**32)
    assert TrainerCfg(seed=2**32 - 1).seed == 2**32 - 1
    with pytest.raises(ConfigError, match="expected series_band an integer >= 0, got -1"):
        SVGPCfg(series_band=-1)
    with pytest.raises(ConfigError, match="expected ivm_max_import an integer >= 1, got 2.5"):
        PredictorCfg(ivm_max_import=2.5)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected svgp an SVGPCfg, got NoneType"):
        PredictorCfg(svgp=None)  # type: ignore[arg-type]
    with pytest.raises(ConfigError, match="expected noise_floor_init > 0 and finite, got inf"):
        SVGPCfg(noise_floor_init=math.inf)  # used to pass: inf > noise_floor_min


def test_unavailable_accelerator_is_refused_before_anything_is_written(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """trainer.accelerator=cuda without CUDA ended in Lightning's MisconfigurationException,
    after training_inputs.json had been rewritten."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    monkeypatch.setattr(torch.backends.mps, "is_available", lambda: False)
    tr, va = _windows(("torso", "left_hand", "right_hand"))
    out = tmp_path / "run"
    (out / "logs" / "classifier" / "version_0").mkdir(parents=True)
    (out / "logs" / "classifier" / "version_0" / "metrics.csv").write_text("earlier run\n")
    (out / "training_inputs.json").write_text("{}\n")
    before = {q: q.read_bytes() for q in out.rglob("*") if q.is_file()}
    cases = [
        ("cuda", 1, r"^trainer.accelerator=cuda but CUDA is not available here; use "
         r"trainer.accelerator=cpu or auto$"),
        ("gpu", 1, r"^trainer.accelerator=gpu but no GPU \(CUDA or MPS\) is available here"),
    ]  # fmt: skip
    for accelerator, devices, message in cases:
        for where in (out, tmp_path / f"new_{accelerator}"):
            with pytest.raises(ConfigError, match=message):
                train_predictor(
                    (tr, va),
                    predictor_cfg=_cfg(),
                    trainer_cfg=TrainerCfg(
                        accelerator=accelerator, devices=devices, tensorboard=False
                    ),
                    out_dir=where,
                    progress=False,
                )
            assert where == out or not where.exists()
    assert {q: q.read_bytes() for q in out.rglob("*") if q.is_file()} == before
    # more CUDA devices than the machine has
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 1)
    with pytest.raises(ConfigError, match=r"trainer.devices=2 but this machine has 1 CUDA"):
        train_predictor(
            (tr, va),
            predictor_cfg=_cfg(),
            trainer_cfg=TrainerCfg(accelerator="cuda", devices=2, tensorboard=False),
            out_dir=tmp_path / "two",
            progress=False,
        )
    assert not (tmp_path / "two").exists()


@pytest.mark.parametrize(
    "name",
    ["predictor/iplanner_ni", "predictor/iplanner_no_ni", "trainer/default", "trainer/fast"],
)
def test_config_files_instantiate(name: str) -> None:
    node = OmegaConf.merge({"seed": 3}, {"node": OmegaConf.load(REPO / "conf" / f"{name}.yaml")})
    obj = instantiate(node.node)
    if name.startswith("predictor"):
        assert isinstance(obj, PredictorCfg) and isinstance(obj.svgp, SVGPCfg)
        assert obj.svgp.noisy_input == ("none" if name.endswith("no_ni") else "simple")
        assert obj.seed == 3
    else:
        assert isinstance(obj, TrainerCfg)


def _flat(obj: object, prefix: str = "") -> dict[str, object]:
    """Every leaf of a checkpoint (nested dicts, lists and tuples) by its path."""
    if isinstance(obj, dict):
        return {k: v for key, val in obj.items() for k, v in _flat(val, f"{prefix}/{key}").items()}
    if isinstance(obj, list | tuple):
        return {k: v for i, val in enumerate(obj) for k, v in _flat(val, f"{prefix}/{i}").items()}
    return {prefix: obj}


def test_training_runs_on_its_own_thread_count(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """TrainerCfg.num_threads holds while training, whatever torch's count around it (restored
    after), so the same seed gives the same predictor, to the bit, on machines with other core
    counts."""
    import iplanner_torch.prediction.training as training

    tr, va = _windows(("torso", "left_hand", "right_hand"))
    inner = training._train_predictor
    seen: list[int] = []

    def spy(*args: object, **kwargs: object) -> Path:
        seen.append(torch.get_num_threads())
        return inner(*args, **kwargs)

    monkeypatch.setattr(training, "_train_predictor", spy)
    before = torch.get_num_threads()
    saved = []
    try:
        for outer in (1, 3):
            torch.set_num_threads(outer)
            path = train_predictor(
                (tr, va),
                predictor_cfg=_cfg(),
                trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False, num_threads=2),
                out_dir=tmp_path / str(outer),
                progress=False,
            )
            assert torch.get_num_threads() == outer
            saved.append(_flat(torch.load(path, map_location="cpu", weights_only=False)))
        torch.set_num_threads(1)
        train_predictor(
            (tr, va),
            predictor_cfg=_cfg(),
            trainer_cfg=TrainerCfg(accelerator="cpu", tensorboard=False, num_threads=None),
            out_dir=tmp_path / "default",
            progress=False,
        )
    finally:
        torch.set_num_threads(before)
    assert seen == [2, 2, 1]  # None leaves torch's count
    a, b = saved
    assert a.keys() == b.keys()
    tensors = [k for k, v in a.items() if isinstance(v, torch.Tensor)]
    assert len(tensors) > 20
    for key in a:
        if isinstance(a[key], torch.Tensor):
            assert torch.equal(a[key], b[key]), key
        else:
            assert a[key] == b[key] or a[key] != a[key], key  # NaN equals itself here
    with pytest.raises(ConfigError, match="expected num_threads an integer >= 1, got 0"):
        TrainerCfg(num_threads=0)


@pytest.mark.parametrize("gp_input", ["relative", "window"])
def test_input_noise_map_is_the_jacobian_of_the_gp_inputs(gp_input: str) -> None:
    """The NIGP noise map: the Jacobian of a window's GP inputs with respect to its positions
    (autograd through the features), and by hand the last frame's velocity (second-order
    one-sided difference: (3 p_T - 4 p_T-1 + p_T-2) fps / 2)."""
    from iplanner_torch.data.windows import compute_features
    from iplanner_torch.prediction.predictor import gp_inputs
    from iplanner_torch.prediction.training import input_noise_map

    n_p, names, fps = 4, ("a", "b"), 15.0
    kinds = ("position", "velocity", "acceleration")
    a_map = input_noise_map(n_p, names, fps, kinds, gp_input)
    k = len(names)
    d = 3 * k * len(kinds)
    assert a_map.shape == (n_p * d, n_p * k * 3)

    def inputs(pos: torch.Tensor) -> torch.Tensor:
        f = compute_features(pos.unsqueeze(0), fps, kinds, joint_names=names)
        return gp_inputs(f, k, gp_input)[0]

    ref = torch.autograd.functional.jacobian(inputs, torch.zeros(n_p, k, 3, dtype=torch.float64))
    torch.testing.assert_close(a_map, ref.reshape(n_p * d, -1), rtol=1e-12, atol=1e-12)
    row = (n_p - 1) * d + 3 * k  # last frame, velocity block, joint a, x
    col = [(t * k) * 3 for t in range(n_p)]  # joint a, x, at each frame
    expected = torch.tensor([0.0, 0.5, -2.0, 1.5], dtype=torch.float64) * fps
    torch.testing.assert_close(a_map[row, col], expected, rtol=1e-12, atol=1e-12)


def _trained(out: Path, windows, noisy_input: str = "simple", resume: bool = False) -> Path:
    tcfg = TrainerCfg(accelerator="cpu", tensorboard=False)
    return train_predictor(
        windows, predictor_cfg=_cfg(noisy_input), trainer_cfg=tcfg, out_dir=out,
        progress=False, resume=resume,
    )  # fmt: skip


def test_resume_retrains_sub_models_of_another_run_in_the_folder(tmp_path: Path) -> None:
    """A run started in a trained folder with other settings and interrupted after its first
    sub-model leaves that run's record beside the earlier run's sub-models. Resuming it used
    to take those as its own (an NI predictor under a no-NI record); each sub-model stamped
    with another run's inputs is now trained anew, so the resumed predictor is the one an
    uninterrupted run gives."""
    import shutil
    import warnings

    from iplanner_torch.errors import DataWarning

    windows = _windows(("torso", "left_hand", "right_hand"))
    _trained(tmp_path / "ni", windows, "simple")
    _trained(tmp_path / "no_ni", windows, "none")
    cut = tmp_path / "cut"  # the NI folder after a no-NI run that trained the classifier
    shutil.copytree(tmp_path / "ni", cut)
    for name in ("training_inputs.json", "classifier.ckpt"):
        shutil.copy(tmp_path / "no_ni" / name, cut / name)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _trained(cut, windows, "none", resume=True)
    anew = [str(w.message) for w in caught if issubclass(w.category, DataWarning)]
    gps = sorted(cut.glob("gp_*.ckpt"))
    assert len(anew) == len(gps) and all("trained anew" in m for m in anew)
    va = windows[1]

    def forecast(folder: str):
        pred = HumanMotionPredictor.load(tmp_path / folder / "predictor.ckpt")
        return pred.predict(va.f_prev[:3], va.progress[:3])

    got, want = forecast("cut"), forecast("no_ni")
    for field in ("weights", "mean", "var"):
        torch.testing.assert_close(getattr(got, field), getattr(want, field), rtol=0, atol=0)
    assert not torch.equal(forecast("ni").var, want.var)  # the settings give other GPs


def test_resume_refuses_a_sub_model_changed_after_it_was_written(tmp_path: Path) -> None:
    """torch reads a changed number inside a tensor without complaint: a resumed run built
    its predictor on it (a forecast 4.8 km off, or a NaN predictor written over the good
    one). The digest written with each sub-model now catches it, and predictor.ckpt is kept."""
    windows = _windows(("torso", "left_hand", "right_hand"))
    _trained(tmp_path, windows)
    good = (tmp_path / "predictor.ckpt").read_bytes()
    gp = sorted(tmp_path.glob("gp_*.ckpt"))[0]
    original = gp.read_bytes()
    for value in (1e6, math.nan):
        d = torch.load(gp, weights_only=False)
        mean = next(v for k, v in d["svgp"]["state_dict"].items() if "variational_mean" in k)
        mean.view(-1)[0] = value
        torch.save(d, gp)
        with pytest.raises(CheckpointError, match=rf"cannot resume from {gp}: .*damaged") as e:
            _trained(tmp_path, windows, resume=True)
        assert f"{gp}: its contents do not match" in str(e.value)  # the type is named once
        assert (tmp_path / "predictor.ckpt").read_bytes() == good
        gp.write_bytes(original)


def test_a_resume_at_another_frame_rate_names_it(tmp_path: Path) -> None:
    """The same demonstrations read at another frame rate: the refusal said only "other
    training data"; it names the frame rate now (recorded -> now)."""
    import dataclasses as dc

    tcfg = TrainerCfg(accelerator="cpu", tensorboard=False)
    tr, va = _windows(("torso", "left_hand", "right_hand"))
    train_predictor((tr, va), predictor_cfg=_cfg(), trainer_cfg=tcfg, out_dir=tmp_path,
                    progress=False)  # fmt: skip
    faster = dc.replace(tr, fps=30.0)
    with pytest.raises(CheckpointError, match=r"frame rate \(15\.0 -> 30\.0 fps\)"):
        train_predictor((faster, va), predictor_cfg=_cfg(), trainer_cfg=tcfg, out_dir=tmp_path,
                        progress=False, resume=True)  # fmt: skip


def test_training_again_replaces_the_logs_of_the_models_it_replaces(tmp_path: Path) -> None:
    """The same inputs trained again into a folder replace its predictor, and now its logs:
    TensorBoard had added the second run's events beside the first's in version_0 (its
    curves ran from the last step back to 0), and the CSV logger warned once per sub-model."""
    tr, va = _windows(("torso", "left_hand", "right_hand"))
    tcfg = TrainerCfg(accelerator="cpu", log_every_n_steps=1, tensorboard=True)
    for _ in range(2):
        train_predictor(
            (tr, va), predictor_cfg=_cfg(), trainer_cfg=tcfg, out_dir=tmp_path, progress=False
        )
    runs = sorted((tmp_path / "tb").glob("*/version_0"))
    assert runs
    for run in runs:
        assert len(list(run.glob("events.out.tfevents*"))) == 1, run
    for log in (tmp_path / "logs").glob("gp_*/version_0/metrics.csv"):
        steps = pd.read_csv(log)["step"].dropna()
        assert steps.is_monotonic_increasing, log  # one run's rows, not two
