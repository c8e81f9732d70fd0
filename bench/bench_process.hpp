// A server the benchmarks start as a child process (riccatid, the echo), so
// that the load generator's own CPU is apart from the server's: its CPU time
// and resident memory are read from /proc, the generator's from getrusage.
#pragma once

#include <sched.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

namespace riccati::bench {

// CPU seconds (user + system) of this process so far.
inline double own_cpu_seconds() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  const auto seconds = [](const timeval& t) { return static_cast<double>(t.tv_sec) + 1e-6 * static_cast<double>(t.tv_usec); };
  return seconds(usage.ru_utime) + seconds(usage.ru_stime);
}

class ServerProcess {
 public:
  // Runs `argv` with "--port-file <dir>/port" appended (and, when
  // `http_port` is set, "--http-port-file <dir>/http-port"), on the CPUs
  // `cpus` alone when it names any, and waits for the port it listens on.
  ServerProcess(std::vector<std::string> argv, const std::filesystem::path& dir, bool http_port = false,
                const std::vector<int>& cpus = {}) {
    std::filesystem::create_directories(dir);
    const auto port_file = dir / "port", http_port_file = dir / "http-port";
    std::filesystem::remove(port_file);
    std::filesystem::remove(http_port_file);
    argv.insert(argv.end(), {"--port-file", port_file.string()});
    if (http_port) argv.insert(argv.end(), {"--http-port-file", http_port_file.string()});
    pid_ = fork();
    if (pid_ == 0) {
      if (!cpus.empty()) {
        cpu_set_t set;
        CPU_ZERO(&set);
        for (int cpu : cpus) CPU_SET(cpu, &set);
        if (sched_setaffinity(0, sizeof set, &set) != 0) {
          std::perror("the server's CPUs (sched_setaffinity)");
          _exit(126);
        }
      }
      std::vector<char*> args;
      for (auto& a : argv) args.push_back(a.data());
      args.push_back(nullptr);
      execv(args[0], args.data());
      std::perror(args[0]);
      _exit(127);
    }
    for (int i = 0; i < 3000 && (port_ <= 0 || (http_port && http_port_ <= 0)); ++i) {
      std::ifstream(port_file) >> port_;
      if (http_port) std::ifstream(http_port_file) >> http_port_;
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        break;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
  }
  ~ServerProcess() {
    if (pid_ <= 0) return;
    kill(pid_, SIGTERM);
    int status = 0;
    waitpid(pid_, &status, 0);
  }
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  bool running() const { return pid_ > 0 && port_ > 0; }
  int port() const { return port_; }
  int http_port() const { return http_port_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

  // CPU seconds (user + system, all threads) the server has used so far.
  double cpu_seconds() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/stat");
    std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    // Fields after the command name (which may hold spaces), from its ')'.
    std::istringstream fields(text.substr(text.rfind(')') + 2));
    std::string field;
    unsigned long long utime = 0, stime = 0;
    for (int i = 3; i <= 15 && fields >> field; ++i) {
      if (i == 14) utime = std::stoull(field);
      if (i == 15) stime = std::stoull(field);
    }
    return static_cast<double>(utime + stime) / static_cast<double>(sysconf(_SC_CLK_TCK));
  }

  // Resident memory (VmRSS) in bytes.
  long long rss_bytes() const {
    std::ifstream in("/proc/" + std::to_string(pid_) + "/status");
    std::string key;
    long long kib = 0;
    while (in >> key) {
      if (key == "VmRSS:") {
        in >> kib;
        break;
      }
      in.ignore(1 << 20, '\n');
    }
    return kib * 1024;
  }

 private:
  pid_t pid_ = -1;
  int port_ = 0;
  int http_port_ = 0;
};

}  // namespace riccati::bench
