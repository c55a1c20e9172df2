"""Expert relabelling (DAgger): a learned policy drives, every sample keeps the expert's label.

:func:`learner_settings` reads a policy file once, when the plan is made, into the ``policy`` of a
:class:`~madp.datagen.plan.DatagenConfig` (path, checksum, kind, beta and the dataset the policy
learned from); :func:`learner_driver` turns it into what moves the swarm in one episode, and
:func:`learner_batch_driver` into what moves the swarms of a batch of episodes in lockstep (a MADP
policy, called once per step for all of them: :func:`batches`). The learner is built by
:func:`madp.controllers.make_controller` (MADP decentralized or LPAC-K3), so its model is loaded once
per process, in the one cache of models.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from madp.io.checksum import sha256_file
from madp.errors import InputError, SettingError
from madp.sim import CoverageEnv

#: What of the policy's dataset a relabelled dataset records as its parent.
PARENT_KEYS = ("root", "num_samples", "created_by", "more")

_verified: set = set()  # (path, sha256) of the policy files checked in this process


def learner_settings(policy: str | Path | None, beta: float = 0.0, sampling: str | None = None,
                     select: str | None = None) -> dict:
    """The ``policy`` setting of a relabelling plan: the policy file's path, checksum and kind, the
    probability ``beta`` that a step executes the expert's action, MADP's sampling (``sampling``: the
    spec of :func:`madp.sampling.parse_sampling`, or the single ``select``; by default one sample per
    robot, ``none``): its rule with its K and S (recorded only when it is not ``none``) and its noise
    source (``torch``, one generator per episode seeded by its scenario), and the policy's parent
    dataset; ``{}`` (the expert drives) without a policy, where a ``beta`` or a sampling is refused."""
    from madp.policies.checkpoint import carried, load_policy
    from madp.sampling import merge_sampling

    given = merge_sampling(sampling, select=select)
    if policy is None:
        if beta:
            raise SettingError("beta", "only meaningful with a policy")
        if given:
            raise SettingError("sampling" if sampling else "select", "only meaningful with a policy")
        return {}
    from madp.policies.madp import SamplingSettings

    policy = Path(policy)
    # checked; the rule's K and S as they are today, and its fallback where the file lacks its network
    chosen = SamplingSettings.of(**{"select": "none", **given}).fitted(carried(policy))
    _, meta = load_policy(policy)
    if chosen.select != "none" and meta["kind"] != "madp":
        raise SettingError("select", f"only MADP chooses among samples; {policy} is {meta['kind']}")
    recorded = {"select": chosen.select, "candidates": chosen.candidates, "sampling_steps": chosen.sampling_steps} \
        if chosen.select != "none" else {}  # a later default does not change the data
    recorded.update({k: getattr(chosen, k) for k in given})  # and whatever else the spec set
    noise = {"noise": "torch"} if meta["kind"] == "madp" else {}
    return {"path": str(policy.resolve()), "sha256": sha256_file(policy), "kind": meta["kind"], "beta": beta,
            **recorded, **noise,
            "parent": {k: v for k, v in meta.get("dataset", {}).items() if k in PARENT_KEYS}}


def batches(policy: dict) -> bool:
    """Whether the relabelling episodes of a shard run as one batch in lockstep
    (:func:`learner_batch_driver`): with a MADP policy; LPAC-K3's episodes run one after another
    (:func:`learner_driver`)."""
    return policy.get("kind") == "madp"


def learner_driver(policy: dict, seed: int) -> Callable[[CoverageEnv, np.ndarray], np.ndarray]:
    """What moves the swarm in a relabelling rollout: ``driver(env, expert_u) -> u`` executes the
    expert's action with probability beta (one draw per step) and the learned policy's otherwise:
    MADP with the plan's selection rule at the plan's K and S (one sample per robot, ``select none``, unless
    the plan names one; never the evaluation default implicitly, so a dataset's bytes do not change
    with that default), or LPAC-K3.

    The policy's noise and the draws are seeded by the scenario seed, and torch runs on one thread
    here, so a shard's bytes do not depend on which process makes it or how many there are."""
    from madp.models.bench import torch_threads

    learner = _learner(policy, seed)
    coin, beta = _coin(seed), float(policy["beta"])

    def drive(env: CoverageEnv, expert_u: np.ndarray) -> np.ndarray:
        if coin.random() < beta:
            return expert_u
        with torch_threads(1):
            return learner(env)

    return drive


def learner_batch_driver(policy: dict, seeds: Sequence[int]) -> Callable[[list[CoverageEnv], np.ndarray, Sequence[int]], np.ndarray]:
    """:func:`learner_driver` of B episodes in lockstep, episode b of scenario seed ``seeds[b]`` (a MADP
    policy: :func:`batches`): ``drive(envs, expert_u [B, N, 2], live) -> u [B, N, 2]``.

    Each episode in ``live`` draws its coin once, from its own stream, exactly as its lone driver
    would at this step; the MADP policy is then called once (:meth:`MADPPolicy.act_batch`, torch on
    one thread) for the live episodes whose coin chose the learner, each with its own noise
    generator (seeded by its scenario seed, as its lone policy's), so every episode's draws and noise
    are those of its lone rollout and its actions differ from it only by the batch's float rounding.
    The other episodes execute ``expert_u`` (the ones not in ``live`` draw nothing)."""
    from madp.models.bench import torch_threads
    from madp.policies.madp import noise_generator

    learner = _learner(policy, seeds[0])
    coins, beta = [_coin(s) for s in seeds], float(policy["beta"])
    generators = [noise_generator(s) for s in seeds]

    def drive(envs: list[CoverageEnv], expert_u: np.ndarray, live: Sequence[int]) -> np.ndarray:
        learned = [b for b in live if not coins[b].random() < beta]
        u = np.array(expert_u, copy=True)
        if learned:
            with torch_threads(1):
                u[learned] = learner.act_batch([envs[b] for b in learned], [generators[b] for b in learned])
        return u

    return drive


def _learner(policy: dict, seed: int):
    """The learned policy of a relabelling plan, its noise seeded by ``seed``: MADP with the plan's
    selection rule at the plan's K and S, or LPAC-K3 (the file checked against the plan's sha256
    once per process)."""
    from madp.controllers import make_controller
    from madp.policies import SamplingSettings

    key = (policy["path"], policy["sha256"])
    if key not in _verified:
        if sha256_file(policy["path"]) != policy["sha256"]:
            raise InputError(f"{policy['path']}: changed since this dataset's plan was made (sha256 differs)")
        _verified.add(key)
    # plans that name a rule without its K and S were made when the default was K = 4 at S = 3
    settings = {k: policy[k] for k in SamplingSettings.__dataclass_fields__ if k in policy}
    if settings.get("select", "none") != "none":
        settings = {"candidates": 4, "sampling_steps": 3, **settings}
    sampling = SamplingSettings.of(**{"select": "none", **settings})
    return make_controller(policy["kind"], policy["path"], seed=seed, sampling=sampling)


def _coin(seed: int) -> np.random.Generator:
    """The stream of an episode's expert/learner draws, seeded by its scenario seed."""
    return np.random.default_rng([seed & 0xFFFFFFFF, seed >> 32, 0xDA66E])
