"""Jobs: identification, validation and smoothing running on riccatid's workers."""
import dataclasses

import grpc

from . import errors
from .v1 import jobs_pb2

_DONE = ("succeeded", "failed", "cancelled")


def _state_name(number):
    return jobs_pb2.JobState.Name(number).removeprefix("JOB_STATE_").lower()


@dataclasses.dataclass(frozen=True)
class Progress:
    """Where a job stands: the pass (1-based) of passes, the sample of samples
    in it, the current estimate; iteration and cost for output error and likelihood."""
    pass_number: int
    passes: int
    sample: int
    samples: int
    theta: tuple
    iteration: int
    cost: float

    @property
    def fraction(self):
        """How much of the filter's passes is done, 0 to 1 (the optimiser's iterations are not counted)."""
        if self.passes == 0 or self.samples == 0:
            return 0.0
        return min(1.0, (max(self.pass_number - 1, 0) + self.sample / self.samples) / self.passes)


def _progress(p):
    return Progress(pass_number=p.pass_number, passes=p.passes, sample=p.sample, samples=p.samples,
                    theta=tuple(p.theta), iteration=p.iteration, cost=p.cost)


class Job:
    """A job as riccatid last said it was: id, state ("queued", "running",
    "cancelling", "succeeded", "failed", "cancelled"), progress, error (code, message)."""

    def __init__(self, client, message):
        self._client = client
        self._update(message)

    def _update(self, message):
        self.proto = message
        self.id = message.id
        self.state = _state_name(message.state)
        self.progress = _progress(message.progress)
        self.attempts = message.attempts
        self.error = (errors.status_code(message.error.code), message.error.message) \
            if message.HasField("error") and message.error.message else None

    @property
    def done(self):
        return self.state in _DONE

    @property
    def kind(self):
        return self.proto.WhichOneof("spec")

    @property
    def model(self):
        return getattr(self.proto, self.kind).model if self.kind else ""

    def __repr__(self):
        return f"<Job {self.id} {self.state}>"

    def refresh(self):
        """Asks riccatid for the job now."""
        self._update(self._client._call("job " + self.id, self._client._jobs.GetJob,
                                         jobs_pb2.GetJobRequest(id=self.id)))
        return self

    def watch(self, progress=None):
        """Yields the job as it changes (state, and progress as it runs) until it ends;
        progress(job), if given, is called with each."""
        if self.done:
            if progress is not None:
                progress(self)
            yield self
            return
        stream = self._client._stream_call(self._client._jobs.WatchJob, jobs_pb2.WatchJobRequest(id=self.id))
        try:
            for message in stream:
                self._update(message)
                if progress is not None:
                    progress(self)
                yield self
                if self.done:
                    return
        except grpc.RpcError as e:
            raise self._client._error(e, "watching job " + self.id) from None
        finally:
            stream.cancel()
        # The stream ended without the job's end (riccatid stopping): read it once more.
        self.refresh()
        if not self.done:
            raise errors.Unavailable(grpc.StatusCode.UNAVAILABLE,
                                     "riccatid ended the watch before the job ended", "watching job " + self.id)
        yield self

    def wait(self, progress=None):
        """Blocks until the job ends; returns it (whatever its end)."""
        for _ in self.watch(progress):
            pass
        return self

    def cancel(self):
        """Cancels the job (a running one stops between samples); returns it."""
        self._update(self._client._call("cancelling job " + self.id, self._client._jobs.CancelJob,
                                         jobs_pb2.CancelJobRequest(id=self.id)))
        return self

    def delete(self):
        """Deletes the ended job with its result (DeleteJob); FailedPrecondition while
        it is queued or running: cancel it first."""
        self._client._call("deleting job " + self.id, self._client._jobs.DeleteJob,
                           jobs_pb2.DeleteJobRequest(id=self.id))

    def result(self, progress=None):
        """Waits for the job, then its result (IdentificationResult, EstimationResult,
        ValidationResult or SmoothingResult); JobFailed if it failed or was cancelled."""
        self.wait(progress)
        if self.state != "succeeded":
            code, message = self.error or (grpc.StatusCode.UNKNOWN, "no reason given")
            raise errors.JobFailed(code, message, self)
        return self._client.result(self.id, model=self.model)
