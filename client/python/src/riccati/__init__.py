"""riccati: the Python client of riccatid.

    import riccati

    c = riccati.Client("127.0.0.1:7531")
    ds = c.upload("two_tank.csv", inputs=["F1", "F2"], outputs=["h1", "h2"])
    res = c.identify("two_tank", ds, passes=10, theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10], q=0, r=1e-3)
    print(res.theta, res.std)
    fit = c.validate("two_tank", ds, res)
    print(fit.fits)

See docs/python.md.
"""
from ._connection import TLS, ConfigError
from .client import Client, Dataset
from .errors import (AlreadyExists, Cancelled, DeadlineExceeded, FailedPrecondition, InvalidArgument, JobFailed,
                     NotFound, PermissionDenied, ResourceExhausted, RiccatiError, Unauthenticated, Unavailable)
from .jobs import Job, Progress
from .results import (Comparison, Diagnostics, EstimationResult, ExperimentFit, IdentificationResult,
                      SmoothingResult, ValidationResult)
from .sessions import Estimate, MeasurementRefused, Session

__all__ = [
    "Client", "Dataset", "TLS", "ConfigError", "Job", "Progress", "Session", "Estimate", "MeasurementRefused",
    "IdentificationResult", "EstimationResult", "ExperimentFit", "Diagnostics", "ValidationResult", "SmoothingResult", "Comparison",
    "RiccatiError", "InvalidArgument", "NotFound", "AlreadyExists", "FailedPrecondition", "ResourceExhausted",
    "Unauthenticated", "PermissionDenied", "Unavailable", "DeadlineExceeded", "Cancelled", "JobFailed",
]
