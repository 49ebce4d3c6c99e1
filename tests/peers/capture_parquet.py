"""Read millgate capture exports with pandas and pyarrow: each CSV reads with
`pandas.read_csv(path)` and no options (a header line, then numbers: `t` and one
float column per channel of the JSON header beside it, `<name>.json`; a channel of
counts gives the decimals its scale means, `0.57`, not `0.5700000000000001`), and each
Parquet file holds the samples of the CSV export of the same capture and the
capture's metadata.

The process context of the capture's time (the header's `context`, the Parquet
file's `millgate.context_status`, `millgate.coil`, `millgate.product`, ...) must say
the same in both: each known value under its key, an unknown one (`null` in the
header) without a key.

Usage: capture_parquet.py CSV PARQUET [CSV PARQUET ...]. With MILLGATE_CONFIG_HASH
set, each file's configuration hash (the CSV header's `config_hash`, the Parquet
file's `millgate.config_hash`) must be it. With MILLGATE_CONTEXT set (a JSON object
such as {"context_status": "valid", "coil": 4711, "product": 205}), each file's
context must hold those values (`null`: no key in the Parquet metadata). Exits
non-zero with the first difference.
"""

import json
import os
import sys
from decimal import Decimal

import numpy as np
import pandas as pd
import pyarrow.parquet as pq


def read_csv(path):
    """The header beside the CSV, and its columns as Python parses each cell."""
    with open(path[: -len(".csv")] + ".json") as f:
        header = json.load(f)
    with open(path) as f:
        lines = f.read().splitlines()
    names = lines[0].split(",")
    columns = {name: [] for name in names}
    for line in lines[1:]:
        for name, cell in zip(names, line.split(",")):
            columns[name].append(float(cell) if cell else float("nan"))
    return header, columns


def check_pandas(csv_path, header, columns):
    """`pandas.read_csv(path)` as a user types it: the header's channels as float
    columns after `t`, every row, the values Python reads from the text (pandas'
    default parser may differ in the last bit), `t` the sample index over the rate."""
    frame = pd.read_csv(csv_path)
    names = ["t"] + [channel["name"] for channel in header["channels"]]
    assert list(frame.columns) == names, (list(frame.columns), names)
    assert all(str(dtype) == "float64" for dtype in frame.dtypes), frame.dtypes
    assert len(frame) == len(columns["t"]), (len(frame), len(columns["t"]))
    for name in names:
        np.testing.assert_allclose(frame[name].to_numpy(), columns[name], rtol=1e-15, atol=0)
    rate = header["sample_rate_hz"]
    assert all(t == k / rate for k, t in enumerate(columns["t"])), f"{csv_path}: t is not k / rate"
    # A channel of counts at a decimal scale and offset (0.01 kN*m) reads as the
    # decimals the device meant: each value's shortest text (as pandas and Python
    # print it) has no more decimals than the scale and offset, 0.57 and not
    # 0.5700000000000001.
    for channel in header["channels"]:
        if channel["encoding"] != "counts":
            continue
        allowed = max(decimals(channel["scale"]), decimals(channel["offset"]))
        for value in frame[channel["name"]].dropna():
            assert decimals(value) <= allowed, (
                f"{csv_path}: {channel['name']} value {value!r} has more than the "
                f"{allowed} decimals of scale {channel['scale']!r}, offset {channel['offset']!r}"
            )


def decimals(value):
    """How many decimals the shortest text of `value` has (`0.57`: 2, `100.0`: 0)."""
    return max(0, -Decimal(repr(float(value))).normalize().as_tuple().exponent)


# The Parquet metadata's context keys (after `millgate.`) and the header's names.
CONTEXT_KEYS = {
    "context_status": "status",
    "context_note": "note",
    "speed_mpm": "speed_mpm",
    "coil": "coil",
    "product": "product",
    "thickness_mm": "thickness_mm",
    "pass": "pass",
    "mill_state": "mill_state",
}


def check_context(path, header, meta):
    context = header.get("context")
    present = {k for k in CONTEXT_KEYS if "millgate." + k in meta}
    if context is None:
        assert not present, f"{path}: context keys {present} without a context in the header"
    else:
        for key, name in CONTEXT_KEYS.items():
            value = context.get(name)
            got = meta.get("millgate." + key)
            if value is None:
                assert got is None, f"{path}: millgate.{key} = {got!r}, the header has no value"
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                assert got is not None and float(got) == float(value), (path, key, got, value)
            else:
                assert got == value, (path, key, got, value)
    expected = os.environ.get("MILLGATE_CONTEXT")
    if expected is not None:
        assert context is not None, f"{path}: no context in the header"
        for key, value in json.loads(expected).items():
            got = meta.get("millgate." + key)
            if value is None:
                assert got is None, f"{path}: millgate.{key} = {got!r}, expected none"
            elif isinstance(value, (int, float)):
                assert got is not None and float(got) == float(value), (path, key, got, value)
            else:
                assert got == value, (path, key, got, value)


def check(csv_path, parquet_path):
    header, columns = read_csv(csv_path)
    check_pandas(csv_path, header, columns)
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
    check_context(parquet_path, header, meta)
    units = json.loads(meta["millgate.units"])
    for channel in header["channels"]:
        assert units[channel["name"]] == channel["unit"], (units, channel)
    for name, values in columns.items():
        got = parquet.column(name).to_pylist()
        same = all(a == b or (a != a and b != b) for a, b in zip(got, values))
        assert same and len(got) == len(values), f"{parquet_path}: column {name} differs from {csv_path}"
    times = parquet.column("time").to_pandas()
    first = times.iloc[0].value
    assert first == header["first_sample_unix_ns"], (first, header)
    assert str(times.dt.tz) == "UTC", times.dt.tz
    assert parquet.num_rows == len(columns["t"])


def main(paths):
    assert paths and len(paths) % 2 == 0, "CSV PARQUET pairs"
    for csv_path, parquet_path in zip(paths[::2], paths[1::2]):
        check(csv_path, parquet_path)
    print(f"{len(paths) // 2} captures: pandas reads each CSV, Parquet == CSV")


if __name__ == "__main__":
    main(sys.argv[1:])
