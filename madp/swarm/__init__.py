"""A swarm of robot processes over a real middleware (``madp swarm``): the world process (the simulator
standing in for physics and sensors, and the radio between the robots) drives one robot process per
robot (:mod:`madp.robot.process`) over Zenoh, with the records of :mod:`madp.robot.wire`.

- :mod:`.world`: the world's control step, its phases, deadlines and failures, the summary;
- :mod:`.radio`: what each robot hears: :mod:`madp.sim.network`'s model between the processes;
- :mod:`.bus`: the world's Zenoh session;
- :mod:`.robots`: starting, watching and stopping the robot processes;
- :mod:`.run`: ``madp swarm``'s run into an output directory (:func:`run_swarm`).

Nothing here imports torch.
"""

from .run import OWNED, run_swarm
from .world import BEACON_BY, COMMAND_BY, TOKEN_BY, World

__all__ = ["BEACON_BY", "COMMAND_BY", "OWNED", "TOKEN_BY", "World", "run_swarm"]
