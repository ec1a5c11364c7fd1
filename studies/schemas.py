"""The declared schemas of the studies' tables: ``frames.parquet`` (``zcut batch``), ``sweep.parquet``
(``zcut sweep``) and ``summary.parquet`` (``zcut compare``), each column once, in the order written,
with the Arrow type it holds.

A table built from rows by pyarrow's inference types a column from its values: one whose every value
is None in a run (no truth, no filter bank, a stage that did not run) becomes ``null``, and tables of
two runs then differ. A writer that builds its table with :func:`arrow_schema` of the columns below
writes the declared types whatever the values.

A column is ``(name, type)`` with the type an Arrow alias (``pa.type_for_alias``): ``string``,
``int64``, ``double``, ``bool``. Every column may hold nulls (a frame without truth has no counts).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

from studies.work import COUNT_COLUMNS, STAGE_COLUMNS

if TYPE_CHECKING:
    import pyarrow as pa

#: one column: its name and its Arrow type alias
Column = tuple[str, str]

# --------------------------------------------------------------------------- frames.parquet
#: the columns every row of ``frames.parquet`` starts with (:func:`studies.work.batch_row`): the log,
#: the frame, the replay table's counts, the registration's fitness and the bin check
FRAMES_HEAD: tuple[Column, ...] = (
    ("log", "string"), ("log_sha256", "string"), ("frame", "int64"), ("stamp_ns", "int64"),
    *((c, "int64") for c in COUNT_COLUMNS),
    ("fitness", "double"), ("rmse_mm", "double"), ("pose_error_mm", "double"), ("pose_error_deg", "double"),
    ("bin_check", "double"), ("bin_flagged", "bool"),
)


def frames_columns(methods: Sequence[str], others: Sequence[str] = ()) -> tuple[Column, ...]:
    """The columns of ``frames.parquet`` for a replay whose reported methods are ``methods``
    (``config.reported_methods``: a TP/FP/FN triple each) and whose filter methods other than the
    z-cut and SOR are ``others`` (an outlier count and a stage time each)."""
    return (
        *FRAMES_HEAD,
        *((m, "int64") for m in others),
        *((f"t_{s}_s", "double") for s in (*STAGE_COLUMNS, *others)),
        ("warnings", "string"), ("scored", "bool"), ("truth", "string"),
        *((f"{m}_{k}", "int64") for m in methods for k in ("tp", "fp", "fn")),
    )


# --------------------------------------------------------------------------- sweep.parquet
#: the columns of ``sweep.parquet`` (:func:`studies.sweep.sweep_frame`): one row per log × frame ×
#: parameter set × method; a z-cut row's parameters, SOR's, the counts over the scored region, the
#: filter bank's columns (``params``, ``kind_tp`` and ``kind_n`` JSON text), the frame's bin check and
#: the truth it was scored against (``paper``, ``sensor`` or ``labels``: docs/accuracy.md, "Two truths")
SWEEP_COLUMNS: tuple[Column, ...] = (
    ("log", "string"), ("log_sha256", "string"), ("frame", "int64"), ("stamp_ns", "int64"), ("method", "string"),
    ("step_mm", "double"), ("max_depth_mm", "double"), ("rho_thr", "double"), ("max_area_px", "double"),
    ("sor_k", "int64"), ("sor_std_ratio", "double"),
    ("tp", "int64"), ("fp", "int64"), ("fn", "int64"), ("n_pred", "int64"),
    ("n_both", "int64"), ("n_sor_only", "int64"), ("n_zcut_only", "int64"),
    ("params", "string"), ("seconds", "double"), ("part", "string"), ("kind_tp", "string"), ("kind_n", "string"),
    ("bin_check", "double"), ("bin_flagged", "bool"), ("truth", "string"),
)

# --------------------------------------------------------------------------- compare's summary.parquet
#: the columns of ``zcut compare``'s ``summary.parquet`` (:func:`studies.compare_records.summary_rows`):
#: one row per frame, the pixels the sides share or not, each side's primary counts and figures
#: (None on an unscored frame), B's F1 minus A's and the paired outcome (+1 B wins, -1 B loses, 0 a tie)
COMPARE_SUMMARY_COLUMNS: tuple[Column, ...] = (
    ("log", "string"), ("frame", "int64"), ("stamp_ns", "int64"), ("scored", "bool"),
    ("both", "int64"), ("only_a", "int64"), ("only_b", "int64"),
    ("blobs", "int64"), ("blobs_a", "int64"), ("blobs_b", "int64"),
    *((f"{side}_{k}", t) for side in ("a", "b")
      for k, t in (("tp", "int64"), ("fp", "int64"), ("fn", "int64"),
                   ("precision", "double"), ("recall", "double"), ("f1", "double"))),
    ("delta_f1", "double"), ("outcome", "int64"),
)


def arrow_schema(columns: Iterable[Column]) -> pa.Schema:
    """The pyarrow schema of ``columns`` (every field nullable)."""
    import pyarrow as pa

    return pa.schema([pa.field(name, pa.type_for_alias(t)) for name, t in columns])


def table_of(rows: list[dict[str, object]], columns: Iterable[Column]) -> pa.Table:
    """``rows`` as a table of the declared ``columns``; a row's key that is not declared is an error
    (pyarrow would drop it silently), a declared column a row lacks is null."""
    import pyarrow as pa

    cols = tuple(columns)
    names = {name for name, _ in cols}
    for row in rows:
        extra = [k for k in row if k not in names]
        if extra:
            raise ValueError(f"row columns not in the declared schema: {', '.join(extra)}")
    return pa.Table.from_pylist(rows, schema=arrow_schema(cols))


def conform(table: pa.Table, columns: Iterable[Column]) -> pa.Table:
    """``table`` with the declared ``columns``, in their order and of their types: a column no row
    had (or whose every value was None, which pyarrow types ``null``) is written with its declared
    type; a column of the table that is not declared is an error, as in :func:`table_of`."""
    import pyarrow as pa

    cols = tuple(columns)
    names = [name for name, _ in cols]
    extra = [n for n in table.column_names if n not in names]
    if extra:
        raise ValueError(f"table columns not in the declared schema: {', '.join(extra)}")
    schema = arrow_schema(cols)
    arrays = [table.column(f.name).cast(f.type) if f.name in table.column_names
              else pa.nulls(table.num_rows, f.type) for f in schema]
    return pa.Table.from_arrays(arrays, schema=schema)
