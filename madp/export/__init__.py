"""Exporting policies for robots: :mod:`.onnx` writes MADP's three networks as ONNX graphs and the
JSON file the robot runtime (:mod:`madp.robot`) needs; :mod:`.swarm` runs a swarm through those files
behind the controller interface (``madp eval --runtime onnx``)."""
