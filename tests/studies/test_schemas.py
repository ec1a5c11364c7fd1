"""The studies' tables have declared schemas (studies/schemas.py): a written file holds the declared
columns, in order, with the declared types, whatever the values (a run without truth or without a
filter bank does not turn a column into pyarrow's ``null``)."""

from __future__ import annotations

import io

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from cli_helpers import run_cli
from log_helpers import without_truth

from cli.main import main
from studies.schemas import (
    COMPARE_SUMMARY_COLUMNS,
    SWEEP_COLUMNS,
    arrow_schema,
    conform,
    frames_columns,
    table_of,
)

SIZE = "120x180"
#: the default config's reported methods (a TP/FP/FN triple each in frames.parquet)
REPORTED = ("zcut", "sor", "union", "intersection")


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    d = tmp_path_factory.mktemp("schemas")
    assert main(["synth", "-o", str(d / "log.mcap"), "--parts", "rods", "--frames", "1", "--seed", "3",
                 "--size", SIZE]) == 0
    without_truth(d / "log.mcap", d / "notruth.mcap")
    return d


def test_compare_summary_has_the_declared_schema_with_orwithout_truth(logs, tmp_path, capsys):
    want = arrow_schema(COMPARE_SUMMARY_COLUMNS)
    for name in ("log", "notruth"):
        rc, _, err = run_cli(capsys, "compare", logs / f"{name}.mcap", "--a", "zcut", "--b", "sor",
                             "-o", tmp_path / name, "--no-rrd")
        assert rc == 0, err
        got = pq.read_schema(tmp_path / name / "summary.parquet")
        assert got.remove_metadata() == want, f"{name}:\n{got}"
    # with truth every column has values: the file is byte for byte the one pyarrow's inference wrote
    rows = pq.read_table(tmp_path / "log" / "summary.parquet").to_pylist()
    inferred, declared = io.BytesIO(), io.BytesIO()
    pq.write_table(pa.Table.from_pylist(rows), inferred)
    pq.write_table(table_of(rows, COMPARE_SUMMARY_COLUMNS), declared)
    assert inferred.getvalue() == declared.getvalue()


def test_a_row_column_the_schema_does_not_declare_is_an_error():
    with pytest.raises(ValueError, match="not in the declared schema: extra"):
        table_of([{"log": "a", "extra": 1}], COMPARE_SUMMARY_COLUMNS)


def test_batch_frames_table_has_the_declared_columns(logs, tmp_path, capsys):
    rc, _, err = run_cli(capsys, "batch", logs / "log.mcap", "-o", tmp_path / "b", "--workers", "1")
    assert rc == 0, err
    got = pq.read_schema(tmp_path / "b" / "frames.parquet")
    assert got.remove_metadata() == arrow_schema(frames_columns(REPORTED)), str(got)


def _same_but_null(got: pa.Schema, want: pa.Schema) -> list[str]:
    """Where ``got`` differs from ``want`` other than a column typed ``null`` (every value None)."""
    if got.names != want.names:
        return [f"columns {got.names} != {want.names}"]
    return [f"{f.name}: {f.type} != {w.type}" for f, w in zip(got, want) if f.type != w.type and f.type != pa.null()]


def test_sweep_table_has_the_declared_columns(logs, tmp_path, capsys):
    rc, _, err = run_cli(capsys, "sweep", logs / "log.mcap", "-o", tmp_path / "s", "--workers", "1",
                         "--step", "0.2", "--max-depth", "30", "--rho", "0.07", "--sor-k", "4", "--sor-std", "1")
    assert rc == 0, err
    got = pq.read_schema(tmp_path / "s" / "sweep.parquet").remove_metadata()
    want = arrow_schema(SWEEP_COLUMNS)
    assert got == want, _same_but_null(got, want)


def test_conform_declares_a_null_column_and_refuses_an_undeclared_one():
    import pyarrow as pa

    t = pa.table({"b": pa.nulls(2), "a": pa.array([1, 2])})
    out = conform(t, (("a", "int64"), ("b", "double"), ("c", "string")))
    assert out.schema == arrow_schema((("a", "int64"), ("b", "double"), ("c", "string")))
    assert out.column("a").to_pylist() == [1, 2] and out.column("c").null_count == 2
    with pytest.raises(ValueError, match="not in the declared schema: a"):
        conform(t, (("b", "double"),))
