"""The API's contract as a client written from the .proto files meets it (issue 16)."""
import grpc
import pytest
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

import riccati
from riccati.v1 import common_pb2, datasets_pb2, jobs_pb2, models_pb2, sessions_pb2

SERVICES = ["riccati.v1.ModelService", "riccati.v1.DatasetService", "riccati.v1.JobService",
            "riccati.v1.SessionService"]


def _messages(package, fields_by_message):
    """Message classes built from their description, as a client without generated code would."""
    f = descriptor_pb2.FileDescriptorProto(name=f"{package}.test.proto", package=package, syntax="proto3")
    for name, fields in fields_by_message.items():
        m = f.message_type.add(name=name)
        for number, (field, kind, label, type_name) in enumerate(fields, 1):
            added = m.field.add(name=field, number=number, type=kind, label=label)
            if type_name:
                added.type_name = type_name
    pool = descriptor_pool.DescriptorPool()
    pool.Add(f)
    return {n: message_factory.MessageFactory(pool).GetPrototype(pool.FindMessageTypeByName(f"{package}.{n}"))
            for n in fields_by_message}


F = descriptor_pb2.FieldDescriptorProto
HEALTH = _messages("grpc.health.v1", {
    "HealthCheckRequest": [("service", F.TYPE_STRING, F.LABEL_OPTIONAL, None)],
    "HealthCheckResponse": [("status", F.TYPE_INT32, F.LABEL_OPTIONAL, None)],  # the enum's numbers
})
# grpc.reflection.v1alpha: the request's list_services (field 7) and the answer's list_services_response (6).
REFLECTION = _messages("grpc.reflection.v1alpha", {
    "ServiceResponse": [("name", F.TYPE_STRING, F.LABEL_OPTIONAL, None)],
    "ListServiceResponse": [("service", F.TYPE_MESSAGE, F.LABEL_REPEATED, ".grpc.reflection.v1alpha.ServiceResponse")],
})
SERVING, NOT_SERVING = 1, 2


def _health(address, service):
    with grpc.insecure_channel(address) as channel:
        check = channel.unary_unary("/grpc.health.v1.Health/Check",
                                    request_serializer=HEALTH["HealthCheckRequest"].SerializeToString,
                                    response_deserializer=HEALTH["HealthCheckResponse"].FromString)
        return check(HEALTH["HealthCheckRequest"](service=service), timeout=10).status


def _reflected_services(address):
    # ServerReflectionRequest { string host = 1; ... string list_services = 7; }: field 7, empty.
    request = bytes([7 << 3 | 2, 0])
    with grpc.insecure_channel(address) as channel:
        info = channel.stream_stream("/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
                                     request_serializer=lambda b: b, response_deserializer=lambda b: b)
        (answer,) = list(info(iter([request]), timeout=10))
    # ServerReflectionResponse: skip to field 6 (list_services_response), length-delimited.
    i = 0
    while i < len(answer):
        key, i = _varint(answer, i)
        if key & 7 == 2:
            size, i = _varint(answer, i)
            if key >> 3 == 6:
                listing = REFLECTION["ListServiceResponse"].FromString(answer[i:i + size])
                return [s.name for s in listing.service]
            i += size
        else:
            _, i = _varint(answer, i)
    raise AssertionError("no list_services_response in the reflection's answer")


def _varint(data, i):
    value, shift = 0, 0
    while True:
        b = data[i]
        i += 1
        value |= (b & 0x7F) << shift
        shift += 7
        if b < 0x80:
            return value, i


def test_every_service_is_serving_under_its_full_name(daemon):
    assert _health(daemon.address, "") == SERVING
    for service in SERVICES:
        assert _health(daemon.address, service) == SERVING, service
    with pytest.raises(grpc.RpcError) as e:
        _health(daemon.address, "riccati.v1.NoSuchService")
    assert e.value.code() == grpc.StatusCode.NOT_FOUND


def test_reflection_lists_the_services(daemon):
    services = _reflected_services(daemon.address)
    assert set(SERVICES) <= set(services)
    assert "grpc.health.v1.Health" in services


def test_progress_pass_is_not_a_python_keyword():
    progress = jobs_pb2.JobProgress(pass_number=3, passes=10)
    assert progress.pass_number == 3
    # The same field number as the `pass` it was: the wire format is unchanged.
    assert progress.SerializeToString()[:2] == bytes([1 << 3 | 0, 3])


# ------------------------------------------------------------------ raw calls, as a client from the protos


def _stubs(address):
    from riccati.v1 import datasets_pb2_grpc, jobs_pb2_grpc, models_pb2_grpc, sessions_pb2_grpc
    channel = grpc.insecure_channel(address)
    return (channel, models_pb2_grpc.ModelServiceStub(channel), datasets_pb2_grpc.DatasetServiceStub(channel),
            jobs_pb2_grpc.JobServiceStub(channel), sessions_pb2_grpc.SessionServiceStub(channel))


def _code(call):
    with pytest.raises(grpc.RpcError) as e:
        call()
    return e.value.code(), e.value.details()


def _upload(datasets, content, format=0, name="x.csv"):
    header = datasets_pb2.UploadHeader(name=name, format=format, input_columns=["F1", "F2"],
                                       output_columns=["h1", "h2"])
    return datasets.UploadDataset(iter([datasets_pb2.UploadDatasetRequest(header=header),
                                        datasets_pb2.UploadDatasetRequest(chunk=content)]), timeout=30)


def test_undefined_enum_values_are_invalid_arguments(daemon, two_tank_csv):
    channel, _, datasets, jobs, _ = _stubs(daemon.address)
    with channel, open(two_tank_csv, "rb") as f:
        content = f.read()
        code, message = _code(lambda: _upload(datasets, content, format=7))
        assert code == grpc.StatusCode.INVALID_ARGUMENT
        assert "format 7 is unknown" in message and "csv" in message and "mat" in message
        assert _upload(datasets, content, format=datasets_pb2.DATASET_FORMAT_CSV).samples == 2000
        ds = _upload(datasets, content).id
        spec = jobs_pb2.ValidationSpec(model="two_tank", dataset_id=ds, theta=common_pb2.Diagonal(
            values=[10, 5, 0.0791, 0.1342]), estimate=9)
        spec.initial_state.first_measurement = True
        code, message = _code(lambda: jobs.SubmitValidation(spec, timeout=30))
        assert code == grpc.StatusCode.INVALID_ARGUMENT and "estimate 9 is unknown" in message
        ident = jobs_pb2.IdentificationSpec(model="two_tank", dataset_id=ds, theta0=[20, 20, 1, 1])
        ident.filter.kind = 17
        ident.filter.r.scalar = 1e-3
        code, message = _code(lambda: jobs.SubmitIdentification(ident, timeout=30))
        assert code == grpc.StatusCode.INVALID_ARGUMENT and "17" in message


def test_a_range_error_names_the_value_and_the_limit(daemon):
    channel, models, _, _, _ = _stubs(daemon.address)
    with channel:
        request = models_pb2.SimulateRequest(model="two_tank", x0=[0.4, 0.15], t=[0, 1])
        request.u.rows, request.u.cols = 2, 2
        request.u.values.extend([0.1, 0.03, 0.1, 0.03])
        request.integrator.substeps = 5000000
        code, message = _code(lambda: models.Simulate(request, timeout=30))
        assert code == grpc.StatusCode.INVALID_ARGUMENT
        assert "5000000" in message and "1000000" in message and "1000001" not in message


def test_sizes_and_sample_ranges_are_checked_at_submit(client, two_tank_csv):
    ds = client.upload(two_tank_csv, inputs=["F1", "F2"], outputs=["h1", "h2"])
    run = dict(r=1e-3, p0=[0, 0, 10, 10, 10, 10], theta0=[20, 20, 1, 1])
    for bad, field in ((dict(x0=[0.4]), "x0"), (dict(theta0=[20, 20, 1]), "theta0"),
                       (dict(first_sample=1999, end_sample=5000), "sample"), (dict(first_sample=3000), "sample")):
        settings = {**run, **bad}
        with pytest.raises(riccati.InvalidArgument) as e:  # from the submit: no job is created
            client.submit_identification("two_tank", ds, **settings)
        assert field in e.value.message, e.value.message
        with pytest.raises(riccati.InvalidArgument) as e:
            client.submit_smoothing("two_tank", ds, **settings)
        assert field in e.value.message, e.value.message
    with pytest.raises(riccati.InvalidArgument) as e:
        client.submit_validation("two_tank", ds, [10, 5, 0.0791, 0.1342], x0=[0.4])
    assert "x0" in e.value.message
    with pytest.raises(riccati.InvalidArgument) as e:
        client.submit_validation("two_tank", ds, [10, 5, 0.0791])
    assert "theta" in e.value.message


def test_cancel_answers_cancelling_and_a_cancelled_job_holds_still(client, two_tank_csv):
    job = client.submit_identification("two_tank", two_tank_csv, inputs=["F1", "F2"], outputs=["h1", "h2"],
                                       passes=4000, theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10], r=1e-3)
    for seen in job.watch():
        if seen.state == "running":
            break
    answer = job.cancel()
    assert answer.state in ("cancelling", "cancelled"), answer.state
    assert answer.proto.state in (jobs_pb2.JOB_STATE_CANCELLING, jobs_pb2.JOB_STATE_CANCELLED)
    job.wait()
    assert job.state == "cancelled"
    final = job.proto.progress
    assert client.job(job.id).proto.progress == final
    assert client.job(job.id).cancel().proto.state == jobs_pb2.JOB_STATE_CANCELLED  # an ended job stays as it is
    # An ended job is deleted (DeleteJob), and is then not found.
    job.delete()
    with pytest.raises(riccati.NotFound):
        client.job(job.id)


def test_session_info_names_its_instance(daemon, client):
    with client.session("two_tank", r=1e-3, p0=[0, 0, 10, 10, 10, 10], theta0=[20, 20, 1, 1]) as s:
        assert s.info.instance
        assert s.refresh().info.instance == s.info.instance
        listed = client._call("list", client._sessions.ListSessions, sessions_pb2.ListSessionsRequest()).sessions
        assert [x.instance for x in listed if x.id == s.id] == [s.info.instance]


def test_a_divergence_within_a_batch_answers_every_measurement(daemon, two_tank_csv):
    import pandas as pd
    record = pd.read_csv(two_tank_csv, float_precision="round_trip")
    channel, _, _, _, sessions = _stubs(daemon.address)
    with channel:
        # A huge variance on A1 with exact measurements sends A1 negative; the model's sqrt then fails.
        request = sessions_pb2.CreateSessionRequest(model="two_tank", theta0=[1e-3, 20, 1, 1])
        request.initial_state.first_measurement = True
        request.p0.diagonal.values.extend([0, 0, 1e12, 10, 10, 10])
        request.filter.r.scalar = 1e-12
        session = sessions.CreateSession(request, timeout=30)
        batch = sessions_pb2.MeasurementBatch()
        for t, f1, f2, h1, h2 in record[["t", "F1", "F2", "h1", "h2"]].itertuples(index=False):
            batch.measurements.add(t=t, u=[f1, f2], y=[h1, h2])
        stream = sessions.Stream(iter([sessions_pb2.StreamRequest(open=sessions_pb2.StreamOpen(session_id=session.id)),
                                       sessions_pb2.StreamRequest(batch=batch)]), timeout=60)
        responses = []
        with pytest.raises(grpc.RpcError) as e:
            for response in stream:
                responses.append(response)
        assert e.value.code() == grpc.StatusCode.FAILED_PRECONDITION
        (response,) = responses
        results = list(response.results)
        assert len(results) == len(record), "one result per measurement"
        assert [r.sequence for r in results] == list(range(len(record)))
        outcomes = [r.WhichOneof("outcome") for r in results]
        first = outcomes.index("error")
        assert 0 < first and set(outcomes[first:]) == {"error"}, "the filter diverged within the batch"
        assert all(r.error.code == grpc.StatusCode.FAILED_PRECONDITION.value[0] for r in results[first:])
        assert results[-1].error.message == results[first].error.message
        info = sessions.GetSession(sessions_pb2.GetSessionRequest(id=session.id), timeout=30)
        assert info.state == sessions_pb2.SESSION_STATE_DIVERGED and info.measurements == first


def test_a_stream_frame_that_does_not_parse_ends_the_stream_naming_it(daemon):
    """Bytes that are no StreamRequest used to end the stream with OK and no answer."""
    channel, _, _, _, sessions = _stubs(daemon.address)
    with channel:
        request = sessions_pb2.CreateSessionRequest(model="two_tank", theta0=[10, 5, 0.08, 0.13])
        request.initial_state.first_measurement = True
        request.filter.r.scalar = 1e-3
        session = sessions.CreateSession(request, timeout=30)
        opening = sessions_pb2.StreamRequest(open=sessions_pb2.StreamOpen(session_id=session.id))
        raw = channel.stream_stream("/riccati.v1.SessionService/Stream")  # bytes in, bytes out
        junk = b"\xff\xff\xff\xff\x07"
        for frames, number in (([junk], 1), ([opening.SerializeToString(), junk], 2)):
            with pytest.raises(grpc.RpcError) as e:
                list(raw(iter(frames), timeout=30))
            assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT, e.value.details()
            assert f"message {number} of the stream is not a StreamRequest" in e.value.details()
        # The session and the daemon serve the next stream as before.
        batch = sessions_pb2.MeasurementBatch()
        batch.measurements.add(t=0, u=[1e-5, 1e-5], y=[0.5, 0.5])
        responses = list(sessions.Stream(iter([opening, sessions_pb2.StreamRequest(batch=batch)]), timeout=30))
        assert [r.WhichOneof("outcome") for r in responses[0].results] == ["estimate"]
        # Batches sent ahead of the bad frame, without waiting for their
        # answers, are all answered, in order, before the stream ends: riccatid
        # reads ahead while it filters, and writes what it filtered first.
        frames = [opening.SerializeToString()]
        for k in range(1, 4):
            batch = sessions_pb2.MeasurementBatch()
            for j in range(64):
                batch.measurements.add(t=k * 100 + j, u=[1e-5, 1e-5], y=[0.5, 0.5])
            frames.append(sessions_pb2.StreamRequest(batch=batch).SerializeToString())
        frames.append(junk)
        answered = []
        with pytest.raises(grpc.RpcError) as e:
            for frame in raw(iter(frames), timeout=30):
                answered.append(sessions_pb2.StreamResponse.FromString(frame))
        assert e.value.code() == grpc.StatusCode.INVALID_ARGUMENT, e.value.details()
        assert "message 5 of the stream is not a StreamRequest" in e.value.details()
        assert [[r.estimate.t for r in a.results] for a in answered] == [
            [k * 100 + j for j in range(64)] for k in range(1, 4)]


def test_a_retried_request_gets_the_object_the_first_made(daemon, two_tank_csv):
    import threading
    channel, _, datasets, jobs, sessions = _stubs(daemon.address)
    with channel, open(two_tank_csv, "rb") as f:
        content = f.read()

        def upload(request_id):
            header = datasets_pb2.UploadHeader(name="two_tank.csv", input_columns=["F1", "F2"],
                                               output_columns=["h1", "h2"], request_id=request_id)
            return datasets.UploadDataset(iter([datasets_pb2.UploadDatasetRequest(header=header),
                                                datasets_pb2.UploadDatasetRequest(chunk=content)]), timeout=30)

        before = len(datasets.ListDatasets(datasets_pb2.ListDatasetsRequest(), timeout=30).datasets)
        first = upload("upload-1")
        assert upload("upload-1").id == first.id
        assert upload("upload-2").id != first.id
        assert len(datasets.ListDatasets(datasets_pb2.ListDatasetsRequest(), timeout=30).datasets) == before + 2

        spec = jobs_pb2.IdentificationSpec(model="two_tank", dataset_id=first.id, theta0=[20, 20, 1, 1], passes=1,
                                           request_id="identify-1")
        spec.initial_state.first_measurement = True
        spec.filter.r.scalar = 1e-3
        spec.p0.diagonal.values.extend([0, 0, 10, 10, 10, 10])
        jobs_before = len(jobs.ListJobs(jobs_pb2.ListJobsRequest(), timeout=30).jobs)
        # Retries that overlap the first call, as after a deadline of 1 ms.
        answers = [None] * 6

        def submit(i):
            answers[i] = jobs.SubmitIdentification(spec, timeout=30).id

        threads = [threading.Thread(target=submit, args=(i,)) for i in range(len(answers))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(set(answers)) == 1 and answers[0].startswith("job")
        assert jobs.SubmitIdentification(spec, timeout=30).id == answers[0]  # and after it ended, or while it runs
        assert len(jobs.ListJobs(jobs_pb2.ListJobsRequest(), timeout=30).jobs) == jobs_before + 1

        validation = jobs_pb2.ValidationSpec(model="two_tank", dataset_id=first.id, identification_job_id=answers[0],
                                             request_id="validate-1")
        validation.initial_state.first_measurement = True
        assert jobs.SubmitValidation(validation, timeout=30).id == jobs.SubmitValidation(validation, timeout=30).id

        session = sessions_pb2.CreateSessionRequest(model="two_tank", theta0=[20, 20, 1, 1], request_id="session-1")
        session.initial_state.first_measurement = True
        session.filter.r.scalar = 1e-3
        session.p0.scalar = 1.0
        made = sessions.CreateSession(session, timeout=30)
        assert sessions.CreateSession(session, timeout=30).id == made.id
        session.request_id = "session-2"
        assert sessions.CreateSession(session, timeout=30).id != made.id

        # A request id is one request's: given to another kind of request, it is refused.
        session.request_id = "identify-1"
        code, message = _code(lambda: sessions.CreateSession(session, timeout=30))
        assert code == grpc.StatusCode.INVALID_ARGUMENT and answers[0] in message


def test_the_client_names_every_creation(client, two_tank_csv):
    ds = client.upload(two_tank_csv, inputs=["F1", "F2"], outputs=["h1", "h2"], request_id="py-upload-1")
    assert client.upload(two_tank_csv, inputs=["F1", "F2"], outputs=["h1", "h2"], request_id="py-upload-1").id == ds.id
    settings = dict(passes=1, theta0=[20, 20, 1, 1], p0=[0, 0, 10, 10, 10, 10], r=1e-3)
    a = client.submit_identification("two_tank", ds, request_id="py-identify-1", **settings)
    assert client.submit_identification("two_tank", ds, request_id="py-identify-1", **settings).id == a.id
    assert client.submit_identification("two_tank", ds, **settings).id != a.id  # a new UUID each call


def test_error_code_is_the_enum_of_grpc_codes():
    field = common_pb2.Error.DESCRIPTOR.fields_by_name["code"]
    assert field.enum_type is not None and field.enum_type.full_name == "riccati.v1.Code"
    for code in grpc.StatusCode:
        assert field.enum_type.values_by_number[code.value[0]].name == "CODE_" + code.name
    # The same bytes as the int32 it was.
    assert common_pb2.Error(code=common_pb2.CODE_NOT_FOUND).SerializeToString()[:2] == bytes([1 << 3 | 0, 5])


def test_close_session_ends_its_stream(daemon):
    import queue
    channel, _, _, _, sessions = _stubs(daemon.address)
    with channel:
        request = sessions_pb2.CreateSessionRequest(model="two_tank", theta0=[20, 20, 1, 1])
        request.initial_state.first_measurement = True
        request.filter.r.scalar = 1e-3
        request.p0.scalar = 1.0
        session = sessions.CreateSession(request, timeout=30)
        requests = queue.Queue()
        requests.put(sessions_pb2.StreamRequest(open=sessions_pb2.StreamOpen(session_id=session.id)))
        batch = sessions_pb2.MeasurementBatch()
        batch.measurements.add(t=0, u=[0.1, 0.03], y=[0.4, 0.15])
        requests.put(sessions_pb2.StreamRequest(batch=batch))
        end = object()
        responses = sessions.Stream(iter(requests.get, end), timeout=60)
        assert next(responses).results[0].WhichOneof("outcome") == "estimate"
        sessions.CloseSession(sessions_pb2.CloseSessionRequest(id=session.id), timeout=30)
        with pytest.raises(grpc.RpcError) as e:
            next(responses)  # the stream ends without another batch sent
        requests.put(end)
        assert e.value.code() == grpc.StatusCode.FAILED_PRECONDITION
        assert f"session {session.id} was closed" in e.value.details()
