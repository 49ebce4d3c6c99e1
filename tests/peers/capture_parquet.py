"""Read millgate capture exports with pyarrow: each Parquet file holds the samples of
the CSV export of the same capture and the capture's metadata.

Usage: capture_parquet.py CSV PARQUET [CSV PARQUET ...]. With MILLGATE_CONFIG_HASH
set, each file's configuration hash (the CSV header's `config_hash`, the Parquet
file's `millgate.config_hash`) must be it. Exits non-zero with the first difference.
"""

import json
import os
import sys

import pyarrow.parquet as pq

PREFIX = "# millgate capture "


def read_csv(path):
    with open(path) as f:
        lines = f.read().splitlines()
    header = json.loads(lines[0][len(PREFIX):])
    names = lines[1].split(",")
    columns = {name: [] for name in names}
    for line in lines[2:]:
        for name, cell in zip(names, line.split(",")):
            columns[name].append(float(cell))
    return header, columns


def check(csv_path, parquet_path):
    header, columns = read_csv(csv_path)
    parquet = pq.read_table(parquet_path)
    meta = {k.decode(): v.decode() for k, v in parquet.schema.metadata.items()}
    stored = json.loads(meta["millgate.capture"])
    assert stored == header, (stored, header)
    assert meta["millgate.subject"] == header["subject"]
    assert meta["millgate.kind"] == header["kind"]
    assert float(meta["millgate.sample_rate_hz"]) == header["sample_rate_hz"]
    assert meta["millgate.gateway_version"] == header["gateway_version"]
    expected_hash = os.environ.get("MILLGATE_CONFIG_HASH")
    if expected_hash is not None:
        assert header.get("config_hash") == expected_hash, (header, expected_hash)
        assert meta.get("millgate.config_hash") == expected_hash, (meta, expected_hash)
    units = json.loads(meta["millgate.units"])
    for channel in header["channels"]:
        assert units[channel["name"]] == channel["unit"], (units, channel)
    for name, values in columns.items():
        got = parquet.column(name).to_pylist()
        assert got == values, f"{parquet_path}: column {name} differs from {csv_path}"
    times = parquet.column("time").to_pandas()
    first = times.iloc[0].value
    assert first == header["first_sample_unix_ns"], (first, header)
    assert str(times.dt.tz) == "UTC", times.dt.tz
    assert parquet.num_rows == len(columns["t"])


def main(paths):
    assert paths and len(paths) % 2 == 0, "CSV PARQUET pairs"
    for csv_path, parquet_path in zip(paths[::2], paths[1::2]):
        check(csv_path, parquet_path)
    print(f"{len(paths) // 2} captures: Parquet == CSV")


if __name__ == "__main__":
    main(sys.argv[1:])
