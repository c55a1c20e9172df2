"""Training the critic of MADP's joint copies (:class:`madp.models.critic.Critic`) on the labels of
:func:`madp.training.critic.collect`, and judging it by how it ranks the copies.

:func:`train` (``madp critic train``): the states of the environments in ``train_envs`` (the rest are
held out by the caller). Two losses, the second weighted by ``rank_weight`` (3 unless told):

* the cell's mass and centroid, per robot: the squared error of the log mass and of the centroid's
  offset (in units of :data:`madp.robot.critic.OFFSET_SCALE_M`), each robot weighted by its share of
  the state's mass;
* the ranking of the K copies of each state, team-wide: every pair of copies whose true J after the
  step differs, a logistic loss on the difference of their team scores Σ_i s_ik
  (:func:`madp.robot.critic.copy_scores`) divided by the state's spread of scores, weighted by how
  much their true changes of J differ (in units of the state's spread of them).

``init`` continues from a trained critic instead of fresh weights (its configuration and mass unit
kept): a critic's next round on the states the policy it steers reaches, when the earlier labels are
gone or to keep what it learned from them.

The world's 8 symmetries are the augmentation: one element per batch moves the windows, the offsets
and the copies' moves alike.

:func:`ranking` scores any per-robot copy scores on held-out states: the mean Spearman rank
correlation of the team-wide sum with the true J after the step among the K copies, and for each
scope (each robot alone, its neighbourhood, the whole team) the share of ``oracle``'s gain that the
kept actions keep, the gain measured from the copies' mean J.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from madp.errors import SettingError
from madp.models.critic import Critic, CriticConfig
from madp.models.symmetry import _vectors, transform_image
from madp.robot.critic import CRITIC_SCOPES, OFFSET_SCALE_M, critic_choice
from madp.sim.env import move
from madp.sim.params import SimParams
from madp.sim.voronoi import ColumnPrefix, coverage_cost

__all__ = ["gain_share", "predicted_scores", "rank_study", "ranking", "spearman", "state_moves", "train",
           "true_cell_scores", "with_derived"]


def state_moves(data: dict, params: SimParams | None = None) -> np.ndarray:
    """``[S, K, N, 2]`` float32: each robot's move (m) in each copy of each state, by the motion rule."""
    params = params or SimParams()
    y, _ = move(data["start_m"][:, None], data["offset_m"][:, None], data["actions_mps"].astype(np.float64), params)
    return (y - data["position_m"][:, None]).astype(np.float32)


def with_derived(data: dict) -> dict:
    """``data`` with the copies' moves (``moves``, :func:`state_moves`) and the critic's neighbour input
    (``near``, :func:`madp.training.critic.stored_neighbours`) added where missing."""
    from madp.training.critic import stored_neighbours

    return {**data, **({} if "moves" in data else {"moves": state_moves(data)}),
            **({} if "near" in data else {"near": stored_neighbours(data)})}


def spearman(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[S]``: the Spearman rank correlation of each row of ``a [S, K]`` with the same row of ``b``
    (average ranks for ties; NaN for a row whose values are all equal)."""
    from scipy.stats import rankdata

    ra, rb = rankdata(a, axis=1), rankdata(b, axis=1)
    ra, rb = ra - ra.mean(1, keepdims=True), rb - rb.mean(1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (ra * rb).sum(1) / np.sqrt((ra ** 2).sum(1) * (rb ** 2).sum(1))


def gain_share(j_after: np.ndarray, j_kept: np.ndarray) -> tuple[np.ndarray, float]:
    """The share of ``oracle``'s gain the kept actions keep: per state ``(mean_k J_k − J_kept) /
    (mean_k J_k − min_k J_k)`` from ``j_after [S, K]`` (the copies' true J) and ``j_kept [S]`` (the kept
    actions' true J), NaN where the copies' J are all equal; and the ratio of the summed gains."""
    mean, best = j_after.mean(1), j_after.min(1)
    with np.errstate(invalid="ignore", divide="ignore"):
        per_state = np.where(mean > best, (mean - j_kept) / (mean - best), np.nan)
    return per_state, float((mean - j_kept).sum() / (mean - best).sum())


def _env_se(per_state: np.ndarray, env: np.ndarray) -> float:
    """The standard error of a mean over states, from the spread of the environments' own means (the
    states of one rollout are not independent): their standard deviation over √(environments)."""
    means = np.array([np.nanmean(per_state[env == e]) for e in np.unique(env)])
    means = means[np.isfinite(means)]
    return float(means.std(ddof=1) / np.sqrt(len(means))) if len(means) > 1 else float("nan")


def ranking(data: dict, scores: np.ndarray, prefixes: dict[int, ColumnPrefix], params: SimParams | None = None) -> dict:
    """How per-robot copy scores ``scores [S, N, K]`` (lower is better) rank the copies of the states of
    ``data``: the mean Spearman correlation of their team sums with the true J after the step, and per
    scope of :data:`madp.robot.critic.CRITIC_SCOPES` the share of ``oracle``'s gain (:func:`gain_share`)
    its kept actions keep (their true J from ``prefixes``: environment index -> the world's prefix table);
    each mean over states with its standard error across environments (``_se``) and, for the shares, the
    ratio of the summed gains (``_pooled``)."""
    params = params or SimParams()
    j = data["j_after"]
    rho = spearman(scores.sum(1), j)
    out = {"states": int(len(j)), "environments": int(len(np.unique(data["env"]))),
           "spearman_team": float(np.nanmean(rho)), "spearman_team_se": _env_se(rho, data["env"])}
    for scope in CRITIC_SCOPES:
        kept = np.empty(len(j))
        for s in range(len(j)):
            k = critic_choice(scores[s], data["neighbours"][s], scope)
            if scope == "team":
                kept[s] = j[s, k[0]]
                continue
            u = data["actions_mps"][s].astype(np.float64)[k, np.arange(len(k))]  # [N, 2]: robot i's action of copy k_i
            pos, _ = move(data["start_m"][s], data["offset_m"][s], u, params)
            kept[s] = coverage_cost(prefixes[int(data["env"][s])], pos)
        per_state, pooled = gain_share(j, kept)
        out[f"gain_share_{scope}"] = float(np.nanmean(per_state))
        out[f"gain_share_{scope}_se"] = _env_se(per_state, data["env"])
        out[f"gain_share_{scope}_pooled"] = pooled
    return out


def _tensors(data: dict, rows: np.ndarray, mass_unit: float) -> dict[str, torch.Tensor]:
    """The training tensors of states ``rows``: inputs, log mass, offsets, moves and copies' ΔJ."""
    offset = (data["centroid_m"][rows] - data["position_m"][rows]) / OFFSET_SCALE_M
    dj = data["j_after"][rows] - data["j_before"][rows][:, None]
    share = data["mass"][rows] / np.maximum(data["mass"][rows].sum(1, keepdims=True), 1e-12)
    return {"x": torch.from_numpy(data["x"][rows].astype(np.float32)), "near": torch.from_numpy(data["near"][rows]),
            "log_mass": torch.from_numpy(np.log(np.maximum(data["mass"][rows], 1e-6 * mass_unit) / mass_unit)).float(),
            "offset": torch.from_numpy(offset).float(), "share": torch.from_numpy(share).float(),
            "moves": torch.from_numpy(data["moves"][rows]), "dj": torch.from_numpy(dj).float()}


def _losses(net: Critic, b: dict[str, torch.Tensor], g: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The cell loss and the ranking loss of one batch of states (module docstring), in D4 element g."""
    s, n = b["x"].shape[:2]
    near = torch.cat([_vectors(b["near"][..., :2], g), b["near"][..., 2:]], -1)
    mass, offset = net(transform_image(b["x"].flatten(0, 1), g), near.flatten(0, 1))
    mass, offset = mass.view(s, n), offset.view(s, n, 2)
    target = _vectors(b["offset"], g)
    w = b["share"]
    cell = ((w * (torch.log(mass + 1e-6) - b["log_mass"]) ** 2).sum() + (w * ((offset - target) ** 2).sum(-1)).sum()) / s
    delta = _vectors(b["moves"], g) / OFFSET_SCALE_M  # [S, K, N, 2]
    d = offset[:, None]
    team = (mass[:, None] * ((delta ** 2).sum(-1) - 2.0 * (delta * d).sum(-1))).sum(-1)  # [S, K]
    team = team / team.std(1, keepdim=True).clamp(min=1e-9)
    dj = b["dj"] / b["dj"].std(1, keepdim=True).clamp(min=1e-12)
    diff_true = dj[:, :, None] - dj[:, None, :]  # > 0: copy l is better than copy k
    diff_pred = team[:, :, None] - team[:, None, :]
    weight = diff_true.abs() * (diff_true > 0)
    rank = (weight * torch.nn.functional.softplus(-2.0 * diff_pred)).sum() / weight.sum().clamp(min=1e-9)
    return cell, rank


def train(data: dict, train_envs: np.ndarray, out: Path, epochs: int = 12, batch: int = 8, lr: float = 2e-3,
          rank_weight: float = 3.0, seed: int = 0, config: CriticConfig | None = None, record: dict | None = None,
          log=print, policy: Path | None = None, init: Critic | None = None) -> Critic:
    """Fit a critic to the states of ``data`` (:func:`madp.training.critic.load_labels`) whose
    environment is in ``train_envs``, and write the MADP policy file ``policy`` (None: the shipped one)
    carrying it to ``out`` (:func:`madp.policies.checkpoint.attach`), for the ``critic`` selection rules.
    ``batch``: states per step; ``rank_weight``: the ranking loss's weight beside the cell loss;
    ``init``: a trained critic to continue from (its configuration and mass unit; ``config`` unused)."""
    rows = np.flatnonzero(np.isin(data["env"], train_envs))
    if len(rows) == 0:
        raise SettingError("train_envs", "no state of the labels file is in the training environments")
    if rank_weight < 0:
        raise SettingError("rank_weight", f"expected a weight >= 0, got {rank_weight!r}")
    if not lr > 0:
        raise SettingError("lr", f"expected a learning rate > 0, got {lr!r}")
    torch.manual_seed(seed)
    data = with_derived(data)
    cfg = init.config if init is not None else \
        CriticConfig(**{**(config or CriticConfig()).to_dict(), "mass_unit": float(data["mass"][rows].mean())})
    net = Critic(cfg)
    if init is not None:
        net.load_state_dict(init.state_dict())
    mass_unit = cfg.mass_unit
    t = _tensors(data, rows, mass_unit)
    opt = torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=1e-4)
    per_epoch = max(1, len(rows) // batch)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, lr, total_steps=epochs * per_epoch)
    gen = torch.Generator().manual_seed(seed)
    t0 = time.perf_counter()
    for epoch in range(epochs):
        net.train()
        perm = torch.randperm(len(rows), generator=gen)
        sums = np.zeros(2)
        for i in range(per_epoch):
            j = perm[i * batch:(i + 1) * batch]
            g = int(torch.randint(8, (1,), generator=gen))
            cell, rank = _losses(net, {k: v[j] for k, v in t.items()}, g)
            loss = cell + rank_weight * rank
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
            sums += (cell.item(), rank.item())
        log(f"epoch {epoch + 1}/{epochs}: cell {sums[0] / per_epoch:.4f}, rank {sums[1] / per_epoch:.4f} "
            f"({time.perf_counter() - t0:.0f} s)")
    net.eval()
    from madp.policies.checkpoint import attach, shipped_checkpoint

    earlier = init.record.get("train_envs", []) if init is not None else []
    learned_from = sorted({int(e) for e in (*train_envs, *earlier)})  # both rounds': rank_study leaves them out
    attach(Path(policy) if policy else shipped_checkpoint("madp"), out, "critic", net, cfg.to_dict(),
           {**(record or {}), "epochs": epochs, "batch": batch, "lr": lr, "rank_weight": rank_weight,
            "seed": seed, "states": int(len(rows)), "train_envs": learned_from,
            **({"init": init.record} if init is not None else {})})
    return net


def predicted_scores(net: Critic, data: dict, rows: np.ndarray | None = None) -> np.ndarray:
    """``[S, N, K]``: the critic's per-robot score of each copy (:func:`madp.robot.critic.copy_scores`)
    on the states ``rows`` of ``data`` (None: all), from each robot's stored input and moves."""
    from madp.models.critic import critic_predictor
    from madp.robot.critic import copy_scores

    rows = np.arange(len(data["env"])) if rows is None else rows
    data = with_derived(data)
    predict = critic_predictor(net)
    out = []
    for s in rows:
        mass, offset_m = predict(data["x"][s].astype(np.float32), data["near"][s])
        out.append(copy_scores(mass, offset_m, data["moves"][s].transpose(1, 0, 2)))
    return np.stack(out)


def true_cell_scores(data: dict, equal_mass: bool = False) -> np.ndarray:
    """``[S, N, K]``: the copies' scores on each robot's true cell mass and centroid (what a perfect critic
    predicts; reads the world map: a bound, not something robots could compute). ``equal_mass``: every
    cell's mass counted 1 (how much of the ranking the masses carry)."""
    from madp.robot.critic import copy_scores

    moves = data["moves"] if "moves" in data else state_moves(data)
    mass = np.ones_like(data["mass"]) if equal_mass else data["mass"]
    return np.stack([copy_scores(mass[s], data["centroid_m"][s] - data["position_m"][s],
                                 moves[s].transpose(1, 0, 2)) for s in range(len(data["env"]))])


def rank_study(paths, critic_path: Path) -> dict:
    """:func:`ranking` of the critic in ``critic_path`` and of the baselines (``explore``'s and ``value``'s
    local cell costs; the true cells' scores as a bound, and with every mass counted 1) on the states of
    the labels files ``paths`` whose environments the critic was not trained on."""
    from madp.models.critic import load_critic
    from madp.training.critic import load_many, world_prefix

    data, meta = load_many(paths)
    net = load_critic(critic_path)
    held = ~np.isin(data["env"], net.record.get("train_envs", []))
    if not held.any():
        raise SettingError("data", f"every environment of the labels was one {critic_path} was trained on")
    data = with_derived({k: v[held] for k, v in data.items()})
    prefixes = {int(e): world_prefix(meta["seed"], int(e)) for e in np.unique(data["env"])}
    rules = {"critic": predicted_scores(net, data)}
    rules["explore"] = data["explore_costs"]
    if np.isfinite(data["value_costs"]).all():
        rules["value"] = data["value_costs"]
    rules["true_cell"] = true_cell_scores(data)
    rules["true_centroid_equal_mass"] = true_cell_scores(data, equal_mass=True)
    j = data["j_after"]
    return {"held_out_envs": [int(e) for e in np.unique(data["env"])], "states": int(len(j)),
            "oracle_gain_over_mean_rel": float(np.mean((j.mean(1) - j.min(1)) / data["j_before"])),
            "collect": meta, "critic": {"path": str(critic_path), **net.record},
            "rules": {name: ranking(data, s, prefixes) for name, s in rules.items()}}
