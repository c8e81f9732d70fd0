"""Filter sessions: a rig's measurements streamed in, an estimate back for each.

    with c.session("two_tank", filter="ekf", theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10],
                   r=1e-3) as s:
        est = s.step(0.0, u=[0.095, 0.031], y=[0.40, 0.15])
        for est in s.stream(frame):          # or (t, u, y) tuples
            print(est.t, est.state["A1"])

One stream per session, opened at the first measurement; measurements go in
batches (`batch`, 100 by default) and each batch waits for its answer, so a
client never buffers more than one batch. A refused measurement raises
MeasurementRefused (the session goes on with the next one); a diverged
filter ends the stream with FailedPrecondition. Leaving the `with` block
closes the session (close=False keeps it, to resume later by its id).
"""
import dataclasses
import queue

import grpc
import numpy as np
import pandas as pd

from . import errors
from ._settings import enum_name
from .v1 import sessions_pb2


class MeasurementRefused(errors.RiccatiError):
    """riccatid refused one measurement (t not after the last, wrong sizes, ...); `sequence` is its number."""

    def __init__(self, code, message, sequence):
        self.sequence = sequence
        super().__init__(code, message, f"measurement {sequence}")


@dataclasses.dataclass
class Estimate:
    """The estimate after one measurement: state and std are Series over the
    model's states then parameters ([x; theta]); innovation and y_predicted by output."""
    sequence: int
    t: float
    state: pd.Series
    std: pd.Series
    y_predicted: pd.Series
    innovation: pd.Series
    nis: float
    covariance: np.ndarray = None
    estimated_inputs: tuple = ()
    residuals: tuple = ()


_END = object()


class Session:
    def __init__(self, client, info, model, close=True, full_covariance=False, batch=100):
        self._client = client
        self.info = info
        self.id = info.id
        self.model = model
        self._close = close
        self._full_covariance = full_covariance
        self._batch = max(1, int(batch))
        self._requests = None
        self._responses = None
        self._sequence = info.measurements
        z = list(model.state_names) + list(model.param_names)
        self._z = pd.Index(z, name="variable")
        self._y = pd.Index(list(model.output_names), name="output")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self):
        return f"<Session {self.id} of {self.model.name}>"

    @property
    def state(self):
        return enum_name(sessions_pb2.SessionState.DESCRIPTOR, self.info.state)

    def refresh(self):
        self.info = self._client._call("session " + self.id, self._client._sessions.GetSession,
                                       sessions_pb2.GetSessionRequest(id=self.id))
        return self

    # ------------------------------------------------------------ the stream

    def _open(self):
        if self._responses is not None:
            return
        self._requests = queue.Queue()
        self._requests.put(sessions_pb2.StreamRequest(
            open=sessions_pb2.StreamOpen(session_id=self.id, full_covariance=self._full_covariance)))
        self._responses = self._client._stream_call(self._client._sessions.Stream,
                                                    iter(self._requests.get, _END))

    def _end_stream(self):
        if self._responses is None:
            return
        self._requests.put(_END)
        try:
            for _ in self._responses:  # the stream's end, after the last answer
                pass
        except grpc.RpcError:
            pass
        self._responses = None

    def _exchange(self, measurements):
        """Sends one batch and returns its results, one per measurement."""
        self._open()
        batch = sessions_pb2.MeasurementBatch()
        for t, u, y in measurements:
            batch.measurements.add(t=float(t), u=np.atleast_1d(np.asarray(u, dtype=float)).tolist(),
                                   y=np.atleast_1d(np.asarray(y, dtype=float)).tolist())
        self._requests.put(sessions_pb2.StreamRequest(batch=batch))
        try:
            response = next(self._responses)
        except grpc.RpcError as e:
            self._responses = None
            raise self._client._error(e, "session " + self.id) from None
        except StopIteration:
            self._responses = None
            raise errors.Unavailable(grpc.StatusCode.UNAVAILABLE, "riccatid ended the stream",
                                     "session " + self.id) from None
        return list(response.results)

    def _estimate(self, result):
        if result.WhichOneof("outcome") == "error":
            raise MeasurementRefused(errors.status_code(result.error.code), result.error.message, result.sequence)
        e = result.estimate
        cov = None
        if e.HasField("covariance") and e.covariance.rows:
            cov = np.asarray(e.covariance.values).reshape((e.covariance.cols, e.covariance.rows)).T
        return Estimate(sequence=result.sequence, t=e.t, state=pd.Series(list(e.state), index=self._z, name="state"),
                        std=pd.Series(list(e.std), index=self._z, name="std"),
                        y_predicted=pd.Series(list(e.y_predicted), index=self._y, name="y_predicted"),
                        innovation=pd.Series(list(e.innovation), index=self._y, name="innovation"),
                        nis=e.nis, covariance=cov, estimated_inputs=tuple(e.estimated_inputs),
                        residuals=tuple(e.residuals))

    def step(self, t, u, y):
        """One measurement: time t (s), inputs u (nu) and outputs y (ny); returns its Estimate."""
        (result,) = self._exchange([(t, u, y)])
        return self._estimate(result)

    def _rows(self, data, inputs, outputs, time):
        if isinstance(data, pd.DataFrame):
            inputs = list(inputs) if inputs else list(self.model.input_names)
            outputs = list(outputs) if outputs else list(self.model.output_names)
            frame = data if time in data.columns else data.reset_index().rename(columns={data.index.name or
                                                                                         "index": time})
            missing = [c for c in [time] + inputs + outputs if c not in frame.columns]
            if missing:
                raise ValueError(f"the DataFrame has no column {', '.join(map(repr, missing))} (give inputs= "
                                 "and outputs= to name the model's columns)")
            t = frame[time].to_numpy(float)
            u = frame[inputs].to_numpy(float)
            y = frame[outputs].to_numpy(float)
            return zip(t, u, y)
        return data

    def stream(self, data, batch=None, inputs=None, outputs=None, time="t", errors="raise"):
        """Yields an Estimate per measurement of `data`: (t, u, y) tuples, or a
        DataFrame with a time column and the model's input and output columns
        (or those named by inputs= and outputs=), sent in batches.

        errors="raise" raises MeasurementRefused at a refused measurement;
        errors="yield" yields the exception in its place and goes on."""
        size = self._batch if batch is None else max(1, int(batch))
        pending = []

        def flush():
            for result in self._exchange(pending):
                try:
                    yield self._estimate(result)
                except MeasurementRefused as refused:
                    if errors != "yield":
                        raise
                    yield refused
            pending.clear()

        for row in self._rows(data, inputs, outputs, time):
            pending.append(row)
            if len(pending) == size:
                yield from flush()
        if pending:
            yield from flush()

    def close(self):
        """Ends the stream and, unless the session was opened with close=False, closes the session."""
        self._end_stream()
        if self._close:
            self._client._call("closing session " + self.id, self._client._sessions.CloseSession,
                               sessions_pb2.CloseSessionRequest(id=self.id))
            self._close = False

