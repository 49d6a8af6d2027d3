"""The L-system report's Cycles figures against what Cycles was measured to cost."""
import json
import pathlib

from photon_lightmaps.engine import lsystem_stats

DATA = pathlib.Path(__file__).resolve().parent / "data" / "cycles_instances.json"


def test_the_bytes_per_cycles_instance_are_the_measured_ones():
    """The report multiplies primitives by CYCLES_BYTES_PER_INSTANCE; the constant is
    the memory a Cycles render added per instance in benchmarks/bench_cycles_instances.py
    (its run is kept in tests/data), rounded."""
    run = json.loads(DATA.read_text())
    assert run["command"] == "python -m benchmarks.bench_cycles_instances"
    rows = run["rows"]
    assert [r["instances"] for r in rows] == sorted(r["instances"] for r in rows) and len(rows) >= 2
    # memory grows with the count: the slope is per instance, not a fixed overhead
    assert all(b["added_bytes"] > a["added_bytes"] for a, b in zip(rows, rows[1:]))
    a, b = rows[-2], rows[-1]
    slope = (b["added_bytes"] - a["added_bytes"]) / (b["instances"] - a["instances"])
    assert slope == run["bytes_per_instance"]
    assert abs(lsystem_stats.CYCLES_BYTES_PER_INSTANCE / slope - 1.0) < 0.01
