"""Where riccatid is and how to prove who we are, as the CLI finds it.

Precedence, as `riccati` (client/cli/connection.cpp): what the program gives
(Client's arguments), else the environment (RICCATI_SERVER, RICCATI_TOKEN_FILE,
RICCATI_TOKEN, RICCATI_TLS, RICCATI_CA, RICCATI_CERT, RICCATI_KEY,
RICCATI_TLS_SERVER_NAME), else the config file: $RICCATI_CONFIG, else
$XDG_CONFIG_HOME/riccati/client.yaml, else ~/.config/riccati/client.yaml:

    server: riccati.example.org:7531
    token_file: ~/.config/riccati/token
    ca: ~/.config/riccati/ca.pem        # TLS, trusting this CA
    cert: ~/.config/riccati/client.pem  # mutual TLS
    key: ~/.config/riccati/client.key
    tls: true                           # TLS with the system's CAs
    tls_server_name: riccatid.example.org

A token file that its group or others can read is refused, as ssh refuses
such a key.
"""
import dataclasses
import os
import stat

DEFAULT_SERVER = "127.0.0.1:7531"
_KEYS = ("server", "token_file", "ca", "cert", "key", "tls", "tls_server_name")


@dataclasses.dataclass
class TLS:
    """TLS settings: ca, cert and key are file paths (None: the system's roots, no client certificate)."""
    ca: str = None
    cert: str = None
    key: str = None
    server_name: str = None


@dataclasses.dataclass
class Connection:
    server: str = DEFAULT_SERVER
    token: str = ""
    tls: bool = False
    ca_pem: bytes = None
    cert_pem: bytes = None
    key_pem: bytes = None
    tls_server_name: str = ""
    config_file: str = ""


class ConfigError(ValueError):
    """The connection's settings cannot be used (a file that cannot be read, an unknown key)."""


def _expand_home(path, env):
    if path.startswith("~/"):
        return env.get("HOME", "") + path[1:]
    return path


def config_path(env):
    if env.get("RICCATI_CONFIG"):
        return env["RICCATI_CONFIG"]
    if env.get("XDG_CONFIG_HOME"):
        return os.path.join(env["XDG_CONFIG_HOME"], "riccati", "client.yaml")
    if env.get("HOME"):
        return os.path.join(env["HOME"], ".config", "riccati", "client.yaml")
    return ""


def _scalar(text):
    """A YAML scalar of the flat config file: quotes removed, a trailing comment cut."""
    text = text.strip()
    if text[:1] in ("'", '"'):
        end = text.find(text[0], 1)
        if end < 0:
            raise ValueError("unterminated quote")
        return text[1:end]
    if " #" in text:
        text = text[:text.index(" #")]
    return text.strip()


def _boolean(text, where):
    value = text.lower()
    if value in ("true", "yes", "on", "y"):
        return True
    if value in ("false", "no", "off", "n", ""):
        return False
    raise ConfigError(f"{where}: expected true or false, not \"{text}\"")


def read_config(path):
    """The config file's keys (a flat map of scalars); an unknown key is refused, as the CLI does."""
    values = {}
    with open(path, encoding="utf-8") as f:
        for number, line in enumerate(f, 1):
            stripped = line.strip()
            if not stripped or stripped.startswith("#") or stripped == "---":
                continue
            key, sep, rest = stripped.partition(":")
            if not sep or line[:1] in (" ", "\t"):
                raise ConfigError(f"config file {path}: line {number}: expected keys and values")
            key = key.strip()
            if key not in _KEYS:
                raise ConfigError(f"config file {path}: unknown key \"{key}\" (known: {', '.join(_KEYS)}; "
                                  "a token itself goes in token_file)")
            try:
                values[key] = _scalar(rest)
            except ValueError as e:
                raise ConfigError(f"config file {path}: line {number}: {e}") from None
    return values


def _read(path, what):
    try:
        with open(path, "rb") as f:
            return f.read()
    except OSError:
        raise ConfigError(f"cannot read the {what} {path}") from None


def read_token_file(path):
    try:
        mode = os.stat(path).st_mode
    except OSError:
        mode = 0
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise ConfigError(f"the token file {path} can be read by others: chmod 600 {path}")
    token = _read(path, "token file").decode("utf-8").rstrip("\r\n ")
    if not token:
        raise ConfigError(f"the token file {path} is empty")
    return token


def resolve(server=None, token=None, tls=None, token_file=None, env=None):
    """The Connection for Client's arguments, the environment and the config file."""
    env = os.environ if env is None else env
    out = Connection()
    file = {}
    path = config_path(env)
    if path and os.path.isfile(path):
        out.config_file = path
        file = read_config(path)
        for key in ("token_file", "ca", "cert", "key"):
            if key in file:
                file[key] = _expand_home(file[key], env)

    def pick(given, variable, key):
        if given:
            return given
        return env.get(variable) or file.get(key, "")

    out.server = pick(server, "RICCATI_SERVER", "server") or DEFAULT_SERVER
    given_tls = tls if isinstance(tls, TLS) else TLS()
    if isinstance(tls, dict):
        given_tls = TLS(**tls)
    ca = pick(given_tls.ca, "RICCATI_CA", "ca")
    cert = pick(given_tls.cert, "RICCATI_CERT", "cert")
    key = pick(given_tls.key, "RICCATI_KEY", "key")
    out.tls_server_name = pick(given_tls.server_name, "RICCATI_TLS_SERVER_NAME", "tls_server_name")
    if tls is False:
        out.tls = False
    else:
        out.tls = (tls is True or isinstance(tls, (TLS, dict)) or env.get("RICCATI_TLS", "") in ("1", "true")
                   or _boolean(file.get("tls", ""), f"config file {path}: tls") or bool(ca) or bool(cert))
    if out.tls:
        if ca:
            out.ca_pem = _read(ca, "CA certificate")
        if bool(cert) != bool(key):
            raise ConfigError("a client certificate needs both cert and key")
        if cert:
            out.cert_pem = _read(cert, "client certificate")
            out.key_pem = _read(key, "client key")
    if token:
        out.token = token
    else:
        token_path = pick(token_file, "RICCATI_TOKEN_FILE", "token_file")
        out.token = read_token_file(token_path) if token_path else env.get("RICCATI_TOKEN", "")
    return out
