// Where riccatid is and how to prove who we are: address, bearer token and
// TLS files, from flags, the environment or the user's config file, in that
// order of precedence (as kubectl, psql and the cloud CLIs do). The token is
// never a command-line argument, so it does not end up in shell history or
// in `ps`: it comes from a file (--token-file, RICCATI_TOKEN_FILE,
// token_file in the config) or from the RICCATI_TOKEN variable.
//
// The config file is $RICCATI_CONFIG, else $XDG_CONFIG_HOME/riccati/client.yaml,
// else ~/.config/riccati/client.yaml (missing: nothing set):
//
//   server: riccati.example.org:7531
//   token_file: ~/.config/riccati/token
//   ca: ~/.config/riccati/ca.pem        # TLS, trusting this CA
//   cert: ~/.config/riccati/client.pem  # mutual TLS
//   key: ~/.config/riccati/client.key
//   tls: true                           # TLS with the system's CAs
//   tls_server_name: riccatid.example.org  # the name to check in the server's
//                                       # certificate, when it is not the one in
//                                       # server (a probe connecting to 127.0.0.1)
#pragma once

#include <grpcpp/grpcpp.h>

#include <functional>
#include <memory>
#include <optional>
#include <string>

namespace riccati::cli {

struct ConnectionFlags {  // as given on the command line; empty: not given
  std::string server;
  std::string token_file;
  std::string ca;
  std::string cert;
  std::string key;
  std::string tls_server_name;
  bool tls = false;
};

struct Connection {
  std::string server = "127.0.0.1:7531";
  std::string token;  // empty: none sent
  bool tls = false;
  std::string ca_pem, cert_pem, key_pem;  // contents; empty ca_pem with tls: the system's roots
  std::string tls_server_name;            // empty: the host of `server`
  std::string config_file;                // the config file read, if any

  std::shared_ptr<grpc::ChannelCredentials> credentials() const;
  // Channel arguments for these settings (the TLS name to check).
  void apply(grpc::ChannelArguments* args) const;
};

using Getenv = std::function<const char*(const char*)>;

// Resolves the connection. Returns an error message (a file that cannot be
// read, a config key that is not known, a token file others can read).
std::optional<std::string> resolve_connection(const ConnectionFlags& flags, const Getenv& getenv, Connection* out);

}  // namespace riccati::cli
