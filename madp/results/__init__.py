"""The documentation's results pages from kept results (``madp eval report``): ``pages.py`` (the tables) and
``notes.py`` (the ideal network against the default's runs, the control step's time)."""
