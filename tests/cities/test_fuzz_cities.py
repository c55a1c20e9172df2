"""Fuzz the city importer: any bytes or JSON in a .csv, .geojson or .json signals file give a city
or a one-line InputError (madp's own error) naming the file — never another exception (a
ValueError of another kind would be a bug, printed with its traceback)."""

from __future__ import annotations

import gzip
import json

import pytest
from hypothesis import strategies as st

from madp.errors import InputError
from madp.cities.importer import import_city

from ..fuzzing import JSON, damage, mutate, twins

CSV = "lat,lon\n45.5231,-122.6765\n45.5200,-122.6800\n45.5250,-122.6700\n45.5301,-122.6601\n"
GEOJSON = {"type": "FeatureCollection", "features": [
    {"type": "Feature", "properties": {"highway": "traffic_signals"},
     "geometry": {"type": "Point", "coordinates": [-122.6765, 45.5231]}},
    {"type": "Feature", "properties": {}, "geometry": {"type": "MultiPoint", "coordinates": [[-122.68, 45.52], [-122.67, 45.525]]}}]}
OVERPASS = {"elements": [{"type": "node", "id": 1, "lat": 45.5231, "lon": -122.6765, "tags": {"highway": "traffic_signals"}},
                         {"type": "node", "id": 2, "lat": 45.52, "lon": -122.68}]}
VALID = {".csv": CSV.encode(), ".geojson": json.dumps(GEOJSON).encode(), ".json": json.dumps(OVERPASS).encode()}


def imports_or_refuses(path) -> None:
    try:
        city = import_city(path, seed=0)
    except InputError as e:
        assert "\n" not in str(e) and str(path) in str(e), str(e)
        return
    assert city.num_signals_in_square >= 1 and city.features.shape == (city.num_signals_in_square, 4)


def prop_damaged_file(tmp_path_factory, data):
    suffix = data.draw(st.sampled_from([".csv", ".geojson", ".json", ".csv.gz"]))
    blob = damage(data, VALID[suffix.removesuffix(".gz")])
    if suffix.endswith(".gz") and data.draw(st.booleans()):
        blob = gzip.compress(blob)
    path = tmp_path_factory.getbasetemp() / f"city{suffix}"
    path.write_bytes(blob)
    imports_or_refuses(path)


def prop_mutated_json(tmp_path_factory, data):
    suffix, base = data.draw(st.sampled_from([(".geojson", GEOJSON), (".json", OVERPASS)]))
    path = tmp_path_factory.getbasetemp() / f"city{suffix}"
    path.write_text(json.dumps(mutate(data, base, rounds=4)))
    imports_or_refuses(path)


def prop_any_json(tmp_path_factory, doc):
    path = tmp_path_factory.getbasetemp() / "any.json"
    path.write_text(json.dumps(doc))
    imports_or_refuses(path)


def prop_csv_rows(tmp_path_factory, rows):
    path = tmp_path_factory.getbasetemp() / "rows.csv"
    path.write_text("lat,lon\n" + "\n".join(",".join(r) for r in rows) + "\n")
    imports_or_refuses(path)


CELL = st.sampled_from(["45.52", "-122.68", "", "nan", "inf", "1e400", "91", "-181", "x", "0", "45.52 ", '"45.5"'])
test_damaged_city_file, test_damaged_city_file_soak = twins(prop_damaged_file, 150, 3000, data=st.data())
test_mutated_city_json, test_mutated_city_json_soak = twins(prop_mutated_json, 150, 3000, data=st.data())
test_any_json_city, test_any_json_city_soak = twins(prop_any_json, 100, 2000, doc=JSON)
test_city_csv_rows, test_city_csv_rows_soak = twins(prop_csv_rows, 100, 2000,
                                                    rows=st.lists(st.lists(CELL | st.text(max_size=6), max_size=4),
                                                                  max_size=8))


def test_cases_the_fuzzers_found(tmp_path):
    """Each raised another exception before it was fixed (the soak found them)."""
    cr = tmp_path / "cr.csv"
    cr.write_bytes(b"lat,lon\n45.5\r2,-122.6\n")  # a carriage return inside a field: csv.Error
    huge = tmp_path / "huge.json"
    huge.write_text(json.dumps({"elements": [{"type": "node", "lat": 10**400, "lon": 1}]}))  # OverflowError
    for path in (cr, huge):
        with pytest.raises(InputError, match=path.name):
            import_city(path, seed=0)
