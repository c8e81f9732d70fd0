// Writes the fuzzers' seed corpora: small valid inputs that mutations start
// from, so the fuzzers reach the parsers' and validators' depths quickly.
//   seed_writer OUT_DIR   ->  OUT_DIR/{csv,mat,request}/...
#include <matio.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "riccati/v1/jobs.pb.h"
#include "riccati/v1/sessions.pb.h"
#include "support/mat_files.hpp"
#include "support/requests.hpp"

namespace fs = std::filesystem;

namespace {

void write_file(const fs::path& path, const std::string& bytes) {
  std::ofstream(path, std::ios::binary) << bytes;
}

// T [1 x n], U [2 x n], Y [2 x n] as the 1999 toolbox stores them.
bool write_mat(const fs::path& path, mat_ft version, matio_compression compression, int n) {
  mat_t* mat = Mat_CreateVer(path.c_str(), nullptr, version);
  if (mat == nullptr) return false;
  std::vector<double> t(n), u(2 * n), y(2 * n);
  for (int k = 0; k < n; ++k) {
    t[k] = k;
    u[2 * k] = 1e-4;
    u[2 * k + 1] = 2e-5;
    y[2 * k] = 0.1 + 1e-3 * k;
    y[2 * k + 1] = 0.05 + 1e-3 * k;
  }
  bool ok = true;
  for (auto [name, rows, data] : {std::tuple{"T", 1, t.data()}, {"U", 2, u.data()}, {"Y", 2, y.data()}}) {
    std::size_t dims[2] = {static_cast<std::size_t>(rows), static_cast<std::size_t>(n)};
    matvar_t* var = Mat_VarCreate(name, MAT_C_DOUBLE, MAT_T_DOUBLE, 2, dims, data, 0);
    ok = ok && var != nullptr && Mat_VarWrite(mat, var, compression) == 0;
    Mat_VarFree(var);
  }
  Mat_Close(mat);
  return ok;
}

// The request fuzzer's framing: a selector byte, then for a session the
// length of the CreateSessionRequest in two bytes, then the batch.
std::string session_seed(const riccati::v1::CreateSessionRequest& create, int samples) {
  riccati::v1::MeasurementBatch batch;
  for (int k = 0; k < samples; ++k) {
    auto* m = batch.add_measurements();
    m->set_t(k);
    for (double u : {1e-4, 2e-5}) m->add_u(u);
    for (double y : {0.1 + 1e-3 * k, 0.05 + 1e-3 * k}) m->add_y(y);
  }
  const std::string c = create.SerializeAsString();
  std::string out(1, '\0');
  out += static_cast<char>(c.size() & 0xff);
  out += static_cast<char>((c.size() >> 8) & 0xff);
  return out + c + batch.SerializeAsString();
}

std::string identification_seed(const riccati::v1::IdentificationSpec& spec) {
  return std::string(1, '\1') + spec.SerializeAsString();
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: seed_writer OUT_DIR\n");
    return 2;
  }
  const fs::path out = argv[1];
  for (const char* sub : {"csv", "mat", "request"}) fs::create_directories(out / sub);

  write_file(out / "csv/two_tank.csv",
             "t,F1,F2,h1,h2\n0,1e-4,0,0.1,0.05\n1,1e-4,0,0.101,0.051\n2,1e-4,2e-5,0.102,0.052\n");
  write_file(out / "csv/extra_columns_crlf.csv",
             "h2,t,note,F2,F1,h1\r\n0.05,0.0,a,0,1e-4,0.1\r\n0.051,0.5,b,0,1e-4,0.101\r\n");
  if (!write_mat(out / "mat/v5.mat", MAT_FT_MAT5, MAT_COMPRESSION_NONE, 8) ||
      !write_mat(out / "mat/v5_zlib.mat", MAT_FT_MAT5, MAT_COMPRESSION_ZLIB, 8)) {
    std::fprintf(stderr, "seed_writer: could not write the MAT seeds\n");
    return 1;
  }
  // Variables beside T and Y that the reader must skip: a struct and a cell.
  {
    namespace mat5 = riccati::testing::mat5;
    const std::string notes = mat5::struct_with_empty_field("notes", "rig");
    const std::string labels = mat5::cell("labels", {1, 1}, mat5::numeric_matrix({"", {1, 1}, {1.0}}));
    const std::vector<riccati::testing::MatVariable> variables = {{"T", {1, 3}, {0, 1, 2}}, {"Y", {1, 3}, {1, 2, 3}}};
    write_file(out / "mat/others.mat", riccati::testing::mat5_file(variables, false, notes + labels));
    write_file(out / "mat/others_zlib.mat",
               riccati::testing::mat5_file(variables, true, mat5::compressed(notes) + mat5::compressed(labels)));
  }

  using namespace riccati;
  auto ekf = testing::two_tank_session();
  write_file(out / "request/session_ekf", session_seed(ekf, 4));
  auto ukf = ekf;
  ukf.mutable_filter()->set_kind(v1::FILTER_KIND_UKF);
  ukf.mutable_filter()->mutable_ukf()->set_weights(v1::SIGMA_WEIGHTS_SCALED);
  write_file(out / "request/session_ukf", session_seed(ukf, 4));
  auto cvode = ekf;
  cvode.mutable_filter()->mutable_integrator()->set_kind(v1::INTEGRATOR_KIND_CVODE_BDF);
  write_file(out / "request/session_cvode", session_seed(cvode, 3));
  auto spec = testing::hensen_spec("ds", 2);
  write_file(out / "request/identification_ekf", identification_seed(spec));
  spec.mutable_filter()->set_kind(v1::FILTER_KIND_UKF);
  spec.mutable_filter()->set_inversion(v1::GAIN_INVERSION_PSEUDO_INVERSE);
  write_file(out / "request/identification_ukf_pinv", identification_seed(spec));
  return 0;
}
