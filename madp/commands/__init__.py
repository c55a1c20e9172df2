"""The command modules that ``madp/cli.py`` (the ``madp`` app) gathers: running a command and reporting its
errors (``main.py``), ``madp bench`` (``bench.py``), ``madp dataset import`` (``data.py``), ``madp eval report``
(``report.py``), ``madp rollout`` (``rollout.py``), ``madp swarm`` (``swarm.py``), ``madp value`` (``value.py``)."""
