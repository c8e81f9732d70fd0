"""Errors: what riccatid said, as Python exceptions.

Every failed call raises a `RiccatiError` carrying the gRPC status code
(`.code`, a `grpc.StatusCode`) and riccatid's message (`.message`, which says
what is wrong and where). The common codes have their own subclasses, so

    try:
        c.identify("two_tank", ds, r=-1)
    except riccati.InvalidArgument as e:
        print(e.code.name, e.message)

A job that ends FAILED or CANCELLED raises `JobFailed`, with the job and
the code and message of the job's error. Arguments that are wrong before
anything is sent (an unknown filter name, a matrix that is not square) are
ValueError and TypeError, as elsewhere in Python.
"""
import grpc


class RiccatiError(Exception):
    """A call to riccatid failed: `code` (grpc.StatusCode) and `message`."""

    def __init__(self, code, message, what=""):
        self.code = code
        self.message = message
        self.what = what
        super().__init__(f"{what}: {message} ({code.name})" if what else f"{message} ({code.name})")


class InvalidArgument(RiccatiError):
    pass


class NotFound(RiccatiError):
    pass


class AlreadyExists(RiccatiError):
    pass


class FailedPrecondition(RiccatiError):
    pass


class ResourceExhausted(RiccatiError):
    pass


class Unauthenticated(RiccatiError):
    pass


class PermissionDenied(RiccatiError):
    pass


class Unavailable(RiccatiError):
    """riccatid could not be reached, or is shutting down."""


class DeadlineExceeded(RiccatiError):
    pass


class Cancelled(RiccatiError):
    pass


class JobFailed(RiccatiError):
    """A job ended FAILED or CANCELLED: `job` is its last state."""

    def __init__(self, code, message, job):
        self.job = job
        super().__init__(code, message, f"job {job.id} {job.state}")


_BY_CODE = {
    grpc.StatusCode.INVALID_ARGUMENT: InvalidArgument,
    grpc.StatusCode.OUT_OF_RANGE: InvalidArgument,
    grpc.StatusCode.NOT_FOUND: NotFound,
    grpc.StatusCode.ALREADY_EXISTS: AlreadyExists,
    grpc.StatusCode.FAILED_PRECONDITION: FailedPrecondition,
    grpc.StatusCode.RESOURCE_EXHAUSTED: ResourceExhausted,
    grpc.StatusCode.UNAUTHENTICATED: Unauthenticated,
    grpc.StatusCode.PERMISSION_DENIED: PermissionDenied,
    grpc.StatusCode.UNAVAILABLE: Unavailable,
    grpc.StatusCode.DEADLINE_EXCEEDED: DeadlineExceeded,
    grpc.StatusCode.CANCELLED: Cancelled,
}

_CODE_BY_NUMBER = {c.value[0]: c for c in grpc.StatusCode}


def status_code(number):
    """The grpc.StatusCode of a number (an Error message's code)."""
    return _CODE_BY_NUMBER.get(number, grpc.StatusCode.UNKNOWN)


def error_for(code, message, what=""):
    return _BY_CODE.get(code, RiccatiError)(code, message, what)


def from_rpc_error(e, what="", server=""):
    """The exception for a grpc.RpcError."""
    code = e.code() if hasattr(e, "code") else grpc.StatusCode.UNKNOWN
    message = e.details() if hasattr(e, "details") else str(e)
    if code == grpc.StatusCode.UNAVAILABLE and server and "ailed to connect" in (message or ""):
        # gRPC's words for a connection it could not make ("failed to connect to all addresses; last
        # error: UNKNOWN: ipv4:127.0.0.1:7531: Failed to connect to remote host: Connection refused"):
        # the cause after the last colon, as the CLI says it.
        cause = message.rsplit(":", 1)[-1].strip()
        cause = cause[:1].lower() + cause[1:]
        message = f"cannot reach riccatid at {server} ({cause}); is it running?"
    return error_for(code, message or "", what)
