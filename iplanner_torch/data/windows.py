"""Features, progress states and training windows (paper sec. 4.1).

For a demonstration with labels ``a_1 .. a_T`` and a current frame ``s`` (0-based here), the
training tuple is ``(F_prev, p, c, n, xi_next)``:

* ``F_prev``: features of frames ``s - n_p + 1 .. s`` (positions, velocities, accelerations),
  computed by :func:`compute_features` on exactly those ``n_p`` frames, which is what the
  predictor does at runtime with the last ``n_p`` tracked frames: NaN imputation and finite
  differences see the same frames in training and at runtime.
* ``p``: the progress state, a bitmask of the actions completed before frame ``s``
  (:func:`progress_bitmask`).
* ``c``: the current action ``a_s``; ``n``: the next action, the first label after the current
  segment that differs from ``c`` (unlabelled frames skipped; -1 when there is none).
* ``xi_next``: positions of frames ``s + 1 .. s + n_f``: the demonstration's clean positions
  when it has them (synthetic data: ground truth), else the observed ones with NaN gaps
  imputed over the whole demonstration (interpolation may use later frames there: it is a
  target, not an input).
"""

from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import Literal

import numpy as np
import torch

from iplanner_torch.checks import is_real, positive
from iplanner_torch.checks import seed as check_seed
from iplanner_torch.data.demonstration import Demonstration
from iplanner_torch.data.skeleton import BONES
from iplanner_torch.errors import ConfigError, DataError, DataWarning, ShapeError
from iplanner_torch.types import check_shape

FeatureKind = Literal["position", "velocity", "acceleration"]
FEATURE_KINDS: tuple[str, ...] = ("position", "velocity", "acceleration")
#: Action names that never count as progress (unless listed explicitly).
NON_PROGRESS_ACTIONS: tuple[str, ...] = ("idle", "return", "unlabelled")


def _fallback_order(joint_names: Sequence[str]) -> list[list[int]]:
    """For each joint, the other joints sorted by distance along the skeleton's bones."""
    names = list(joint_names)
    adj: dict[str, set[str]] = {n: set() for n in names}
    for a, b in BONES:
        if a in adj and b in adj:
            adj[a].add(b)
            adj[b].add(a)
    orders = []
    for start in names:
        seen, frontier, order = {start}, [start], []
        while frontier:
            nxt = []
            for n in frontier:
                for m in sorted(adj[n]):
                    if m not in seen:
                        seen.add(m)
                        nxt.append(m)
                        order.append(names.index(m))
            frontier = nxt
        orders.append(order)
    return orders


def impute_nan(positions: torch.Tensor, joint_names: Sequence[str] | None = None) -> torch.Tensor:
    """Fill lost joints (NaN in any coordinate) along time.

    A gap is filled by linear interpolation between the observed frames around it; before the
    first (after the last) observed frame the first (last) observation is held. A joint lost
    in every frame takes the trajectory of the nearest joint along the skeleton's bones that
    is observed (e.g. a lost hand takes its elbow's), else of any observed joint (a tracked
    subset may hold no connected joint), which needs ``joint_names``.

    Args:
        positions: (..., T, K, 3) joint positions [m], NaN where lost.
        joint_names: the K names, to fill joints lost in every frame.

    Returns:
        (..., T, K, 3) positions without NaN.

    Raises:
        ShapeError: when ``positions`` is not (..., T, K, 3) of a floating dtype, or
            ``joint_names`` does not name K joints.
        DataError: when a joint is lost in every frame and no other joint is observed (or
            ``joint_names`` is not given).
    """
    x = positions
    if not isinstance(x, torch.Tensor) or x.dim() < 3 or x.shape[-1] != 3:
        got = tuple(x.shape) if isinstance(x, torch.Tensor) else type(x).__name__
        raise ShapeError(f"expected positions (..., T, K, 3), got {got}")
    if not x.is_floating_point():
        raise ShapeError(f"expected positions of a floating dtype, got {x.dtype}")
    if joint_names is not None and len(joint_names) != x.shape[-2]:
        raise ShapeError(
            f"expected {x.shape[-2]} joint_names (K of positions), got {len(joint_names)}"
        )
    obs = torch.isfinite(x).all(dim=-1)  # (..., T, K)
    if bool(obs.all()):
        return x
    if x.dim() > 3:  # impute only the sequences that have a gap
        flat = x.reshape(-1, *x.shape[-3:])  # (B, T, K, 3)
        rows = torch.nonzero(~obs.reshape(flat.shape[0], -1).all(dim=1))[:, 0]
        out = flat.clone()
        out[rows] = _impute_sequences(flat[rows], joint_names)
        return out.reshape(x.shape)
    return _impute_sequences(x, joint_names)


def _impute_sequences(x: torch.Tensor, joint_names: Sequence[str] | None) -> torch.Tensor:
    """:func:`impute_nan` on (..., T, K, 3) without the shortcut for complete sequences."""
    t_len = x.shape[-3]
    obs = torch.isfinite(x).all(dim=-1)  # (..., T, K)
    idx = torch.arange(t_len, device=x.device).view(-1, 1).expand(obs.shape)  # (..., T, K)
    prev = torch.where(obs, idx, torch.full_like(idx, -1)).cummax(dim=-2).values
    nxt = torch.where(obs, idx, torch.full_like(idx, t_len))
    nxt = nxt.flip(-2).cummin(dim=-2).values.flip(-2)
    x0 = torch.where(obs.unsqueeze(-1), x, torch.zeros_like(x))
    xp = x0.gather(-3, prev.clamp(min=0).unsqueeze(-1).expand(x.shape))
    xn = x0.gather(-3, nxt.clamp(max=t_len - 1).unsqueeze(-1).expand(x.shape))
    span = (nxt - prev).clamp(min=1).to(x.dtype)
    w = ((idx - prev).to(x.dtype) / span).unsqueeze(-1)
    out = xp + w * (xn - xp)
    out = torch.where((prev < 0).unsqueeze(-1), xn, out)
    out = torch.where((nxt >= t_len).unsqueeze(-1), xp, out)
    out = torch.where(obs.unsqueeze(-1), x, out)
    lost = ~obs.any(dim=-2)  # (..., K) joint lost in every frame
    if bool(lost.any()):
        bad = sorted({int(k) for k in torch.nonzero(lost)[:, -1].tolist()})
        if joint_names is None:
            raise DataError(
                f"joint(s) {bad} lost (NaN) in every frame; pass joint_names to fill them "
                "from a neighbouring joint"
            )
        orders = _fallback_order(joint_names)
        n_joints = len(joint_names)
        for k in bad:
            need = lost[..., k]
            # connected joints first (nearest along the bones), then any other observed joint
            others = [j for j in range(n_joints) if j != k and j not in orders[k]]
            candidates = [*orders[k], *others]
            for j in candidates:
                use = need & ~lost[..., j]
                out[..., k, :] = torch.where(use[..., None, None], out[..., j, :], out[..., k, :])
                need = need & ~use
            if bool(need.any()):
                raise DataError(
                    f"joint {joint_names[k]!r} lost (NaN) in every frame and no other joint "
                    "is observed"
                )
    return out


def compute_features(
    positions: torch.Tensor | np.ndarray,
    fps: float,
    kinds: Sequence[str] = FEATURE_KINDS,
    *,
    joint_names: Sequence[str] | None = None,
) -> torch.Tensor:
    """Per-frame features of a joint trajectory: positions, velocities, accelerations.

    NaN (lost joints) are imputed first with :func:`impute_nan` (linear interpolation in
    time, edge hold, whole-window losses from a neighbouring joint). Velocities are
    ``torch.gradient`` of positions and accelerations ``torch.gradient`` of velocities along
    time with spacing ``1 / fps`` and ``edge_order=2``: central differences inside, second
    order one-sided differences at both ends (exact for quadratic trajectories, so the last
    frame's velocity is the current one, not half a frame late).

    Args:
        positions: (..., T, K, 3) joint positions [m], NaN where lost; T >= 3 when
            derivatives are asked for.
        fps: frame rate [Hz].
        kinds: which features, ``"position"`` first, then any of ``"velocity"``,
            ``"acceleration"``.
        joint_names: the K names (to fill joints lost in every frame).

    Returns:
        (..., T, D) features, D = 3 K len(kinds), no NaN; each block is flattened
        joint-major, so ``f[..., :3K].view(..., K, 3)`` are the positions. float32 unless the
        input is float64; on the input's device.

    Raises:
        ShapeError: when positions is not (..., T, K, 3) or T is too short.
        ConfigError: for unknown kinds or kinds not starting with "position", or an
            ``fps`` that is not a finite number > 0.
        DataError: from :func:`impute_nan`.
    """
    x = torch.as_tensor(positions)
    if not x.is_floating_point():
        x = x.float()
    if x.dtype not in (torch.float32, torch.float64):
        x = x.float()
    check_shape("positions", x, ("...", "T", "K", 3))
    if x.dim() < 3:
        check_shape("positions", x, ("T", "K", 3))
    kinds = tuple(kinds)
    if not kinds or kinds[0] != "position" or any(k not in FEATURE_KINDS for k in kinds):
        raise ConfigError(
            f"kinds must start with 'position' and be among {FEATURE_KINDS}, got {kinds}"
        )
    if len(set(kinds)) != len(kinds):
        raise ConfigError(f"kinds has duplicates: {kinds}")
    fps = positive("fps", fps)  # inf would make the derivatives' spacing 0: inf and NaN
    t_len, k = x.shape[-3], x.shape[-2]
    if len(kinds) > 1 and t_len < 3:
        raise ShapeError(f"expected positions with T >= 3 frames for derivatives, got T={t_len}")
    x = impute_nan(x, joint_names)
    blocks = {"position": x}
    if "velocity" in kinds or "acceleration" in kinds:
        v = torch.gradient(x, spacing=1.0 / fps, dim=-3, edge_order=2)[0]
        blocks["velocity"] = v
        if "acceleration" in kinds:
            blocks["acceleration"] = torch.gradient(v, spacing=1.0 / fps, dim=-3, edge_order=2)[0]
    flat = [blocks[kind].reshape(*x.shape[:-2], 3 * k) for kind in kinds]  # each (..., T, 3K)
    return torch.cat(flat, dim=-1)


def _checked_labels(labels: torch.Tensor | np.ndarray) -> torch.Tensor:
    """(T,) int64 action labels, on their device, after the checks :func:`progress_bitmask`
    and :func:`next_action_labels` make.

    Raises:
        ShapeError: when ``labels`` is not (T,) of an integer dtype (floats would be cut to
            integers, NaN to a large negative one).
        DataError: for a label below -1.
    """
    raw = torch.as_tensor(labels)
    check_shape("labels", raw, ("T",))
    if raw.is_floating_point() or raw.is_complex() or raw.dtype == torch.bool:
        raise ShapeError(f"expected labels (T,) of an integer dtype, got {raw.dtype}")
    lab = raw.long()
    if lab.numel() and int(lab.min()) < -1:
        first = int(torch.nonzero(lab < -1)[0, 0])
        raise DataError(
            f"labels: frame {first} has label {int(lab[first])}; expected an action index "
            ">= 0, or -1 for an unlabelled frame"
        )
    return lab


def progress_bitmask(
    labels: torch.Tensor | np.ndarray, progress_actions: Sequence[int] | None = None
) -> torch.Tensor:
    """Progress states (paper sec. 3.1): which actions were completed before each frame.

    An action is completed at frame ``t`` when one of its segments ended before ``t`` (the
    label changed away from it at or before ``t``). Unlabelled frames (-1) inside an action
    do not end it: a segment that a gap interrupts ends only when the next labelled frame
    after the gap carries another action, or when no labelled frame follows (then it ends
    where the gap starts). This is how :func:`next_action_labels` reads through gaps.
    Bit ``a`` (value ``1 << a``) stands for action ``a``; only ``progress_actions`` set bits.

    Args:
        labels: (T,) int action labels, -1 for unlabelled.
        progress_actions: the action indices that count (< 63); None: every label >= 0.

    Returns:
        (T,) int64 bitmask, on the labels' device.

    Raises:
        ShapeError: when ``labels`` is not (T,) of an integer dtype (floats would be cut to
            integers, NaN to a large negative one).
        ConfigError: for an action index outside 0..62.
        DataError: for a label below -1.
    """
    lab = _checked_labels(labels)
    t_len = lab.shape[0]
    out = torch.zeros(t_len, dtype=torch.int64, device=lab.device)
    if t_len < 2:
        return out
    if progress_actions is None:
        acts = sorted({int(a) for a in lab.tolist() if a >= 0})
    else:
        acts = sorted({int(a) for a in progress_actions})
    if any(not 0 <= a < 63 for a in acts):
        raise ConfigError(f"progress actions must be in 0..62, got {acts}")
    ended = torch.zeros(t_len, dtype=torch.bool, device=lab.device)
    ended[1:] = lab[1:] != lab[:-1]  # frame t starts a new segment: lab[t-1] ended
    prev = torch.cat([lab[:1], lab[:-1]])
    # the label of the first labelled frame at or after each frame (-2: none follows)
    labelled = torch.nonzero(lab >= 0).flatten()  # (L,) frame indices
    ahead = torch.searchsorted(labelled, torch.arange(t_len, device=lab.device))  # (T,)
    has = ahead < labelled.numel()
    next_label = torch.full_like(lab, -2)
    next_label[has] = lab[labelled[ahead[has]]]
    ended &= next_label != prev  # a gap followed by the same action does not end it
    for a in acts:
        done = (ended & (prev == a)).long().cummax(dim=0).values
        out |= done << a
    return out


def next_action_labels(labels: np.ndarray) -> np.ndarray:
    """(T,) the next action after each frame's segment (paper sec. 4.1), -1 when none.

    The next action is the first label after the current segment that differs from the
    current one; unlabelled (-1) frames are skipped.

    Args:
        labels: (T,) integer action labels, -1 for unlabelled (an array or a tensor).

    Raises:
        ShapeError: when ``labels`` is not (T,) of an integer dtype (floats were cut to
            integers, NaN to a large negative one), as :func:`progress_bitmask`.
        DataError: for a label below -1.
    """
    lab = _checked_labels(labels).cpu().numpy()
    if lab.size == 0:
        return lab.copy()
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    seg_lab = lab[starts]
    seg_next = np.full(len(starts), -1, dtype=np.int64)
    for j in range(len(starts)):
        later = seg_lab[j + 1 :]
        hit = np.flatnonzero((later >= 0) & (later != seg_lab[j]))
        if hit.size:
            seg_next[j] = later[hit[0]]
    seg_of = np.cumsum(np.r_[True, lab[1:] != lab[:-1]]) - 1
    return seg_next[seg_of]


@dataclass(frozen=True, kw_only=True)
class WindowCfg:
    """How demonstrations are cut into training windows (paper sec. 4.1)."""

    n_prev: int = 15  # n_p, observed frames per window (1 s at 15 Hz)
    n_future: int = 15  # n_f, predicted frames per window
    stride: int = 1  # frames between consecutive window ends
    joints: tuple[str, ...] | None = None  # joints to use by name, in order; None: all
    feature_kinds: tuple[FeatureKind, ...] = FEATURE_KINDS  # "position" first
    progress_actions: tuple[str, ...] | None = None  # None: all but idle/return/unlabelled

    def __post_init__(self) -> None:
        # every command's joint selection is checked here, for every data format: a single
        # string is refused (it was read as a list of one here, and refused or split into
        # letters elsewhere)
        if isinstance(self.joints, str):
            raise ConfigError(
                f"joints: expected a list of joint names, got the single string "
                f"{self.joints!r}; write it as a list: [{self.joints}]"
            )
        for name in ("joints", "progress_actions", "feature_kinds"):
            val = getattr(self, name)
            if val is not None and not isinstance(val, (str, Sequence)):  # a number, a bool
                raise ConfigError(f"{name}: expected a list of names, got {val!r}")
        if self.feature_kinds is None:
            raise ConfigError("feature_kinds: expected a list of names, got None")
        for name in ("joints", "progress_actions"):
            val = getattr(self, name)
            if val is not None:
                if isinstance(val, str):
                    val = (val,)
                object.__setattr__(self, name, tuple(str(v) for v in val))
        kinds = self.feature_kinds
        object.__setattr__(
            self, "feature_kinds", (kinds,) if isinstance(kinds, str) else tuple(kinds)
        )
        # each field on its own, so the message names the one that is wrong (null or 1.5
        # failed in the comparison)
        for name, least in (("n_prev", 3), ("n_future", 1), ("stride", 1)):
            value = getattr(self, name)
            if not (is_real(value) and isinstance(value, numbers.Integral) and value >= least):
                raise ConfigError(f"{name}: expected an integer >= {least}, got {value!r}")
        kinds = self.feature_kinds
        if not kinds or kinds[0] != "position" or any(k not in FEATURE_KINDS for k in kinds):
            raise ConfigError(f"feature_kinds must start with 'position', got {kinds}")
        if self.joints is not None and (
            not self.joints or len(set(self.joints)) != len(self.joints)
        ):
            raise ConfigError(f"joints must be non-empty and unique, got {self.joints}")

    def progress_indices(self, action_names: Sequence[str]) -> tuple[int, ...]:
        """Indices of the progress actions among ``action_names``.

        Raises:
            ConfigError: for a progress action that is not an action name.
        """
        names = list(action_names)
        if self.progress_actions is None:
            return tuple(i for i, n in enumerate(names) if n not in NON_PROGRESS_ACTIONS)
        missing = [a for a in self.progress_actions if a not in names]
        if missing:
            raise ConfigError(f"progress_actions {missing} are not among actions {names}")
        return tuple(names.index(a) for a in self.progress_actions)


@dataclass(kw_only=True)
class WindowSet:
    """Training tuples of many demonstrations (N windows).

    Attributes:
        f_prev: (N, n_p, D) features of the observed frames (see :func:`compute_features`).
        progress: (N,) int64 progress bitmask at the current frame.
        current: (N,) int64 current action.
        next_action: (N,) int64 next action, -1 when none.
        xi_next: (N, n_f, K, 3) future joint positions [m] (clean when available).
        pose_now: (N, K, 3) the (imputed, observed) pose at the current frame [m].
        demo_index: (N,) int64 index of the demonstration in the list given to
            :func:`build_windows`.
        frame_index: (N,) int64 current frame ``s`` within it.
        joint_names: the K joint names.
        action_names: the A action names.
        fps: frame rate [Hz].
        cfg: the window settings.
    """

    f_prev: torch.Tensor
    progress: torch.Tensor
    current: torch.Tensor
    next_action: torch.Tensor
    xi_next: torch.Tensor
    pose_now: torch.Tensor
    demo_index: torch.Tensor
    frame_index: torch.Tensor
    joint_names: tuple[str, ...]
    action_names: tuple[str, ...]
    fps: float
    cfg: WindowCfg

    TENSORS = (
        "f_prev",
        "progress",
        "current",
        "next_action",
        "xi_next",
        "pose_now",
        "demo_index",
        "frame_index",
    )

    def __len__(self) -> int:
        return int(self.f_prev.shape[0])

    @property
    def num_features(self) -> int:
        """D."""
        return int(self.f_prev.shape[-1])

    def subset(self, index: torch.Tensor) -> WindowSet:
        """The windows at ``index`` ((M,) int64 indices or (N,) bool mask)."""
        return replace(self, **{n: getattr(self, n)[index] for n in self.TENSORS})

    def to(self, device: torch.device | str) -> WindowSet:
        """A copy with every tensor on ``device``."""
        return replace(self, **{n: getattr(self, n).to(device) for n in self.TENSORS})

    def batch(self, index: torch.Tensor) -> dict[str, torch.Tensor]:
        """A dict of the tensors at ``index`` (the DataModule's batch format)."""
        return {n: getattr(self, n)[index] for n in self.TENSORS}


def compatible_demonstrations(
    demos: Sequence[Demonstration], joints: tuple[str, ...] | None = None
) -> list[Demonstration]:
    """The demonstrations as :func:`build_windows` uses them: checked to share action names,
    fps and joints (or to hold every joint of ``joints``, then selected to them).

    Raises:
        DataError: when there is no demonstration, or one disagrees with the first, naming it.
    """
    if not demos:
        raise DataError("no demonstrations to build windows from")
    first = demos[0]
    out = []
    for d in demos:
        if d.action_names != first.action_names:
            raise DataError(
                f"demonstration {d.name!r}: action_names {d.action_names} differ from "
                f"{first.name!r}'s {first.action_names}"
            )
        if not np.isclose(d.fps, first.fps):
            raise DataError(f"demonstration {d.name!r}: fps {d.fps} differs from {first.fps}")
        if joints is not None:
            missing = [j for j in joints if j not in d.joint_names]
            if missing:
                raise DataError(
                    f"demonstration {d.name!r} has no joint(s) {missing} of the selection "
                    f"{list(joints)} (it has {list(d.joint_names)})"
                )
            d = d.select_joints(list(joints)) if d.joint_names != joints else d
        elif d.joint_names != first.joint_names:
            raise DataError(f"demonstration {d.name!r}: joint_names differ from {first.name!r}'s")
        out.append(d)
    return out


def build_windows(demos: Sequence[Demonstration], cfg: WindowCfg) -> WindowSet:
    """Cut demonstrations into training windows (paper sec. 4.1, module docstring).

    Window ends are ``s = n_p - 1 + k stride`` up to ``T - n_f - 1``, so a fully labelled
    demonstration gives ``floor((T - n_p - n_f) / stride) + 1`` windows (none when shorter);
    frames labelled -1 are skipped.

    Args:
        demos: demonstrations sharing action names, fps and (the selected) joints.
        cfg: window settings.

    Returns:
        The windows (CPU tensors, float32 features).

    Windows in which no joint is observed in any frame (the whole body lost for ``n_prev``
    frames or more) are left out with a :class:`DataWarning` naming the demonstration.

    Raises:
        DataError: when demonstrations disagree or lack a selected joint, or a demonstration
            has no window with an observed joint.
        ConfigError: for unknown progress actions.
    """
    demos = compatible_demonstrations(demos, cfg.joints)
    first = demos[0]
    n_p, n_f = cfg.n_prev, cfg.n_future
    prog_idx = cfg.progress_indices(first.action_names)
    k = first.num_joints
    win_pos, fut, prog, cur, nxt, di, fi = [], [], [], [], [], [], []
    for i, d in enumerate(demos):
        t_len = d.num_frames
        s = np.arange(n_p - 1, t_len - n_f, cfg.stride)
        s = s[d.labels[s] >= 0] if s.size else s
        if s.size == 0:
            continue
        window = d.positions[s[:, None] + np.arange(-n_p + 1, 1)]  # (N_i, n_p, K, 3)
        seen = np.isfinite(window).all(-1).any(axis=(1, 2))  # (N_i,) some joint observed
        if not seen.any():
            raise DataError(
                f"demonstration {d.name!r}: no joint is observed in any frame of any window "
                "(lost (NaN) in every frame)"
            )
        if not seen.all():
            blind = s[~seen]
            warnings.warn(
                f"demonstration {d.name!r}: {blind.size} window(s) in which no joint is "
                f"observed in any frame (ending at frames {blind.min()}-{blind.max()}) are "
                "left out",
                DataWarning,
                stacklevel=2,
            )
            s, window = s[seen], window[seen]
        win_pos.append(window)
        source = d.clean_positions
        if source is None:
            try:
                source = impute_nan(torch.from_numpy(d.positions), d.joint_names).numpy()
            except DataError as exc:
                raise DataError(f"demonstration {d.name!r}: {exc}") from exc
        fut.append(source[s[:, None] + np.arange(1, n_f + 1)])  # (N_i, n_f, K, 3)
        prog.append(progress_bitmask(d.labels, prog_idx).numpy()[s])
        cur.append(d.labels[s])
        nxt.append(next_action_labels(d.labels)[s])
        di.append(np.full(s.size, i))
        fi.append(s)
    if not win_pos:
        f_prev = torch.zeros(0, n_p, 3 * k * len(cfg.feature_kinds))
        xi = torch.zeros(0, n_f, k, 3)
        empty = torch.zeros(0, dtype=torch.int64)
        tensors = dict(progress=empty, current=empty, next_action=empty, demo_index=empty,
                       frame_index=empty)  # fmt: skip
    else:
        pos = torch.from_numpy(np.concatenate(win_pos)).float()
        f_prev = compute_features(pos, first.fps, cfg.feature_kinds, joint_names=first.joint_names)
        xi = torch.from_numpy(np.concatenate(fut)).float()
        tensors = {
            name: torch.from_numpy(np.concatenate(v).astype(np.int64))
            for name, v in (
                ("progress", prog),
                ("current", cur),
                ("next_action", nxt),
                ("demo_index", di),
                ("frame_index", fi),
            )  # fmt: skip
        }
    pose_now = f_prev[:, -1, : 3 * k].reshape(-1, k, 3)  # (N, K, 3)
    return WindowSet(
        f_prev=f_prev,
        xi_next=xi,
        pose_now=pose_now,
        joint_names=first.joint_names,
        action_names=first.action_names,
        fps=float(first.fps),
        cfg=cfg,
        **tensors,
    )


def _stratum(d: Demonstration) -> str:
    if "target" in d.metadata:
        return f"target={d.metadata['target']}"
    skip = {i for i, n in enumerate(d.action_names) if n in NON_PROGRESS_ACTIONS}
    for a in d.labels:
        if a >= 0 and int(a) not in skip:
            return f"first={int(a)}"
    return "none"


#: (train, val, test) shares of the demonstrations when ``data.split`` does not say.
DEFAULT_SPLIT: tuple[float, float, float] = (0.8, 0.1, 0.1)


def check_split_fractions(fractions: Sequence[float]) -> tuple[float, float, float]:
    """``fractions`` as three floats, checked: (train, val, test) shares, non-negative, summing
    to 1.

    Raises:
        ConfigError: naming the shares given, when they are not that.
    """
    try:
        fr = tuple(float(f) for f in fractions)
    except (TypeError, ValueError) as err:
        raise ConfigError(
            f"fractions: expected 3 numbers (train, val, test), got {fractions!r} ({err})"
        ) from None
    if len(fr) != 3 or any(not f >= 0 for f in fr) or not math.isclose(sum(fr), 1.0):
        raise ConfigError(
            f"fractions: expected 3 non-negative shares (train, val, test) summing to 1, "
            f"got {list(fr)}"
        )
    return fr  # type: ignore[return-value]


def split_by_demonstration(
    demos: Sequence[Demonstration],
    fractions: tuple[float, float, float] = DEFAULT_SPLIT,
    seed: int = 0,
) -> tuple[list[Demonstration], list[Demonstration], list[Demonstration]]:
    """Split demonstrations (never windows) into train / val / test.

    Stratified: demonstrations are grouped by ``metadata["target"]`` when present, else by
    their first action other than idle/return/unlabelled, and each group is shuffled and cut
    by the fractions (rounded; the remainder goes to train), so every target appears in
    every split where the group is large enough.

    Args:
        demos: the demonstrations.
        fractions: (train, val, test), non-negative, summing to 1.
        seed: shuffling seed.

    Returns:
        (train, val, test) lists, each in the input order.

    Raises:
        ConfigError: for bad fractions, or a seed that is not an integer in [0, 2^32 - 1].
    """
    fr = check_split_fractions(fractions)
    rng = np.random.default_rng(check_seed(seed))  # None would split differently each call
    groups: dict[str, list[int]] = {}
    for i, d in enumerate(demos):
        groups.setdefault(_stratum(d), []).append(i)
    which = np.zeros(len(demos), dtype=np.int64)
    for key in sorted(groups):
        idx = rng.permutation(groups[key])
        n_val = int(round(len(idx) * fr[1]))
        n_test = int(round(len(idx) * fr[2]))
        if n_val + n_test >= len(idx) and fr[0] > 0:
            n_test = max(0, len(idx) - 1 - n_val)
            n_val = min(n_val, len(idx) - 1 - n_test)
        which[idx[len(idx) - n_val - n_test : len(idx) - n_test]] = 1
        which[idx[len(idx) - n_test :]] = 2
    return tuple([d for d, w in zip(demos, which) if w == s] for s in range(3))  # type: ignore[return-value]
