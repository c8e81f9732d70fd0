"""riccati.Client: riccatid's API from Python, named as the CLI names it."""
import os
import uuid

import grpc
import numpy as np
import pandas as pd

from . import _connection, _data, _settings, errors, results
from .jobs import Job
from .sessions import Session
from .v1 import datasets_pb2, datasets_pb2_grpc, jobs_pb2, jobs_pb2_grpc, models_pb2, models_pb2_grpc
from .v1 import sessions_pb2, sessions_pb2_grpc

_CHUNK = 64 * 1024


class Dataset:
    """A dataset stored by riccatid: id, name, input_names, output_names, samples, t_start, t_end,
    true_parameters (a dict, empty unless the upload declared them)."""

    def __init__(self, info):
        self.proto = info
        self.id = info.id
        self.name = info.name
        self.input_names = list(info.input_names)
        self.output_names = list(info.output_names)
        self.samples = info.samples
        self.t_start = info.t_start
        self.t_end = info.t_end
        self.true_parameters = dict(info.true_parameters)

    def __repr__(self):
        return f"<Dataset {self.id} {self.name!r}: {self.samples} samples>"


class Client:
    """A connection to riccatid.

        c = riccati.Client("127.0.0.1:7531")     # or Client(): RICCATI_SERVER, the config file, the default

    token: the bearer token (else RICCATI_TOKEN_FILE, RICCATI_TOKEN or the
    config file's token_file); tls: None (from the environment and config
    file, as the CLI), False, True (the system's roots) or riccati.TLS(ca=,
    cert=, key=, server_name=) with file paths. timeout: seconds for each
    call but the waits for jobs and streams.
    """

    def __init__(self, addr=None, token=None, tls=None, token_file=None, timeout=60.0):
        self.connection = _connection.resolve(addr, token, tls, token_file)
        self.server = self.connection.server
        self.timeout = timeout
        options = [("grpc.max_receive_message_length", -1), ("grpc.max_send_message_length", -1)]
        if self.connection.tls:
            credentials = grpc.ssl_channel_credentials(self.connection.ca_pem, self.connection.key_pem,
                                                       self.connection.cert_pem)
            if self.connection.tls_server_name:
                options.append(("grpc.ssl_target_name_override", self.connection.tls_server_name))
            self._channel = grpc.secure_channel(self.server, credentials, options)
        else:
            self._channel = grpc.insecure_channel(self.server, options)
        self._metadata = (("authorization", "Bearer " + self.connection.token),) if self.connection.token else ()
        self._models = models_pb2_grpc.ModelServiceStub(self._channel)
        self._datasets = datasets_pb2_grpc.DatasetServiceStub(self._channel)
        self._jobs = jobs_pb2_grpc.JobServiceStub(self._channel)
        self._sessions = sessions_pb2_grpc.SessionServiceStub(self._channel)
        self._model_cache = {}

    def close(self):
        self._channel.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self):
        return f"<riccati.Client {self.server}>"

    # ------------------------------------------------------------ calls

    def _error(self, e, what):
        return errors.from_rpc_error(e, what, self.server)

    def _call(self, what, method, request):
        try:
            return method(request, timeout=self.timeout, metadata=self._metadata)
        except grpc.RpcError as e:
            raise self._error(e, what) from None

    def _create(self, what, method, request):
        """A creating call, tried again (up to twice) when riccatid could not be
        reached or the deadline passed: the request carries a request_id, so a
        retry gets the object the first try made, never a second one."""
        for attempt in range(3):
            try:
                return method(request, timeout=self.timeout, metadata=self._metadata)
            except grpc.RpcError as e:
                if attempt == 2 or e.code() not in (grpc.StatusCode.UNAVAILABLE, grpc.StatusCode.DEADLINE_EXCEEDED):
                    raise self._error(e, what) from None

    def _stream_call(self, method, request):
        return method(request, metadata=self._metadata)

    # ------------------------------------------------------------ models

    def models(self):
        """The models riccatid has loaded (riccati.v1.ModelInfo messages)."""
        return list(self._call("listing models", self._models.ListModels, models_pb2.ListModelsRequest()).models)

    def model(self, name):
        """A model's ModelInfo: names of states, parameters, inputs, outputs, defaults and bounds."""
        if name not in self._model_cache:
            self._model_cache[name] = self._call("model " + name, self._models.GetModel,
                                                 models_pb2.GetModelRequest(name=name))
        return self._model_cache[name]

    def simulate(self, model, t, u, x0, params=None, estimate=None, **settings):
        """Open-loop simulation: a DataFrame indexed by t with the outputs, then the states.

        params: what the CLI's --params takes (see parameters()); None: the
        model's defaults. Settings as `riccati simulate`'s flags: hold,
        integrator, substeps, rtol, atol, max_steps."""
        _settings.check_keywords(settings, _settings.settings_of(models_pb2.SimulateRequest), "simulate")
        info = self.model(model)
        t = np.asarray(t, dtype=float)
        u = np.asarray(u, dtype=float).reshape(len(t), -1) if np.size(u) else np.zeros((len(t), 0))
        request = models_pb2.SimulateRequest(model=model, t=t.tolist(), x0=np.atleast_1d(x0).astype(float).tolist())
        if params is not None or estimate is not None:
            request.theta.extend(self.parameters(model, params, estimate))
        request.u.rows, request.u.cols = u.shape[1], len(t)
        request.u.values.extend(u.T.flatten(order="F").tolist())
        _settings.fill(request, settings)
        response = self._call("simulating " + model, self._models.Simulate, request)
        y = results.matrix(response.y)
        x = results.matrix(response.x)
        return pd.DataFrame(np.column_stack([y.T, x.T]), index=pd.Index(t, name="t"),
                            columns=list(info.output_names) + list(info.state_names))

    def parameters(self, model, params, estimate=None):
        """Parameter values from what the CLI's --params takes: an identification's
        Job, result or job id (its estimate: for the iterated filter the mean over
        its last pass, or with estimate="final" the estimate at its end), a YAML
        file with theta: [...], "10,5,0.0791,0.1342", a list, or a Series by
        parameter name."""
        job_id = None
        if isinstance(params, Job):
            job_id = params.id
        elif isinstance(params, results._Result):
            job_id = params.job_id
        elif isinstance(params, str) and params.startswith("job-"):
            job_id = params
        if job_id is not None:
            r = self._call("result of job " + job_id, self._jobs.GetResult, jobs_pb2.GetResultRequest(job_id=job_id))
            if r.HasField("estimation"):
                if estimate is not None:  # as riccatid says of a validation asking the same
                    raise ValueError(f"estimate: job {job_id} is an output-error or likelihood identification, "
                                     "with one estimate; the choice is the iterated filter's")
                return list(r.estimation.theta)
            if not r.HasField("identification"):
                raise ValueError(f"params: job {job_id} is not an identification")
            final = estimate is not None and _settings.enum_number(
                jobs_pb2.EstimateChoice.DESCRIPTOR, estimate, "estimate") == jobs_pb2.ESTIMATE_CHOICE_FINAL
            return list(r.identification.theta if final else r.identification.theta_mean)
        if estimate is not None:
            raise ValueError(f"estimate chooses among an identification job's estimates; params {params!r} is not one")
        if isinstance(params, str) and os.path.isfile(params):
            import yaml  # Debian's python3-yaml; only for a parameter file
            with open(params) as f:
                theta = (yaml.safe_load(f) or {}).get("theta")
            if theta is None:
                raise ValueError(f"params: {params} has no theta: [...]")
            params = theta
        elif isinstance(params, str):
            try:
                params = [float(v) for v in params.split(",")]
            except ValueError:
                raise ValueError(f"params: {params!r} is not a list of numbers (give a job, its id, a YAML file "
                                 "or numbers)") from None
        if isinstance(params, pd.Series):
            names = list(self.model(model).param_names)
            params = params.reindex(names) if set(params.index) == set(names) else params
        return np.atleast_1d(np.asarray(params, dtype=float)).tolist()

    # ------------------------------------------------------------ datasets

    def upload(self, data, inputs=None, outputs=None, time="t", name=None, request_id=None, ts=None,
               true_parameters=None):
        """Stores a dataset: a CSV or MAT file's path, a pandas DataFrame (a time
        column, else its index, and the columns named by inputs and outputs), or
        (t, u, y) numpy arrays with a sample per row. Returns a Dataset (its .id).
        ts: the sample time of a CSV file or DataFrame without a time column
        (t = k * ts), as the CLI's --ts. true_parameters: {name: value}, the
        parameters the data was made with, as the CLI's --truth (the workbench's
        result table then shows each estimate's error). request_id (default: a
        new UUID) makes a retry get the same dataset."""
        file_name, content, inputs, outputs, time = _data.as_upload(data, inputs, outputs, time, ts)
        header = datasets_pb2.UploadHeader(name=name or file_name, time_column=time,
                                           input_columns=list(inputs or []), output_columns=list(outputs or []),
                                           request_id=request_id or str(uuid.uuid4()), size_bytes=len(content),
                                           sample_time=float(ts or 0.0),
                                           true_parameters={str(k): float(v) for k, v in
                                                            (true_parameters or {}).items()})

        def parts():
            yield datasets_pb2.UploadDatasetRequest(header=header)
            for start in range(0, len(content), _CHUNK):
                yield datasets_pb2.UploadDatasetRequest(chunk=content[start:start + _CHUNK])

        return Dataset(self._create("uploading " + (name or file_name),
                                    lambda _, **kw: self._datasets.UploadDataset(parts(), **kw), None))

    def dataset(self, id):
        return Dataset(self._call("dataset " + id, self._datasets.GetDataset, datasets_pb2.GetDatasetRequest(id=id)))

    def datasets(self):
        return [Dataset(d) for d in self._call("listing datasets", self._datasets.ListDatasets,
                                               datasets_pb2.ListDatasetsRequest()).datasets]

    def delete_dataset(self, ds):
        self._call("deleting dataset", self._datasets.DeleteDataset,
                   datasets_pb2.DeleteDatasetRequest(id=self._dataset_id(ds)))

    def dataset_data(self, ds):
        """A dataset's samples: a DataFrame indexed by t, its inputs then its outputs."""
        data = self._call("dataset", self._datasets.GetDatasetData,
                          datasets_pb2.GetDatasetRequest(id=self._dataset_id(ds)))
        u, y = results.matrix(data.u), results.matrix(data.y)
        return pd.DataFrame(np.column_stack([u.T, y.T]), index=pd.Index(list(data.t), name="t"),
                            columns=list(data.info.input_names) + list(data.info.output_names))

    def _dataset_id(self, ds, inputs=None, outputs=None, model=None):
        """A dataset's id: a Dataset, an id, or data to upload (a path to a file, a DataFrame, arrays),
        its columns named by inputs and outputs, or, when neither is given, as the model's."""
        if isinstance(ds, Dataset):
            return ds.id
        if isinstance(ds, str) and not os.path.isfile(ds):
            return ds
        if inputs is None and outputs is None and model is not None:
            info = self.model(model)
            inputs, outputs = list(info.input_names), list(info.output_names)
        return self.upload(ds, inputs=inputs, outputs=outputs).id

    # ------------------------------------------------------------ jobs

    def job(self, id):
        return Job(self, self._call("job " + id, self._jobs.GetJob, jobs_pb2.GetJobRequest(id=id)))

    def jobs(self):
        return [Job(self, j) for j in self._call("listing jobs", self._jobs.ListJobs,
                                                 jobs_pb2.ListJobsRequest()).jobs]

    def result(self, job, model=None):
        """A finished job's result (see riccati.results)."""
        job_id = job.id if isinstance(job, Job) else job
        if model is None:
            model = (job if isinstance(job, Job) else self.job(job_id)).model
        message = self._call("result of job " + job_id, self._jobs.GetResult,
                             jobs_pb2.GetResultRequest(job_id=job_id))
        return results.from_proto(message, self.model(model))

    def compare(self, *jobs, data=None, horizon=None, inputs=None, outputs=None):
        """Output-error and likelihood fits side by side, as `riccati compare` (riccatid
        compares: CompareJobs). jobs: Jobs, results or job ids. A Comparison: .table by job
        (model, method, k, n, log_likelihood, aic, aicc, bic, lowest_aic, lowest_bic and
        fit_percent.<output>), .tests the likelihood-ratio test of each nested pair
        (smaller, larger, statistic, dof, p, significant).

        data: a common validation record (a Dataset, its id, or data to upload, with
        inputs and outputs naming its columns): each job is validated on it
        (simulated, or with horizon=K predicted K samples ahead with its filter and
        noise model) and .table has validation_fit_percent.<output> too, as
        `riccati compare --data`."""
        if horizon is not None and data is None:
            raise TypeError("compare(): horizon needs data, the common validation record")
        ids = [j.id if isinstance(j, Job) else j.job_id if isinstance(j, results._Result) else j for j in jobs]
        request = jobs_pb2.CompareJobsRequest(job_ids=ids)
        message = self._call("comparing the jobs", self._jobs.CompareJobs, request)
        if data is not None:
            dataset = self._dataset_id(data, inputs, outputs, message.jobs[0].model if message.jobs else None)
            extra = {} if horizon is None else {"horizon": horizon}
            for j in message.jobs:
                validation = self.submit_validation(j.model, dataset, j.job_id, **extra)
                validation.result()
                request.validation_job_ids.append(validation.id)
            message = self._call("comparing the jobs", self._jobs.CompareJobs, request)
        return results.Comparison(message)

    def submit_identification(self, model, ds, inputs=None, outputs=None, request_id=None, **settings):
        """Submits an identification; returns its Job (watch(), cancel(), result()).

        ds: a Dataset, its id, or data to upload (see upload(); inputs and
        outputs name its columns). The settings are keywords named as the CLI's
        flags of `riccati identify`, made from the API's schema (see
        riccati._settings): method, filter, passes, theta0, p0, q, r, x0, hold,
        integrator, substeps, bound, fix, log_scale, estimate_x0, output_sigma,
        estimate_r, ...; and experiment (more records: datasets, ids or data),
        exclude and output_limit.

        request_id (default: a new UUID) names the request: a retry with it
        (this client retries once riccatid is unreachable or the deadline
        passed) gets the job the first try made."""
        _settings.check_keywords(settings, [*_settings.settings_of(jobs_pb2.IdentificationSpec),
                                            *_settings.IDENTIFY_EXTRAS], "identify")
        dataset = self._dataset_id(ds, inputs, outputs, model)
        more = [self._dataset_id(e, inputs, outputs, model) for e in settings.get("experiment") or ()]
        spec = jobs_pb2.IdentificationSpec(model=model, dataset_id=dataset)
        extras = _settings.fill(spec, settings)
        _settings.check_experiments(extras, 1 + len(more))
        _settings.sample_mask(spec.mask, extras, 1)
        for e, dataset in enumerate(more, 2):
            experiment = spec.experiments.add(dataset_id=dataset)
            if spec.HasField("initial_state"):  # each experiment starts as the first, as the CLI sends them
                experiment.initial_state.CopyFrom(spec.initial_state)
            _settings.sample_mask(experiment.mask, extras, e)
        spec.request_id = request_id or str(uuid.uuid4())
        return Job(self, self._create("submitting the identification", self._jobs.SubmitIdentification, spec))

    def identify(self, model, ds, progress=None, **settings):
        """Identifies the model's parameters on the dataset and waits: the
        result (IdentificationResult for the iterated filter, EstimationResult
        for "oe" and "ml"). progress(job), if given, is called as the job runs."""
        return self.submit_identification(model, ds, **settings).result(progress)

    def submit_validation(self, model, ds, params, inputs=None, outputs=None, request_id=None, **settings):
        """Submits a validation: the model simulated with `params` over the dataset's inputs.

        params: an identification's Job, its id or its result (riccatid takes
        its estimate, as estimate= chooses), or what else the CLI's --params
        takes (values, a YAML file; see parameters()). Settings as `riccati
        validate`'s flags: x0, hold, integrator, substeps, rtol, atol,
        estimate, estimate_x0 (states, or True: all) and x0_samples."""
        _settings.check_keywords(settings, _settings.settings_of(jobs_pb2.ValidationSpec), "validate")
        spec = jobs_pb2.ValidationSpec(model=model, dataset_id=self._dataset_id(ds, inputs, outputs, model))
        _settings.fill(spec, settings)
        if isinstance(params, Job):
            spec.identification_job_id = params.id
        elif isinstance(params, results._Result):
            spec.identification_job_id = params.job_id
        elif isinstance(params, str) and params.startswith("job-"):
            spec.identification_job_id = params
        else:
            spec.theta.values.extend(self.parameters(model, params))
        spec.request_id = request_id or str(uuid.uuid4())
        return Job(self, self._create("submitting the validation", self._jobs.SubmitValidation, spec))

    def validate(self, model, ds, params, progress=None, **settings):
        """Validates and waits: a ValidationResult (.fits, .to_frame())."""
        return self.submit_validation(model, ds, params, **settings).result(progress)

    def submit_smoothing(self, model, ds, inputs=None, outputs=None, request_id=None, params=None, estimate=None,
                         **settings):
        """Submits fixed-interval smoothing (the EKF's RTS smoother, or the UKF's); settings as
        `riccati smooth`'s flags. params: the parameters it starts from, as the CLI's --params
        (a job, its id or result, with estimate= choosing; values; see parameters()), instead of theta0."""
        _settings.check_keywords(settings, _settings.settings_of(jobs_pb2.SmoothingSpec), "smooth")
        if params is not None and settings.get("theta0") is not None:
            raise TypeError("smooth(): give params or theta0, not both")
        spec = jobs_pb2.SmoothingSpec(model=model, dataset_id=self._dataset_id(ds, inputs, outputs, model))
        _settings.fill(spec, settings)
        if params is not None or estimate is not None:
            spec.theta0.extend(self.parameters(model, params, estimate))
        spec.request_id = request_id or str(uuid.uuid4())
        return Job(self, self._create("submitting the smoothing", self._jobs.SubmitSmoothing, spec))

    def smooth(self, model, ds, progress=None, **settings):
        return self.submit_smoothing(model, ds, **settings).result(progress)

    # ------------------------------------------------------------ sessions

    def session(self, model, close=True, full_covariance=False, batch=100, request_id=None, **settings):
        """Creates a filter session (use it in a `with` block); settings as
        `riccati stream`'s flags: filter, x0, theta0, p0, q, r, hold, integrator, ..."""
        _settings.check_keywords(settings, _settings.settings_of(sessions_pb2.CreateSessionRequest), "session")
        request = sessions_pb2.CreateSessionRequest(model=model)
        _settings.fill(request, settings)
        request.request_id = request_id or str(uuid.uuid4())
        info = self._create("creating the session", self._sessions.CreateSession, request)
        return Session(self, info, self.model(model), close=close, full_covariance=full_covariance, batch=batch)
