"""The city importer: traffic-signal files (CSV, GeoJSON, Overpass JSON) to scenarios, and the 40 cities
shipped with madp (``data/``) that the ``cities`` suite evaluates on."""
