"""The documentation's results pages from kept results (``madp eval report``): ``pages.py``."""
