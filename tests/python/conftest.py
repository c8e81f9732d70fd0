"""A real riccatid for the tests: build/bin/riccatid on a free loopback port
(--listen 127.0.0.1:0, the port read from --port-file) with a temporary data
directory, as tests/service/daemon_fixture.hpp starts it for the C++ tests.

CTest (tests/CMakeLists.txt, label python) installs the package into the
build tree and sets RICCATI_DAEMON_BIN, RICCATI_CLI_BIN,
RICCATI_TEST_PLUGIN_DIR and RICCATI_TEST_DATA_DIR; by hand, from the
repository, after scripts/build.sh riccatid riccati:

    /usr/bin/python3 -m pip install --no-build-isolation --no-deps --target /tmp/riccati-py ./client/python
    PYTHONPATH=/tmp/riccati-py /usr/bin/python3 -m pytest tests/python
"""
import hashlib
import os
import signal
import subprocess
import time

import pytest

import riccati

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DAEMON = os.environ.get("RICCATI_DAEMON_BIN", os.path.join(ROOT, "build", "bin", "riccatid"))
CLI = os.environ.get("RICCATI_CLI_BIN", os.path.join(ROOT, "build", "bin", "riccati"))
PLUGINS = os.environ.get("RICCATI_TEST_PLUGIN_DIR", os.path.join(ROOT, "build", "lib", "riccati", "models"))
DATA = os.environ.get("RICCATI_TEST_DATA_DIR", os.path.join(ROOT, "tests", "data"))


class Daemon:
    """riccatid as a child process; stop() sends SIGTERM and returns its exit status."""

    def __init__(self, work, *args):
        self.data_dir = os.path.join(work, "data")
        port_file = os.path.join(work, "port")
        self.log = open(os.path.join(work, "riccatid.log"), "w+")
        self.process = subprocess.Popen(
            [DAEMON, "--listen", "127.0.0.1:0", "--data-dir", self.data_dir, "--port-file", port_file,
             "--models-dir", PLUGINS, "--workers", "2", "--log-level", "warn", *args],
            stderr=self.log, env={**os.environ, "GRPC_CLIENT_CHANNEL_BACKUP_POLL_INTERVAL_MS": "100"})
        port = ""
        while not port:  # the daemon writes the port file once it listens
            if self.process.poll() is not None:
                self.log.seek(0)
                raise RuntimeError(f"riccatid exited at start ({self.process.returncode}): {self.log.read()}")
            if os.path.exists(port_file):
                with open(port_file) as f:
                    port = f.read().strip()
            time.sleep(0.01)
        self.address = "127.0.0.1:" + port

    def stop(self):
        self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(timeout=120)
        finally:
            self.log.close()


def _daemon(tmp_path_factory, *args):
    d = Daemon(str(tmp_path_factory.mktemp("riccatid")), *args)
    yield d
    status = d.stop()
    assert status == 0, f"riccatid did not stop cleanly: exit status {status}"


@pytest.fixture(scope="session")
def daemon(tmp_path_factory):
    yield from _daemon(tmp_path_factory)


TOKEN = "py-client-test-token-7f3a"


@pytest.fixture(scope="session")
def token_daemon(tmp_path_factory):
    """A riccatid that refuses calls without TOKEN (tenant "lab")."""
    tokens = tmp_path_factory.mktemp("tokens") / "tokens"
    tokens.write_text(f"lab sha256:{hashlib.sha256(TOKEN.encode()).hexdigest()}\n")
    tokens.chmod(0o600)
    yield from _daemon(tmp_path_factory, "--tokens-file", str(tokens))


@pytest.fixture(autouse=True)
def no_user_config(monkeypatch, tmp_path):
    """The tests' clients see no RICCATI_* variable and no config file of the user running them."""
    for name in list(os.environ):
        if name.startswith("RICCATI_") and name not in ("RICCATI_DAEMON_BIN", "RICCATI_CLI_BIN",
                                                         "RICCATI_TEST_PLUGIN_DIR", "RICCATI_TEST_DATA_DIR"):
            monkeypatch.delenv(name)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    monkeypatch.delenv("XDG_CONFIG_HOME", raising=False)


@pytest.fixture
def client(daemon):
    with riccati.Client(daemon.address) as c:
        yield c


@pytest.fixture(scope="session")
def two_tank_csv():
    return os.path.join(DATA, "two_tank.csv")
