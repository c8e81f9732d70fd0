"""What `Client.upload` takes, as the bytes of a file riccatid reads (CSV or MAT)."""
import io
import os

import numpy as np
import pandas as pd


def _column(a, what):
    a = np.asarray(a, dtype=float)
    if a.ndim == 1:
        return a[:, None]
    if a.ndim != 2:
        raise ValueError(f"{what}: expected a 1-d or 2-d array (samples in rows)")
    return a


def _csv(frame):
    # repr() of a float reads back as the same double, so the upload is exact.
    out = io.StringIO()
    frame.to_csv(out, index=False, float_format=None, lineterminator="\n")
    return out.getvalue().encode("utf-8")


def as_upload(data, inputs, outputs, time, ts=None):
    """(name, bytes, inputs, outputs, time column) for a path, a DataFrame or (t, u, y) arrays.
    With ts (a sample time), the data has no time column: the time column is then ""."""
    if ts is not None and not ts > 0:
        raise ValueError(f"ts must be a positive sample time, got {ts!r}")
    if isinstance(data, (str, os.PathLike)):
        path = os.fspath(data)
        with open(path, "rb") as f:
            return os.path.basename(path), f.read(), inputs, outputs, "" if ts else time
    if isinstance(data, pd.DataFrame):
        frame = data
        if ts is None and time not in frame.columns:
            # The index is the time (a frame indexed by t, as to_frame() gives).
            frame = frame.reset_index()
            frame = frame.rename(columns={frame.columns[0]: time})
        columns = ([] if ts else [time]) + list(inputs or []) + list(outputs or [])
        missing = [c for c in columns if c not in frame.columns]
        if missing:
            raise ValueError(f"the DataFrame has no column {', '.join(map(repr, missing))} "
                             f"(it has {', '.join(map(str, frame.columns))})")
        if not inputs and not outputs:
            columns = list(frame.columns)
        return "dataframe.csv", _csv(frame[columns]), inputs, outputs, "" if ts else time
    if isinstance(data, (tuple, list)) and len(data) == 3:
        if ts is not None:
            raise ValueError("(t, u, y) arrays carry their times: ts is for a file or DataFrame without a time column")
        t, u, y = data
        t = np.asarray(t, dtype=float)
        u, y = _column(u, "u"), _column(y, "y")
        if t.ndim != 1 or u.shape[0] != len(t) or y.shape[0] != len(t):
            raise ValueError(f"(t, u, y): t has {len(t)} samples, u {u.shape[0]} and y {y.shape[0]}; "
                             "give each sample in a row")
        inputs = list(inputs) if inputs else [f"u{i + 1}" for i in range(u.shape[1])]
        outputs = list(outputs) if outputs else [f"y{i + 1}" for i in range(y.shape[1])]
        if len(inputs) != u.shape[1] or len(outputs) != y.shape[1]:
            raise ValueError(f"(t, u, y): {u.shape[1]} inputs and {y.shape[1]} outputs, but names for "
                             f"{len(inputs)} and {len(outputs)}")
        frame = pd.DataFrame(np.column_stack([t, u, y]), columns=[time] + inputs + outputs)
        return "arrays.csv", _csv(frame), inputs, outputs, time
    raise TypeError("upload() takes a file path (CSV or MAT), a pandas DataFrame or (t, u, y) arrays")
