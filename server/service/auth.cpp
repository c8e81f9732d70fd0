#include "service/auth.hpp"

#include <openssl/err.h>
#include <openssl/pem.h>
#include <openssl/x509.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <cstdio>
#include <cctype>
#include <fstream>
#include <memory>
#include <sstream>

#include "engine/sha256.hpp"
#include "service/files.hpp"

namespace riccati::service {

namespace {

// Methods every caller may use without a token: health checks (load
// balancers and orchestrators have none) and server reflection.
bool is_public_method(std::string_view path) {
  return path.rfind("/grpc.health.v1.Health/", 0) == 0 ||
         path.rfind("/grpc.reflection.v1alpha.ServerReflection/", 0) == 0;
}

// What gRPC would refuse only when it binds, with "cannot listen on ...":
// files without a PEM certificate or key, a key of another certificate.
// Checked with OpenSSL here, so that the error names the file and the fault.
struct BioFree {
  void operator()(BIO* b) const { BIO_free(b); }
};
struct X509Free {
  void operator()(X509* c) const { X509_free(c); }
};
struct KeyFree {
  void operator()(EVP_PKEY* k) const { EVP_PKEY_free(k); }
};
std::unique_ptr<BIO, BioFree> memory_bio(const std::string& pem) {
  return std::unique_ptr<BIO, BioFree>(BIO_new_mem_buf(pem.data(), static_cast<int>(pem.size())));
}

Result<std::unique_ptr<X509, X509Free>> first_certificate(const std::string& pem, const std::string& path,
                                                          const char* what) {
  auto bio = memory_bio(pem);
  std::unique_ptr<X509, X509Free> cert(PEM_read_bio_X509(bio.get(), nullptr, nullptr, nullptr));
  ERR_clear_error();
  if (cert == nullptr) {
    return invalid_argument(std::string(what) + " " + path +
                            (pem.empty() ? " is empty" : " holds no PEM certificate (-----BEGIN CERTIFICATE-----)"));
  }
  return cert;
}

Status check_tls_files(const SecurityConfig& config, const std::string& cert_pem, const std::string& key_pem,
                       const std::string& ca_pem) {
  RICCATI_ASSIGN_OR_RETURN(const auto cert, first_certificate(cert_pem, config.tls_cert, "tls_cert"));
  auto bio = memory_bio(key_pem);
  const std::unique_ptr<EVP_PKEY, KeyFree> key(PEM_read_bio_PrivateKey(bio.get(), nullptr, nullptr, nullptr));
  ERR_clear_error();
  if (key == nullptr) {
    return invalid_argument("tls_key " + config.tls_key +
                            (key_pem.empty() ? " is empty" : " holds no PEM private key (or one with a passphrase)"));
  }
  if (X509_check_private_key(cert.get(), key.get()) != 1) {
    ERR_clear_error();
    return invalid_argument("tls_key " + config.tls_key + " is not the key of the certificate in tls_cert " +
                            config.tls_cert);
  }
  if (!config.tls_client_ca.empty()) {
    RICCATI_RETURN_IF_ERROR(first_certificate(ca_pem, config.tls_client_ca, "tls_client_ca").status());
  }
  return Status::ok();
}

// As sshd does: a private key others can read is no longer private, and
// one its group or others can write can be replaced. Group read is allowed
// (Debian's ssl-cert group, a Kubernetes secret with an fsGroup).
Status check_private_key_mode(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) return Status::ok();  // read_file says what is wrong
  if ((st.st_mode & (S_IROTH | S_IWOTH | S_IWGRP)) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof mode, "%04o", static_cast<unsigned>(st.st_mode & 07777));
    return failed_precondition("tls_key " + path + " has mode " + mode + ": a private key must not be readable by " +
                               "others nor writable by its group or others (chmod 600 " + path +
                               ", or 640 with riccatid's group)");
  }
  return Status::ok();
}

}  // namespace

std::string token_digest(std::string_view token) { return "sha256:" + sha256_hex(token); }

Result<TokenTable> TokenTable::load(const std::string& path) {
  // Whoever can write the tokens file can add a token for any tenant.
  struct stat st {};
  if (::stat(path.c_str(), &st) == 0) {
    if ((st.st_mode & (S_IWGRP | S_IWOTH)) != 0) {
      return failed_precondition("tokens file " + path +
                                 " is writable by its group or others, who could add a token for any tenant "
                                 "(chmod go-w " + path + ")");
    }
    if (st.st_uid != ::geteuid() && st.st_uid != 0) {
      return failed_precondition("tokens file " + path + " is owned by uid " + std::to_string(st.st_uid) +
                                 ", not by riccatid's user or root, who could add a token for any tenant");
    }
  }
  RICCATI_ASSIGN_OR_RETURN(const std::string text, read_regular_file(path, "tokens file", kMaxTokensFileBytes));
  TokenTable table;
  std::istringstream lines(text);
  std::string line;
  for (int number = 1; std::getline(lines, line); ++number) {
    std::istringstream fields(line);
    std::string tenant, digest, role, extra;
    if (!(fields >> tenant) || tenant[0] == '#') continue;
    const std::string where = "tokens file " + path + ", line " + std::to_string(number);
    const bool has_role = static_cast<bool>(fields >> digest) && static_cast<bool>(fields >> role);
    if (digest.empty() || (has_role && role != "operator") || (fields >> extra)) {
      return invalid_argument(where + ": expected \"<tenant> sha256:<hex digest>\", and \" operator\" after it for an "
                              "operator's token");
    }
    const bool well_formed = digest.size() == 7 + 64 && digest.rfind("sha256:", 0) == 0 &&
                             digest.find_first_not_of("0123456789abcdef", 7) == std::string::npos;
    if (!well_formed) {
      return invalid_argument(where + ": the token must be given as sha256:<64 lower-case hex digits> (riccatid "
                              "--hash-token prints it), never in clear");
    }
    if (!table.tenants_.emplace(digest, tenant).second) {
      return invalid_argument(where + ": this token is listed twice");
    }
    if (has_role) table.operators_.insert(digest);
  }
  if (table.tenants_.empty()) return invalid_argument("tokens file " + path + " lists no token");
  return table;
}

std::optional<std::string> TokenTable::tenant_for(std::string_view token) const {
  auto it = tenants_.find(token_digest(token));
  if (it == tenants_.end()) return std::nullopt;
  return it->second;
}

bool TokenTable::is_operator(std::string_view token) const { return operators_.count(token_digest(token)) != 0; }

Result<std::shared_ptr<const Authenticator>> Authenticator::create(const std::string& tokens_file) {
  auto auth = std::make_shared<Authenticator>();
  if (!tokens_file.empty()) {
    RICCATI_ASSIGN_OR_RETURN(TokenTable table, TokenTable::load(tokens_file));
    auth->tokens_ = std::move(table);
  }
  return std::shared_ptr<const Authenticator>(std::move(auth));
}

Result<std::string> Authenticator::tenant_for_header(std::string_view authorization) const {
  if (!tokens_) return std::string(kDefaultTenant);
  constexpr std::string_view kScheme = "Bearer ";
  if (authorization.size() <= kScheme.size() || authorization.substr(0, kScheme.size()) != kScheme) {
    return Status(StatusCode::kUnauthenticated, "the authorization metadata must be \"Bearer <token>\"");
  }
  auto tenant = tokens_->tenant_for(authorization.substr(kScheme.size()));
  if (!tenant) return Status(StatusCode::kUnauthenticated, "the bearer token is not valid");
  return *tenant;
}

bool Authenticator::is_operator_header(std::string_view authorization) const {
  if (!tokens_) return true;  // one user, on loopback
  constexpr std::string_view kScheme = "Bearer ";
  if (authorization.size() <= kScheme.size() || authorization.substr(0, kScheme.size()) != kScheme) return false;
  return tokens_->is_operator(authorization.substr(kScheme.size()));
}

bool Authenticator::is_operator(const grpc::ServerContextBase& context) const {
  if (!tokens_) return true;
  const auto& metadata = context.client_metadata();
  const auto header = metadata.find("authorization");
  return header != metadata.end() &&
         is_operator_header(std::string_view(header->second.data(), header->second.size()));
}

Status operator_only(const char* what) {
  return {StatusCode::kPermissionDenied,
          std::string(what) + " is for an operator of riccatid: a token marked \"operator\" in the tokens file "
                              "(\"<tenant> sha256:<digest> operator\"), or SIGHUP to riccatid on its host"};
}

std::string Authenticator::tenant(const grpc::ServerContextBase& context) const {
  if (!tokens_) return std::string(kDefaultTenant);
  const auto& metadata = context.client_metadata();
  const auto header = metadata.find("authorization");
  if (header == metadata.end()) return "";
  auto tenant = tenant_for_header(std::string_view(header->second.data(), header->second.size()));
  return tenant.is_ok() ? tenant.value() : "";
}

grpc::Status TokenAuthProcessor::Process(const InputMetadata& metadata, grpc::AuthContext* /*context*/,
                                         OutputMetadata* /*consumed*/, OutputMetadata* /*response*/) {
  const auto path = metadata.find(":path");
  if (path != metadata.end() && is_public_method(std::string_view(path->second.data(), path->second.size()))) {
    return grpc::Status::OK;
  }
  const auto header = metadata.find("authorization");
  if (header == metadata.end()) {
    return {grpc::StatusCode::UNAUTHENTICATED, "no bearer token: send the metadata \"authorization: Bearer <token>\""};
  }
  const auto tenant = auth_->tenant_for_header(std::string_view(header->second.data(), header->second.size()));
  if (!tenant.is_ok()) return {grpc::StatusCode::UNAUTHENTICATED, tenant.status().message()};
  return grpc::Status::OK;
}

bool is_loopback(const std::string& listen) {
  return listen.rfind("127.", 0) == 0 || listen.rfind("localhost:", 0) == 0 || listen.rfind("[::1]:", 0) == 0;
}

Result<std::shared_ptr<grpc::ServerCredentials>> server_credentials(const SecurityConfig& config,
                                                                    const std::string& listen,
                                                                    std::shared_ptr<const Authenticator> auth,
                                                                    std::string* description) {
  const bool tls = !config.tls_cert.empty() || !config.tls_key.empty();
  const bool loopback = is_loopback(listen);
  if (!tls && !loopback) {
    return invalid_argument("listening on " + listen +
                            " needs TLS (tls_cert and tls_key): plain TCP is allowed on a loopback address only");
  }
  if (!auth->enabled() && !loopback) {
    return invalid_argument("listening on " + listen +
                            " needs a tokens file: without authentication riccatid listens on loopback only");
  }
  std::shared_ptr<grpc::ServerCredentials> credentials;
  if (tls) {
    if (config.tls_cert.empty() || config.tls_key.empty()) {
      return invalid_argument("TLS needs both tls_cert and tls_key");
    }
    RICCATI_ASSIGN_OR_RETURN(const std::string cert, read_regular_file(config.tls_cert, "TLS certificate", kMaxConfigFileBytes));
    RICCATI_RETURN_IF_ERROR(check_private_key_mode(config.tls_key));
    RICCATI_ASSIGN_OR_RETURN(const std::string key, read_regular_file(config.tls_key, "TLS key", kMaxConfigFileBytes));
    grpc::SslServerCredentialsOptions options(config.tls_client_ca.empty()
                                                  ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                                  : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
    options.pem_key_cert_pairs.push_back({key, cert});
    if (!config.tls_client_ca.empty()) {
      RICCATI_ASSIGN_OR_RETURN(options.pem_root_certs, read_regular_file(config.tls_client_ca, "TLS client CA", kMaxConfigFileBytes));
    }
    RICCATI_RETURN_IF_ERROR(check_tls_files(config, cert, key, options.pem_root_certs));
    credentials = grpc::SslServerCredentials(options);
    *description = config.tls_client_ca.empty() ? "tls" : "mutual-tls";
  } else {
    // Plain bytes on the wire, but only from this host. Local credentials
    // (unlike insecure ones) can carry the token processor.
    credentials = grpc::experimental::LocalServerCredentials(LOCAL_TCP);
    *description = "plain-tcp-loopback";
  }
  if (auth->enabled()) {
    *description += ", tokens=" + std::to_string(auth->tokens());
    credentials->SetAuthMetadataProcessor(std::make_shared<TokenAuthProcessor>(std::move(auth)));
  } else {
    *description += ", no authentication";
  }
  return credentials;
}

}  // namespace riccati::service
