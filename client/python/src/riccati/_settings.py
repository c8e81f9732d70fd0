"""Keyword arguments into requests, made from the API's schema.

A request's settings are its fields with the riccati.v1.setting option
(proto/riccati/v1/common.proto), found by walking its descriptor as
riccati/settings_schema.cpp does: an annotated field is a setting, a singular
message field is walked into (filter.q, filter.ukf.alpha, initial_state.estimate).
A setting's keyword is its CLI flag without the dashes, '-' as '_' (--p0 is
p0, --first-sample first_sample, --estimate-r estimate_r), so a field added
to the proto with the option is a keyword here with no change to this file.

Values, by the kind of the field:

- covariance (p0, q, r, v, w, r0): one number (the whole diagonal), a list
  (the diagonal) or a square matrix (rows); whether the size fits the model
  is riccatid's to say, as for the CLI;
- choices (filter, hold, integrator, method, ...): the names the CLI takes
  ("ekf", "cvode-bdf", "oe"), read from the enums' descriptors;
- initial state (x0): "first" or a list of numbers;
- bounds (bound): {name: (lower, upper)}, None for a side left as the
  model's, or "NAME=LO:HI" strings; fixed (fix): {name: value or None}, a
  list of names (held at theta0) or "NAME[=VALUE]" strings;
- names (log_scale, estimate_x0): a list, a comma-separated string, or True
  for the flag given alone (its implicit value, "all");
- numbers: a number or a list; counts: whole numbers; switches: True.

A keyword left out (or None) is not sent: riccatid's default stands. Whether
a setting applies to the method or filter kind asked for is riccatid's to
say, in the same words for every client.
"""
import difflib
import numbers

import numpy as np
from google.protobuf.descriptor import FieldDescriptor

from .v1 import common_pb2, jobs_pb2, models_pb2, sessions_pb2

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


# --------------------------------------------------------------------------- the schema


class Setting:
    """A request's field with the riccati.v1.setting option."""

    def __init__(self, chain, option):
        self.chain = list(chain)  # the fields from the request's down to this one
        self.field = self.chain[-1]
        self.path = ".".join(f.name for f in self.chain)
        self.option = option
        self.keyword = option.flag.lstrip("-").replace("-", "_")
        self.kind = _kind(self.field)

    def __repr__(self):
        return f"<Setting {self.path} ({self.keyword}, {self.kind})>"


def _kind(field):
    # As value_kind() in riccati/settings_schema.cpp.
    repeated = field.label == FieldDescriptor.LABEL_REPEATED
    if field.type == FieldDescriptor.TYPE_MESSAGE:
        special = {("riccati.v1.Covariance", False): "covariance", ("riccati.v1.InitialState", False): "initial_state",
                   ("riccati.v1.ParameterBound", True): "bounds", ("riccati.v1.FixedParameter", True): "fixed"}
        return special.get((field.message_type.full_name, repeated), "text")
    if field.cpp_type in (FieldDescriptor.CPPTYPE_DOUBLE, FieldDescriptor.CPPTYPE_FLOAT):
        return "numbers" if repeated else "number"
    if field.cpp_type in (FieldDescriptor.CPPTYPE_UINT32, FieldDescriptor.CPPTYPE_UINT64):
        return "count"
    if field.cpp_type == FieldDescriptor.CPPTYPE_BOOL:
        return "switch"
    if field.cpp_type == FieldDescriptor.CPPTYPE_ENUM:
        return "choice"
    if field.cpp_type == FieldDescriptor.CPPTYPE_STRING:
        return "names" if repeated else "text"
    return "text"


def _declaration(descriptor, flag, depth=0):
    # The first declaration with help of the setting `flag` in `descriptor`.
    for field in descriptor.fields:
        options = field.GetOptions()
        if options.HasExtension(common_pb2.setting):
            option = options.Extensions[common_pb2.setting]
            if option.flag == flag and option.help:
                return option
        if (field.type == FieldDescriptor.TYPE_MESSAGE and field.label != FieldDescriptor.LABEL_REPEATED
                and depth < 8):
            found = _declaration(field.message_type, flag, depth + 1)
            if found is not None:
                return found
    return None


def _completed(option):
    # As completed() in riccati/settings_schema.cpp: a setting written as its
    # flag alone takes the rest from the flag's declaration (identification's
    # first); what it states itself stays.
    if option.help:
        return option
    for request in (jobs_pb2.IdentificationSpec, jobs_pb2.SmoothingSpec, jobs_pb2.ValidationSpec,
                    sessions_pb2.CreateSessionRequest, sessions_pb2.RetuneSessionRequest, models_pb2.SimulateRequest):
        declared = _declaration(request.DESCRIPTOR, option.flag)
        if declared is not None:
            out = common_pb2.Setting()
            out.CopyFrom(declared)
            for field, value in option.ListFields():
                out.ClearField(field.name)
                if field.label == FieldDescriptor.LABEL_REPEATED:
                    getattr(out, field.name).extend(value)
                else:
                    setattr(out, field.name, value)
            return out
    raise ValueError(f"setting {option.flag} has no help and no declaration with help")


def _walk(descriptor, chain, out):
    for field in descriptor.fields:
        chain.append(field)
        options = field.GetOptions()
        if options.HasExtension(common_pb2.setting):
            out.append(Setting(chain, _completed(options.Extensions[common_pb2.setting])))
        # Into singular messages, which may hold settings; the bound keeps a recursive type finite.
        if (field.type == FieldDescriptor.TYPE_MESSAGE and field.label != FieldDescriptor.LABEL_REPEATED
                and len(chain) < 8):
            _walk(field.message_type, chain, out)
        chain.pop()


_SCHEMAS = {}
# The filter kinds a request can run where it cannot run them all: a smoother
# runs the EKF or the UKF (as offered() in riccati/settings_schema.cpp; the
# tests hold this package's settings to riccatid's schema).
_FILTERS_RUN = {"riccati.v1.SmoothingSpec": ("ekf", "ukf")}


def settings_of(message_type):
    """{keyword: Setting} of a request type (a generated message class or its descriptor), in field order.

    Not offered, as riccati/settings_schema.cpp's offered(): in a request that
    has a filter kind but no method (a session, smoothing), which runs the
    filter, the settings of the other methods only; in smoothing, those of the
    optimal filter only."""
    descriptor = getattr(message_type, "DESCRIPTOR", message_type)
    if descriptor.full_name not in _SCHEMAS:
        found = []
        _walk(descriptor, [], found)
        paths = {s.path for s in found}
        method = "filter" if "filter.kind" in paths and "method" not in paths else ""
        kinds = _FILTERS_RUN.get(descriptor.full_name)

        def offered(s):
            if method and s.option.methods and method not in s.option.methods:
                return False
            return not kinds or not s.option.filters or any(k in s.option.filters for k in kinds)

        _SCHEMAS[descriptor.full_name] = {s.keyword: s for s in found if offered(s)}
    return _SCHEMAS[descriptor.full_name]


def check_keywords(given, allowed, command):
    """A TypeError naming each keyword that is not a setting, with the close ones, as Python does for a function."""
    unknown = [k for k in given if k not in allowed]
    if not unknown:
        return
    parts = []
    for k in unknown:
        close = difflib.get_close_matches(k, list(allowed), n=3, cutoff=0.6)
        parts.append(f"{k!r}" + (f" (did you mean {' or '.join(close)}?)" if close else ""))
    raise TypeError(f"{command}() got {'an unknown setting' if len(unknown) == 1 else 'unknown settings'} "
                    f"{', '.join(parts)}; it takes {', '.join(sorted(allowed))}")


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
    if isinstance(x0, str) and x0 == "first":
        out.first_measurement = True
    elif isinstance(x0, str):
        raise ValueError(f"{keyword}: give \"first\" or a list of numbers, not {x0!r}")
    else:
        out.x0.extend(_floats(x0, keyword))
    return out


def _names(value, keyword, implicit=""):
    if value is True:
        if not implicit:
            raise TypeError(f"{keyword}: expected names, not True")
        return [implicit]
    if isinstance(value, str):
        return [n.strip() for n in value.split(",") if n.strip()]
    try:
        return [str(n) for n in value]
    except TypeError:
        raise TypeError(f"{keyword}: expected names, not {value!r}") from None


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


def _text_ranges(value, keyword, form):
    """{name: (lower, upper)} from a dict, or from "NAME=LO:HI" strings (one, or a list) as the CLI takes them."""
    if isinstance(value, dict):
        return value
    out = {}
    for item in [value] if isinstance(value, str) else value:
        name, _, rest = str(item).partition("=")
        lower, colon, upper = rest.partition(":")
        if not name.strip() or not colon:
            raise ValueError(f"{keyword}: {item!r} is not {form}")
        out[name.strip()] = tuple(float(v) if v.strip() else None for v in (lower, upper))
    return out


def ranges(value, keyword, add, name_field="name"):
    for name, limits in _text_ranges(value, keyword, f"{name_field.upper()}=LO:HI").items():
        lower, upper = _range(limits, keyword, name)
        item = add(**{name_field: name})
        if lower is not None:
            item.lower = float(lower)
        if upper is not None:
            item.upper = float(upper)


def _fixed(value, keyword, repeated):
    if isinstance(value, str):
        value = _names(value, keyword)
    if not isinstance(value, dict):
        value = dict(n.split("=", 1) if "=" in n else (n, None) for n in value)
    for name, at in value.items():
        item = repeated.add(name=name.strip())
        if at is not None:
            item.value = float(at)


def _at_least_minimum(s, value):
    """A value below the setting's declared minimum (horizon=0, passes=0) is refused, as
    the CLI and the workbench refuse it, rather than sent as the field's "unset" 0."""
    if s.option.HasField("minimum") and value < s.option.minimum:
        raise ValueError(f"{s.keyword}: {value:g} is below the least value, {s.option.minimum:g}")
    return value


def set_setting(request, s, value):
    """Writes `value` (as the keyword takes it) into the request at the setting's path."""
    holder = request
    for f in s.chain[:-1]:
        holder = getattr(holder, f.name)
    name, keyword = s.field.name, s.keyword
    if s.kind == "number":
        setattr(holder, name, _at_least_minimum(s, float(value)))
    elif s.kind == "count":
        setattr(holder, name, _at_least_minimum(s, _uint(value, keyword)))
    elif s.kind == "switch":
        if not isinstance(value, bool):
            raise TypeError(f"{keyword}: expected True or False, not {value!r}")
        setattr(holder, name, value)
    elif s.kind == "text":
        setattr(holder, name, str(value))
    elif s.kind == "choice":
        setattr(holder, name, enum_number(s.field.enum_type, value, keyword))
    elif s.kind == "numbers":
        getattr(holder, name).extend(_floats(value, keyword))
    elif s.kind == "names":
        getattr(holder, name).extend(_names(value, keyword, s.option.implicit))
    elif s.kind == "covariance":
        getattr(holder, name).CopyFrom(covariance(value, keyword))
    elif s.kind == "initial_state":
        getattr(holder, name).MergeFrom(initial_state(value, keyword))  # beside initial_state.estimate
    elif s.kind == "bounds":
        ranges(value, keyword, getattr(holder, name).add)
    elif s.kind == "fixed":
        _fixed(value, keyword, getattr(holder, name))
    else:
        raise TypeError(f"{keyword}: a {s.kind} setting cannot be given from Python")


def fill(request, kw):
    """Every keyword of `kw` that is a setting of the request, written in; the keywords that are not."""
    schema = settings_of(request)
    rest = {}
    for keyword, value in kw.items():
        if keyword not in schema:
            rest[keyword] = value
        elif value is not None and value is not False:
            set_setting(request, schema[keyword], value)
    return rest


# --------------------------------------------------------------------------- what the schema does not hold

# Structure rather than settings, as the CLI's --experiment, --exclude and --output-limit.
IDENTIFY_EXTRAS = ("experiment", "exclude", "output_limit")


def sample_mask(request_mask, kw, experiment):
    """Experiment `experiment`'s (1-based) mask: every output limit, and its excluded ranges."""
    if kw.get("output_limit"):
        ranges(kw["output_limit"], "output_limit", request_mask.limits.add, name_field="output")
    for span in kw.get("exclude") or ():
        span = tuple(span)
        if len(span) == 2:
            span = (1,) + span
        if len(span) != 3:
            raise ValueError(f"exclude: expected (first, end) or (experiment, first, end), not {span!r}")
        if span[0] == experiment:
            request_mask.excluded.add(first=_uint(span[1], "exclude"), end=_uint(span[2], "exclude"))


def check_experiments(kw, count):
    for span in kw.get("exclude") or ():
        span = tuple(span)
        if len(span) == 3 and not 1 <= span[0] <= count:
            raise ValueError(f"exclude: there is no experiment {span[0]} (1 is the dataset"
                             + (f", 2 to {count} the experiment= records" if count > 1 else "") + ")")
