"""Recordings of rollouts: MCAP files with Foxglove schemas or as rosbag2 (``record.py``), and the
rollout hooks that collect what they hold (``recorders.py``)."""
