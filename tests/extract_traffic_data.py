"""Make tests/data/traffic_*.csv.gz from the sample collections the ``traffic`` package ships.

Run once, with the ``real`` extra installed (``pip install -e '.[real]'``): ``python
tests/extract_traffic_data.py``. Nothing is downloaded: the collections are files inside the
installed package (``traffic/data/samples/collections``). Each extract keeps the airborne rows of
one 12-minute window inside a square about an airport, in fedtrack's SI columns (``time`` s since
1970, ``altitude`` m, ``groundspeed`` and ``vertical_rate`` m/s; the collections are in ft, kt and
ft/min), positions rounded to 1e-6 deg, heights to 0.1 m.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pandas as pd

SAMPLES = Path(importlib.util.find_spec("traffic").origin).parent / "data" / "samples" / "collections"
HERE = Path(__file__).resolve().parent / "data"
# name -> (collection, window start UTC, centre lat, lon, half-width deg lat, deg lon)
EXTRACTS = {
    "paris": ("quickstart.json.gz", "2021-10-07 13:29:00", 48.86, 2.40, 0.75, 1.1),
    "switzerland": ("switzerland.json.gz", "2018-08-01 11:39:00", 46.9, 8.2, 1.2, 1.8),
}


def extract(collection: str, start: str, lat: float, lon: float, dlat: float, dlon: float) -> pd.DataFrame:
    d = pd.read_json(SAMPLES / collection)
    d["timestamp"] = pd.to_datetime(d["timestamp"], utc=True)
    t0 = pd.Timestamp(start, tz="UTC")
    d = d[(d.timestamp >= t0) & (d.timestamp < t0 + pd.Timedelta("12min"))
          & ((d.latitude - lat).abs() <= dlat) & ((d.longitude - lon).abs() <= dlon)]
    if "onground" in d:
        d = d[~d.onground.fillna(False).astype(bool)]
    d = d.dropna(subset=["latitude", "longitude", "altitude"])
    out = pd.DataFrame({
        "time": (d.timestamp - pd.Timestamp("1970-01-01", tz="UTC")).dt.total_seconds(),
        "icao24": d.icao24,
        "latitude": d.latitude.round(6), "longitude": d.longitude.round(6),
        "altitude": (d.altitude * 0.3048).round(1),
        "groundspeed": (d.groundspeed * 1852 / 3600).round(2),
        "track": d.track.round(2),
        "vertical_rate": (d.vertical_rate * 0.3048 / 60).round(2),
    })
    return out.sort_values(["icao24", "time"])


if __name__ == "__main__":
    for name, spec in EXTRACTS.items():
        path = HERE / f"traffic_{name}.csv.gz"
        df = extract(*spec)
        df.to_csv(path, index=False, compression={"method": "gzip", "mtime": 0})
        print(f"{path.name}: {len(df)} rows, {df.icao24.nunique()} aircraft, {path.stat().st_size / 1e3:.0f} kB")
