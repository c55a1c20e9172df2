"""What runs on a robot: one robot's MADP control step from the files ``madp export`` writes, with
numpy, onnxruntime and the torch-free parts of madp (the simulator's message records and robot maps,
the selection rules' numba kernels). Importing this package never imports torch (tests/robot checks it).

- :mod:`.agent`: :class:`RobotAgent`, one robot holding only what it knows (its own sensor readings,
  position estimate and the messages its radio delivered) -> its observation, token and action;
  :class:`SensorReading`, one reading of its sensor;
- :mod:`.runtime`: :class:`RobotRuntime`, observation, position and inbox -> action and message;
- :mod:`.inbox`: which received messages a robot uses, and the counts of those it drops;
- :mod:`.frame`: the d4 frame of one robot (the evaluation default);
- :mod:`.choice`: a robot's choice among its K samples (its view of its own map, the local cell cost,
  MPPI's weights, the medoid);
- :mod:`.ros2`: the ROS 2 side: message definitions and rosbag2 (MCAP) recordings of rollouts and swarms;
- :mod:`.wire`: the records between the processes of a swarm and their Zenoh keys;
- :mod:`.process`: one robot of a swarm as its own process (``madp-robot run``);
- :mod:`.cli`: the ``madp-robot`` command (``step``: one control step of an export; ``run``).
"""

from .agent import RobotAgent, SensorReading
from .inbox import InboxCounts, read_inbox
from .runtime import RobotRuntime, StepResult, robot_noise

__all__ = ["InboxCounts", "RobotAgent", "RobotRuntime", "SensorReading", "StepResult", "read_inbox", "robot_noise"]
