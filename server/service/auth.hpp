// Who may call riccatid, and over what.
//
// Authentication happens in one place: a gRPC AuthMetadataProcessor
// (TokenAuthProcessor) that runs before any handler, reads the bearer token
// of the call ("authorization: Bearer <token>") and looks its SHA-256 up in
// the tokens file. A call without a valid token is answered UNAUTHENTICATED
// and nothing of it reaches a handler. Handlers ask Authenticator::tenant()
// and pass the tenant to the managers and the store, which never return
// another tenant's objects.
//
// Transport: TLS (certificate and key from files; with a client CA, mutual
// TLS), or plain TCP on a loopback address only, for development (local
// credentials: plain bytes on the wire, but gRPC checks that the peer is on
// this host). Without a tokens file every caller is tenant "default", which
// is allowed on loopback only as well.
#pragma once

#include <grpcpp/grpcpp.h>
#include <grpcpp/security/auth_metadata_processor.h>

#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <string_view>

#include "engine/status.hpp"

namespace riccati::service {

// The tenant of callers when authentication is off.
inline constexpr std::string_view kDefaultTenant = "default";

// The tokens file: one line per token, "<tenant> sha256:<hex digest of the
// token>", and " operator" after it for a token that may also do what is
// riccatid's operator's (ReloadModels); blank lines and lines starting with
// # are ignored. Only digests are stored, so the file does not give the
// tokens away.
class TokenTable {
 public:
  static Result<TokenTable> load(const std::string& path);
  // The tenant a token belongs to.
  std::optional<std::string> tenant_for(std::string_view token) const;
  bool is_operator(std::string_view token) const;
  std::size_t size() const { return tenants_.size(); }

 private:
  std::map<std::string, std::string> tenants_;  // digest ("sha256:...") -> tenant
  std::set<std::string> operators_;             // digests of operators' tokens
};

// "sha256:<64 hex digits>" of the token, as the tokens file holds it.
std::string token_digest(std::string_view token);

// Who a call is from. Holds the token table (none: authentication off, every
// caller is kDefaultTenant). Shared by the auth processor, which refuses
// calls without a valid token before any handler runs, and the handlers,
// which ask tenant().
class Authenticator {
 public:
  // No tokens file: authentication off.
  static Result<std::shared_ptr<const Authenticator>> create(const std::string& tokens_file);

  bool enabled() const { return tokens_.has_value(); }
  std::size_t tokens() const { return tokens_ ? tokens_->size() : 0; }
  // The tenant of an "authorization" metadata value, or the reason it is refused.
  Result<std::string> tenant_for_header(std::string_view authorization) const;
  // The tenant of a call. Its token was checked by the processor before the
  // handler ran; a call without one gets "", which owns nothing.
  std::string tenant(const grpc::ServerContextBase& context) const;
  // Whether the call's (or the header's) token is an operator's; without
  // a tokens file, every caller is (one user, on loopback).
  bool is_operator(const grpc::ServerContextBase& context) const;
  bool is_operator_header(std::string_view authorization) const;

 private:
  std::optional<TokenTable> tokens_;
};

// PERMISSION_DENIED for a tenant's call to what is the operator's (`what`).
Status operator_only(const char* what);

// Refuses calls without a valid token (except health checks and reflection)
// with UNAUTHENTICATED before they reach a handler.
//
// The tenant is not handed on through the AuthContext: in the gRPC of Debian
// 12 (1.51) a property added here lands in the connection's context, shared
// by every later call on that connection, so a second tenant on the same
// channel would read the first one's. Handlers look the token up again
// instead (Authenticator::tenant).
class TokenAuthProcessor final : public grpc::AuthMetadataProcessor {
 public:
  explicit TokenAuthProcessor(std::shared_ptr<const Authenticator> auth) : auth_(std::move(auth)) {}
  bool IsBlocking() const override { return false; }  // a hash and a map lookup
  grpc::Status Process(const InputMetadata& metadata, grpc::AuthContext* context, OutputMetadata* consumed,
                       OutputMetadata* response) override;

 private:
  const std::shared_ptr<const Authenticator> auth_;
};

struct SecurityConfig {
  std::string tls_cert;       // PEM certificate chain of the server
  std::string tls_key;        // PEM private key
  std::string tls_client_ca;  // PEM CA of client certificates: mutual TLS when set
  std::string tokens_file;    // bearer tokens; empty: no authentication (loopback only)
};

// Whether `listen` (host:port) is a loopback address.
bool is_loopback(const std::string& listen);

// The credentials for the listening port, with the token processor when
// authentication is on. Refuses plain TCP and unauthenticated access off
// loopback. `description` says what was chosen, for the log.
Result<std::shared_ptr<grpc::ServerCredentials>> server_credentials(const SecurityConfig& config,
                                                                    const std::string& listen,
                                                                    std::shared_ptr<const Authenticator> auth,
                                                                    std::string* description);

}  // namespace riccati::service
