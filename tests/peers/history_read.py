"""Reads a millgate history file with Python's own sqlite3 and datetime, as a
maintenance engineer's script would; prints what it found as JSON for
gateway/tests/history.rs."""

import json
import sqlite3
import sys
from datetime import datetime

path = sys.argv[1]
# Read-only, through a URI: the gateway's writer may hold the file meanwhile.
db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
times = [
    datetime.fromisoformat(text.replace("Z", "+00:00"))
    for (text,) in db.execute("SELECT time FROM bites ORDER BY id")
]
print(
    json.dumps(
        {
            "bites": len(times),
            "span_s": (times[-1] - times[0]).total_seconds(),
            "ordered": times == sorted(times),
            "user_version": db.execute("PRAGMA user_version").fetchone()[0],
            "journal_mode": db.execute("PRAGMA journal_mode").fetchone()[0],
        }
    )
)
