#include "connection.hpp"

#include <sys/stat.h>
#include <yaml-cpp/yaml.h>

#include <fstream>
#include <set>
#include <sstream>

namespace riccati::cli {

namespace {

std::string expand_home(const std::string& path, const Getenv& getenv) {
  if (path.rfind("~/", 0) != 0) return path;
  const char* home = getenv("HOME");
  return std::string(home != nullptr ? home : "") + path.substr(1);
}

std::optional<std::string> read_file(const std::string& path, const char* what, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return std::string("cannot read the ") + what + " " + path;
  std::ostringstream text;
  text << in.rdbuf();
  *out = text.str();
  return std::nullopt;
}

// A token file others can read is refused, as ssh refuses such a key.
std::optional<std::string> read_token_file(const std::string& path, std::string* token) {
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0 && (st.st_mode & (S_IRWXG | S_IRWXO)) != 0) {
    return "the token file " + path + " can be read by others: chmod 600 " + path;
  }
  if (auto error = read_file(path, "token file", token)) return error;
  while (!token->empty() && (token->back() == '\n' || token->back() == '\r' || token->back() == ' ')) {
    token->pop_back();
  }
  if (token->empty()) return "the token file " + path + " is empty";
  return std::nullopt;
}

std::string config_path(const Getenv& getenv) {
  if (const char* explicit_path = getenv("RICCATI_CONFIG"); explicit_path != nullptr && explicit_path[0] != '\0') {
    return explicit_path;
  }
  if (const char* xdg = getenv("XDG_CONFIG_HOME"); xdg != nullptr && xdg[0] != '\0') {
    return std::string(xdg) + "/riccati/client.yaml";
  }
  const char* home = getenv("HOME");
  return home != nullptr ? std::string(home) + "/.config/riccati/client.yaml" : "";
}

std::string env_or_empty(const Getenv& getenv, const char* name) {
  const char* v = getenv(name);
  return v != nullptr ? v : "";
}

}  // namespace

std::shared_ptr<grpc::ChannelCredentials> Connection::credentials() const {
  if (!tls) return grpc::InsecureChannelCredentials();
  grpc::SslCredentialsOptions options;
  options.pem_root_certs = ca_pem;
  options.pem_cert_chain = cert_pem;
  options.pem_private_key = key_pem;
  return grpc::SslCredentials(options);
}

void Connection::apply(grpc::ChannelArguments* args) const {
  if (tls && !tls_server_name.empty()) args->SetSslTargetNameOverride(tls_server_name);
}

std::optional<std::string> resolve_connection(const ConnectionFlags& flags, const Getenv& getenv, Connection* out) {
  // The config file: the lowest precedence.
  ConnectionFlags file;
  const std::string path = config_path(getenv);
  if (!path.empty() && std::ifstream(path).good()) {
    out->config_file = path;
    try {
      const YAML::Node root = YAML::LoadFile(path);
      static const std::set<std::string> kKeys = {"server", "token_file", "ca", "cert", "key", "tls",
                                                  "tls_server_name"};
      if (!root.IsMap() && !root.IsNull()) return "config file " + path + ": expected keys and values";
      for (const auto& entry : root) {
        const auto key = entry.first.as<std::string>();
        if (kKeys.count(key) == 0) {
          return "config file " + path + ": unknown key \"" + key +
                 "\" (known: server, token_file, ca, cert, key, tls, tls_server_name; a token itself goes in "
                 "token_file)";
        }
      }
      if (root["server"]) file.server = root["server"].as<std::string>();
      if (root["token_file"]) file.token_file = expand_home(root["token_file"].as<std::string>(), getenv);
      if (root["ca"]) file.ca = expand_home(root["ca"].as<std::string>(), getenv);
      if (root["cert"]) file.cert = expand_home(root["cert"].as<std::string>(), getenv);
      if (root["key"]) file.key = expand_home(root["key"].as<std::string>(), getenv);
      if (root["tls"]) file.tls = root["tls"].as<bool>();
      if (root["tls_server_name"]) file.tls_server_name = root["tls_server_name"].as<std::string>();
    } catch (const YAML::Exception& e) {
      return "config file " + path + ": " + e.what();
    }
  }
  // Flag, else environment, else config file.
  auto pick = [&](const std::string& flag, const char* env, const std::string& from_file) {
    if (!flag.empty()) return flag;
    std::string v = env_or_empty(getenv, env);
    return v.empty() ? from_file : v;
  };
  const std::string server = pick(flags.server, "RICCATI_SERVER", file.server);
  if (!server.empty()) out->server = server;
  const std::string ca = pick(flags.ca, "RICCATI_CA", file.ca);
  const std::string cert = pick(flags.cert, "RICCATI_CERT", file.cert);
  const std::string key = pick(flags.key, "RICCATI_KEY", file.key);
  out->tls_server_name = pick(flags.tls_server_name, "RICCATI_TLS_SERVER_NAME", file.tls_server_name);
  const std::string tls_env = env_or_empty(getenv, "RICCATI_TLS");
  out->tls = flags.tls || tls_env == "1" || tls_env == "true" || file.tls || !ca.empty() || !cert.empty();
  if (!ca.empty()) {
    if (auto error = read_file(ca, "CA certificate", &out->ca_pem)) return error;
  }
  if (cert.empty() != key.empty()) return std::string("a client certificate needs both --cert and --key");
  if (!cert.empty()) {
    if (auto error = read_file(cert, "client certificate", &out->cert_pem)) return error;
    if (auto error = read_file(key, "client key", &out->key_pem)) return error;
  }

  // The token: a file named by flag, environment or config, else RICCATI_TOKEN.
  const std::string token_file = pick(flags.token_file, "RICCATI_TOKEN_FILE", file.token_file);
  if (!token_file.empty()) {
    if (auto error = read_token_file(token_file, &out->token)) return error;
  } else {
    out->token = env_or_empty(getenv, "RICCATI_TOKEN");
  }
  return std::nullopt;
}

}  // namespace riccati::cli
