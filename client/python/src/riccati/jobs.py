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
    in it, the current estimate; for output error and likelihood ("oe", "ml")
    the optimiser's iteration of max_iterations and the cost after it."""
    pass_number: int
    passes: int
    sample: int
    samples: int
    theta: tuple
    iteration: int
    cost: float
    method: str = "filter"
    max_iterations: int = 0
    succeeded: bool = False

    @property
    def fraction(self):
        """How much is done, 0 to 1. The iterated filter (and smoothing): the
        passes' samples. Output error and likelihood: the optimiser's
        iterations of max_iterations (an upper bound on the work: it usually
        converges before, and the job then ends early), the filter passes
        that give its start counting as the first iteration. A job that
        succeeded: 1."""
        if self.succeeded:
            return 1.0
        passes = 0.0
        if self.passes > 0 and self.samples > 0:
            passes = min(1.0, (max(self.pass_number - 1, 0) + self.sample / self.samples) / self.passes)
        if self.max_iterations == 0:
            return passes
        if self.iteration == 0:
            return passes / self.max_iterations
        return min(1.0, self.iteration / self.max_iterations)

    def __str__(self):
        if self.max_iterations and (self.iteration or not self.passes):
            return f"iteration {self.iteration}/{self.max_iterations}, cost {self.cost:.4g}"
        if self.passes:
            return f"pass {self.pass_number}/{self.passes}, sample {self.sample}/{self.samples}"
        return "not started"


# What riccatid takes for max_iterations 0 (EstimationSettings in jobs.proto).
_DEFAULT_MAX_ITERATIONS = 200


def _progress(p, spec=None, succeeded=False):
    method, max_iterations = "filter", 0
    if spec is not None and spec.method in (jobs_pb2.IDENTIFICATION_METHOD_OE, jobs_pb2.IDENTIFICATION_METHOD_ML):
        method = "oe" if spec.method == jobs_pb2.IDENTIFICATION_METHOD_OE else "ml"
        max_iterations = spec.estimation.max_iterations or _DEFAULT_MAX_ITERATIONS
    return Progress(pass_number=p.pass_number, passes=p.passes, sample=p.sample, samples=p.samples,
                    theta=tuple(p.theta), iteration=p.iteration, cost=p.cost, method=method,
                    max_iterations=max_iterations, succeeded=succeeded)


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
        self.progress = _progress(message.progress,
                                  message.identification if message.HasField("identification") else None,
                                  self.state == "succeeded")
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
