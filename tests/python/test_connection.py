"""Where the client connects and with what token: as the CLI decides."""
import os

import pytest

import riccati
from riccati import _connection
from conftest import TOKEN


def _config(tmp_path, text):
    path = tmp_path / "client.yaml"
    path.write_text(text)
    return str(path)


def test_arguments_then_environment_then_config_file(tmp_path):
    token_file = tmp_path / "token"
    token_file.write_text("from-file\n")
    token_file.chmod(0o600)
    config = _config(tmp_path, f"server: cfg.example:1  # the lab's\ntoken_file: {token_file}\n")
    env = {"RICCATI_CONFIG": config}
    c = _connection.resolve(env=env)
    assert (c.server, c.token, c.tls, c.config_file) == ("cfg.example:1", "from-file", False, config)
    env["RICCATI_SERVER"] = "env.example:2"
    env["RICCATI_TOKEN"] = "ignored while a token file is named"
    c = _connection.resolve(env=env)
    assert (c.server, c.token) == ("env.example:2", "from-file")
    c = _connection.resolve("arg.example:3", token="given", env=env)
    assert (c.server, c.token) == ("arg.example:3", "given")
    assert _connection.resolve(env={}).server == "127.0.0.1:7531"
    assert _connection.resolve(env={"RICCATI_TOKEN": "t"}).token == "t"


def test_the_config_file_is_found_where_the_cli_looks(tmp_path):
    (tmp_path / "xdg" / "riccati").mkdir(parents=True)
    (tmp_path / "xdg" / "riccati" / "client.yaml").write_text("server: xdg.example:4\n")
    (tmp_path / "home" / ".config" / "riccati").mkdir(parents=True)
    (tmp_path / "home" / ".config" / "riccati" / "client.yaml").write_text("server: 'home.example:5'\n")
    home = {"HOME": str(tmp_path / "home")}
    assert _connection.resolve(env=home).server == "home.example:5"
    assert _connection.resolve(env={**home, "XDG_CONFIG_HOME": str(tmp_path / "xdg")}).server == "xdg.example:4"


def test_what_the_cli_refuses_is_refused(tmp_path):
    with pytest.raises(riccati.ConfigError, match='unknown key "token"'):
        _connection.resolve(env={"RICCATI_CONFIG": _config(tmp_path, "token: secret\n")})
    open_file = tmp_path / "open-token"
    open_file.write_text("t")
    open_file.chmod(0o644)
    with pytest.raises(riccati.ConfigError, match="chmod 600"):
        _connection.resolve(env={"RICCATI_TOKEN_FILE": str(open_file)})
    with pytest.raises(riccati.ConfigError, match="needs both cert and key"):
        _connection.resolve(tls=riccati.TLS(cert=str(open_file)), env={})
    c = _connection.resolve(env={"RICCATI_CONFIG": _config(tmp_path, "tls: true\n")})
    assert c.tls and c.ca_pem is None


def test_a_token_reaches_riccatid(token_daemon, tmp_path, monkeypatch):
    with riccati.Client(token_daemon.address) as c:
        with pytest.raises(riccati.Unauthenticated) as e:
            c.models()
        assert e.value.code.name == "UNAUTHENTICATED"
    with riccati.Client(token_daemon.address, token=TOKEN) as c:
        assert "two_tank" in [m.name for m in c.models()]
    # From the environment, as the CLI reads it.
    token_file = tmp_path / "token"
    token_file.write_text(TOKEN + "\n")
    token_file.chmod(0o600)
    monkeypatch.setenv("RICCATI_TOKEN_FILE", str(token_file))
    monkeypatch.setenv("RICCATI_SERVER", token_daemon.address)
    with riccati.Client() as c:
        assert c.model("two_tank").name == "two_tank"


def test_an_unreachable_daemon_says_so(tmp_path):
    import socket
    with socket.socket() as s:  # a port nothing listens on: bound, never listening
        s.bind(("127.0.0.1", 0))
        address = "127.0.0.1:%d" % s.getsockname()[1]
        with riccati.Client(address, timeout=10) as c:
            with pytest.raises(riccati.Unavailable) as e:
                c.models()
    assert e.value.message == f"cannot reach riccatid at {address} (connection refused); is it running?"
    assert "is it running?" in e.value.message
    assert os.environ.get("RICCATI_SERVER") is None
