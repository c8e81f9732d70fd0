"""Results of jobs, as pandas objects indexed by the model's names.

Every result keeps the message riccatid sent as `.proto` (riccati.v1 types),
for anything not shown here. to_frame() names its columns as the CLI's CSV
and MAT exports do (docs/results.md): a state or parameter by its name
("h1", "A1"), anything else as quantity.name ("y.h1", "y_model.h1",
"residual.h1", "std.A1").
"""
import numpy as np
import pandas as pd

from ._settings import enum_name
from .v1 import jobs_pb2

# The two-sided 95 % quantile of the normal distribution (the iterated
# filter's intervals; output error and likelihood send their own).
Z95 = 1.959963984540054


def matrix(m):
    """A riccati.v1.Matrix (column-major) as a numpy array of rows x cols."""
    return np.asarray(m.values, dtype=float).reshape((m.cols, m.rows)).T if m.rows and m.cols else \
        np.zeros((m.rows, m.cols))


def _names(names, count, prefix):
    names = list(names)
    return names if len(names) == count else [f"{prefix}{i + 1}" for i in range(count)]


def _series(values, names, name):
    values = np.asarray(values, dtype=float)
    return pd.Series(values, index=pd.Index(_names(names, len(values), "p"), name="parameter"), name=name)


def _correlation(covariance):
    std = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    with np.errstate(divide="ignore", invalid="ignore"):
        out = covariance / np.outer(std, std)
    return out


def column(quantity, name):
    """The one naming of exported columns (docs/results.md): "y_model.h1"; a
    state or parameter (quantity "") by its name alone."""
    return f"{quantity}.{name}" if quantity else name


def _frame(m, columns, t):
    """A variables x N matrix as a frame indexed by time, a column per variable."""
    a = matrix(m)
    return pd.DataFrame(a.T, index=pd.Index(t, name="t"), columns=_names(columns, a.shape[0], "v"))


def _figure(rows):
    """A matplotlib Figure with a subplot per row, sharing x. Figure, not pyplot:
    no backend is chosen or changed, so it works headless and beside a GUI."""
    try:
        from matplotlib.figure import Figure
    except ImportError as e:  # an optional dependency (Debian: python3-matplotlib)
        raise ImportError("plots need matplotlib (Debian: apt install python3-matplotlib)") from e
    fig = Figure(figsize=(8, 1.8 + 1.6 * rows), layout="constrained")
    return fig, fig.subplots(rows, 1, sharex=True, squeeze=False)[:, 0]


def _save(fig, path):
    """Saved to `path` when given (the format from its extension: .png, .svg, .pdf)."""
    if path is not None:
        fig.savefig(path)
    return fig


def _fits(fits):
    return pd.DataFrame({"rmse": [f.rmse for f in fits], "fit_percent": [f.fit_percent for f in fits],
                         "vaf_percent": [f.vaf_percent for f in fits], "rrse": [f.rrse for f in fits]},
                        index=pd.Index([f.name for f in fits], name="output"))


class _Result:
    def __init__(self, job_id, message, model):
        self.job_id = job_id
        self.proto = message
        self.model = model  # riccati.v1.ModelInfo of the job's model

    def _describe(self):
        return ""

    def __repr__(self):
        what = self._describe()
        return f"<{type(self).__name__} of job {self.job_id}, model {self.model.name}" + \
            (f": {what}>" if what else ">")


def _values(series):
    return ", ".join(f"{n} = {v:.6g}" for n, v in series.items())


class IdentificationResult(_Result):
    """The iterated filter's result (method "filter", the 1999 toolbox's multi-pass rule).

    - theta: the mean over the last pass (what the toolbox reports), a Series by parameter
    - theta_final: the estimate at the end of the last pass
    - std: the standard errors of theta: output error's at that estimate, not the
      filter's P (which counts the record once per pass); covariance_method says which
    - ci: the 95 % intervals (columns lower, upper): the simulation error optimum's,
      one Gauss-Newton step (theta_step) from theta, widened to hold theta
    - filter_std: sqrt(diag P) of the parameters at the end (the toolbox's std)
    - summary(): those in one table, as `riccati result` prints it
    - covariance, correlation: of the parameters (DataFrames), std's; filter_covariance:
      the parameters' block of the filter's P at the end
    - traces: the estimate after every sample of every pass, a DataFrame
      indexed by (pass, t), a column per parameter (the toolbox's Trace)
    - passes: per pass, its final and mean estimate (final.A1, mean.A1), NIS
      (nis_mean) and innovation RMS (innovation_rms.h1)
    - to_frame(): the last pass by sample: states, model outputs (y_model.o,
      the toolbox's Ymod), innovations (innovation.o)
    """

    def __init__(self, job_id, message, model):
        super().__init__(job_id, message, model)
        r = message
        names = list(r.param_names)
        self.param_names = names
        self.theta = _series(r.theta_mean, names, "theta")
        self.theta_final = _series(r.theta, names, "theta_final")
        self.std = _series(r.theta_std, names, "std")
        self.covariance_method = r.covariance_method
        n = len(names)
        index = pd.Index(names, name="parameter")
        if len(r.ci_lower) == n and len(r.ci_upper) == n:
            self.ci = pd.DataFrame({"lower": list(r.ci_lower), "upper": list(r.ci_upper)}, index=index)
        else:  # stored before the intervals: std was sqrt(diag P)
            self.ci = pd.DataFrame({"lower": self.theta - Z95 * self.std, "upper": self.theta + Z95 * self.std})
        self.filter_std = _series(r.filter_theta_std, names, "filter_std") if len(r.filter_theta_std) == n else self.std
        self.theta_step = _series(r.theta_step, names, "theta_step") if len(r.theta_step) == n else None
        p = matrix(r.covariance)
        filter_block = p[-n:, -n:] if p.shape[0] >= n and n > 0 else np.zeros((n, n))
        self.filter_covariance = pd.DataFrame(filter_block, index=index, columns=names)
        block = matrix(r.theta_covariance)
        if block.shape != (n, n):
            block = filter_block
        self.covariance = pd.DataFrame(block, index=index, columns=names)
        self.correlation = pd.DataFrame(_correlation(block), index=index, columns=names)
        self.warnings = list(r.warnings)
        t = np.asarray(r.t, dtype=float)
        traces = []
        for k, p_result in enumerate(r.passes, 1):
            trace = matrix(p_result.theta_trace)
            times = t if trace.shape[1] == len(t) else np.arange(trace.shape[1], dtype=float)
            traces.append(pd.DataFrame(trace.T, columns=names,
                                       index=pd.MultiIndex.from_arrays([np.full(len(times), k), times],
                                                                       names=["pass", "t"])))
        self.traces = pd.concat(traces) if traces else pd.DataFrame(columns=names)
        self.passes = pd.DataFrame(
            [{"nis_mean": p_result.nis_mean,
              **{column("final", n_): v for n_, v in zip(names, p_result.theta_final)},
              **{column("mean", n_): v for n_, v in zip(names, p_result.theta_mean)},
              **{column("innovation_rms", o): v for o, v in zip(model.output_names, p_result.innovation_rms)}}
             for p_result in r.passes], index=pd.Index(range(1, len(r.passes) + 1), name="pass"))

    def summary(self):
        """The parameter table, as `riccati result` prints it: the estimate (the
        mean over the last pass), its standard error, the 95 % interval, the std
        relative to the estimate (%), the filter's own std (sqrt(diag P)) and the
        estimate at the end of the last pass."""
        with np.errstate(divide="ignore", invalid="ignore"):
            relative = 100.0 * self.std / self.theta.abs()
        return pd.DataFrame({"estimate": self.theta, "std": self.std, "lower": self.ci["lower"],
                             "upper": self.ci["upper"], "rel_std_percent": relative, "filter_std": self.filter_std,
                             "final": self.theta_final})

    def plot_traces(self, path=None):
        """The parameters' traces (the toolbox's Trace), a subplot per parameter, the
        passes one after the other with a line between them, and the reported estimate
        (the mean over the last pass). Returns the matplotlib Figure; saves it to `path`
        if given (PNG, SVG, ... by the extension)."""
        fig, axes = _figure(len(self.param_names))
        for ax, name in zip(axes, self.param_names):
            x = 0
            for k, trace in self.traces[name].groupby(level="pass"):
                ax.plot(np.arange(x, x + len(trace)), trace.to_numpy(), color="C0", lw=1)
                x += len(trace)
                ax.axvline(x, color="0.8", lw=0.8)
            ax.axhline(self.theta[name], color="C1", lw=1, ls="--", label=f"estimate {self.theta[name]:.6g}")
            ax.set_ylabel(name)
            ax.legend(loc="upper right", fontsize="small")
        axes[-1].set_xlabel("sample (passes one after the other)")
        fig.suptitle(f"{self.model.name}: parameter traces, job {self.job_id}")
        return _save(fig, path)

    def to_frame(self):
        """The last pass by sample: the states (h1), the model's outputs along it
        (y_model.h1, the toolbox's Ymod) and the innovations (innovation.h1)."""
        r = self.proto
        t = np.asarray(r.t, dtype=float)
        outputs = self.model.output_names
        parts = [_frame(r.x_trace, self.model.state_names, t),
                 _frame(r.y_model, [column("y_model", o) for o in outputs], t),
                 _frame(r.innovations, [column("innovation", o) for o in outputs], t)]
        return pd.concat(parts, axis=1)

    def _describe(self):
        return f"iterated filter, {len(self.proto.passes)} passes, theta {_values(self.theta)}"


class Diagnostics:
    """The residual tests of one record, each at 95 %, as riccatid computed them
    (statistics, limits, p-values and degrees of freedom; nothing recomputed here).

    - whiteness: per output, Ljung-Box Q over lags 1..h (a DataFrame by output)
    - independence: per output and input, N R^2 of the residual on the input at
      lags 0..h (by (output, input)); dof 0 and no p-value for a constant input
    - nis: the mean NIS against its two-sided band (one row; empty without a NIS)
    - to_frame(): the three in one frame, a row per test, with a "test" column
    - white, uncorrelated_with_inputs, nis_consistent, passed: the verdicts
    - summary: riccatid's text, one line per test

    Each frame has the columns statistic, limit, p_value, dof and verdict ("pass"
    or "fail"); NIS's limit is its band's upper end, with lower beside it.
    """

    def __init__(self, message, output_names, input_names):
        d = message
        self.proto = d
        outputs = _names(output_names, len(d.ljung_box), "y")
        ny = len(outputs)
        nu = len(d.cross_statistic) // ny if ny else 0
        inputs = _names(input_names, nu, "u")
        self.samples, self.lags, self.band = d.samples, d.lags, d.band

        def verdict(ok):
            return "pass" if ok else "fail"

        def column(values, count):  # a stored result from before riccatid sent them: NaN
            values = list(values)
            return values if len(values) == count else [np.nan] * count

        self.whiteness = pd.DataFrame(
            {"statistic": list(d.ljung_box), "limit": [d.ljung_box_limit] * ny,
             "p_value": column(d.ljung_box_p, ny), "dof": [d.ljung_box_dof or np.nan] * ny,
             "verdict": [verdict(q <= d.ljung_box_limit) for q in d.ljung_box]},
            index=pd.Index(outputs, name="output"))
        pairs = ny * nu
        limits = list(d.cross_limit)
        tested = [limit > 0 for limit in limits]  # a constant input has no limit, 0 dof: not tested
        self.independence = pd.DataFrame(
            {"statistic": list(d.cross_statistic), "limit": limits,
             "p_value": [p if t else np.nan for p, t in zip(column(d.cross_p, pairs), tested)],
             "dof": column(d.cross_dof, pairs),
             "verdict": [verdict(not t or s <= limit) for s, limit, t in zip(d.cross_statistic, limits, tested)]},
            index=pd.MultiIndex.from_tuples([(outputs[k // nu], inputs[k % nu]) for k in range(pairs)],
                                            names=["output", "input"]))
        has_nis = bool(np.isfinite(d.nis_mean))
        self.nis = pd.DataFrame(
            {"statistic": [d.nis_mean], "lower": [d.nis_lower], "limit": [d.nis_upper],
             "p_value": [d.nis_p if d.nis_dof else np.nan], "dof": [d.nis_dof or np.nan],
             "verdict": [verdict(d.nis_consistent)]} if has_nis else
            {c: [] for c in ("statistic", "lower", "limit", "p_value", "dof", "verdict")},
            index=pd.Index(["mean NIS"] if has_nis else [], name="test"))
        self.white, self.uncorrelated_with_inputs = d.white, d.uncorrelated_with_inputs
        self.nis_consistent = d.nis_consistent
        self.passed = self.white and self.uncorrelated_with_inputs and self.nis_consistent
        self.summary = d.summary

    def to_frame(self):
        """A row per test: test ("whiteness", "independence", "nis"), output, input
        (empty where the test has none), statistic, limit, p_value, dof, verdict."""
        columns = ["test", "output", "input", "statistic", "limit", "p_value", "dof", "verdict"]
        w = self.whiteness.reset_index().assign(test="whiteness", input="")
        i = self.independence.reset_index().assign(test="independence")
        n = self.nis.reset_index(drop=True).assign(test="nis", output="", input="")
        return pd.concat([w[columns], i[columns], n[columns]], ignore_index=True)

    def __repr__(self):
        return self.to_frame().to_string(index=False)


class ExperimentFit(_Result):
    """What an output-error or likelihood estimate does on one record."""

    def __init__(self, job_id, message, model):
        super().__init__(job_id, message, model)
        e = message
        self.dataset_id = e.dataset_id
        states = pd.Index(_names(model.state_names, len(e.x0), "x"), name="state")
        self.x0 = pd.Series(list(e.x0), index=states, name="x0")
        self.x0_std = pd.Series(list(e.x0_std), index=states[:len(e.x0_std)], name="std")
        self.fits = _fits(e.fits)
        # named by the fits' outputs (else the model's) and the model's inputs
        self.diagnostics = Diagnostics(e.diagnostics, [f.name for f in e.fits] or model.output_names,
                                       model.input_names)

    def to_frame(self):
        """By sample, per output o: y.o measured, y_model.o (OE: simulated, ML: one
        step ahead), residual.o = y - y_model in the output's unit,
        residual_normalised.o (what the diagnostics test: OE divided by sigma, ML
        whitened by the innovation covariance; 0 where left out), used.o."""
        e = self.proto
        t = np.asarray(e.t, dtype=float)
        outputs = list(self.model.output_names)
        y = _frame(e.y_measured, [column("y", o) for o in outputs], t)
        y_model = _frame(e.y_model, [column("y_model", o) for o in outputs], t)
        raw = pd.DataFrame(y.to_numpy() - y_model.to_numpy(), index=y.index,
                           columns=[column("residual", o) for o in outputs])
        parts = [y, y_model, raw, _frame(e.residuals, [column("residual_normalised", o) for o in outputs], t)]
        used = _frame(e.mask, [column("used", o) for o in outputs], t).astype(bool)
        return pd.concat(parts + [used], axis=1)

    def _describe(self):
        return f"dataset {self.dataset_id}"


class EstimationResult(_Result):
    """An output-error ("oe") or maximum-likelihood ("ml") identification.

    - theta, std: Series by parameter (std 0 for a fixed one, inf for one the data do not determine)
    - ci: the 95 % intervals (columns lower, upper); fixed: a boolean Series
    - covariance_method: which covariance std comes from (white residuals, or robust
      to autocorrelated ones), in words
    - gradient: how the optimiser had its gradient (exact sensitivities, or central
      differences and why), in words
    - covariance, correlation: DataFrames by parameter
    - traces: the criterion after each iteration (a DataFrame indexed by iteration)
    - experiments: an ExperimentFit per record; fits: their fits, by (experiment, output)
    - criteria: a Series log_likelihood, aic, aicc, bic, k (quantities estimated), n
      (scalar residuals used), to compare models fitted to the same data (lower is better)
    - to_frame(): by sample, measured and model outputs and residuals (indexed
      by (experiment, t) when there are several records)
    """

    def __init__(self, job_id, message, model):
        super().__init__(job_id, message, model)
        r = message
        names = list(r.param_names)
        self.method = enum_name(jobs_pb2.IdentificationMethod.DESCRIPTOR, r.method)
        self.param_names = names
        self.theta = _series(r.theta, names, "theta")
        self.std = _series(r.theta_std, names, "std")
        self.covariance_method = r.covariance_method
        index = pd.Index(names, name="parameter")
        self.ci = pd.DataFrame({"lower": list(r.ci_lower), "upper": list(r.ci_upper)}, index=index)
        self.fixed = pd.Series(list(r.fixed), index=index, name="fixed", dtype=bool)
        self.covariance = pd.DataFrame(matrix(r.covariance), index=index, columns=names)
        self.correlation = pd.DataFrame(matrix(r.correlation), index=index, columns=names)
        self.warnings = list(r.warnings)
        self.cost = r.cost
        self.converged = r.converged
        self.iterations = r.iterations
        self.termination = r.termination
        self.gradient = r.gradient
        self.criteria = pd.Series({"log_likelihood": r.log_likelihood, "aic": r.aic, "aicc": r.aicc, "bic": r.bic,
                                   "k": r.estimated_quantities, "n": r.samples}, name="criteria", dtype=float)
        self.traces = pd.DataFrame({"cost": list(r.cost_history)},
                                   index=pd.Index(range(1, len(r.cost_history) + 1), name="iteration"))
        self.experiments = [ExperimentFit(job_id, e, model) for e in r.experiments]
        self.fits = pd.concat([e.fits for e in self.experiments], keys=range(1, len(self.experiments) + 1),
                              names=["experiment"]) if self.experiments else _fits([])
        if len(self.experiments) == 1:
            self.fits = self.experiments[0].fits
        self.init_passes = (IdentificationResult(job_id, r.init_passes, model)
                            if r.HasField("init_passes") and len(r.init_passes.passes) > 0 else None)

    def to_frame(self):
        frames = [e.to_frame() for e in self.experiments]
        if len(frames) == 1:
            return frames[0]
        return pd.concat(frames, keys=range(1, len(frames) + 1), names=["experiment"])

    def summary(self):
        """The parameter table, as `riccati result` prints it: by parameter the
        estimate, its standard error, the 95 % interval, the standard error
        relative to the estimate (%) and whether it was fixed."""
        with np.errstate(divide="ignore", invalid="ignore"):
            relative = 100.0 * self.std / self.theta.abs()
        return pd.DataFrame({"estimate": self.theta, "std": self.std, "lower": self.ci["lower"],
                             "upper": self.ci["upper"], "rel_std_percent": relative, "fixed": self.fixed})

    def plot(self, path=None):
        """Per output of each experiment the measured and the model's output over
        time, with the fit %, and under it the residual (y - y_model, the
        output's unit; samples left out not drawn). Returns the matplotlib
        Figure; saves it to `path` if given (PNG, SVG, ...)."""
        outputs = list(self.model.output_names)
        rows = [(k, e, o) for k, e in enumerate(self.experiments, 1) for o in outputs]
        fig, axes = _figure(2 * len(rows))
        for i, (k, e, name) in enumerate(rows):
            frame = e.to_frame()
            fit_ax, residual_ax = axes[2 * i], axes[2 * i + 1]
            label = name if len(self.experiments) == 1 else f"{name} (exp. {k})"
            fit_ax.plot(frame.index, frame[column("y", name)], color="0.4", lw=1, label="measured")
            fit_ax.plot(frame.index, frame[column("y_model", name)], color="C1", lw=1.2,
                        label="simulated" if self.method == "oe" else "one step ahead")
            fit = e.fits.loc[name, "fit_percent"] if name in e.fits.index else float("nan")
            fit_ax.set_ylabel(label)
            fit_ax.set_title(f"{label}: fit {fit:.2f} %", fontsize="small", loc="left")
            fit_ax.legend(loc="upper right", fontsize="small")
            residual = frame[column("residual", name)].where(frame[column("used", name)])
            residual_ax.plot(frame.index, residual, color="C0", lw=0.8)
            residual_ax.axhline(0.0, color="0.6", lw=0.8)
            residual_ax.set_ylabel(f"residual {name}")
        axes[-1].set_xlabel("t [s]")
        fig.suptitle(f"{self.model.name}: {self.method} estimate, job {self.job_id}")
        return _save(fig, path)

    def _describe(self):
        end = "converged" if self.converged else "not converged"
        return f"{self.method}, {end} after {self.iterations} iterations, cost {self.cost:.6g}, " \
               f"theta {_values(self.theta)}"

    def __str__(self):
        lines = [f"{self.method} estimate of {self.model.name}, job {self.job_id}: "
                 f"{'converged' if self.converged else 'not converged'} after {self.iterations} iterations "
                 f"({self.termination}), cost {self.cost:.6g}; gradient: {self.gradient}"]
        c = self.criteria
        if c["n"] > 0:
            lines.append(f"log-likelihood {c['log_likelihood']:.10g}; AIC {c['aic']:.10g}, AICc {c['aicc']:.10g}, "
                         f"BIC {c['bic']:.10g} (k = {int(c['k'])} estimated, n = {int(c['n'])})")
        lines.append(self.summary().to_string())
        lines += [f"warning: {w}" for w in self.warnings]
        for k, e in enumerate(self.experiments, 1):
            lines += [f"experiment {k} ({e.dataset_id}):", e.fits.to_string()]
        return "\n".join(lines)


class ValidationResult(_Result):
    """The model simulated over a dataset's inputs and compared with its outputs.

    - theta: the parameters simulated with; x0: the initial states
    - fits: a DataFrame by output: rmse, fit_percent (MATLAB's compare), vaf_percent, rrse
    - horizon: 0 for the simulation; K for K-step-ahead predictions (validate(...,
      horizon=K)), by predictor (the job's filter and noise model, in words)
    - to_frame(): by sample, per output o: y.o measured, y_model.o simulated (or
      predicted) and residual.o = y - y_model (the output's unit)
    """

    def __init__(self, job_id, message, model):
        super().__init__(job_id, message, model)
        r = message
        self.theta = _series(r.theta, model.param_names, "theta")
        self.x0 = pd.Series(list(r.x0), index=pd.Index(_names(model.state_names, len(r.x0), "x"), name="state"),
                            name="x0")
        self.fits = _fits(r.fits)
        self.parameters_from = r.parameters_from
        self.x0_from = r.x0_from
        self.horizon = r.horizon
        self.predictor = r.predictor

    def plot(self, path=None):
        """Measured and simulated outputs over time, a subplot per output with its fit %.
        Returns the matplotlib Figure; saves it to `path` if given (PNG, SVG, ...)."""
        frame = self.to_frame()
        outputs = list(self.model.output_names)
        fig, axes = _figure(len(outputs))
        for ax, name in zip(axes, outputs):
            ax.plot(frame.index, frame[column("y", name)], color="0.4", lw=1, label="measured")
            ax.plot(frame.index, frame[column("y_model", name)], color="C1", lw=1.2, label="simulated")
            fit = self.fits.loc[name, "fit_percent"] if name in self.fits.index else float("nan")
            ax.set_ylabel(name)
            ax.set_title(f"{name}: fit {fit:.2f} %", fontsize="small", loc="left")
            ax.legend(loc="upper right", fontsize="small")
        axes[-1].set_xlabel("t [s]")
        fig.suptitle(f"{self.model.name}: validation, job {self.job_id}")
        return _save(fig, path)

    def to_frame(self):
        r = self.proto
        t = np.asarray(r.t, dtype=float)
        outputs = list(self.model.output_names)
        y = _frame(r.y_measured, [column("y", o) for o in outputs], t)
        y_model = _frame(r.y_simulated, [column("y_model", o) for o in outputs], t)
        raw = pd.DataFrame(y.to_numpy() - y_model.to_numpy(), index=y.index,
                           columns=[column("residual", o) for o in outputs])
        return pd.concat([y, y_model, raw], axis=1)

    def _describe(self):
        fits = ", ".join(f"{n} {f:.2f} %" for n, f in self.fits["fit_percent"].items())
        return f"validation, fit {fits}" if fits else "validation"


class SmoothingResult(_Result):
    """States and parameters given every sample: to_frame() has the smoothed
    estimate (h1, A1) and its std (std.h1) by sample; filtered() the forward
    filter's, named the same."""

    def __init__(self, job_id, message, model):
        super().__init__(job_id, message, model)
        self.names = list(message.names)

    def _pair(self, z, std):
        t = np.asarray(self.proto.t, dtype=float)
        return pd.concat([_frame(z, self.names, t), _frame(std, [column("std", n) for n in self.names], t)], axis=1)

    def to_frame(self):
        return self._pair(self.proto.z_smoothed, self.proto.std_smoothed)

    def filtered(self):
        return self._pair(self.proto.z_filtered, self.proto.std_filtered)

    def summary(self):
        """By state and parameter: the smoothed estimate and its std at the
        first and the last sample, and the filter's at the last (where the
        two agree: the smoother adds what later samples say about earlier
        ones)."""
        smoothed, filtered = self.to_frame(), self.filtered()
        first, last = smoothed.iloc[0], smoothed.iloc[-1]
        return pd.DataFrame({"first": [first[n] for n in self.names],
                             "std_first": [first[column("std", n)] for n in self.names],
                             "last": [last[n] for n in self.names],
                             "std_last": [last[column("std", n)] for n in self.names],
                             "filtered_last": [filtered.iloc[-1][n] for n in self.names]},
                            index=pd.Index(self.names, name="name"))

    def plot(self, path=None):
        """Per state and parameter the smoothed estimate with its 95 % band
        (+-1.96 std) and the forward filter's estimate over time. Returns the
        matplotlib Figure; saves it to `path` if given (PNG, SVG, ...)."""
        smoothed, filtered = self.to_frame(), self.filtered()
        fig, axes = _figure(len(self.names))
        for ax, name in zip(axes, self.names):
            half = 1.96 * smoothed[column("std", name)]
            ax.fill_between(smoothed.index, smoothed[name] - half, smoothed[name] + half, color="C0", alpha=0.2,
                            lw=0, label="smoothed, 95 %")
            ax.plot(filtered.index, filtered[name], color="C1", lw=0.9, label="filtered")
            ax.plot(smoothed.index, smoothed[name], color="C0", lw=1.2, label="smoothed")
            ax.set_ylabel(name)
            ax.legend(loc="upper right", fontsize="small")
        axes[-1].set_xlabel("t [s]")
        fig.suptitle(f"{self.model.name}: smoothed and filtered estimates, job {self.job_id}")
        return _save(fig, path)

    def _describe(self):
        return f"smoothing of {len(self.names)} states and parameters over {len(self.proto.t)} samples"


def from_proto(job_result, model):
    kind = job_result.WhichOneof("result")
    wrap = {"identification": IdentificationResult, "estimation": EstimationResult,
            "validation": ValidationResult, "smoothing": SmoothingResult}.get(kind)
    if wrap is None:
        raise ValueError(f"job {job_result.job_id}: a result this client does not know ({kind})")
    return wrap(job_result.job_id, getattr(job_result, kind), model)


class Comparison:
    """Fits side by side, as riccatid compared them (Client.compare).

    - table: a DataFrame by job: model, method, k, n, log_likelihood, aic, aicc, bic,
      lowest_aic, lowest_bic (the best of these fits by that criterion; lower is
      better among fits to the same data) and fit_percent.<output> (the first
      record's: oe's simulated, ml's one step ahead); with a common validation
      record (compare(data=...)), validation_job and validation_fit_percent.<output>
    - validation_dataset, validation_horizon: that record, and 0 (simulation) or K
    - tests: a DataFrame, a row per nested pair (the smaller model the larger with
      some parameters held): smaller, larger, statistic = 2 (ln L_larger -
      ln L_smaller), dof, p, significant (p < 0.05: the larger fits significantly better)
    """

    def __init__(self, message):
        self.proto = message
        rows = []
        for j in message.jobs:
            row = {"job": j.job_id, "model": j.model, "method": enum_name(jobs_pb2.IdentificationMethod.DESCRIPTOR,
                                                                          j.method),
                   "k": j.estimated_quantities, "n": j.samples, "log_likelihood": j.log_likelihood, "aic": j.aic,
                   "aicc": j.aicc, "bic": j.bic, "lowest_aic": j.lowest_aic, "lowest_bic": j.lowest_bic}
            for f in j.fits:
                row[column("fit_percent", f.name)] = f.fit_percent
            if message.validation_dataset_id:
                row["validation_job"] = j.validation_job_id
                for f in j.validation_fits:
                    row[column("validation_fit_percent", f.name)] = f.fit_percent
            rows.append(row)
        self.validation_dataset = message.validation_dataset_id or None
        self.validation_horizon = message.validation_horizon if message.validation_dataset_id else None
        self.table = pd.DataFrame(rows).set_index("job") if rows else pd.DataFrame()
        self.tests = pd.DataFrame([{"smaller": t.smaller, "larger": t.larger, "statistic": t.statistic, "dof": t.dof,
                                    "p": t.p, "significant": t.significant} for t in message.tests],
                                  columns=["smaller", "larger", "statistic", "dof", "p", "significant"])

    def __repr__(self):
        return f"<Comparison of {len(self.table)} jobs, {len(self.tests)} likelihood-ratio tests>"

