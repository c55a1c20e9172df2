"""MADP's rules for choosing among its K samples per robot: one record per rule (:data:`RULES`) and the
one chooser (:func:`choose`) that serves both the simulator's batch (:func:`madp.policies.select.select_actions`,
every robot of an environment at once) and the robot runtime (:meth:`madp.robot.RobotRuntime.step`, one
robot). numpy and numba only (no torch).

A rule's record says what it is (:class:`Rule`): its name, a one-line help, what its choice reads (its
robot's own map, the true map, or the whole world: those two make it an upper bound, not a controller
robots could run), which learned network of the policy file it needs (a map prior, ``madp value train``,
or a critic, ``madp critic train``) and whether it keeps one copy per neighbourhood. Its one function
says how it ranks: ``weigh``, the map a robot's local cell cost is summed on (its window's map with
something in the blocks it has not explored), or ``score``, each candidate's cost some other way (the
critic's predicted change of J). Every list of rules, the command line's help, the documentation's
table of rules and the summary tables' prose derive from the records.

Nothing here imports torch, numba or the simulator until a rule is applied: the command line lists the
records, and the robot runtime imports them (``madp-robot`` packages this module).

A new rule is one record in :data:`RULES` and its ``weigh`` or ``score`` function (``docs/extend/rule.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable, Collection, Optional

import numpy as np

from madp.errors import SettingError

if TYPE_CHECKING:  # the records import nothing heavy: the command line lists them; the functions import on use
    from madp.robot.choice import LocalViews
    from madp.robot.prior import Predict
    from madp.sim.params import SimParams
    from madp.sim.robot_maps import RobotMaps

__all__ = ["DEFAULT_CANDIDATES", "DEFAULT_RULE", "Learned", "MAX_CANDIDATES", "NEEDS", "RULES", "SEES", "Rule", "check_rule", "choose",
           "default_candidates", "rule", "rule_names", "rules_table", "runnable", "select_help", "weigh"]

#: What a rule's choice reads: nothing but the samples, the robot's own map (what it sensed), the true map
#: in each robot's window, or the whole world (the true J of each joint sample).
SEES = ("samples", "own map", "true map", "world")

@dataclass(frozen=True)
class Learned:
    """A learned network a policy file may carry beside the policy, for the rules that read it: ``key``
    names its weights (``key.*``), its config's metadata key, its export's graph role (``key.onnx``);
    ``made_by``: the command that writes a policy file carrying one."""

    key: str
    made_by: str


#: The learned networks a rule may read (:attr:`Rule.needs`), by name.
NEEDS = {"map prior": Learned("map_prior", "madp value train"), "critic": Learned("critic", "madp critic train")}

#: ``weigh(maps, views, predict) -> views``: the map each robot's local cell cost is summed on, from its
#: ``views`` (rows of the robots of ``maps``; ``predict``: the policy file's map prior, or None).
Weigh = Callable[["RobotMaps", "LocalViews", Optional["Predict"]], "LocalViews"]
#: ``score(views, candidates_mps [R, K, 2], params, predict) -> [R, K]``: each robot's cost of each of
#: its candidates (lower is better), from its ``views`` row (after ``weigh``) and ``predict``, the
#: torch-free forward of the network the rule needs.
Score = Callable[["LocalViews", np.ndarray, "SimParams", Optional[Callable]], np.ndarray]


@dataclass(frozen=True)
class Rule:
    """One rule among K samples per robot.

    ``name``; ``help``: one line, what it keeps; ``sees``: one of :data:`SEES`; ``weigh``: the map its
    robots' views hold (None: the window's map as it is; unused unless it ranks); ``score``: each
    candidate's cost (None: its local cell cost on the weighed map); ``needs``: the policy file's
    learned network it reads, a key of :data:`NEEDS` ("" for none); ``joint``: each robot keeps its
    action of the copy whose cost summed over its neighbourhood is least (neighbours send their K costs
    in one more round of messages), not its own best; ``fallback``: the rule that runs in its place, at
    the same K, on a policy file that carries no ``needs`` network ("": none, such a file is refused;
    :func:`runnable`)."""

    name: str
    help: str
    sees: str
    weigh: Optional[Weigh] = None
    score: Optional[Score] = None
    needs: str = ""
    joint: bool = False
    fallback: str = ""

    @property
    def prior(self) -> bool:
        """It ranks on the policy file's learned map prior."""
        return self.needs == "map prior"

    @property
    def bound(self) -> bool:
        """An upper bound that reads the true map or the world, not a controller robots could run."""
        return self.sees in ("true map", "world")

    @property
    def ranks(self) -> bool:
        """It keeps, per robot, the candidate of least cost from its window (its local cell cost or its ``score``)."""
        return self.sees in ("own map", "true map")


def _explore(maps: RobotMaps, views: LocalViews, predict: Optional[Predict]) -> LocalViews:
    from madp.robot.choice import map_prior

    return map_prior(maps, views)


def _value(maps: RobotMaps, views: LocalViews, predict: Optional[Predict]) -> LocalViews:
    from madp.robot.prior import value_view

    return value_view(maps, views, predict, floor=False)


def _value_floor(maps: RobotMaps, views: LocalViews, predict: Optional[Predict]) -> LocalViews:
    from madp.robot.prior import value_view

    return value_view(maps, views, predict, floor=True)


def _critic_view(maps: RobotMaps, views: LocalViews, predict: Optional[Predict]) -> LocalViews:
    from madp.robot.critic import critic_view

    return critic_view(maps, views)


def _critic(views: LocalViews, candidates_mps: np.ndarray, params: SimParams, predict: Optional[Callable]) -> np.ndarray:
    from madp.robot.critic import critic_costs

    return critic_costs(views, candidates_mps, params, predict)


#: The rules, by name, in the order the help and the tables list them.
RULES: dict[str, Rule] = {r.name: r for r in (
    Rule("none", "one sample per robot (K = 1), MADP's plain sampling", "samples"),
    Rule("explore", "each robot keeps the sample of least cost of its own Voronoi cell on its own map, with the "
                    "blocks it has not explored at the mean importance of those it has", "own map", _explore),
    Rule("value", "explore with the policy file's learned map prior in place of the mean", "own map", _value,
         needs="map prior"),
    Rule("value_explore", "value with explore's mean as a floor", "own map", _value_floor, needs="map prior"),
    Rule("value_joint", "value, one copy per neighbourhood: the neighbours' costs of each copy summed", "own map",
         _value, needs="map prior", joint=True),
    Rule("value_explore_joint", "value_joint with explore's mean as a floor", "own map", _value_floor,
         needs="map prior", joint=True),
    Rule("critic", "each robot keeps the sample of least change of J its part causes, by the policy file's learned "
                   "critic of its true cell's mass and centroid", "own map", _critic_view, _critic, needs="critic",
         fallback="explore"),
    Rule("critic_hood", "critic, one copy per neighbourhood: the neighbours' predicted changes summed", "own map",
         _critic_view, _critic, needs="critic", joint=True),
    Rule("oracle", "the joint sample of least true J after the step", "world"),
    Rule("oracle_hood", "oracle per neighbourhood: the copy of least true J summed over its robots' whole cells",
         "world", joint=True),
    Rule("oracle_cell", "explore's choice on the true map", "true map"),
    Rule("oracle_joint", "value_joint's choice on the true map", "true map", joint=True),
)}
#: The rule MADP uses unless told otherwise (README, Choosing among MADP's samples); on a policy file
#: without the network it needs, its ``fallback`` runs (:func:`runnable`).
DEFAULT_RULE = "critic"
#: K for a rule named without a number of candidates.
DEFAULT_CANDIDATES = 4
#: The most candidates per robot: K samples cost K denoiser passes and K × N actions per step.
MAX_CANDIDATES = 1024


def rule_names(bound: Optional[bool] = None, prior: Optional[bool] = None, joint: Optional[bool] = None,
               sees: Optional[tuple[str, ...]] = None, needs: Optional[str] = None) -> tuple[str, ...]:
    """The names of the rules with these properties (None: either), in :data:`RULES`' order."""
    return tuple(r.name for r in RULES.values() if (bound is None or r.bound == bound)
                 and (prior is None or r.prior == prior) and (joint is None or r.joint == joint)
                 and (sees is None or r.sees in sees) and (needs is None or r.needs == needs))


def rule(name: str) -> Rule:
    """The record of rule ``name``; a one-line error naming the setting ``select`` otherwise."""
    if name not in RULES:
        raise SettingError("select", f"expected one of {', '.join(RULES)}, got {name!r}")
    return RULES[name]


def runnable(name: str, carried: Collection[str]) -> str:
    """The rule that runs for rule ``name`` on a policy file carrying the learned networks ``carried``
    (keys of :data:`NEEDS`): ``name``, or its ``fallback`` when the file lacks the network it needs and
    it has one (a rule without a fallback stays ``name``, and is refused where its network is read)."""
    r = rule(name)
    return r.fallback if r.needs and r.fallback and r.needs not in carried else name


def default_candidates(name: str) -> int:
    """K when only the rule is given: 1 for a rule that does not choose (``none``), else
    :data:`DEFAULT_CANDIDATES`."""
    return 1 if rule(name).sees == "samples" else DEFAULT_CANDIDATES


def check_rule(name: str, candidates: int) -> None:
    """A one-line :class:`madp.errors.SettingError` unless ``name`` is a rule and ``candidates`` K fits
    it: K = 1 for ``none``, 1 < K <= :data:`MAX_CANDIDATES` for a rule that chooses."""
    r = rule(name)
    if isinstance(candidates, bool) or not isinstance(candidates, (int, np.integer)) or candidates < 1:
        raise SettingError("candidates", f"expected a whole number of samples per robot >= 1, got {candidates!r}")
    if candidates > MAX_CANDIDATES:
        raise SettingError("candidates", f"expected at most {MAX_CANDIDATES} samples per robot, got {candidates}")
    if r.sees == "samples" and candidates > 1:
        raise SettingError("select/candidates", f"{candidates} candidates per robot need a rule to choose among "
                           f"them ({', '.join(rule_names(sees=SEES[1:]))}), got select {name}")
    if r.sees != "samples" and candidates == 1:
        raise SettingError("select/candidates", f"select {name} chooses among several samples per robot: "
                           "expected candidates > 1, got 1")


def weigh(r: Rule, maps: RobotMaps, views: LocalViews, predict: Optional[Predict] = None) -> LocalViews:
    """``views`` on the map rule ``r`` ranks on (its ``weigh``; as they are without one)."""
    return views if r.weigh is None else r.weigh(maps, views, predict)


def choose(r: Rule, candidates_mps: np.ndarray, views: Optional[LocalViews], params: SimParams,
           neighbours: Optional[np.ndarray] = None, predict: Optional[Callable] = None) -> tuple[np.ndarray, Optional[np.ndarray]]:
    """The one chooser of a rule that reads samples or a map: ``candidates_mps [R, K, 2]`` (m/s, robot r's
    K candidates in row r) -> the kept actions ``[R, 2]`` and, for a rule that ranks, each robot's cost
    of each candidate ``[R, K]`` (its local cell cost, or the rule's ``score``; else None).

    ``views``: row r what robot r knows, on the map the rule ranks on (:func:`weigh`); ``neighbours``
    ``[R, R]`` bool: for a ``joint`` rule, whose costs each robot holds (None: each keeps its own best,
    the provisional action a robot takes before its cost round); ``predict``: the forward of the
    network a rule with a ``score`` reads. A robot
    that holds no neighbour does not choose: it takes the Lloyd step of the disc it expects to cover
    (:func:`lone_steps`)."""
    if r.sees == "samples" or candidates_mps.shape[1] == 1:
        return candidates_mps[:, 0], None
    if not r.ranks:
        raise ValueError(f"selection rule {r.name} reads the world: the simulator chooses for it")
    from madp.robot.choice import joint_copy, local_cell_costs, lone_steps

    if r.score is not None and predict is None:
        raise ValueError(f"selection rule {r.name} reads the policy file's {r.needs}: choose() needs its predict")
    costs = (r.score(views, candidates_mps, params, predict) if r.score is not None
             else local_cell_costs(views, candidates_mps, params))
    index = joint_copy(costs, neighbours) if r.joint and neighbours is not None else costs.argmin(1)
    chosen = np.take_along_axis(candidates_mps, index[:, None, None], 1)[:, 0]
    lone, steps = lone_steps(views, params)  # a robot that hears no one: its bounded Lloyd step
    return np.where(lone[:, None], steps, chosen), costs


def select_help() -> str:
    """The command line's help of ``--select``, from the records: the names, the default, the bounds
    marked as bounds, and where the table of rules is."""
    names = " | ".join(r.name + (" (an upper bound: reads the " + r.sees + ")" if r.bound else "") for r in RULES.values())
    return (f"MADP: the rule that keeps one of --candidates K samples per robot (default: {DEFAULT_RULE}; none: "
            f"K = 1): {names}. What each keeps: docs/concepts/sampling.md; those that read a learned "
            f"{' or '.join(NEEDS)} need a policy file carrying it ({', '.join(n.made_by for n in NEEDS.values())}); "
            f"{fallbacks()}.")


def fallbacks() -> str:
    """One clause per rule that falls back on a policy file without its network, from the records."""
    return "; ".join(f"{r.name} runs {r.fallback} on a file without a {r.needs}" for r in RULES.values() if r.fallback)


def rules_table() -> str:
    """The documentation's table of rules (Markdown), from the records."""
    rows = ["| rule | what it keeps | reads | needs | kind |", "|---|---|---|---|---|"]
    for r in RULES.values():
        needs = f"a policy file with a {r.needs} (`{NEEDS[r.needs].made_by}`)" if r.needs else "—"
        needs += f"; `{r.fallback}` runs on one without" if r.fallback else ""
        kind = "upper bound, not a controller" if r.bound else "controller" + (", joint" if r.joint else "")
        rows.append(f"| `{r.name}` | {r.help} | {r.sees} | {needs} | {kind} |")
    return "\n".join(rows)

