// omni-bench-posegraph (./omni bench posegraph): our Ceres batch back end beside MRPT's
// `graph-slam --levmarq` (Debian mrpt-apps, with its Dijkstra spanning-tree initialisation) on
// every graph in <datasets>/pose-graphs, same files, same run. Both run as processes (wall time
// includes reading and writing the files); both results are scored by the same evaluator
// (omni::pgm::ComputeChi2: the input graph's edges and information matrices at the vertex
// poses of each system's output file). Prints a table and writes out/bench/posegraph.jsonl.
#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "omni/bench/measured_run.h"
#include "omni/io/g2o.h"
#include "omni/pose_graph_mapper/chi2.h"

namespace fs = std::filesystem;

namespace {

std::string ReadAll(const std::string& path) {
  std::ifstream f(path);
  std::stringstream s;
  s << f.rdbuf();
  return s.str();
}

std::string LastLine(const std::string& text) {
  std::istringstream in(text);
  std::string line, last;
  while (std::getline(in, line))
    if (!line.empty()) last = line;
  return last;
}

// chi^2 of `graph`'s edges at the vertex poses stored in `result_path`.
std::optional<double> ScoreResult(const omni::io::PoseGraph& graph, const std::string& result_path,
                                  std::string* why) {
  auto res = omni::io::ReadPoseGraph(result_path);
  if (!res.ok()) {
    *why = res.error().message;
    return std::nullopt;
  }
  omni::io::PoseGraph g = graph;
  g.vertices2 = res->vertices2;
  g.vertices3 = res->vertices3;
  auto chi2 = omni::pgm::ComputeChi2(g);
  if (!chi2.ok()) {
    *why = result_path + ": " + chi2.error().message;
    return std::nullopt;
  }
  return *chi2;
}

struct Row {
  std::string system, dataset, status = "ok";
  double chi2_before = 0, chi2 = -1, wall_s = 0;
  int iterations = -1;
  long max_rss_kb = 0;
};

std::string Num(double v, int prec = 4) {
  if (v < 0) return "-";
  std::ostringstream s;
  s.precision(prec);
  s << v;
  return s.str();
}

void Usage(FILE* f) {
  std::fprintf(
      f,
      "usage: omni bench posegraph [--datasets DIR] [--out DIR] [--only NAME[,NAME]]\n"
      "                            [--peer PATH|none] [--timeout S] [--repeat N]\n"
      "  Runs ours (omni-posegraph optimize) and the peer (MRPT graph-slam --levmarq,\n"
      "  Debian mrpt-apps) on every DIR/pose-graphs/*.g2o, scores both output files with\n"
      "  our chi^2 evaluator (input edges and information at the output poses), prints a\n"
      "  table and writes OUT/posegraph.jsonl (default out/bench). Without graph-slam the\n"
      "  peer rows say 'absent'. DIR defaults to $OMNI_DATASETS_DIR or ../shared/datasets.\n"
      "  --repeat N runs both N times, alternating, and reports each side's median wall time\n"
      "  (default 1).\n");
}

}  // namespace

int main(int argc, char** argv) {
  std::string datasets = std::getenv("OMNI_DATASETS_DIR") ? std::getenv("OMNI_DATASETS_DIR")
                                                          : std::string(OMNI_DEFAULT_DATASETS);
  std::string out_dir = "out/bench", peer = "", only;
  double timeout_s = 600;
  int repeat = 1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto next = [&]() -> std::string {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "omni bench posegraph: %s needs a value\n", a.c_str());
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "-h" || a == "--help") {
      Usage(stdout);
      return 0;
    } else if (a == "--datasets") {
      datasets = next();
    } else if (a == "--out") {
      out_dir = next();
    } else if (a == "--peer") {
      peer = next();
    } else if (a == "--only") {
      only = "," + next() + ",";
    } else if (a == "--timeout") {
      timeout_s = std::atof(next().c_str());
    } else if (a == "--repeat") {
      repeat = std::atoi(next().c_str());
      if (repeat < 1 || repeat > 100) {
        std::fprintf(stderr, "omni bench posegraph: --repeat needs an integer in [1, 100]\n");
        return 2;
      }
    } else {
      std::fprintf(stderr, "omni bench posegraph: unknown argument '%s'\n", a.c_str());
      Usage(stderr);
      return 2;
    }
  }
  const fs::path graphs_dir = fs::path(datasets) / "pose-graphs";
  if (!fs::is_directory(graphs_dir)) {
    std::fprintf(stderr, "omni bench posegraph: %s is absent: no graphs to run\n",
                 graphs_dir.c_str());
    return 1;
  }
  const fs::path self = fs::read_symlink("/proc/self/exe");
  const std::string ours = (self.parent_path() / "omni-posegraph").string();
  if (access(ours.c_str(), X_OK) != 0) {
    std::fprintf(stderr, "omni bench posegraph: %s is not built\n", ours.c_str());
    return 1;
  }
  if (peer.empty()) peer = omni::bench::FindInPath("graph-slam");
  if (peer == "none") peer.clear();
  if (peer.empty())
    std::printf(
        "note: MRPT's graph-slam is not installed (Debian package mrpt-apps): the peer is "
        "skipped and its rows say 'absent'.\n");

  const fs::path work = fs::path(out_dir) / "posegraph";
  fs::create_directories(work);
  std::vector<fs::path> files;
  for (const auto& e : fs::directory_iterator(graphs_dir))
    if (e.path().extension() == ".g2o") files.push_back(e.path());
  std::sort(files.begin(), files.end());

  std::vector<Row> rows;
  std::printf("%-15s %-4s %6s %6s %11s | %11s %11s | %8s %8s | %5s %5s | %s\n", "dataset", "type",
              "V", "E", "chi2 input", "chi2 ours", "chi2 MRPT", "wall ours", "wall MRPT", "it o",
              "it M", "goals (chi2 <= peer, wall <= peer/3)");
  for (const auto& file : files) {
    const std::string name = file.stem().string();
    if (!only.empty() && only.find("," + name + ",") == std::string::npos) continue;
    auto graph = omni::io::ReadPoseGraph(file.string());
    if (!graph.ok()) {
      std::printf("%-15s unreadable: %s\n", name.c_str(), graph.error().message.c_str());
      continue;
    }
    const bool is3d = graph->is_3d();
    const auto chi2_in = omni::pgm::ComputeChi2(*graph);
    const double chi2_before = chi2_in.ok() ? *chi2_in : -1;

    auto run_ours = [&]() {
      Row o{"omni-ceres", name};
      o.chi2_before = chi2_before;
      const std::string out = (work / (name + ".ours.g2o")).string();
      const std::string log = (work / (name + ".ours.log")).string();
      omni::bench::MeasuredRun r = omni::bench::RunMeasured(
          {ours, "optimize", file.string(), "-o", out, "--json"}, log, timeout_s);
      o.wall_s = r.wall_s;
      o.max_rss_kb = r.peak_rss_kb;
      const std::string text = ReadAll(log);
      if (r.timed_out) {
        o.status = "timeout";
      } else if (r.exit_code != 0) {
        o.status = "failed: " + LastLine(text);
      } else {
        if (const size_t at = text.find("\"iterations\": "); at != std::string::npos)
          o.iterations = std::atoi(text.c_str() + at + 14);
        std::string why;
        auto c = ScoreResult(*graph, out, &why);
        if (c)
          o.chi2 = *c;
        else
          o.status = "unscorable: " + why;
      }
      return o;
    };
    auto run_peer = [&]() {
      Row p{"mrpt-graph-slam", name};
      p.chi2_before = chi2_before;
      if (peer.empty()) {
        p.status = "absent";
        return p;
      }
      const std::string out = (work / (name + ".mrpt.g2o")).string();
      const std::string log = (work / (name + ".mrpt.log")).string();
      fs::remove(out);
      omni::bench::MeasuredRun r = omni::bench::RunMeasured(
          {peer, "--levmarq", is3d ? "--3d" : "--2d", "-i", file.string(), "-o", out}, log,
          timeout_s);
      p.wall_s = r.wall_s;
      p.max_rss_kb = r.peak_rss_kb;
      const std::string text = ReadAll(log);
      int it = -1;  // MRPT prints "Iter: k ,total sqr. err: ..." per iteration
      for (size_t at = text.find("Iter: "); at != std::string::npos;
           at = text.find("Iter: ", at + 6))
        it = std::max(it, std::atoi(text.c_str() + at + 6) + 1);
      p.iterations = it;
      if (r.timed_out) {
        p.status = "timeout";
      } else if (r.exit_code != 0 || !fs::exists(out)) {
        p.status = "failed (exit " + std::to_string(r.exit_code) + ", log " + log + ")";
      } else {
        std::string why;
        auto c = ScoreResult(*graph, out, &why);
        if (c)
          p.chi2 = *c;
        else
          p.status = "unscorable: " + why;
      }
      return p;
    };
    // Ours and the peer alternate, `repeat` times; the wall time is each side's median (the
    // machine's load varies from run to run), the rest is the last run's.
    Row o, p;
    std::vector<double> walls_o, walls_p;
    for (int k = 0; k < repeat; ++k) {
      o = run_ours();
      p = run_peer();
      walls_o.push_back(o.wall_s);
      walls_p.push_back(p.wall_s);
    }
    o.wall_s = omni::bench::Median(walls_o);
    p.wall_s = omni::bench::Median(walls_p);
    std::string goals;
    if (o.chi2 >= 0 && p.chi2 >= 0) {
      goals = std::string(o.chi2 <= p.chi2 * (1 + 1e-6) ? "chi2 ok" : "chi2 WORSE");
      goals += o.wall_s <= p.wall_s / 3 ? ", wall ok" : ", wall > 1/3";
      if (p.chi2 > 0) goals += " (chi2 x" + Num(p.chi2 / std::max(o.chi2, 1e-12), 3) + " lower)";
    } else {
      goals = o.status != "ok" ? "ours " + o.status : "peer " + p.status;
    }
    const size_t nv = is3d ? graph->vertices3.size() : graph->vertices2.size();
    const size_t ne = is3d ? graph->edges3.size() : graph->edges2.size();
    std::printf("%-15s %-4s %6zu %6zu %11s | %11s %11s | %7.2fs %7s | %5s %5s | %s\n", name.c_str(),
                is3d ? "SE3" : "SE2", nv, ne, Num(chi2_before).c_str(), Num(o.chi2, 6).c_str(),
                Num(p.chi2, 6).c_str(), o.wall_s,
                p.status == "absent" ? "absent" : (Num(p.wall_s, 3) + "s").c_str(),
                o.iterations < 0 ? "-" : std::to_string(o.iterations).c_str(),
                p.iterations < 0 ? "-" : std::to_string(p.iterations).c_str(), goals.c_str());
    std::fflush(stdout);
    rows.push_back(o);
    rows.push_back(p);
  }

  const fs::path jsonl = fs::path(out_dir) / "posegraph.jsonl";
  std::ofstream js(jsonl);
  for (const auto& r : rows) {
    js << "{\"system\": \"" << r.system << "\", \"dataset\": \"" << r.dataset
       << "\", \"chi2_before\": " << (r.chi2_before >= 0 ? Num(r.chi2_before, 10) : "null")
       << ", \"chi2\": " << (r.chi2 >= 0 ? Num(r.chi2, 10) : "null")
       << ", \"wall_s\": " << (r.status == "absent" ? "null" : Num(r.wall_s, 4))
       << ", \"iterations\": " << (r.iterations >= 0 ? std::to_string(r.iterations) : "null")
       << ", \"max_rss_mb\": " << Num(r.max_rss_kb / 1024.0, 4) << ", \"status\": \"";
    for (char c : r.status) {
      if (c == '"' || c == '\\') js << '\\';
      js << c;
    }
    js << "\"}\n";
  }
  std::printf(
      "\nchi2 = sum e^T Omega e over the input graph's edges (g2o errors, the file's information "
      "matrices) at each system's output poses, scored by our evaluator.\nwall = whole process "
      "(read, initialise, optimise, write), median of %d run(s) each, alternating. Outputs and "
      "logs: %s\nwrote %s\n",
      repeat, work.c_str(), jsonl.c_str());
  return 0;
}
