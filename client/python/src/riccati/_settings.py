"""Keyword arguments, named as the CLI's flags (client/cli/settings.cpp), into requests.

A flag's name without its dashes, the others as underscores: --p0 is p0,
--first-sample is first_sample, --no-joseph is no_joseph. Values:

- covariances (p0, q, r, v, w, r0): one number (the whole diagonal), a list
  (the diagonal) or a square matrix (rows); whether the size fits the model
  is riccatid's to say, as for the CLI;
- enum settings (filter, hold, integrator, inversion, weights, form, method,
  estimate): the names the CLI takes ("ekf", "cvode-bdf", "oe", ...), listed
  from the API's descriptors, so a value added to the proto is known here;
- x0: "first" (each state with an output of its name starts at its first
  measurement; the default) or a list of numbers;
- bound: {name: (lower, upper)} (None for a side left as the model's);
  fix: {name: value or None} or a list of names (held at theta0);
  output_limit: {output: (lower, upper)}; exclude: [(first, end), ...] of
  experiment 1 or [(experiment, first, end), ...]; log_scale: names;
  estimate_x0 (identify): True (all) or state names.
"""
import numbers

import numpy as np

from .v1 import common_pb2, jobs_pb2, sessions_pb2

# --------------------------------------------------------------------------- enums


def _value_prefix(enum):
    prefix = ""
    for c in enum.name:
        if c.isupper() and prefix:
            prefix += "_"
        prefix += c.upper()
    return prefix + "_"


def enum_value_name(value):
    """The name people write for an enum value ("ekf", "cvode-bdf", "zoh"), as riccati/enum_names.cpp."""
    short = value.GetOptions().Extensions[common_pb2.short_name]
    if short:
        return short
    name = value.name
    prefix = _value_prefix(value.type)
    if name.startswith(prefix):
        name = name[len(prefix):]
    return name.lower().replace("_", "-")


def enum_choices(enum):
    return [enum_value_name(v) for v in enum.values if v.number != 0]


def enum_number(enum, name, keyword):
    if isinstance(name, numbers.Integral) and not isinstance(name, bool):
        return int(name)
    for value in enum.values:
        if value.number != 0 and enum_value_name(value) == name:
            return value.number
    raise ValueError(f"{keyword}={name!r} is unknown ({', '.join(enum_choices(enum))})")


def enum_name(enum, number):
    value = enum.values_by_number.get(number)
    return enum_value_name(value) if value is not None and number != 0 else ""


# --------------------------------------------------------------------------- values


def _floats(value, keyword):
    array = np.asarray(value, dtype=float)
    if array.ndim > 1:
        raise ValueError(f"{keyword}: expected a number or a list of numbers, not a {array.ndim}-d array")
    return [float(v) for v in np.atleast_1d(array)]


def covariance(value, keyword):
    """One value (the whole diagonal), the diagonal, or a full matrix (rows), as the CLI reads them."""
    out = common_pb2.Covariance()
    if isinstance(value, numbers.Real):
        out.scalar = float(value)
        return out
    array = np.asarray(value, dtype=float)
    if array.ndim == 0:
        out.scalar = float(array)
    elif array.ndim == 1:
        out.diagonal.values.extend(float(v) for v in array)
    elif array.ndim == 2:
        if array.shape[0] != array.shape[1]:
            raise ValueError(f"{keyword}: a full matrix must be square, not {array.shape[0]} x {array.shape[1]}")
        out.full.rows, out.full.cols = array.shape
        out.full.values.extend(float(v) for v in array.flatten(order="F"))
    else:
        raise ValueError(f"{keyword}: expected a number, a list or a matrix")
    return out


def initial_state(x0, keyword="x0"):
    out = common_pb2.InitialState()
    if x0 is None or (isinstance(x0, str) and x0 == "first"):
        out.first_measurement = True
    elif isinstance(x0, str):
        raise ValueError(f"{keyword}: give \"first\" or a list of numbers, not {x0!r}")
    else:
        out.x0.extend(_floats(x0, keyword))
    return out


def _names(value, keyword):
    if isinstance(value, str):
        return [n.strip() for n in value.split(",") if n.strip()]
    if value is True:
        return ["all"]
    try:
        return [str(n) for n in value]
    except TypeError:
        raise TypeError(f"{keyword}: expected names") from None


def _range(value, keyword, name):
    try:
        lower, upper = value
    except (TypeError, ValueError):
        raise ValueError(f"{keyword}[{name!r}]: expected (lower, upper), None for a side left open") from None
    return lower, upper


def _uint(value, keyword):
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 0:
        raise ValueError(f"{keyword}: expected a whole number (0 or more), not {value!r}")
    return int(value)


# --------------------------------------------------------------------------- settings

FILTER_KEYWORDS = ("filter", "hold", "integrator", "substeps", "rtol", "atol", "q", "r", "inversion", "no_joseph",
                   "weights", "alpha", "beta", "kappa", "v", "w", "r0", "form", "hold_outputs")
RUN_KEYWORDS = FILTER_KEYWORDS + ("x0", "theta0", "p0")
IDENTIFY_KEYWORDS = RUN_KEYWORDS + (
    "passes", "first_sample", "end_sample", "method", "init_passes", "bound", "fix", "log_scale", "estimate_x0",
    "experiment", "exclude", "output_limit", "output_sigma", "estimate_q", "estimate_r", "max_iterations",
    "function_tolerance", "gradient_tolerance", "parameter_tolerance")
SMOOTH_KEYWORDS = RUN_KEYWORDS + ("first_sample", "end_sample")
VALIDATE_KEYWORDS = ("x0", "hold", "integrator", "substeps", "rtol", "atol", "estimate", "estimate_x0")


def check_keywords(given, allowed, command):
    unknown = sorted(set(given) - set(allowed))
    if unknown:
        raise TypeError(f"{command}() got unknown settings {', '.join(unknown)} (it takes {', '.join(allowed)})")


def integrator_settings(kw):
    out = common_pb2.IntegratorSettings()
    if kw.get("integrator") is not None:
        out.kind = enum_number(common_pb2.IntegratorKind.DESCRIPTOR, kw["integrator"], "integrator")
    if kw.get("substeps") is not None:
        out.substeps = _uint(kw["substeps"], "substeps")
    if kw.get("rtol") is not None:
        out.rtol = float(kw["rtol"])
    if kw.get("atol") is not None:
        out.atol = float(kw["atol"])
    return out


def filter_settings(kw):
    out = common_pb2.FilterSettings()
    if kw.get("filter") is not None:
        out.kind = enum_number(common_pb2.FilterKind.DESCRIPTOR, kw["filter"], "filter")
    if kw.get("hold") is not None:
        out.hold = enum_number(common_pb2.HoldOrder.DESCRIPTOR, kw["hold"], "hold")
    integrator = integrator_settings(kw)
    if integrator.ByteSize() > 0:
        out.integrator.CopyFrom(integrator)
    for key, field in (("q", out.q), ("r", out.r)):
        if kw.get(key) is not None:
            field.CopyFrom(covariance(kw[key], key))
    if kw.get("inversion") is not None:
        out.inversion = enum_number(common_pb2.GainInversion.DESCRIPTOR, kw["inversion"], "inversion")
    if kw.get("no_joseph"):
        out.short_covariance_update = True
    if kw.get("weights") is not None:
        out.ukf.weights = enum_number(common_pb2.SigmaWeights.DESCRIPTOR, kw["weights"], "weights")
    for key in ("alpha", "beta", "kappa"):
        if kw.get(key) is not None:
            setattr(out.ukf, key, float(kw[key]))
    for key in ("v", "w", "r0"):
        if kw.get(key) is not None:
            getattr(out.optimal, key).CopyFrom(covariance(kw[key], key))
    if kw.get("form") is not None:
        out.optimal.form = enum_number(common_pb2.OptimalForm.DESCRIPTOR, kw["form"], "form")
    if kw.get("hold_outputs"):
        out.optimal.hold_outputs = True
    return out


def fill_run(request, model, kw):
    """What a job and a session share: model, filter, initial state, theta0 and P0."""
    request.model = model
    request.filter.CopyFrom(filter_settings(kw))
    request.initial_state.CopyFrom(initial_state(kw.get("x0")))
    if kw.get("theta0") is not None:
        request.theta0.extend(_floats(kw["theta0"], "theta0"))
    if kw.get("p0") is not None:
        request.p0.CopyFrom(covariance(kw["p0"], "p0"))


def sample_mask(kw, experiment):
    out = jobs_pb2.SampleMask()
    for output, value in (kw.get("output_limit") or {}).items():
        lower, upper = _range(value, "output_limit", output)
        limit = out.limits.add(output=output)
        if lower is not None:
            limit.lower = float(lower)
        if upper is not None:
            limit.upper = float(upper)
    for span in kw.get("exclude") or ():
        span = tuple(span)
        if len(span) == 2:
            span = (1,) + span
        if len(span) != 3:
            raise ValueError(f"exclude: expected (first, end) or (experiment, first, end), not {span!r}")
        if span[0] == experiment:
            out.excluded.add(first=_uint(span[1], "exclude"), end=_uint(span[2], "exclude"))
    return out


def estimation_settings(kw):
    out = jobs_pb2.EstimationSettings()
    if kw.get("output_sigma") is not None:
        out.output_sigma.extend(_floats(kw["output_sigma"], "output_sigma"))
    if kw.get("estimate_q"):
        out.estimate_process_noise = True
    if kw.get("estimate_r"):
        out.estimate_measurement_noise = True
    if kw.get("max_iterations") is not None:
        out.max_iterations = _uint(kw["max_iterations"], "max_iterations")
    for key in ("function", "gradient", "parameter"):
        if kw.get(key + "_tolerance") is not None:
            setattr(out, key + "_tolerance", float(kw[key + "_tolerance"]))
    return out


def identification_spec(model, dataset_id, more_datasets, kw):
    spec = jobs_pb2.IdentificationSpec()
    fill_run(spec, model, kw)
    spec.dataset_id = dataset_id
    for key in ("passes", "first_sample", "end_sample", "init_passes"):
        if kw.get(key) is not None:
            setattr(spec, key, _uint(kw[key], key))
    if kw.get("method") is not None:
        spec.method = enum_number(jobs_pb2.IdentificationMethod.DESCRIPTOR, kw["method"], "method")
    for name, value in (kw.get("bound") or {}).items():
        lower, upper = _range(value, "bound", name)
        bound = spec.bounds.add(name=name)
        if lower is not None:
            bound.lower = float(lower)
        if upper is not None:
            bound.upper = float(upper)
    fix = kw.get("fix") or {}
    if isinstance(fix, str):
        fix = _names(fix, "fix")
    for name in fix:
        fixed = spec.fixed.add(name=name)
        if isinstance(fix, dict) and fix[name] is not None:
            fixed.value = float(fix[name])
    if kw.get("log_scale") is not None:
        spec.log_scale.extend(_names(kw["log_scale"], "log_scale"))
    if kw.get("estimate_x0"):
        spec.initial_state.estimate.extend(_names(kw["estimate_x0"], "estimate_x0"))
    mask = sample_mask(kw, 1)
    if mask.ByteSize() > 0:
        spec.mask.CopyFrom(mask)
    for e, dataset in enumerate(more_datasets, 2):
        experiment = spec.experiments.add(dataset_id=dataset)
        experiment.initial_state.CopyFrom(spec.initial_state)
        mask = sample_mask(kw, e)
        if mask.ByteSize() > 0:
            experiment.mask.CopyFrom(mask)
    estimation = estimation_settings(kw)
    if estimation.ByteSize() > 0:
        spec.estimation.CopyFrom(estimation)
    return spec


def smoothing_spec(model, dataset_id, kw, full_covariance=False):
    spec = jobs_pb2.SmoothingSpec()
    fill_run(spec, model, kw)
    spec.dataset_id = dataset_id
    for key in ("first_sample", "end_sample"):
        if kw.get(key) is not None:
            setattr(spec, key, _uint(kw[key], key))
    spec.full_covariance = bool(full_covariance)
    return spec


def session_request(model, kw):
    request = sessions_pb2.CreateSessionRequest()
    fill_run(request, model, kw)
    return request


def validation_spec(model, dataset_id, kw):
    spec = jobs_pb2.ValidationSpec(model=model, dataset_id=dataset_id)
    spec.initial_state.CopyFrom(initial_state(kw.get("x0")))
    if kw.get("hold") is not None:
        spec.hold = enum_number(common_pb2.HoldOrder.DESCRIPTOR, kw["hold"], "hold")
    integrator = integrator_settings(kw)
    if integrator.ByteSize() > 0:
        spec.integrator.CopyFrom(integrator)
    if kw.get("estimate") is not None:
        spec.estimate = enum_number(jobs_pb2.EstimateChoice.DESCRIPTOR, kw["estimate"], "estimate")
    if kw.get("estimate_x0"):
        spec.estimate_x0_samples = _uint(kw["estimate_x0"], "estimate_x0")
        spec.initial_state.estimate.append("all")
    return spec
