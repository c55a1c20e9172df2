"""One robot's control step of MADP, from the files of ``madp export``, with numpy and onnxruntime only.

Per control step t, robot i (the paper's Fig. 1, as :meth:`madp.models.MADP.sample_decentralized`
computes it for every robot at once):

1. **frame**: with ``frame="d4"`` every robot moves what it holds by element
   ``g = frame_element(seed, t)`` of the world's symmetries (:mod:`madp.robot.frame`), which all
   robots sharing the episode's seed compute alike;
2. **token** (:meth:`RobotRuntime.message`): ``z_i`` = perception graph on its observation;
   ``p_i = (x_i - mean of its neighbourhood's positions) / r_c``; it broadcasts
   ``Message(i, t, x_i, [z_i, p_i])``;
3. **act** (:meth:`RobotRuntime.step`): from the tokens its inbox brings (:mod:`madp.robot.inbox`:
   bad messages dropped and counted), it runs the encoder graph once on its neighbourhood (itself and
   the senders within r_c, ascending by id) and the denoiser graph S times (DPM-Solver++(2M), the
   constants of ``runtime.json``) on K noise draws as one batch; it keeps its own token's K actions,
   moves them back to the world's axes, clips them to u_max and keeps one by the selection rule
   (:func:`madp.selection.choose`, the chooser the simulator uses too: numpy and numba);
4. **costs** (the ``joint`` rules only, :attr:`madp.selection.Rule.joint`): the action of step 3 is provisional.
   The robot broadcasts its K costs (:meth:`RobotRuntime.cost_message`), and keeps its action of the
   copy k whose cost summed with those of the neighbours it holds is least
   (:meth:`RobotRuntime.choose_joint`).

Noise: candidate k of robot j starts from ``noise(ids)[k, j]``; a robot must know its neighbours' noise
(so every robot of a neighbourhood sees the same swarm sample), and by default derives it from the
episode's seed, the step and the robot's id (:func:`robot_noise`). Nothing here imports torch.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable

import numpy as np

from madp.errors import InputError, SettingError
from madp.io.checksum import sha256_file
from madp.io.jsonfile import read_json
from madp.sampling import parse_sampling, spec_text
from madp.selection import NEEDS, RULES, Rule, check_rule, choose, rule_names, weigh
from madp.sim.network import Message
from madp.sim.params import SimParams
from madp.sim.rules import clip_speed, closer_than_squared

from .choice import LocalViews
from .frame import frame_element, inverse_action, transform_observation, transform_points
from .inbox import InboxCounts, read_inbox

__all__ = ["FORMAT", "RobotRuntime", "StepResult", "check_own", "robot_noise"]

FORMAT = "madp-onnx-runtime/1"
GRAPHS = ("perception", "encoder", "denoiser")

Noise = Callable[[np.ndarray], np.ndarray]


def robot_noise(seed: int, step: int, ids: np.ndarray, candidates: int) -> np.ndarray:
    """``[K, T, 2]`` float32 standard normal: robot ``ids[t]``'s starting noise of its K candidates
    at ``step`` of the episode of ``seed``, a function of those three alone (so its neighbours draw
    the same)."""
    out = [np.random.default_rng([int(seed) & ((1 << 63) - 1), int(step), int(i), 0x4D41]).standard_normal((candidates, 2))
           for i in ids]
    return np.stack(out, 1).astype(np.float32) if out else np.zeros((candidates, 0, 2), np.float32)


def check_own(observation: np.ndarray, position_m: np.ndarray) -> None:
    """A robot's own inputs must be finite: a NaN or infinite observation ``[4, S, S]`` or position
    ``[2]`` is a :class:`madp.errors.SettingError` naming it (a robot's sensors are broken: the caller
    stops the robot, never sends a NaN command)."""
    for name, value, shape in (("observation", observation, None), ("position_m", position_m, (2,))):
        a = np.asarray(value, dtype=np.float64)
        if shape is not None and a.shape != shape:
            raise SettingError(name, f"expected shape {shape}, got {a.shape}")
        if not np.isfinite(a).all():
            raise SettingError(name, f"expected finite values, got {int((~np.isfinite(a)).sum())} NaN or infinite")


@dataclass(frozen=True)
class StepResult:
    """One robot's control step: ``action_mps [2]`` (float64, world axes), the K candidates it chose
    from ``candidates_mps [K, 2]``, the ``message`` it broadcast and the ``counts`` of its inbox. Under
    a ``_joint`` rule ``costs [K]`` (float64) are its own cost of each copy, ``lone`` whether it heard
    no one (its action is then its lone step), and ``action_mps`` is provisional:
    :meth:`RobotRuntime.choose_joint` gives the one it applies."""

    action_mps: np.ndarray
    candidates_mps: np.ndarray
    message: Message
    counts: InboxCounts
    costs: np.ndarray | None = None
    lone: bool = False


class RobotRuntime:
    """The exported policy in ``directory`` (``madp export``), run with ``threads`` onnxruntime
    threads (default 1: a robot's one core). ``params``: the motion constants of the selection rule
    (default: those ``runtime.json`` holds). ``max_age``: the oldest messages used, in steps (0: this
    step's only). Construction reads and checks the files (a one-line error naming the file)."""

    def __init__(self, directory: str | Path, threads: int = 1, params: SimParams | None = None,
                 max_age: int | None = 0, sampling: str | None = None):
        import onnxruntime as ort

        self.directory = Path(directory)
        spec_file = self.directory / "runtime.json"
        spec = read_json(spec_file, f"make it with madp export POLICY --out {self.directory}")
        if not isinstance(spec, dict) or spec.get("format") != FORMAT:
            raise InputError(f"{spec_file}: expected format {FORMAT!r}, got {spec.get('format') if isinstance(spec, dict) else spec!r}")
        self.spec = spec
        try:  # a missing or bad field: one line naming the file, not a KeyError
            learned = [n.key for n in NEEDS.values() if n.key in spec["graphs"]]  # a map prior or a critic: their rules only
            roles = (*GRAPHS, *learned)
            graphs = {role: str(spec["graphs"][role]) for role in roles}
            m, sel = spec["model"], spec["selection"]
            self.token_dim, self.z_dim, self.action_dim = int(m["token_dim"]), int(m["z_dim"]), int(m["action_dim"])
            self.offset_token = m["pos_token"] == "neighbourhood_offset"
            self.radius_m = float(spec["radii"]["comm_radius_m"])
            self.world_size_m = float(spec["radii"]["world_size_m"])
            self.timesteps = [int(k) for k in spec["sampler"]["timesteps"]]
            self.coefficients = [tuple(float(v) for v in c) for c in spec["sampler"]["coefficients"]]
            self.mean = np.asarray(spec["action_stats"]["mean"], np.float32)
            self.std = np.asarray(spec["action_stats"]["std"], np.float32)
            self.frame, self.rule, self.candidates = sel["frame"], sel["rule"], int(sel["candidates"])
            self.params = params or SimParams(**spec["motion"])
        except (KeyError, TypeError, ValueError) as e:
            raise InputError(f"{spec_file}: not a complete {FORMAT} file ({type(e).__name__}: {e})") from None
        self._apply_sampling(spec_file, sampling)
        runs = rule_names(bound=False)
        if self.rule not in runs:
            raise InputError(f"{spec_file}: selection rule {self.rule!r} is not one a robot runs ({', '.join(runs)})")
        self.record: Rule = RULES[self.rule]
        if self.record.needs and NEEDS[self.record.needs].key not in graphs:
            raise InputError(f"{spec_file}: selection rule {self.rule} needs the {self.record.needs}'s graph, which the "
                             "export does not name (export again from a policy file that carries one)")
        self.max_age = max_age
        self._check_graphs(spec_file, graphs)
        opts = ort.SessionOptions()
        opts.intra_op_num_threads, opts.inter_op_num_threads = int(threads), 1
        opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
        self.sessions = {}
        for role, name in graphs.items():
            try:
                self.sessions[role] = ort.InferenceSession(str(self.directory / name), opts,
                                                           providers=["CPUExecutionProvider"])
            except Exception as e:  # onnxruntime's own error types for a missing or damaged graph
                raise InputError(f"{self.directory / name}: not a loadable ONNX graph ({type(e).__name__})") from None
        sizes = {"perception z": (self.sessions["perception"].get_outputs()[0].shape[-1], self.z_dim),
                 "encoder tokens": (self.sessions["encoder"].get_inputs()[0].shape[-1], self.token_dim)}
        for what, (graph, spec_size) in sizes.items():
            if isinstance(graph, int) and graph != spec_size:
                raise InputError(f"{spec_file}: says {spec_size} for the {what} size, its graph has {graph} "
                                 "(graphs and runtime.json of different exports)")

    def _apply_sampling(self, spec_file: Path, text: str | None) -> None:
        """``--sampling`` (:func:`madp.sampling.parse_sampling`) over the export's: its rule, K and frame
        may change here; the sampler, S, η, fixed noise and precision are the export's (a one-line error
        when the spec says otherwise: export again)."""
        given = parse_sampling(text)
        fixed = {"sampler": "dpm++", "sampling_steps": len(self.timesteps), "eta": 0.0, "fixed_noise": False,
                 "precision": "fp32"}
        for setting, value in given.items():
            if setting in fixed and value != fixed[setting]:
                raise SettingError("sampling", f"{spec_text({setting: value})}: {spec_file} fixes it at "
                                               f"{spec_text({setting: fixed[setting]})}; export again with it")
        self.rule = given.get("select", self.rule)
        self.candidates = given.get("candidates", self.candidates)
        self.frame = given.get("frame", self.frame)
        if self.frame not in ("world", "d4"):
            raise SettingError("sampling", f"frame: expected world or d4, got {self.frame!r}")
        if given:
            check_rule(self.rule, self.candidates)

    def _check_graphs(self, spec_file: Path, graphs: dict[str, str]) -> None:
        """Each graph's sha256 against the one ``runtime.json`` records (a one-line error naming the file)."""
        digests = self.spec.get("graph_sha256")
        if not isinstance(digests, dict) or set(digests) != set(graphs):
            raise InputError(f"{spec_file}: no sha256 of each graph (graph_sha256); export again with madp export")
        for role, name in graphs.items():
            path = self.directory / name
            digest = sha256_file(path)
            if digest != digests[role]:
                raise InputError(f"{path}: its sha256 differs from the one {spec_file.name} records "
                                 "(an interrupted or mixed export); export again with madp export --overwrite")

    # ------------------------------------------------------------------------------------ helpers
    @property
    def sampling_spec(self) -> str:
        """How this runtime samples, as a ``--sampling`` spec (:func:`madp.sampling.spec_text`)."""
        return spec_text({"sampler": "dpm++", "sampling_steps": len(self.timesteps), "candidates": self.candidates,
                          "select": self.rule, "frame": self.frame, "precision": "fp32"})

    @property
    def reads_map(self) -> bool:
        """Whether its rule reads the robot's map (the step needs the robot's view)."""
        return self.record.ranks

    @property
    def joint(self) -> bool:
        """Whether its rule sums the neighbours' costs (a round of cost messages each step)."""
        return self.record.joint

    def predict_prior(self, windows: np.ndarray) -> np.ndarray:
        """The map prior's graph: ``windows [R, 3, H, W]`` (:func:`madp.robot.prior.prior_inputs`) ->
        each coarse cell's importance per m² ``[R, H, W]`` (float64)."""
        x = np.ascontiguousarray(windows, np.float32)
        return self.sessions["map_prior"].run(None, {"windows": x})[0].astype(np.float64)

    def predict_critic(self, windows: np.ndarray, neighbours: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The critic's graph: ``windows [R, 5, H, H]``, ``neighbours [R, M, 3]``
        (:func:`madp.robot.critic.critic_inputs`) -> each robot's cell mass ``[R]`` and centroid offset
        ``[R, 2]`` m (float64)."""
        from .critic import OFFSET_SCALE_M

        mass, offset = self.sessions["critic"].run(None, {"windows": np.ascontiguousarray(windows, np.float32),
                                                          "neighbours": np.ascontiguousarray(neighbours, np.float32)})
        return mass.astype(np.float64), offset.astype(np.float64) * OFFSET_SCALE_M

    @property
    def predict(self):
        """The forward of the learned network its rule reads (:attr:`madp.selection.Rule.needs`), or None."""
        return {"map prior": self.predict_prior, "critic": self.predict_critic}.get(self.record.needs)

    def view(self, maps, view: LocalViews) -> LocalViews:
        """A robot's view as its rule ranks on: ``view`` (from its own ``maps``, :func:`madp.robot.choice.map_views`)
        weighed by the rule (:func:`madp.selection.weigh`; the map prior's graph for the rules that
        need one)."""
        return weigh(self.record, maps, view, self.predict)

    def frame_of(self, seed: int, step: int) -> int:
        """The d4 element of ``step`` of the episode of ``seed`` (0 with ``frame="world"``)."""
        return frame_element(seed, step) if self.frame == "d4" else 0

    def _in_range(self, own: np.ndarray, others: np.ndarray) -> np.ndarray:
        """``[M]`` bool: which of ``others [M, 2]`` (frame positions, float32) are within r_c of ``own [2]``,
        in float32 (:func:`madp.sim.rules.closer_than_squared`, the model's attention mask's rule)."""
        return closer_than_squared(others - own, self.radius_m)

    def _offset(self, own: np.ndarray, neighbours: np.ndarray) -> np.ndarray:
        """``p [2]`` float32: the neighbourhood offset of a robot at ``own`` among ``neighbours [M, 2]``."""
        if not self.offset_token:
            return np.zeros(2, np.float32)
        off = (neighbours - own).sum(0) if len(neighbours) else np.zeros(2, np.float32)
        return (-off / np.float32(len(neighbours) + 1) / np.float32(self.radius_m)).astype(np.float32)

    def token(self, observation: np.ndarray, position_m: np.ndarray, neighbours_m: np.ndarray, g: int) -> np.ndarray:
        """``[z, p]`` (float32 ``[token_dim]``) of a robot with ``observation [4, S, S]`` at ``position_m``
        whose neighbours (world axes; those beyond r_c are ignored) are at ``neighbours_m [M, 2]``, in frame g."""
        obs = transform_observation(np.asarray(observation, np.float32), g) if g else np.asarray(observation, np.float32)
        z = self.sessions["perception"].run(None, {"observation": obs[None]})[0][0]
        own = transform_points(np.asarray(position_m, np.float32), g, self.world_size_m)
        nbr = transform_points(np.asarray(neighbours_m, np.float32).reshape(-1, 2), g, self.world_size_m)
        nbr = nbr[self._in_range(own, nbr)]
        return np.concatenate([z.astype(np.float32), self._offset(own, nbr)])

    def message(self, robot_id: int, step: int, observation: np.ndarray, position_m: np.ndarray,
                neighbours_m: np.ndarray, seed: int) -> Message:
        """What robot ``robot_id`` broadcasts at ``step``: its position and token (:meth:`token`)."""
        check_own(observation, position_m)
        tok = self.token(observation, position_m, neighbours_m, self.frame_of(seed, step))
        return Message(int(robot_id), int(step), np.asarray(position_m, np.float64).copy(), tok)

    # ------------------------------------------------------------------------------------- acting
    def sample(self, tokens: np.ndarray, positions_m: np.ndarray, noise: np.ndarray) -> np.ndarray:
        """The reverse diffusion of one neighbourhood: ``tokens [T, D]``, frame ``positions_m [T, 2]``,
        ``noise [K, T, 2]`` -> normalised actions ``[K, T, 2]`` (float32)."""
        t = len(tokens)
        mask = self._in_range(positions_m[:, None], positions_m[None]) | np.eye(t, dtype=bool)
        memory = self.sessions["encoder"].run(None, {"tokens": tokens[None], "positions_m": positions_m[None],
                                                     "mask": mask[None]})[0]
        k = len(noise)
        feeds = {"memory": np.repeat(memory, k, 0), "positions_m": np.repeat(positions_m[None], k, 0),
                 "mask": np.repeat(mask[None], k, 0)}
        x = np.asarray(noise, np.float32)
        prev = None
        for (alp, sig, ca, cb, cc), step in zip(self.coefficients, self.timesteps):
            eps = self.sessions["denoiser"].run(None, {"noisy_actions": x, "step": np.full(k, step, np.int64), **feeds})[0]
            x0 = (x - sig * eps) / alp
            out = cb * x0 if ca == 0.0 else ca * x + cb * x0
            if cc != 0.0:
                out = out + cc * prev
            prev, x = x0, out.astype(np.float32)
        return x

    def step(self, robot_id: int, step: int, observation: np.ndarray, position_m: np.ndarray, inbox, seed: int,
             view: LocalViews | None = None, noise: Noise | None = None, own: Message | None = None) -> StepResult:
        """Robot ``robot_id``'s control step ``step`` of the episode of ``seed``.

        ``observation [4, S, S]`` and ``position_m [2]`` its own; ``inbox``: the :class:`Message`\\ s it
        received (this step's tokens of its neighbours; bad ones are dropped and counted, never
        raised); ``view``: its :class:`madp.policies.select.LocalViews` row (R = 1: its own position
        as the motion rule integrates it, its sensed map's block sums with its rule's prior: :meth:`view`),
        for the rules that read its map (:attr:`madp.selection.Rule.ranks`; the neighbours are
        taken from the inbox); ``noise(ids) -> [K, T, 2]``: the starting noise of the neighbourhood's robots
        (default :func:`robot_noise`); ``own``: its message of this step when already computed by
        :meth:`message` (else computed here from the inbox's positions)."""
        check_own(observation, position_m)
        g = self.frame_of(seed, step)
        own_f = transform_points(np.asarray(position_m, np.float32), g, self.world_size_m)

        def within(pos: np.ndarray) -> np.ndarray:
            return self._in_range(own_f, transform_points(pos.astype(np.float32), g, self.world_size_m))

        same = None if self.frame != "d4" else (lambda sent: self.frame_of(seed, sent) == g)
        kept, counts = read_inbox(inbox, robot_id, step, position_m, self.token_dim, self.radius_m, within,
                                  self.max_age, same)
        nbr_m = np.array([p for _, p, _ in kept], np.float64).reshape(-1, 2)
        if own is None:
            own = Message(int(robot_id), int(step), np.asarray(position_m, np.float64).copy(),
                          self.token(observation, position_m, nbr_m, g))
        members = sorted([(int(robot_id), own.position_m, own.token), *kept], key=lambda m: m[0])
        ids = np.array([m[0] for m in members], np.int64)
        me = int(np.flatnonzero(ids == robot_id)[0])
        tokens = np.stack([m[2] for m in members]).astype(np.float32)
        pos_f = transform_points(np.stack([m[1] for m in members]).astype(np.float32), g, self.world_size_m)
        eps0 = noise(ids) if noise is not None else robot_noise(seed, step, ids, self.candidates)
        x = self.sample(tokens, pos_f, np.asarray(eps0, np.float32).reshape(self.candidates, len(ids), 2))
        u = (x[:, me] * self.std + self.mean).astype(np.float64)  # [K, 2] m/s in the frame
        u = inverse_action(u, g) if g else u
        u = clip_speed(u, self.params.max_speed_mps)
        if self.joint and len(u) > 1:  # provisional: its own best, or its lone step; costs for the cost round
            action, costs = choose(self.record, u[None], self._row(view, nbr_m), self.params, predict=self.predict)
            return StepResult(action[0], u, own, counts, costs[0], not len(nbr_m))
        return StepResult(self.choose(u, view, nbr_m), u, own, counts)

    def _row(self, view: LocalViews | None, neighbours_m: np.ndarray) -> LocalViews:
        """``view`` (R = 1) with ``neighbours_m [M, 2]`` as its neighbours."""
        if view is None:
            raise ValueError(f"selection rule {self.rule} reads the robot's map: step() needs its view")
        m = max(len(neighbours_m), 1)
        nbr = np.zeros((1, m, 2))
        nbr[0, :len(neighbours_m)] = neighbours_m
        valid = np.zeros((1, m), bool)
        valid[0, :len(neighbours_m)] = True
        return replace(view, neighbours_m=nbr, valid=valid)

    def choose(self, candidates_mps: np.ndarray, view: LocalViews | None, neighbours_m: np.ndarray) -> np.ndarray:
        """The action ``[2]`` the selection rule keeps among ``candidates_mps [K, 2]`` (world axes):
        :func:`madp.selection.choose` on its ``view`` with ``neighbours_m [M, 2]``."""
        if not self.record.ranks or len(candidates_mps) == 1:
            return candidates_mps[0]
        return choose(self.record, candidates_mps[None], self._row(view, neighbours_m), self.params,
                      predict=self.predict)[0][0]

    # ------------------------------------------------------------------------------ the cost round
    def cost_message(self, result: StepResult) -> Message:
        """What a robot broadcasts in the cost round of a ``_joint`` rule: its position and its K costs
        (float32) as the message's token, from its :meth:`step` ``result``."""
        if result.costs is None:
            raise ValueError(f"selection rule {self.rule} has no cost round")
        m = result.message
        return Message(m.sender, m.step, np.asarray(m.position_m, np.float64).copy(), result.costs.astype(np.float32))

    def choose_joint(self, result: StepResult, costs: list, neighbours: np.ndarray) -> np.ndarray:
        """A ``_joint`` rule's action ``[2]``: of its ``result``'s K candidates, that of the copy whose
        own cost plus the costs of the senders among ``neighbours`` (ids: the robots whose positions it
        holds within r_c) is least (ties: the lowest copy). ``costs``: the cost messages its radio
        delivered; those that are not a :class:`Message` of this step with K finite costs, or from a
        robot not among ``neighbours``, are not counted, and of a sender's several one is. A robot that
        heard no one keeps its lone step."""
        if result.costs is None or result.lone:
            return result.action_mps
        own = np.asarray(result.costs, np.float64)
        held = {int(result.message.sender): own}
        want = {int(j) for j in np.asarray(neighbours).reshape(-1)}
        for msg in costs:
            try:
                sender, step, c = int(msg.sender), int(msg.step), np.asarray(msg.token, np.float64)
            except (AttributeError, TypeError, ValueError):
                continue
            if sender in want and sender not in held and step == result.message.step and c.shape == own.shape \
                    and np.isfinite(c).all():
                held[sender] = c
        total = np.sum([held[j] for j in sorted(held)], axis=0)  # ascending by id, as the simulator sums
        return result.candidates_mps[int(total.argmin())]
