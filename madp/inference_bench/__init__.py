"""The inference benchmarks of ``madp bench infer``: MADP's control step by preset, sampler, K and
selection rule, the robot runtime's step (``bench.py``), and the roofline of one robot's step (``roofline.py``)."""
